"""Calibration of the camera pose of every view from the views themselves.

Public API::

    calibrate_views(images, K, distance, theta0_deg, settings, ...)                      -> CalibrationResult
    ColourModel.from_group(run["colour_model"]).foreground_probability(images)           -> (N, H, W) float32

Where things are: the methods' objectives (:mod:`.methods`, :mod:`.objective`), the coarse-to-fine driver
(:mod:`.coarse_to_fine`), the CMA-ES wrapper (:mod:`.optimise`), the stages (:mod:`.stage`, ``stage_*``). Outside
the package: reading a session and storing its run (:func:`vastcal.calibration_session.calibrate_session`) and
the progress display's side (:mod:`vastcal.calibration_progress`).

The default method is ``coherence`` (vastcal's own cost); ``pi`` is the paper's objective as published, ``vr`` the
voxel-residual baseline.
"""

from vastcal.calibrate.run import CalibrationResult, Marks, References, calibrate_views
from vastcal.config import CalibrationSettings, Level
from vastcal.segmentation import ColourModel, Gaussian, fit_automatic, fit_from_mask, fit_from_scribbles

__all__ = [
    "CalibrationResult",
    "CalibrationSettings",
    "ColourModel",
    "Gaussian",
    "Level",
    "Marks",
    "References",
    "calibrate_views",
    "fit_automatic",
    "fit_from_mask",
    "fit_from_scribbles",
]
