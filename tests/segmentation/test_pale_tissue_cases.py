"""The automatic silhouettes on the simulator's pale cases: a pale tapering tail tip and a pale band of tissue
between the dorsal pigment line and the capillary wall the larva lies against. Both are body: the silhouette
keeps them, and not the wall's own dark line."""

from __future__ import annotations

import numpy as np
import pytest

from vastcal.rig import simulated_capillary
from vastcal.segmentation import fit_automatic, specimen_maps
from vastcal.simulators.camera import SimulatedCamera
from vastcal.simulators.camera.battery import battery_config

pytestmark = pytest.mark.slow  # five full revolutions rendered and segmented

CLEAN = {"debris": 0.0, "bubbles": 0.0, "fin_fold": False, "pectoral_fins": False}
"""The clean scene: the larva alone in the capillary (lamp field, defocus and melanophores kept)."""
SCENES = {
    "clean scene, 8 views": (CLEAN, 8),
    "battery scene, 21 views": ({}, 21),
}
"""(simulation overrides, views) of each scene; the battery scene is the battery's own (fin fold, fins, debris,
bubbles) at its rig file's 21 views. Both are imaged through the simulated rig's capillary (lumen as bright as the
surroundings, as in the battery's sessions and the real frames)."""
BAND_CUT = pytest.mark.xfail(
    strict=True,
    reason="the pale band between the dorsal pigment line and the wall (2.7 px deep, 0.33 of the body's contrast) is "
    "cut in three steps of a pixel: the wall rule (the view not darker than the empty capillary by a quarter of the "
    "specimen's contrast), the sheet rule (more than a pixel from the half-contrast core) and the rim rule (half of "
    "the pigment line's plateau): the edge lies a median 3 px inside the true one",
)
PALE_TIP_SEED = 9
"""A battery larva with a pale tail tip (contrast 0.17 of the body's at the tip), not against the wall."""
WALL_BAND_SEED = 4
"""A battery larva lying dorsal side against the wall, a pale band 15 µm deep at 0.33 of the body's contrast."""


class _Angle:
    deg = 0.0

    def __call__(self) -> float:
        return self.deg


def _segmented(seed: int, scene: str) -> tuple[SimulatedCamera, np.ndarray, np.ndarray, np.ndarray]:
    """(camera, truth coverage ≥ ½, automatic silhouettes, capillary-axis distance µm) of a scene's views."""
    overrides, n_views = SCENES[scene]
    cfg = battery_config(seed, **overrides)
    assert cfg.simulation is not None
    src = _Angle()
    cam = SimulatedCamera(cfg.optics, cfg.camera, cfg.simulation, src, capillary=simulated_capillary())
    frames, truth, rho = [], [], []
    with cam:
        cam.start()
        for k in range(n_views):
            src.deg = 360.0 * k / n_views
            frames.append(cam.snap(2.0).pixels)
            geom = cam._renderer.last_geometry
            assert geom is not None
            truth.append(geom.coverage >= 0.5)
            rho.append(geom.rho0.copy())
    stack = np.stack(frames)
    return cam, np.stack(truth), specimen_maps(fit_automatic(stack), stack) > 0.5, np.stack(rho)


@pytest.fixture(
    scope="module",
    params=[
        pytest.param("clean scene, 8 views", id="clean"),
        pytest.param("battery scene, 21 views", id="battery"),
    ],
)
def pale_tip(request: pytest.FixtureRequest) -> tuple[SimulatedCamera, np.ndarray, np.ndarray, np.ndarray]:
    return _segmented(PALE_TIP_SEED, request.param)


@pytest.fixture(
    scope="module",
    params=[
        pytest.param("clean scene, 8 views", id="clean", marks=BAND_CUT),
        pytest.param("battery scene, 21 views", id="battery", marks=BAND_CUT),
    ],
)
def wall_band(request: pytest.FixtureRequest) -> tuple[SimulatedCamera, np.ndarray, np.ndarray, np.ndarray]:
    return _segmented(WALL_BAND_SEED, request.param)


def test_the_cases_are_drawn_and_the_pale_tissue_is_fainter_than_the_body() -> None:
    cam_tip, cam_band = (
        SimulatedCamera(c.optics, c.camera, c.simulation, _Angle())  # type: ignore[arg-type]
        for c in (battery_config(PALE_TIP_SEED), battery_config(WALL_BAND_SEED))
    )
    assert cam_tip.specimen.features["pale_tail_tip"] and not cam_tip.specimen.features["wall_contact"]
    assert cam_band.specimen.features["wall_band"] and cam_band.specimen.features["wall_contact"]
    pale = cam_tip.specimen.pale
    assert pale is not None
    x_tip = pale.x_head_um + pale.length_um
    c = pale.contrast(np.array([pale.x_head_um + 0.5 * pale.length_um, x_tip]), np.zeros(2), np.zeros(2))
    assert c[0] == pytest.approx(1.0) and c[1] == pytest.approx(pale.tip_contrast, abs=1e-6) and c[1] < 0.4


def test_the_silhouette_keeps_the_pale_tail_tip(pale_tip) -> None:
    _, truth, sil, _ = pale_tip
    for k in range(truth.shape[0]):
        cols = np.nonzero(truth[k].any(axis=0))[0]
        tip = cols.max()
        assert np.nonzero(sil[k].any(axis=0))[0].max() >= tip - 3, f"view {k}: the silhouette ends short of the tip"
        end = truth[k][:, tip - 60 : tip + 1]
        kept = (end & sil[k][:, tip - 60 : tip + 1]).sum() / end.sum()
        assert kept >= 0.9, f"view {k}: only {kept:.0%} of the last 60 px of the tail kept"


def test_the_silhouette_keeps_the_band_up_to_the_wall_but_not_the_walls_line(wall_band) -> None:
    cam, truth, sil, rho = wall_band
    R = cam._renderer.capillary.inner_radius_um
    band = cam.specimen.pale.band_depth_um if cam.specimen.pale is not None else 0.0
    contact_views = 0
    for k in range(truth.shape[0]):
        near_wall = truth[k] & (rho[k] > R - 25.0)
        if near_wall.sum() < 50:
            continue
        contact_views += 1
        wall_line = (rho[k] > R - 5.0) & ~truth[k]
        assert not (wall_line & sil[k]).any(), f"view {k}: the wall's line counted as larva"
        top = np.nonzero(near_wall.any(axis=1))[0].mean() < truth.shape[1] / 2
        inset = []
        for c in np.nonzero(near_wall.any(axis=0))[0]:
            t_rows, s_rows = np.nonzero(truth[k][:, c])[0], np.nonzero(sil[k][:, c])[0]
            inset.append(
                99 if not s_rows.size else (s_rows.min() - t_rows.min() if top else t_rows.max() - s_rows.max())
            )
        # the band is band/5.5 ≈ 2.7 px deep: an edge at the pigment line would sit ≥ 2.5 px inside
        assert np.median(inset) <= 1.5 and np.percentile(inset, 90) <= 2.0, (
            f"view {k}: silhouette {np.median(inset)} px inside the true edge at the wall (band {band:.0f} µm)"
        )
    assert contact_views >= 2
