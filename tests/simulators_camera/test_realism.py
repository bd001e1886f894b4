"""What real larvae show: each feature appears when switched on, is absent when off,
and every draw is reproducible from ``simulation.seed``."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import ndimage

from vastcal.config import CameraConfig, OpticsConfig, RoiConfig, SimulationConfig
from vastcal.errors import ConfigError
from vastcal.simulators.camera import SimulatedCamera
from vastcal.simulators.camera.battery import battery_config
from vastcal.simulators.camera.larva import Specimen, draw_specimen
from vastcal.simulators.camera.phantom import zebrafish_phantom
from vastcal.simulators.camera.render import BrightfieldRenderer, Capillary, RayGeometry
from vastcal.simulators.camera.scene import Particle, draw_illumination, draw_particles, paint_particles
from vastcal.simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, camera_pose

OPTICS = OpticsConfig()
CAMERA = CameraConfig(pixel_format="Mono12", exposure_us=2000.0, roi=RoiConfig(0, 352, 1024, 320))
TRUTH = RigTruth(yaw_deg=0.0, pitch_deg=0.0, axis_offset_um=0.0, distance_um=65000.0)
CAP = Capillary(lumen_transmission=1.0, line_depth=0.0)
K = PinholeIntrinsics.from_optics(OPTICS, (0, 352)).K


def sim(seed: int = 5, **on: object) -> SimulationConfig:
    """Every feature off (the defaults) except the larva's variation and those in ``on``."""
    return dataclasses.replace(SimulationConfig(seed=seed), **{"larva_varies": True, **on})


def geometry(
    sp: Specimen, angle: float, offset: tuple[float, float] = (0.0, 0.0)
) -> tuple[BrightfieldRenderer, RayGeometry]:
    r = BrightfieldRenderer(sp.phantom, CAP, fin_fold=sp.fin_fold, fins=sp.pectoral_fins)
    R, t = camera_pose(TRUTH, angle)
    return r, r.ray_geometry(K, R, t, 1024, 320, offset)


def test_every_feature_is_off_by_default_and_the_default_larva_is_the_fixed_phantom() -> None:
    s = SimulationConfig()
    sp = draw_specimen(s, OPTICS, CAMERA)
    assert (
        sp.phantom.volume_mm3() == zebrafish_phantom().volume_mm3()
        and sp.phantom.features == zebrafish_phantom().features
    )
    assert sp.fin_fold is None and sp.pectoral_fins == () and sp.wall_offset_um is None
    assert len(draw_particles(s, sp, (0.0, 0.0), OPTICS, CAMERA)) == 0
    ill = draw_illumination(s, OPTICS)
    assert ill.is_flat and ill.defocus_sigma_px == 0.0


def test_larvae_span_3_to_5_dpf_and_3_to_4_5_mm() -> None:
    feats = [draw_specimen(sim(seed)).features for seed in range(40)]
    ages = np.array([f["age_dpf"] for f in feats])
    lengths = np.array([f["length_um"] for f in feats])
    assert ages.min() < 3.3 and ages.max() > 4.7 and np.all((ages >= 3.0) & (ages <= 5.0))
    assert np.all((lengths > 2850) & (lengths < 4700)) and lengths.min() < 3200 and lengths.max() > 4300
    assert np.corrcoef(ages, lengths)[0, 1] > 0.9
    assert len({round(f["edge_transmission"], 6) for f in feats}) == 40  # contrast varies too


def test_fin_fold_is_lighter_than_the_body_darker_than_the_background_and_reaches_past_the_tail() -> None:
    sp_on, sp_off = draw_specimen(sim(fin_fold=True)), draw_specimen(sim(fin_fold=False))
    assert sp_on.phantom == sp_off.phantom  # the fold is not part of the measured body
    r, g = geometry(sp_on, 0.0)  # at 0° the camera looks along z: the sagittal sheet face-on
    _, g_off = geometry(sp_off, 0.0)
    assert g_off.tau_extra is None and np.array_equal(g.coverage, g_off.coverage)
    T = r.transmission(g)
    fold = (g.tau_extra > 0) & (g.coverage == 0)
    assert fold.sum() > 2000
    body = g.coverage >= 1.0
    assert np.median(T[body]) < T[fold].min() and T[fold].max() < 1.0
    # the rounded paddle past the tail tip: fold pixels right of the body's last column
    tail_col = np.nonzero(g.coverage.any(axis=0))[0].max()
    assert fold[:, tail_col + 3 :].sum() > 20
    # edge-on (90°) the sheet is a thin line: far fewer pixels, darker ones
    _, g90 = geometry(sp_on, 90.0)
    line = (g90.tau_extra > 0) & (g90.coverage == 0)
    assert 0 < line.sum() < 0.2 * fold.sum() and g90.tau_extra.max() > 5 * g.tau_extra[fold].max()


def test_pectoral_fins_stick_out_of_the_body_in_a_dorsal_view() -> None:
    sp = draw_specimen(sim(pectoral_fins=True))
    assert len(sp.pectoral_fins) == 2
    _, g = geometry(sp, 90.0)  # looking along y: dorsal view, the fins out to the sides
    fins = (g.tau_extra > 0) & (g.coverage == 0)
    rows = np.nonzero(fins.any(axis=1))[0]
    body_rows = np.nonzero(g.coverage.any(axis=1))[0]
    assert fins.sum() > 100 and rows.min() < body_rows.min() and rows.max() > body_rows.max()  # both sides
    assert np.exp(-g.tau_extra[fins]).min() > 0.5  # thin, translucent
    _, g_off = geometry(draw_specimen(sim()), 90.0)
    assert g_off.tau_extra is None


def test_melanophores_are_dark_specks_inside_the_body_mostly_on_the_outline() -> None:
    sp = draw_specimen(sim(seed=11, melanophores=40.0))
    mel = [f for f in sp.phantom.features if f.name.startswith("melanophore")]
    assert len(mel) == sp.features["melanophores"] and 20 <= len(mel) <= 60
    assert all(sp.phantom.contains(f.surface_points(16)).all() for f in mel)  # the silhouette is the body's
    midline = sum(abs(f.centre_um[2]) < abs(f.centre_um[1]) for f in mel)
    assert midline >= 0.6 * len(mel)
    plain = draw_specimen(sim(seed=11))
    _, g_on = geometry(sp, 0.0)
    _, g_off = geometry(plain, 0.0)
    assert np.array_equal(g_on.coverage, g_off.coverage)
    specks = (g_on.tau_features - g_off.tau_features) > 0.3
    labels, n = ndimage.label(specks)
    assert 0.4 * len(mel) <= n <= len(mel)
    # many on the outline: within 3 px of the silhouette's edge
    edge = ndimage.binary_dilation(g_on.coverage > 0.5, iterations=3) & ~ndimage.binary_erosion(
        g_on.coverage > 0.5, iterations=3
    )
    on_edge = len(set(np.unique(labels[specks & edge])) - {0})
    assert on_edge >= 0.3 * n


def test_a_larva_against_the_wall_touches_it_in_the_view_that_sees_the_gap() -> None:
    sp = draw_specimen(sim(seed=2, wall_contact_probability=1.0), lumen_radius_um=CAP.inner_radius_um)
    assert sp.features["wall_contact"] and sp.wall_offset_um is not None
    oy, oz = sp.wall_offset_um
    phi = math.degrees(math.atan2(oz, oy))
    # at stage angle −φ the offset points along the image's v axis: the body's edge meets the wall line
    r, g = geometry(sp, -phi, sp.wall_offset_um)
    u = int(np.argmax(g.coverage.sum(axis=0)))  # the widest column
    col = g.coverage[:, u]
    rows = np.nonzero(col > 0.5)[0]
    wall_rows = np.nonzero(g.rho0[:, u] < CAP.inner_radius_um)[0]
    gap_px = min(rows.min() - wall_rows.min(), wall_rows.max() - rows.max())
    assert -1 <= gap_px <= 1 + 3.0 / 5.5
    no = draw_specimen(sim(seed=2))
    assert no.wall_offset_um is None and not no.features["wall_contact"]


def test_debris_drifts_between_views_and_bubbles_have_a_bright_centre_and_a_dark_rim() -> None:
    s = sim(seed=4, debris=6.0, bubbles=3.0)
    sp = draw_specimen(s)
    cloud = draw_particles(s, sp, (0.0, 0.0), OPTICS, CAMERA)
    assert len(cloud) > 0 and set(cloud.kinds) <= {"debris", "bubble"}
    a, b = cloud.at_view(3), cloud.at_view(4)
    moved = [math.dist(p.centre_um, q.centre_um) for p, q in zip(a, b)]
    assert min(moved) > 1.0  # not rigid with the capillary: a rigid body would not move in this frame
    assert all(math.hypot(p.centre_um[1], p.centre_um[2]) < 330.0 for p in cloud.at_view(20))
    assert a == cloud.at_view(3)  # reproducible
    T = np.ones((101, 101), np.float32)
    Kp = np.array([[11818.18, 0.0, 50.0], [0.0, 11818.18, 50.0], [0.0, 0.0, 1.0]])
    R, t = np.eye(3), np.array([0.0, 0.0, 65000.0])
    paint_particles(T, [Particle("bubble", (0.0, 0.0, 0.0), 40.0, strength=0.7)], Kp, R, t)
    r_px = 40.0 * 11818.18 / 65000.0
    assert (
        T[50, 50] > 1.05
        and T[50, 50 + int(round(0.85 * r_px))] < 0.5
        and T[50, 50 + int(2 * r_px)] == pytest.approx(1.0, abs=1e-3)
    )
    T = np.ones((101, 101), np.float32)
    paint_particles(T, [Particle("debris", (0.0, 0.0, 0.0), 15.0, strength=1.5)], Kp, R, t)
    assert T.min() < 0.3 and T.max() == 1.0
    assert len(draw_particles(sim(seed=4), sp, (0.0, 0.0), OPTICS, CAMERA)) == 0


def test_illumination_gradient_vignetting_and_defocus() -> None:
    ill = draw_illumination(sim(seed=6, illumination_gradient=0.1, vignetting=0.2, defocus_blur_px=(1.0, 1.0)), OPTICS)
    assert ill.defocus_sigma_px == 1.0 and 0 < ill.vignetting <= 0.2 and max(map(abs, ill.gradient)) <= 0.1
    f = ill.field(PinholeIntrinsics.from_optics(OPTICS).K, 1024, 1024)
    gx, gy = ill.gradient
    assert (f[512, -1] - f[512, 0]) / 2 == pytest.approx(gx, abs=0.01) and (
        f[-1, 512] - f[0, 512]
    ) / 2 == pytest.approx(gy, abs=0.01)
    assert f[0, 0] * f[-1, -1] < f[511, 0] * f[511, -1]  # corners darker (vignetting)
    with pytest.raises(ConfigError, match="simulation.defocus_blur_px"):
        draw_illumination(sim(defocus_blur_px=(2.0, 1.0)), OPTICS)


class _Angle:
    def __init__(self) -> None:
        self.deg = 0.0

    def __call__(self) -> float:
        return self.deg


def _snap_all(cfg_seed: int, angles: list[float], **over: object) -> tuple[list[np.ndarray], dict]:
    cfg = battery_config(cfg_seed, **over)
    src = _Angle()
    cam = SimulatedCamera(cfg.optics, cfg.camera, cfg.simulation, src, capillary=Capillary(lumen_transmission=1.0))
    frames = []
    with cam:
        cam.start()
        for a in angles:
            src.deg = a
            frames.append(cam.snap(2.0).pixels)
    return frames, cam.truth_record()


def test_a_battery_larva_is_reproducible_from_its_seed_and_its_truth_says_what_was_drawn() -> None:
    f1, t1 = _snap_all(24, [0.0, 120.0])
    f2, t2 = _snap_all(24, [0.0, 120.0])
    assert all(np.array_equal(a, b) for a, b in zip(f1, f2)) and t1["specimen"] == t2["specimen"]
    f3, t3 = _snap_all(25, [0.0, 120.0])
    assert not np.array_equal(f1[0], f3[0]) and t3["specimen"] != t1["specimen"]
    sp = t1["specimen"]
    for key in (
        "age_dpf",
        "length_um",
        "fin_fold",
        "pectoral_fins",
        "melanophores",
        "wall_contact",
        "tail_out_of_frame",
        "debris",
        "bubbles",
        "illumination_gradient",
        "vignetting",
        "defocus_sigma_px",
    ):
        assert key in sp
    assert sp["fin_fold"] and sp["pectoral_fins"] and sp["wall_contact"]
    # the truth's body excludes the fins: hull and solid body as the plain phantom would give them
    assert t1["hull_volume_mm3"] > t1["true_volume_mm3"] > 0.1


def test_a_tail_out_of_frame_is_recorded_per_view_with_the_in_frame_hull() -> None:
    frames, t = _snap_all(3, [0.0, 90.0, 200.0], tail_out_of_frame_probability=1.0, debris=0.0, bubbles=0.0)
    assert t["specimen"]["tail_out_of_frame"]
    assert t["frame_cut_views"] == [0, 1, 2]  # a rigid larva turning about the axis leaves the frame in every view
    assert all(s["body_cut_by_frame"] for s in t["snaps"])
    lo, hi = t["frame_x_range_um"]
    assert hi < t["specimen"]["x_centre_um"] + 0.5 * t["specimen"]["length_um"]
    assert t["hull_in_frame_volume_mm3"] < t["hull_volume_mm3"] and t["hull_in_frame_area_mm2"] < t["hull_area_mm2"]
    assert all(f[:, -1].min() < 0.95 * np.median(f[:, 0]) for f in frames)  # the body is dark at the right edge
    _, t_in = _snap_all(3, [0.0], debris=0.0, bubbles=0.0)
    assert (
        not t_in["specimen"]["tail_out_of_frame"]
        and t_in["frame_cut_views"] == []
        and "hull_in_frame_volume_mm3" not in t_in
    )


def test_battery_overrides_and_colour_frames() -> None:
    cfg = battery_config(8, fin_fold=False, debris=0.0)
    assert (
        cfg.simulation is not None
        and cfg.simulation.seed == 8
        and not cfg.simulation.fin_fold
        and cfg.simulation.pectoral_fins
    )
    with pytest.raises(TypeError, match="fin_fold_heigth"):
        battery_config(8, fin_fold_heigth=(1.0, 2.0))
    src = _Angle()
    cam = SimulatedCamera(cfg.optics, dataclasses.replace(cfg.camera, pixel_format="RGB8"), cfg.simulation, src)
    with cam:
        cam.start()
        px = cam.snap(2.0).pixels
    assert px.shape == (320, 1024, 3) and px.dtype == np.uint8 and px.min() < 100 < px.max()
