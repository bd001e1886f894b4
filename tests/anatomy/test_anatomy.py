"""Anatomy of the organ phantom against its analytic truth; what is not found says why."""

from __future__ import annotations

import numpy as np
import pytest

from vastcal.anatomy import measure_anatomy
from vastcal.simulators.camera.organs import organ_phantom, organ_truth


@pytest.fixture(scope="module")
def measured(organ_tomogram):
    hull, tomo = organ_tomogram
    return measure_anatomy(tomo.attenuation, hull.occupancy, hull.grid), organ_truth(organ_phantom())


def _value(anat, name):
    f = anat.feature(name)
    assert f is not None and f.found, (name, f)
    return f.value, f.U


def test_body_length_within_2_percent_and_inside_its_interval(measured):
    anat, truth = measured
    v, U = _value(anat, "body_length")
    assert v == pytest.approx(truth["body_length_um"], rel=0.02)
    assert abs(v - truth["body_length_um"]) <= U


@pytest.mark.parametrize(("name", "organ"), [("eye_1", "left eye"), ("eye_2", "right eye"), ("yolk", "yolk")])
def test_organ_volume_within_10_percent_and_centroid_within_10_um(measured, name, organ):
    anat, truth = measured
    t = truth["organs"][organ]
    v, U = _value(anat, f"{name}_volume")
    assert v == pytest.approx(t["volume_mm3"], rel=0.10)
    c, _ = _value(anat, f"{name}_centroid")
    assert np.linalg.norm(np.asarray(c) - t["centroid_um"]) < 10.0
    d, _ = _value(anat, f"{name}_diameter")
    assert d == pytest.approx(t["equivalent_diameter_um"], rel=0.04)


def test_inter_eye_distance_and_head_size(measured):
    anat, truth = measured
    assert _value(anat, "inter_eye_distance")[0] == pytest.approx(truth["inter_eye_distance_um"], abs=10.0)
    assert _value(anat, "head_height")[0] == pytest.approx(truth["head_height_um"], rel=0.06)
    assert _value(anat, "head_width")[0] == pytest.approx(truth["head_width_um"], rel=0.06)
    assert anat.head_end == "x-"


def test_a_tomogram_without_dark_organs_reports_them_not_found(organ_tomogram):
    hull, tomo = organ_tomogram
    flat = np.where(hull.occupancy, np.float32(4e-4), np.float32(0.0))
    anat = measure_anatomy(flat, hull.occupancy, hull.grid)
    for name in ("eye_1_volume", "eye_2_centroid", "inter_eye_distance", "yolk_volume", "head_height"):
        f = anat.feature(name)
        assert f is not None and not f.found and f.reason and f.value is None, name
        assert f.as_dict()["found"] is False and "value" not in f.as_dict()
    assert anat.feature("body_length").found


def test_body_cut_by_the_frame_has_no_length(organ_tomogram):
    hull, tomo = organ_tomogram
    anat = measure_anatomy(tomo.attenuation, hull.occupancy, hull.grid, cut_views=[3, 4])
    f = anat.feature("body_length")
    assert not f.found and "frame" in f.reason and "[3, 4]" in f.reason
