"""Phantom truth: exact volume/area, features inside the body, exact orthographic hull factor."""

from __future__ import annotations

import numpy as np
import pytest

from vastcal.errors import AnalysisError
from vastcal.simulators.camera.phantom import (
    EllipsoidFeature,
    Phantom,
    capsule_phantom,
    orthographic_hull_factor,
    spheroid_phantom,
    zebrafish_phantom,
)
from vastcal.simulators.camera.profiles import LarvaProfile, SpheroidProfile


@pytest.mark.parametrize(
    "phantom",
    [spheroid_phantom(), spheroid_phantom(300.0, 300.0), capsule_phantom()],
    ids=["spheroid", "sphere", "capsule"],
)
def test_quadrature_matches_closed_forms(phantom: Phantom) -> None:
    prof = phantom.profile
    assert phantom.volume_mm3() * 1e9 == pytest.approx(prof.exact_volume_um3(), rel=1e-10)
    assert phantom.area_mm2() * 1e6 == pytest.approx(prof.exact_area_um2(), rel=1e-10)


def test_flattened_spheroid_is_the_triaxial_ellipsoid() -> None:
    """Lateral scale s: a spheroid becomes the ellipsoid with semi-axes (a, b, s·b), whose area is
    4π·abc·R_G(a⁻², b⁻², c⁻²) (Carlson's symmetric elliptic integral)."""
    from scipy.special import elliprg

    a, b, s = 1500.0, 280.0, 0.6
    ph = Phantom(SpheroidProfile(a, b), lateral_scale=s)
    c = s * b
    assert ph.volume_mm3() * 1e9 == pytest.approx(4.0 / 3.0 * np.pi * a * b * c, rel=1e-10)
    assert ph.area_mm2() * 1e6 == pytest.approx(4.0 * np.pi * a * b * c * elliprg(a**-2, b**-2, c**-2), rel=1e-6)
    assert ph.area_mm2() < 0.9 * spheroid_phantom(a, b).area_mm2()  # the test has teeth
    assert ph.contains(np.array([[0.0, 0.0, 0.95 * c], [0.0, 0.95 * b, 0.0]])).all()
    assert not ph.contains(np.array([[0.0, 0.0, 1.05 * c]])).any()


def test_lateral_scale_outside_0_1_is_rejected() -> None:
    for s in (0.0, 1.2):
        with pytest.raises(AnalysisError, match="lateral_scale"):
            Phantom(SpheroidProfile(), lateral_scale=s)


def test_larva_truth_matches_brute_force_integration() -> None:
    prof = LarvaProfile()
    lo, hi = prof.x_range
    x = np.linspace(lo, hi, 2_000_001)
    r = prof.radius_um(x)
    dr = np.gradient(r, x)
    vol = np.trapezoid(np.pi * r * r, x)
    area = np.trapezoid(2 * np.pi * r * np.sqrt(1 + dr * dr), x)
    assert prof.volume_um3() == pytest.approx(vol, rel=1e-6)
    assert prof.area_um2() == pytest.approx(area, rel=1e-3)


def test_zebrafish_phantom_is_larva_sized_with_features_inside() -> None:
    ph = zebrafish_phantom()
    lo, hi = ph.profile.x_range
    assert hi - lo == pytest.approx(3000.0)
    assert 500.0 <= 2 * ph.profile.max_radius_um() <= 600.0
    assert 0.1 < ph.volume_mm3() < 0.4 and 1.5 < ph.area_mm2() < 4.0
    assert {f.name for f in ph.features} == {"left eye", "right eye", "yolk"}
    for f in ph.features:
        assert ph.contains(f.surface_points()).all()
    # smooth closed profile: zero at both ends, thin tail tip, head narrower than the yolk bulge
    r = ph.profile.radius_um
    assert float(r(lo)) == 0.0 and float(r(hi)) < 1e-6
    assert r(hi - 150.0) < 40.0 < r(lo + 150.0)


def test_feature_outside_the_body_is_rejected() -> None:
    with pytest.raises(AnalysisError, match="not fully inside"):
        Phantom(SpheroidProfile(), (EllipsoidFeature("blob", (0.0, 250.0, 0.0), (50.0, 50.0, 50.0), 0.01),))


def test_hull_factor_of_regular_views_is_the_regular_polygon() -> None:
    for n in (3, 4, 8, 21):
        angles = np.arange(n) * 360.0 / n
        two_n = 2 * n if n % 2 else n  # odd N: 2N distinct directions; even N: opposite views coincide
        assert orthographic_hull_factor(angles) == pytest.approx(two_n * np.tan(np.pi / two_n) / np.pi, rel=1e-12)
    assert orthographic_hull_factor([0.0, 180.0]) == float("inf")
    assert orthographic_hull_factor([10.0, 100.0]) == pytest.approx(4 / np.pi)


@pytest.mark.parametrize("lateral_scale", [1.0, 0.6])
def test_hull_truth_matches_a_brute_force_voxel_hull_for_uneven_views(lateral_scale: float) -> None:
    """Orthographic hull of a spheroid (round or flattened sideways) from 3 uneven views, by voxels
    (volume) and marching cubes (area)."""
    from skimage.measure import marching_cubes, mesh_surface_area

    a, b = 600.0, 300.0
    ph = Phantom(SpheroidProfile(a, b), lateral_scale=lateral_scale)
    angles = [0.0, 50.0, 110.0]
    step = 5.0
    xs = np.arange(-a - 3 * step, a + 3 * step + 1e-9, step)
    ys = np.arange(-380.0, 380.0 + 1e-9, step)
    X, Y, Z = np.meshgrid(xs, ys, ys, indexing="ij")
    r = ph.profile.radius_um(xs)[:, None, None]
    field = np.full(X.shape, -np.inf, np.float32)
    for phi in np.radians(angles):  # view i constrains |p · n_i| ≤ support h_i·r(x), n_i ⟂ the viewing direction
        h = np.hypot(np.cos(phi), lateral_scale * np.sin(phi))
        field = np.maximum(field, np.abs(Y * np.cos(phi) + Z * np.sin(phi)) - h * r)
    assert (field[:, [0, -1], :] > 0).all() and (field[:, :, [0, -1]] > 0).all()
    vol_voxels = np.count_nonzero(field <= 0) * step**3 / 1e9
    verts, faces, _, _ = marching_cubes(field, 0.0, spacing=(step, step, step))
    area_mc = mesh_surface_area(verts, faces) / 1e6
    assert ph.hull_volume_mm3(angles) == pytest.approx(vol_voxels, rel=3e-3)
    assert ph.hull_area_mm2(angles) == pytest.approx(area_mc, rel=1e-2)
    assert ph.hull_volume_mm3(angles) > 1.1 * ph.volume_mm3()  # a visibly fat hull: the test has teeth
