"""Real hardware drivers: the rotation stage (serial, Zaber ASCII) and the GenTL camera.

Drivers implement the interfaces of :mod:`vastcal.devices` and raise :mod:`vastcal.errors`;
they never import the pipeline stages.
"""
