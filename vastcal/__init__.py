"""vastcal: acquisition and calibration for a rotating-capillary light microscope.

Pipeline stages (pure functions of arrays and session metadata): :mod:`vastcal.calibrate`,
:mod:`vastcal.reconstruct`, :mod:`vastcal.measure`, :mod:`vastcal.report`. Hardware is reached
only through :mod:`vastcal.devices` by :mod:`vastcal.acquire`.
"""

__version__ = "0.1.0"
