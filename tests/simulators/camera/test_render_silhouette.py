"""The rendered silhouette is geometrically exact (≪ 0.05 px) for the perspective camera.

The reference edge is found independently of the renderer: rays from vastcal.geometry's P,
min over the ray of ρ(s) − r(x(s)) by bounded Brent, the edge by brentq along a column.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq, minimize_scalar

from vastcal.config import OpticsConfig, RoiConfig
from vastcal.errors import CameraError
from vastcal.geometry import intrinsics_from_optics, projection_matrices
from vastcal.simulators.camera.phantom import Phantom, spheroid_phantom, zebrafish_phantom
from vastcal.simulators.camera.profiles import SpheroidProfile
from vastcal.simulators.camera.render import BrightfieldRenderer, Capillary, refraction_collected
from vastcal.simulators.camera.truth_geometry import PinholeIntrinsics, RigTruth, camera_pose

OPTICS = OpticsConfig()
ROI = RoiConfig(0, 352, 1024, 320)
TRUTH = RigTruth(yaw_deg=0.7, pitch_deg=-0.9, axis_offset_um=40.0, distance_um=65000.0)


def reference_P(angle: float) -> np.ndarray:
    K = intrinsics_from_optics(OPTICS, ROI)
    return projection_matrices(
        K, TRUTH.distance_um, np.array([[TRUTH.yaw_deg, TRUTH.pitch_deg, TRUTH.gamma_deg, angle]])
    )[0, 0]


def ray_gap(P: np.ndarray, ph: Phantom, u: float, v: float, offset: tuple[float, float] = (0.0, 0.0)) -> float:
    """min over the ray of (elliptic distance √(y² + (z/s)²) to the body's axis − r(x)), µm: < 0 iff the ray meets the
    body.

    ``offset``: (y, z) of the body's axis off the rotation axis, µm.
    """
    M = P[:, :3]
    C = -np.linalg.solve(M, P[:, 3]) - np.array([0.0, *offset])
    D = np.linalg.solve(M, np.array([u, v, 1.0]))
    D /= np.linalg.norm(D)
    s0 = -(C[1] * D[1] + C[2] * D[2]) / (D[1] ** 2 + D[2] ** 2)

    def gap(s: float) -> float:
        X = C + s * D
        return float(np.hypot(X[1], X[2] / ph.lateral_scale) - ph.profile.radius_um(X[0]))

    res = minimize_scalar(gap, bounds=(s0 - 400.0, s0 + 400.0), method="bounded", options={"xatol": 1e-7})
    return float(res.fun)


def reference_edges(
    P: np.ndarray, ph: Phantom, u: float, v_inside: float, offset: tuple[float, float] = (0.0, 0.0)
) -> tuple[float, float]:
    top = brentq(lambda v: ray_gap(P, ph, u, v, offset), v_inside - 150.0, v_inside, xtol=1e-7)
    bottom = brentq(lambda v: ray_gap(P, ph, u, v, offset), v_inside, v_inside + 150.0, xtol=1e-7)
    return top, bottom


def edges_from_coverage(col: np.ndarray) -> tuple[float, float]:
    """Sub-pixel edges of a column's coverage profile: the area under a box-filtered step."""
    inside = np.nonzero(col >= 1.0)[0]
    a, b = inside[0], inside[-1]
    top = (a + 0.5) - col[a - 4 : a + 1].sum()
    bottom = (b - 0.5) + col[b : b + 5].sum()
    return float(top), float(bottom)


@pytest.mark.parametrize(
    "phantom,columns",
    [
        (spheroid_phantom(), [300, 512, 700]),
        (zebrafish_phantom(), [300, 380, 470, 560]),
        (Phantom(SpheroidProfile(1500.0, 280.0), lateral_scale=0.5), [300, 512, 700]),
    ],
    ids=["spheroid", "zebrafish", "flat-spheroid"],
)
@pytest.mark.parametrize("angle", [0.0, 73.0])
def test_silhouette_edges_are_subpixel_exact(phantom: Phantom, columns: list[int], angle: float) -> None:
    r = BrightfieldRenderer(phantom)
    K = PinholeIntrinsics.from_optics(OPTICS, (ROI.x, ROI.y)).K
    R, t = camera_pose(TRUTH, angle)
    cov = r.ray_geometry(K, R, t, ROI.width, ROI.height).coverage
    P = reference_P(angle)
    for u in columns:
        col = cov[:, u].astype(float)
        v_in = float(np.mean(np.nonzero(col >= 1.0)[0]))
        ref = reference_edges(P, phantom, float(u), v_in)
        got = edges_from_coverage(col)
        assert got == pytest.approx(ref, abs=0.02), (u, got, ref)


@pytest.mark.parametrize("angle", [0.0, 73.0, 200.0])
def test_an_off_axis_specimen_is_rendered_where_it_lies_and_the_capillary_stays(angle: float) -> None:
    """A larva lying off the rotation axis: exact edges of the displaced body; capillary lines unmoved."""
    offset = (25.0, -15.0)
    ph = zebrafish_phantom()
    r = BrightfieldRenderer(ph)
    K = PinholeIntrinsics.from_optics(OPTICS, (ROI.x, ROI.y)).K
    R, t = camera_pose(TRUTH, angle)
    moved = r.ray_geometry(K, R, t, ROI.width, ROI.height, offset)
    still = r.ray_geometry(K, R, t, ROI.width, ROI.height)
    assert np.array_equal(moved.rho0, still.rho0)  # the capillary turns about the rotation axis
    assert np.abs(moved.coverage - still.coverage).max() > 0.5
    P = reference_P(angle)
    for u in (380, 560):
        col = moved.coverage[:, u].astype(float)
        v_in = float(np.mean(np.nonzero(col >= 1.0)[0]))
        assert edges_from_coverage(col) == pytest.approx(reference_edges(P, ph, float(u), v_in, offset), abs=0.02)


def test_a_specimen_that_does_not_fit_in_the_capillary_is_refused() -> None:
    r = BrightfieldRenderer(zebrafish_phantom())
    K = PinholeIntrinsics.from_optics(OPTICS, (ROI.x, ROI.y)).K
    with pytest.raises(CameraError, match="does not fit"):
        r.ray_geometry(K, *camera_pose(TRUTH, 0.0), ROI.width, ROI.height, (80.0, 0.0))


def test_grey_levels_carry_the_subpixel_edge() -> None:
    """Noise-free Mono12 of a clear body: 1 − I/I_bg = coverage · (1 − edge transmission)."""
    ph = Phantom(SpheroidProfile(1500.0, 280.0), body_attenuation_per_um=0.0, edge_transmission=0.5)
    r = BrightfieldRenderer(ph, Capillary(line_depth=0.0, lumen_transmission=1.0))
    K = PinholeIntrinsics.from_optics(OPTICS, (ROI.x, ROI.y)).K
    R, t = camera_pose(TRUTH, 30.0)
    img = r.render(K, R, t, ROI.width, ROI.height, "Mono12", noise=0.0).astype(float)
    P = reference_P(30.0)
    for u in (350, 512, 650):
        col = img[:, u]
        bg = np.median(col[col > col.max() - 2])
        cov = np.clip((1.0 - col / bg) / 0.5, 0.0, 1.0)
        v_in = float(np.mean(np.nonzero(cov >= 0.999)[0]))
        cov[cov >= 0.999] = 1.0
        ref = reference_edges(P, ph, float(u), v_in)
        got = edges_from_coverage(cov)
        assert got == pytest.approx(ref, abs=0.05), (u, got, ref)


def test_rotating_the_specimen_moves_the_features_not_the_silhouette_of_a_spheroid() -> None:
    r = BrightfieldRenderer(spheroid_phantom())
    K = PinholeIntrinsics.from_optics(OPTICS, (ROI.x, ROI.y)).K
    zero = RigTruth(0.0, 0.0, 0.0, 65000.0)
    a = r.ray_geometry(K, *camera_pose(zero, 0.0), ROI.width, ROI.height).coverage
    b = r.ray_geometry(K, *camera_pose(zero, 123.0), ROI.width, ROI.height).coverage
    assert np.abs(a - b).max() < 1e-3


def test_zebrafish_eyes_and_yolk_are_darker_than_the_body() -> None:
    ph = zebrafish_phantom()
    r = BrightfieldRenderer(ph)
    K = PinholeIntrinsics.from_optics(OPTICS, (ROI.x, ROI.y)).K
    zero = RigTruth(0.0, 0.0, 0.0, 65000.0)
    img = r.render(K, *camera_pose(zero, 90.0), ROI.width, ROI.height, "Mono12", noise=0.0).astype(float)
    R, t = camera_pose(zero, 90.0)

    def px(X: tuple[float, float, float]) -> tuple[int, int]:
        x = K @ (R @ np.asarray(X) + t)
        return int(round(x[1] / x[2])), int(round(x[0] / x[2]))

    eye = img[px((-1090.0, 0.0, 80.0))]
    yolk = img[px((-480.0, 0.0, 0.0))]
    body = img[px((500.0, 0.0, 0.0))]
    bg = img[5, 5]
    assert eye < yolk < body < bg


def test_refraction_darkens_the_outline_and_spares_normal_incidence() -> None:
    """Snell's law at a cylinder: no deviation at normal incidence, light lost towards grazing incidence;
    a rendered clear body with n > 1 has a dark outline whose width grows with n, and its silhouette stays put."""
    s = np.linspace(0.0, 1.0, 201)
    f = refraction_collected(s, 1.02, 0.1)
    assert f[0] == pytest.approx(1.0) and f[-1] == pytest.approx(0.0)
    assert np.all(np.diff(f) <= 1e-7)  # monotone: more loss nearer grazing incidence
    assert np.all(refraction_collected(s, 1.0, 0.1) == 1.0)
    K = PinholeIntrinsics.from_optics(OPTICS, (ROI.x, ROI.y)).K
    R, t = camera_pose(TRUTH, 30.0)
    dark_widths = []
    for n in (1.0, 1.01, 1.03):
        ph = Phantom(
            SpheroidProfile(1500.0, 280.0), body_attenuation_per_um=0.0, edge_transmission=1.0, refractive_index=n
        )
        r = BrightfieldRenderer(ph, Capillary(line_depth=0.0, lumen_transmission=1.0))
        img = r.render(K, R, t, ROI.width, ROI.height, "Mono12", noise=0.0).astype(float)
        geom = r.last_geometry
        col = 1.0 - img[:, 512] / img[0, 512]
        inside = geom.coverage[:, 512] >= 1.0
        dark_widths.append(int(np.count_nonzero(col[inside] > 0.5)))
        if n == 1.0:
            assert np.abs(col[inside]).max() < 1e-3  # a clear body without refraction is invisible inside
    assert dark_widths[0] == 0 < dark_widths[1] < dark_widths[2]
