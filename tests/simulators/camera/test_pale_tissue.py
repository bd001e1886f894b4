"""The pale tail tip and the pale band along the wall: drawn from their own streams, fainter where they
should be and nowhere else, and part of the measured body."""

from __future__ import annotations

import dataclasses

import numpy as np

from vastcal.config import CameraConfig, OpticsConfig, RoiConfig, SimulationConfig
from vastcal.simulators.camera.battery import battery_config
from vastcal.simulators.camera.larva import draw_specimen
from vastcal.simulators.camera.render import BrightfieldRenderer, Capillary
from vastcal.simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, camera_pose

OPTICS = OpticsConfig()
CAMERA = CameraConfig(pixel_format="Mono12", exposure_us=2000.0, roi=RoiConfig(0, 352, 1024, 320))
TRUTH = RigTruth(yaw_deg=0.0, pitch_deg=0.0, axis_offset_um=0.0, distance_um=65000.0)
K = PinholeIntrinsics.from_optics(OPTICS, (0, 352)).K


def sim(seed: int, **on: object) -> SimulationConfig:
    return dataclasses.replace(SimulationConfig(seed=seed), **{"larva_varies": True, "melanophores": 60.0, **on})


def test_switching_the_cases_on_changes_no_other_draw() -> None:
    for seed in range(12):
        off = draw_specimen(sim(seed, wall_contact_probability=0.5), OPTICS, CAMERA)
        on = draw_specimen(
            sim(seed, wall_contact_probability=0.5, pale_tail_tip_probability=1.0, wall_band_probability=0.0),
            OPTICS,
            CAMERA,
        )
        assert on.pale is not None and off.pale is None
        assert on.phantom == off.phantom and on.wall_offset_um == off.wall_offset_um


def test_a_band_larva_touches_the_wall_with_its_back_and_its_pigment_lies_below_the_band() -> None:
    sp = draw_specimen(sim(0, wall_contact_probability=1.0, wall_band_probability=1.0), OPTICS, CAMERA)
    assert sp.pale is not None and sp.pale.band_depth_um >= 8.0 and sp.wall_offset_um is not None
    assert sp.wall_offset_um[0] < -0.9 * np.hypot(*sp.wall_offset_um)  # the axis moved dorsally (−y)
    prof = sp.phantom.profile
    dorsal = [f for f in sp.phantom.features if f.name.startswith("melanophore") and f.centre_um[1] < 0]
    assert dorsal
    for f in dorsal:
        r = float(prof.radius_um(np.array([f.centre_um[0]]))[0])
        assert r + f.centre_um[1] - f.semi_axes_um[1] >= sp.pale.band_depth_um  # below the band


def test_the_pale_tip_is_fainter_than_the_same_tip_at_full_contrast_and_the_body_is_unchanged() -> None:
    base = sim(3, melanophores=0.0)
    plain = draw_specimen(base, OPTICS, CAMERA)
    pale = draw_specimen(dataclasses.replace(base, pale_tail_tip_probability=1.0), OPTICS, CAMERA)
    cap = Capillary(lumen_transmission=1.0, line_depth=0.0)
    R, t = camera_pose(TRUTH, 0.0)
    images = []
    for sp in (plain, pale):
        r = BrightfieldRenderer(sp.phantom, cap, pale=sp.pale)
        g = r.ray_geometry(K, R, t, 1024, 320)
        images.append((1.0 - r.transmission(g), g.coverage))
    (a_plain, cov), (a_pale, cov2) = images
    assert np.array_equal(cov, cov2)
    cols = np.nonzero(cov.any(axis=0))[0]
    tip, mid = cols[-15:], cols[len(cols) // 2 - 5 : len(cols) // 2 + 5]
    inside = cov >= 1.0
    ratio_tip = a_pale[:, tip][inside[:, tip]].mean() / a_plain[:, tip][inside[:, tip]].mean()
    ratio_mid = a_pale[:, mid][inside[:, mid]].mean() / a_plain[:, mid][inside[:, mid]].mean()
    assert ratio_mid == 1.0 and abs(ratio_tip - pale.pale.tip_contrast) < 0.05  # type: ignore[union-attr]


def test_a_battery_of_30_holds_both_cases() -> None:
    feats = []
    for seed in range(30):
        cfg = battery_config(seed)
        assert cfg.simulation is not None
        feats.append(draw_specimen(cfg.simulation, cfg.optics, cfg.camera).features)
    tips = [f["pale_tail_tip"] for f in feats]
    bands = [f["wall_band"] for f in feats]
    assert 4 <= sum(tips) <= 15 and 4 <= sum(bands) <= 12
    assert all(f["wall_contact"] for f in feats if f["wall_band"])
