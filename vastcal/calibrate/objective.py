"""What a calibration cost is: the :class:`Objective` protocol, the inputs of one level, and the prior as a term.

An objective maps a population of poses θ (B, 3 + N) in degrees — [yaw, pitch, γ, ω_0 … ω_{N−1}] — to B costs,
lower is better. Each method builds its objective for one resolution level from a :class:`LevelMaps`
(:data:`vastcal.calibrate.methods.OBJECTIVES`); :class:`WithPrior` adds the Gaussian prior on the rolls and the yaw.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from vastcal.calibrate.region import Region
from vastcal.config import CalibrationSettings
from vastcal.voxels import VoxelGrid


class Objective(Protocol):
    """A batch cost: θ (B, 3 + N) degrees → (B,) costs, lower is better."""

    def __call__(self, theta_deg: np.ndarray) -> np.ndarray: ...


@dataclass
class LevelMaps:
    """The inputs of one level's objective.

    Attributes:
        index: the level (0 = coarsest).
        pf: (N, h, w) specimen posteriors resized to the level.
        silhouettes: makes the (N, h, w) rough silhouettes at the level (0..1; VR), on demand.
        K: 3×3 intrinsics, 0-based pixels of the level's maps.
        distance: camera-to-axis distance, world units.
        region: the voxels where the specimen can be (world units, axis = x).
        theta: (3 + N,) θ (degrees) the level starts from: the coherence cost finds its edges under it.
        edge_lines: lines across the axis image along which the coherence cost finds each view's edges.
        shared: what the level's objectives share (e.g. the coherence cost's signed-distance atlas).
        densities: makes the (2, N, h, w) log colour densities of the specimen and the background at the level
            (:mod:`vastcal.segmentation.colour_densities`; the PI cost), on demand; None when the problem has none.
        box: (lower, upper, voxel edge), world units: the box where the specimen can be for any θ in the search box
            (the first level's region's bounds, the same at every level) and the level's voxel edge in it.
    """

    index: int
    pf: np.ndarray
    silhouettes: Callable[[], np.ndarray]
    K: np.ndarray
    distance: float
    region: Region
    theta: np.ndarray
    edge_lines: int
    shared: dict[str, Any] = field(default_factory=dict)
    densities: Callable[[], np.ndarray] | None = None
    box: tuple[np.ndarray, np.ndarray, float] | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(h, w) of the level's maps."""
        return (int(self.pf.shape[1]), int(self.pf.shape[2]))

    def padded_voxels(self) -> tuple[np.ndarray, np.ndarray]:
        """The region's voxels padded to a multiple of 1024 (repeats of the first) and their weights (0 on padding)."""
        return pad_voxels(self.region.voxels)

    def box_voxels(self) -> tuple[np.ndarray, np.ndarray]:
        """A regular grid of voxels (world units) over :attr:`box` with its voxel edge, not carved: the voxel set of the
        paper's costs, padded as :meth:`padded_voxels` (the region's own voxels when there is no box)."""
        if self.box is None:
            return self.padded_voxels()
        return pad_voxels(VoxelGrid.from_bounds(*self.box).centres())


def pad_voxels(vox: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Voxels (M, 3) padded to a multiple of 1024 (repeats of the first) and their weights (1, 0 on padding)."""
    pad = (-len(vox)) % 1024
    weights = np.concatenate([np.ones(len(vox)), np.zeros(pad)])
    return (np.concatenate([vox, np.repeat(vox[:1], pad, axis=0)]) if pad else vox), weights


class ObjectiveFactory(Protocol):
    """Builds a method's objective for one level.

    ``exact``: the cost of a θ must not depend on the rest of its batch (the judge of the starts and stages).
    ``local_zooms``: zoom stages of a ray-searching cost around each ray's best sample (the polish's cost).
    """

    def __call__(
        self, level: LevelMaps, settings: CalibrationSettings, *, exact: bool, local_zooms: int
    ) -> Objective: ...


def roll_prior(theta: np.ndarray, theta0: np.ndarray, sigma_deg: float) -> np.ndarray:
    """Mean squared standardised deviation (B,) of the rolls of views 1..N−1 from their commanded angles."""
    d = (np.atleast_2d(theta)[:, 4:] - np.asarray(theta0)[4:]) / sigma_deg
    return np.mean(d * d, axis=1) if d.shape[1] else np.zeros(len(np.atleast_2d(theta)))


@dataclass(frozen=True)
class Prior:
    """The weak Gaussian prior: ``weight`` × (mean squared standardised roll deviation + squared standardised yaw).

    Attributes:
        theta0: (3 + N,) its centre, degrees (the commanded rolls; the yaw's start).
        weight: relative to the data cost; 0 = no prior.
        roll_deg: sigma of every roll, degrees.
        yaw_deg: sigma of the yaw, degrees (0 = no yaw term).
    """

    theta0: np.ndarray
    weight: float
    roll_deg: float
    yaw_deg: float

    @classmethod
    def of(cls, theta0: np.ndarray, settings: CalibrationSettings) -> Prior:
        """The prior the settings ask for, centred on θ0."""
        return cls(np.asarray(theta0), settings.roll_prior_weight, settings.roll_prior_deg, settings.yaw_prior_deg)

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        """(B,) prior cost of θ (B, 3 + N) degrees."""
        if self.weight <= 0:
            return np.zeros(len(np.atleast_2d(theta)))
        p = roll_prior(theta, self.theta0, self.roll_deg)
        if self.yaw_deg > 0:
            p = p + ((np.atleast_2d(theta)[:, 0] - np.asarray(self.theta0)[0]) / self.yaw_deg) ** 2
        return self.weight * p


@dataclass(frozen=True)
class WithPrior:
    """An objective plus a :class:`Prior`: the cost every search, stage and judge minimises."""

    data: Objective
    prior: Prior

    def __call__(self, theta_deg: np.ndarray) -> np.ndarray:
        return np.asarray(self.data(theta_deg), float) + self.prior(theta_deg)
