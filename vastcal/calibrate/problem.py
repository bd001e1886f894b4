"""What every start of a calibration shares: the specimen maps, the parameter space and the per-level objectives.

The images enter once: the colour model (:func:`vastcal.segmentation.colour_model_for`), then the specimen
posteriors at the finest level's size (:meth:`Problem.build`). Each level resizes those maps, carves the region
where the specimen can be and builds the method's objective from them (:data:`.methods.OBJECTIVES`).
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from vastcal.calibrate.methods import objective_factory
from vastcal.calibrate.objective import LevelMaps, Objective, Prior, WithPrior
from vastcal.calibrate.parameters import ParameterSpace
from vastcal.calibrate.region import Region, specimen_region
from vastcal.calibrate.sampling import resize_stack
from vastcal.config import CalibrationSettings
from vastcal.errors import EmptyHullError
from vastcal.segmentation import ColourModel, specimen_maps_within
from vastcal.segmentation.colour_densities import log_colour_densities

log = logging.getLogger(__name__)


def _area_resize(images: np.ndarray, factor: float) -> np.ndarray:
    if factor <= 1.0:
        return images
    h, w = images.shape[1:3]
    size = (max(4, int(round(w / factor))), max(4, int(round(h / factor))))
    return np.stack([cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in images])


DENSITY_METHODS = ("pi",)
"""The methods whose objective reads the colour densities (:attr:`.objective.LevelMaps.densities`)."""


def _resized_log_densities(log_dens: np.ndarray, factor: float) -> np.ndarray:
    """(2, N, h, w) log densities area-averaged by ``factor`` (in the log domain: a density of the area's mean log)."""
    if factor <= 1.0:
        return log_dens
    two, n = log_dens.shape[:2]
    small, _ = resize_stack(log_dens.reshape(two * n, *log_dens.shape[2:]), factor)
    return small.reshape(two, n, *small.shape[1:])


class Problem:
    """The maps every start shares, the parameter space and the settings; builds each level's objectives.

    Attributes:
        pf: (N, h, w) specimen posteriors at the finest level's size; sil_src: the rough silhouettes made from them
            (or from given masks), 0/1.
        K_small: intrinsics of ``pf``'s pixels.
        log_densities: (2, N, h, w) log colour densities of the specimen and the background at ``pf``'s size
            (:func:`vastcal.segmentation.colour_densities.log_colour_densities`), for the methods that read them;
            else None.
    """

    def __init__(
        self,
        pf: np.ndarray,
        sil_src: np.ndarray,
        K_small: np.ndarray,
        distance: float,
        space: ParameterSpace,
        settings: CalibrationSettings,
        log_densities: np.ndarray | None = None,
    ) -> None:
        self.pf, self.sil_src, self.K_small, self.log_densities = pf, sil_src, K_small, log_densities
        self.distance, self.space, self.settings = distance, space, settings
        self.factory = objective_factory(settings.method)
        self.prior = Prior.of(space.theta0, settings)
        self._region0: tuple[Region, np.ndarray, np.ndarray] | None = None  # (region, K, silhouettes) of level 0
        self._shared: tuple[int, dict] = (-1, {})  # what the objectives of one level share (one level at a time)

    @classmethod
    def build(
        cls,
        images: np.ndarray,
        model: ColourModel,
        K: np.ndarray,
        distance: float,
        space: ParameterSpace,
        settings: CalibrationSettings,
        silhouettes: np.ndarray | None = None,
    ) -> Problem:
        """Posteriors once, at the finest level's resolution (area-averaged colours: less noise, 4× fewer pixels),
        a sub-revolution at a time within ``settings.memory_mb``; rough silhouettes from ``silhouettes`` (N, H, W)
        when given, else the posteriors above ``settings.threshold``."""
        w_full = images.shape[2]
        finest = max(1.0, w_full / max(lv.width_px for lv in settings.levels))
        small = _area_resize(images, finest)
        pf = specimen_maps_within(model, small, settings.memory_mb, band_px=max(1.0, 3.0 / finest))  # 3 px rim band
        dens = log_colour_densities(model, small) if settings.method in DENSITY_METHODS else None
        del small  # the maps are all that is kept of the resized frames
        if silhouettes is not None:
            sil_full = (np.asarray(silhouettes) > 0).astype(np.float32)
            size = (pf.shape[2], pf.shape[1])
            sil_src = np.stack([cv2.resize(s, size, interpolation=cv2.INTER_AREA) for s in sil_full])
        else:  # 0/1: resize_stack averages it in float32 one map at a time
            sil_src = (pf > settings.threshold).astype(np.uint8)
        S_small = np.diag([pf.shape[2] / w_full, pf.shape[1] / images.shape[1], 1.0])
        S_small[:2, 2] = 0.5 * np.diag(S_small)[:2] - 0.5
        return cls(pf, sil_src, S_small @ np.asarray(K, float), float(distance), space, settings, dens)

    def _first_region(self) -> tuple[Region, np.ndarray, np.ndarray]:
        """The region carved from the coarsest rough silhouettes under θ0 with the box's displacement bound."""
        if self._region0 is None:
            st, space = self.settings, self.space
            f0 = max(1.0, self.pf.shape[2] / st.levels[0].width_px)
            sil0, S0 = resize_stack(self.sil_src, f0)
            coarse_sil, K_region = sil0 > 0.5, S0 @ self.K_small
            region = specimen_region(
                K_region,
                self.distance,
                space.theta0,
                space.half_width,
                space.free_mask,
                coarse_sil,
                st.levels[0].voxels,
                max_tolerance_px=st.region_tolerance * coarse_sil.shape[1],
            )
            self._region0 = (region, K_region, coarse_sil)
        return self._region0

    def _region(self, li: int, theta: np.ndarray) -> Region:
        """Level 0's region, or one carved around θ (degrees) with a small tolerance for a later level."""
        region0, K_region, coarse_sil = self._first_region()
        if li == 0:
            return region0
        space = self.space
        try:
            return specimen_region(
                K_region,
                self.distance,
                theta,
                space.half_width,
                np.zeros_like(space.free_mask),
                coarse_sil,
                self.settings.levels[li].voxels,
                extra_px=self.settings.refine_tolerance_px,
            )
        except EmptyHullError:
            raise EmptyHullError(
                f"the coarse search ended at a pose where the {theta.size - 3} views share no specimen "
                f"(yaw {theta[0]:+.2f}°, pitch {theta[1]:+.2f}°, γ {theta[2]:+.3f}°): their silhouettes do not pin "
                f"down the axis; take more views or hold more of θ fixed (--free)"
            ) from None

    def level(self, li: int, x: np.ndarray) -> LevelMaps:
        """The maps, region and intrinsics of level ``li`` around the free coordinates ``x``."""
        lv = self.settings.levels[li]
        factor = max(1.0, self.pf.shape[2] / lv.width_px)
        maps_pf, S = resize_stack(self.pf, factor)
        theta = self.space.theta(x)[0]
        region = self._region(li, theta)
        if self._shared[0] != li:
            self._shared = (li, {})  # the previous level's, before the next is made
        return LevelMaps(
            li,
            maps_pf,
            lambda: resize_stack(self.sil_src, factor)[0],
            S @ self.K_small,
            self.distance,
            region,
            theta,
            lv.edge_lines,
            self._shared[1],
            None if self.log_densities is None else lambda: _resized_log_densities(self.log_densities, factor),
            self._box(li),
        )

    def _box(self, li: int) -> tuple[np.ndarray, np.ndarray, float]:
        """The first level's region's bounds and level ``li``'s voxel edge in them: the first region's edge scaled by
        the levels' voxel counts (the same grid for every θ of the level, its judge's too)."""
        region0 = self._first_region()[0]
        levels = self.settings.levels
        size = region0.voxel_size * (levels[0].voxels / levels[li].voxels) ** (1.0 / 3.0)
        return region0.lower, region0.upper, float(size)

    def objective(self, level: LevelMaps, *, exact: bool = False, local_zooms: int = 0) -> Objective:
        """The method's data objective of ``level`` (:class:`.objective.ObjectiveFactory`)."""
        return self.factory(level, self.settings, exact=exact, local_zooms=local_zooms)

    def cost(self, data: Objective) -> WithPrior:
        """``data`` plus the prior."""
        return WithPrior(data, self.prior)
