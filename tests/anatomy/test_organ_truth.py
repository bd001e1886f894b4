"""The simulated organs' truth: exact volumes and centroids, a swim bladder at older ages, in the truth record."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vastcal.simulators.camera.battery import battery_config
from vastcal.simulators.camera.larva import draw_specimen
from vastcal.simulators.camera.organs import SWIM_BLADDER_FROM_DPF, organ_phantom, organ_truth


def test_organ_phantom_truth_is_analytic():
    t = organ_truth(organ_phantom(), (10.0, -5.0))
    eye = t["organs"]["left eye"]
    assert eye["volume_mm3"] == pytest.approx(4 / 3 * math.pi * 90 * 60 * 45 * 1e-9)
    assert eye["centroid_um"][1] == pytest.approx(10.0) and eye["centroid_um"][2] > 0
    assert t["inter_eye_distance_um"] == pytest.approx(2 * abs(eye["centroid_um"][2] + 5.0))
    assert t["body_length_um"] == pytest.approx(2400.0)


def _specimen(seed: int):
    cfg = battery_config(seed)
    return draw_specimen(cfg.simulation, cfg.optics, cfg.camera)


def test_older_larvae_have_a_swim_bladder_younger_do_not():
    ages = {}
    for seed in range(12):
        sp = _specimen(seed)
        names = {f.name for f in sp.phantom.features}
        ages[seed] = (sp.features["age_dpf"], "swim bladder" in names)
        assert {"left eye", "right eye", "yolk"} <= names
    assert any(has for _, has in ages.values()) and not all(has for _, has in ages.values())
    for age, has in ages.values():
        assert has == (age >= SWIM_BLADDER_FROM_DPF)


def test_larva_truth_has_every_organ_with_its_own_attenuation():
    sp = _specimen(0)
    t = organ_truth(sp.phantom)
    assert t["body_length_um"] == pytest.approx(sp.features["length_um"])
    mus = {k: o["attenuation_per_um"] for k, o in t["organs"].items()}
    assert mus["left eye"] > mus["yolk"] > sp.phantom.body_attenuation_per_um
    assert np.isfinite(t["head_height_um"]) and t["head_width_um"] < t["head_height_um"]
