"""vastcal: acquisition and calibration for a rotating-capillary light microscope.

What a Python user needs, importable from ``vastcal`` itself::

    import vastcal

    with vastcal.Session.open("S.h5") as s:          # a session (vastcal.session)
        print(s.n_views, s.angles_deg)
    vastcal.calibrate_session("S.h5")                # calibration run stored in the session
    m = vastcal.reconstruct_session("S.h5")          # hull, volume (mm³) and area (mm²) stored in it
    summary = vastcal.run_session("S.h5")            # calibrate, reconstruct and report in one call

Layers, each importing only from the ones below it: :mod:`vastcal.errors` and :mod:`vastcal.config`;
:mod:`vastcal.session` (the file); pure functions of arrays — :mod:`vastcal.geometry`, :mod:`vastcal.voxels`,
:mod:`vastcal.hull`, :mod:`vastcal.measure`, :mod:`vastcal.qc`, :mod:`vastcal.uncertainty`; the stages that
read a session and store their runs — :mod:`vastcal.calibrate`, :mod:`vastcal.reconstruct`; the report
(:mod:`vastcal.report`) and :mod:`vastcal.pipeline`; hardware is reached only through :mod:`vastcal.devices`
by :mod:`vastcal.acquire`; :mod:`vastcal.cli` is the command line.

The names below are imported when first used, so ``import vastcal`` (and ``vastcal --help``) stays quick.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_PUBLIC = {
    "Session": "vastcal.session",
    "SessionWriter": "vastcal.session",
    "calibrate_session": "vastcal.calibration_session",
    "CalibrationResult": "vastcal.calibrate",
    "reconstruct_session": "vastcal.reconstruct",
    "visual_hull": "vastcal.hull",
    "measure_hull": "vastcal.measure",
    "Measurement": "vastcal.measure",
    "run_session": "vastcal.pipeline",
    "RunSummary": "vastcal.pipeline",
    "write_report": "vastcal.report",
    "load_config": "vastcal.config",
    "VastcalError": "vastcal.errors",
}
"""Each public name and the module that defines it."""

__all__ = ["__version__", *sorted(_PUBLIC)]


def __getattr__(name: str) -> Any:
    """Import a public name's module on first use (PEP 562)."""
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'vastcal' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
