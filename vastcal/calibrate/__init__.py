"""Calibration of the camera pose of every view (probabilistic inference, voxel-residual baseline).

Public API::

    calibrate_session(path_or_session, method="pi", seed=..., free=..., mask=...) -> CalibrationResult
    calibrate_views(images, K, distance, theta0_deg, ...)                        -> CalibrationResult
    ColourModel.from_group(run["colour_model"]).foreground_probability(images)   -> (N, H, W) float32
"""

from vastcal.calibrate.run import CalibrationResult, CalibrationSettings, Level, calibrate_views
from vastcal.calibrate.session_run import calibrate_session, load_colour_model
from vastcal.segmentation import ColourModel, Gaussian, fit_automatic, fit_from_mask, fit_from_scribbles

__all__ = [
    "CalibrationResult",
    "CalibrationSettings",
    "ColourModel",
    "Gaussian",
    "Level",
    "calibrate_session",
    "calibrate_views",
    "load_colour_model",
    "fit_automatic",
    "fit_from_mask",
    "fit_from_scribbles",
]
