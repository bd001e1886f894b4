"""Calibration of the camera pose of every view from the views themselves.

Public API::

    calibrate_session(path_or_session, method="coherence", seed=..., free=..., mask=...) -> CalibrationResult
    calibrate_views(images, K, distance, theta0_deg, settings, ...)                      -> CalibrationResult
    ColourModel.from_group(run["colour_model"]).foreground_probability(images)           -> (N, H, W) float32

Where things are: the methods' objectives (:mod:`.methods`, :mod:`.objective`), the coarse-to-fine driver
(:mod:`.coarse_to_fine`), the CMA-ES wrapper (:mod:`.optimise`), the stages (:mod:`.stage`, ``stage_*``), the
progress display's side (:mod:`.observer`). The default method is ``coherence`` (vastcal's own cost); ``pi`` is the
paper's objective as published, ``vr`` the voxel-residual baseline.
"""

from vastcal.calibrate.run import CalibrationResult, Marks, References, calibrate_views
from vastcal.calibrate.session_run import calibrate_session, load_colour_model
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
    "calibrate_session",
    "calibrate_views",
    "load_colour_model",
    "fit_automatic",
    "fit_from_mask",
    "fit_from_scribbles",
]
