"""The photometric yaw search (projection matching of absorption images).

On the simulated rig (simulation seed 1: true yaw −0.717°) the silhouette calibration leaves the
yaw at its prior (≈ 0°, 0.73° off); the grey levels bring it within 0.05° (0.027° before the last stage ran to
convergence on maps fine along the axis; +0.011° since, ``benchmarks/calibrate_simulated.py 8``), and the last stage records that its iterations converged.
Its building blocks are tested on exact synthetic images.
"""

from __future__ import annotations

import importlib.util
import logging
from pathlib import Path

import numpy as np
import pytest

from vastcal.calibrate import calibrate_views
from vastcal.calibrate.photometric_yaw import (
    AbsorptionMatch,
    absorption_images,
    combine_group_yaws,
    distinct_directions,
    drop_static,
    grid_phase,
    refine_yaw,
    spread_order,
    yaw_groups,
)
from vastcal.geometry import projection_matrices
from vastcal.segmentation import fit_automatic, specimen_maps

_spec = importlib.util.spec_from_file_location("synthetic_views", Path(__file__).with_name("synthetic.py"))
synthetic = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(synthetic)  # type: ignore[union-attr]


def test_drop_static_removes_what_spans_the_frame_and_keeps_the_specimen() -> None:
    pf = np.zeros((60, 200), np.float32)
    pf[5:8, :] = 1.0  # a capillary wall from the left edge to the right
    pf[25:40, 50:120] = 1.0  # the specimen
    out = drop_static(pf)
    assert out[6].max() == 0.0
    assert np.all(out[25:40, 50:120] == 1.0)


def test_absorption_of_a_known_attenuation_under_a_varying_background() -> None:
    K, d = synthetic.camera()
    theta = np.r_[0.0, 0.0, 0.0, [0.0, 90.0, 180.0]]
    P = projection_matrices(K, d, theta[None])[0]
    h, w = synthetic.H, synthetic.W
    v = np.arange(h, dtype=np.float32)[:, None]
    background = 3000.0 + 5.0 * (v - h / 2) ** 2 / h * np.ones((1, w), np.float32)  # brighter away from the axis image
    truth = np.zeros((3, h, w), np.float32)
    truth[:, 50:70, 100:220] = 0.8
    images = background[None] * np.exp(-truth)
    pf = (truth > 0).astype(np.float32)
    a = absorption_images(images, pf, P)
    assert np.allclose(a[:, 50:70, 100:220], 0.8, atol=1e-3)
    assert np.abs(a[:, :40]).max() < 1e-3


@pytest.mark.parametrize("accelerated", [False, True])
def test_a_resumed_reconstruction_gives_the_cost_of_one_run_from_zero(accelerated: bool) -> None:
    theta = synthetic.truth_theta(6, seed=2)
    images = synthetic.render(theta)
    K, d = synthetic.camera()
    pf = specimen_maps(fit_automatic(images), images)
    a = absorption_images(images, pf, projection_matrices(K, d, theta[None])[0])
    match = AbsorptionMatch(a, pf, K, d, theta, sirt_iterations=24, accelerated=accelerated)
    rec = match.start(theta)
    first = match.resume(rec, 10)
    assert match.resume(rec, 24) == pytest.approx(match(theta), rel=1e-5)  # 10 then 14 more = 24 from zero
    assert match.resume(rec, 24) < first  # and a no-op once it has them


def test_no_absorption_contrast_leaves_the_yaw_alone(caplog: pytest.LogCaptureFixture) -> None:
    theta = synthetic.truth_theta(8, seed=1)
    images = synthetic.render(theta, dark_specimen=False)  # bright specimen on a dark background
    K, d = synthetic.camera()
    pf = specimen_maps(fit_automatic(images), images)
    with caplog.at_level(logging.WARNING, logger="vastcal.calibrate.photometric_yaw"):
        assert (
            refine_yaw(images, pf, K, d, theta, (theta[0] - 1, theta[0] + 1), min_directions=0) is None
        )  # 8 views: the contrast alone
    assert "not darker than its background" in caplog.text


def test_grey_levels_find_the_yaw_the_silhouettes_leave_to_the_prior(
    simulated: tuple[np.ndarray, np.ndarray, dict],
) -> None:
    images, commanded, truth = simulated
    K, d = np.array(truth["K"]), truth["distance_um"]
    r = calibrate_views(images, K, d, np.r_[0.0, 0.0, 0.0, commanded], seed=0)
    assert abs(r.theta_deg[0] - truth["yaw_deg"]) > 0.5  # the silhouettes' answer: the prior's 0°
    assert r.colour_model is not None
    refined = refine_yaw(images, specimen_maps(r.colour_model, images), K, d, r.theta_deg, (-3.0, 3.0))
    assert refined is not None and refined.n_evaluations >= 10
    assert abs(refined.yaw_deg - truth["yaw_deg"]) < 0.05  # 0.027° with 100 SIRT iterations at ½ width; 0.011° since
    assert refined.scanned_yaw_deg.min() < refined.yaw_deg < refined.scanned_yaw_deg.max()
    assert refined.converged and refined.final_iterations >= 100  # the yaw stopped moving between two doublings
    assert refined.report()["final_iterations"] == refined.final_iterations
    assert (
        refined.group_yaws_deg is not None and refined.group_yaws_deg.size == 1
    )  # 21 views: one reconstruction of them all
    # split into two interleaved sub-revolutions: the last stage on each, the yaw their mean
    split = refine_yaw(
        images, specimen_maps(r.colour_model, images), K, d, r.theta_deg, (-3.0, 3.0), group_views=10, min_directions=9
    )
    assert split is not None and split.group_yaws_deg is not None and list(split.group_views) == [9, 9]
    assert split.yaw_deg == pytest.approx(float(np.mean(split.group_yaws_deg)))
    assert (
        abs(split.yaw_deg - truth["yaw_deg"]) < 0.1
        and split.report()["group_yaws_deg"] == split.group_yaws_deg.tolist()
    )
    # a sub-revolution larger than the group size (21 views against 15): reconstructed at three lattice phases, their median
    named: list[str] = []
    phased = refine_yaw(
        images,
        specimen_maps(r.colour_model, images),
        K,
        d,
        r.theta_deg,
        (-3.0, 3.0),
        group_views=15,
        part=lambda what, n: named.append(what),
    )
    assert [p for p in named if p.endswith("first samples")] == [
        "lattice phase 2/3: first samples",
        "lattice phase 3/3: first samples",
    ]
    assert phased is not None and phased.group_yaws_deg is not None and list(phased.group_views) == [21, 21, 21]
    assert (
        phased.yaw_deg == pytest.approx(float(np.median(phased.group_yaws_deg)))
        and len(set(phased.group_yaws_deg.tolist())) == 3
    )
    assert abs(phased.yaw_deg - truth["yaw_deg"]) < 0.05 and phased.yaw_sigma_deg is not None
    # seven sub-revolutions of three views: after five (not three), their median's standard error is within a loose tolerance
    parts: list[str] = []
    stages: list[tuple[int, int]] = []
    stopped = refine_yaw(
        images,
        specimen_maps(r.colour_model, images),
        K,
        d,
        r.theta_deg,
        (-3.0, 3.0),
        group_views=3,
        yaw_standard_error_deg=1.0,
        part=lambda what, n: parts.append(what),
        stage=lambda w, n: stages.append((w, n)),
        min_directions=3,
    )
    assert stages[-1] == (1024, 5)  # the first sub-revolution's first samples; the later ones' are parts of their own
    assert [p for p in parts if p.endswith("first samples")] == [
        f"sub-revolution {k}/7: first samples" for k in range(2, 6)
    ]
    assert stopped is not None and stopped.group_yaws_deg is not None and list(stopped.group_views) == [3] * 5  # not 7
    assert stopped.yaw_deg == pytest.approx(float(np.median(stopped.group_yaws_deg)))
    assert (
        stopped.yaw_sigma_deg is not None
        and stopped.yaw_sigma_deg >= 1.2533 * np.std(stopped.group_yaws_deg, ddof=1) / np.sqrt(5) - 1e-12
    )


def test_too_few_directions_leave_the_yaw_alone(
    simulated: tuple[np.ndarray, np.ndarray, dict], caplog: pytest.LogCaptureFixture
) -> None:
    """An even revolution's views face each other in pairs: 12 views look along 6 directions, 11 along 11; the yaw is
    searched from 11 directions on, and not from fewer (a warning says why)."""
    rng = np.random.default_rng(3)
    for n, expected in ((8, 4), (9, 9), (10, 5), (11, 11), (12, 6), (13, 13), (21, 21)):
        angles = np.arange(n) * 360.0 / n + rng.normal(0.0, 1.0, n)  # a stage's drift of ~1°
        assert distinct_directions(angles[yaw_groups(angles)[0]]) == expected, n
    angles = np.arange(36) * 360.0 / 36 + rng.normal(
        0.0, 1.0, 36
    )  # 18 directions, facing pairs ~1.4° apart: 18 or more
    assert 18 <= distinct_directions(angles[yaw_groups(angles)[0]]) <= 35
    images, commanded, truth = simulated
    K, d = np.array(truth["K"]), truth["distance_um"]
    views = np.arange(0, 21, 2)  # 11 of the 21 views, spread over the turn: 11 directions, then 10
    pf = specimen_maps(fit_automatic(images[views]), images[views])
    theta = np.r_[0.0, 0.0, 0.0, commanded[views]]
    assert distinct_directions(commanded[views]) == 11 and distinct_directions(commanded[views[:-1]]) == 10
    with caplog.at_level(logging.WARNING, logger="vastcal.calibrate.photometric_yaw"):
        assert refine_yaw(images[views[:-1]], pf[:-1], K, d, theta[:-1], (-3.0, 3.0)) is None
    assert "distinct directions" in caplog.text and "yaw not measured" in caplog.text


def test_yaw_groups_are_interleaved_sub_revolutions_of_at_least_the_group_size() -> None:
    angles = np.arange(63) * 360.0 / 63 + 0.3
    groups = yaw_groups(angles, 21)
    assert [g.size for g in groups] == [21, 21, 21]
    assert np.array_equal(np.sort(np.concatenate(groups)), np.arange(63))
    for g in groups:  # each spans the revolution evenly
        assert np.allclose(np.diff(angles[g]), 3 * 360.0 / 63)
    assert [g.size for g in yaw_groups(angles[:41], 21)] == [41]  # fewer than twice the size: all in one
    assert [g.size for g in yaw_groups(np.arange(62) * 360.0 / 62, 21)] == [31, 31]  # two groups: every view used
    assert [g.size for g in yaw_groups(angles, None)] == [63]
    shuffled = np.random.default_rng(0).permutation(63)  # views in any order: grouped by angle
    for g in yaw_groups(angles[shuffled], 21):
        assert np.allclose(np.diff(np.sort(angles[shuffled][g])), 3 * 360.0 / 63)
    fine = np.arange(81) * 360.0 / 81  # three groups or more: each of the validated size, within a sixth of its spacing
    groups = yaw_groups(fine, 21)
    assert [g.size for g in groups] == [21, 21, 21] and np.unique(np.concatenate(groups)).size == 63
    for j, g in enumerate(groups):
        places = (j / 3 + np.arange(21)) * 360.0 / 21
        assert np.abs(np.sort(fine[g]) - places).max() <= 360.0 / 81 / 2 + 1e-9 <= 360.0 / 21 / 6
        gaps = np.abs(np.mod(fine[g][:, None] - fine[g][None] + 180.0, 360.0) - 180.0)
        assert np.abs(gaps - 180.0).min() > 360.0 / 21 / 6  # no two of them (nearly) facing each other
    assert [g.size for g in yaw_groups(np.arange(24) * 15.0, 21)] == [23]  # an even revolution: one view left out
    assert [g.size for g in yaw_groups(np.arange(21) * 360.0 / 21, 21)] == [21]  # a 21-view session: one reconstruction
    spread = np.floor(
        np.arange(88) * 360 / 88
    )  # 88 of 360 views at 1° steps: 4 odd revolutions, none with facing views
    groups = yaw_groups(spread, 21)
    assert [g.size for g in groups] == [21] * 4 and np.unique(np.concatenate(groups)).size == 84
    for g in groups:
        facing = np.abs(np.mod(spread[g][:, None] - spread[g][None, :], 360.0) - 180.0)
        assert facing.min() >= 0.5 * 360.0 / 21 - 2.0


def test_each_sub_revolution_has_its_own_lattice_phase_spread_over_the_voxel() -> None:
    assert grid_phase(0) == (0.0, 0.0, 0.0)  # one reconstruction of all views: the lattice as it always was
    phases = np.array([grid_phase(j) for j in range(16)])
    assert np.all((phases >= 0) & (phases < 1))
    gaps = np.abs(phases[:, None] - phases[None])
    gaps = np.minimum(gaps, 1 - gaps).max(axis=-1)  # circular distance, worst axis
    assert gaps[~np.eye(16, dtype=bool)].min() > 0.1  # no two sub-revolutions share (nearly) one lattice
    theta = synthetic.truth_theta(6, seed=2)
    images = synthetic.render(theta)
    K, d = synthetic.camera()
    pf = specimen_maps(fit_automatic(images), images)
    a = np.zeros_like(pf)
    m0 = AbsorptionMatch(a, pf, K, d, theta)
    m1 = AbsorptionMatch(a, pf, K, d, theta, grid_phase=(0.5, 0.25, 0.75))
    shift = np.array([0.5 * m0.voxel_um, 0.25 * m0.voxel_across_um, 0.75 * m0.voxel_across_um])
    grid0 = {tuple(np.round(x, 6)) for x in m0.X + shift}
    assert (
        len(grid0 & {tuple(np.round(x, 6)) for x in m1.X}) > 0.5 * m1.n_voxels
    )  # the same lattice, moved by the phase


def test_sub_revolutions_combine_by_their_median_with_an_error_from_their_spread() -> None:
    assert combine_group_yaws(np.array([0.2]), [0.003]) == (0.2, 0.003)
    yaw, se = combine_group_yaws(np.array([0.20, 0.24]), [0.002, 0.002])
    assert yaw == pytest.approx(0.22) and se == pytest.approx(0.02)  # half their difference exceeds the noise's
    ys = np.array([0.20, 0.21, 0.22, 0.35])  # one lattice resonating with the specimen
    yaw, se = combine_group_yaws(ys, [0.002] * 4)
    assert yaw == pytest.approx(0.215) and se == pytest.approx(1.2533 * np.std(ys, ddof=1) / 2)
    assert combine_group_yaws(ys, [0.002, None, 0.002, 0.002])[1] == pytest.approx(se)  # unknown noise: the spread's
    assert spread_order(1) == [0]
    for g in (4, 7, 17):
        order = spread_order(g)
        assert sorted(order) == list(range(g)) and order[0] == 0
        assert max(order[:3]) - min(order[:3]) >= g // 3  # the first three span the spacing


def test_samples_moved_past_a_lowest_one_at_an_end_are_announced_before_they_run(
    simulated: tuple[np.ndarray, np.ndarray, dict],
) -> None:
    images, commanded, truth = simulated
    K, d = np.array(truth["K"]), truth["distance_um"]
    theta = np.r_[0.0, 0.0, 0.0, commanded]  # yaw 0.72° from the truth: ±0.1° of samples all lie on one side of it
    pf = specimen_maps(fit_automatic(images), images)
    events: list[tuple[str, object]] = []
    refine_yaw(
        images,
        pf,
        K,
        d,
        theta,
        (-3.0, 3.0),
        schedule=((128, 0.05, 2),),
        final_iterations=(25, 50),
        part=lambda what, n: events.append(("part", what)),
        progress=lambda e, c: events.append(("eval", e)),
    )
    extended = [i for i, ev in enumerate(events) if ev == ("part", "samples extended past the lowest")]
    assert len(extended) == 2  # the box allows both extensions; each named before its reconstructions
    for i in extended:
        assert events[i + 1][0] == "eval"


def test_a_product_split_over_threads_is_bit_identical(monkeypatch: pytest.MonkeyPatch) -> None:
    """The reconstruction's products, their rows cut into blocks computed on two threads, equal one product bit for bit
    (rows of very unequal length: the blocks are cut by stored entries, and a block may hold one row)."""
    import scipy.sparse as sp

    from vastcal.calibrate import photometric_yaw as py

    rng = np.random.default_rng(5)
    dense = (rng.random((300, 200)) < np.linspace(0.001, 0.6, 300)[:, None]) * rng.random((300, 200))
    M = sp.csr_matrix(dense.astype(np.float32))
    x = rng.random(200).astype(np.float32)
    monkeypatch.setenv("VASTCAL_THREADS", "2")
    monkeypatch.setattr(py, "MIN_ENTRIES_PER_THREAD", 10)
    assert np.array_equal(py._threaded_product(M)(x), M @ x)
    monkeypatch.setattr(py, "MIN_ENTRIES_PER_THREAD", 10**9)  # too small to split: the plain product
    assert np.array_equal(py._threaded_product(M)(x), M @ x)


_COST_SCRIPT = """
import importlib.util, sys
from pathlib import Path
from vastcal.calibrate.photometric_yaw import AbsorptionMatch, absorption_images
from vastcal.geometry import projection_matrices
from vastcal.segmentation import fit_automatic, specimen_maps
spec = importlib.util.spec_from_file_location("synthetic_views", sys.argv[1])
synthetic = importlib.util.module_from_spec(spec)
spec.loader.exec_module(synthetic)
theta = synthetic.truth_theta(8, seed=3)
images = synthetic.render(theta)
K, d = synthetic.camera()
pf = specimen_maps(fit_automatic(images), images)
a = absorption_images(images, pf, projection_matrices(K, d, theta[None])[0])
match = AbsorptionMatch(a, pf, K, d, theta, sirt_iterations=12)
off = theta.copy()
off[0] += 0.3
print(repr(match.s_aa), repr(match(theta)), repr(match(off)))
"""


def test_the_cost_does_not_depend_on_how_many_threads_blas_is_given() -> None:
    """The CLI gives OpenBLAS one thread, a library caller perhaps all: the same E to the last bit either way (BLAS dot
    products sum long vectors in one piece per thread)."""
    import os
    import subprocess
    import sys

    runs = []
    for threads in ("1", "2"):
        env = {**os.environ, "OPENBLAS_NUM_THREADS": threads, "OMP_NUM_THREADS": threads}
        out = subprocess.run(
            [sys.executable, "-c", _COST_SCRIPT, str(Path(__file__).with_name("synthetic.py"))],
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
            check=True,
        )
        runs.append(out.stdout.strip())
    assert runs[0] == runs[1]


def test_splats_off_the_frame_stay_within_their_own_view() -> None:
    """A specimen cut by the frame in every view (simulated larvae 24 and 28 of the battery) has voxels whose splats fall
    off the frame; their pixel index was 0 — view 0's — so a later view's row sums (bincount of its indices less its
    offset) met negative indices and the calibration stopped with an internal error."""
    from types import SimpleNamespace

    h, w = 8, 10
    K = np.array([[100.0, 0.0, 4.5], [0.0, 100.0, 3.5], [0.0, 0.0, 1.0]])
    P = projection_matrices(K, 1000.0, np.array([[0.0, 0.0, 0.0, 0.0, 90.0]]))[0]
    X = np.array(
        [[0.0, 0.0, 0.0], [0.0, 300.0, 0.0], [0.0, 0.0, -300.0], [400.0, 0.0, 0.0]]
    )  # one inside, three off the frame
    match = SimpleNamespace(shape=(2, h, w), _Xt=np.ascontiguousarray(X.T), voxel_um=1.0, voxel_across_um=1.0, K=K)
    for i in range(2):
        pixel, weight = AbsorptionMatch._splats(match, P, i, slice(None))
        assert np.all((pixel >= i * h * w) & (pixel < (i + 1) * h * w))
        assert np.all(np.isfinite(weight)) and weight.sum(axis=0)[0] > 0 and np.any(weight == 0)
        np.bincount(pixel.ravel() - i * h * w, weight.ravel(), minlength=h * w)  # the row sums of system()
