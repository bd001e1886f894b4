"""Regions one view loses or adds against the other views: found, sized, repaired, flagged — each on a simulated
revolution edited to raise it."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from qc_sim import Measured  # type: ignore[import-not-found]

from vastcal import qc, region_repair
from vastcal.hull import visual_hull
from vastcal.measure import MeasureSettings, measure_hull

UM_PER_PX = 11.0  # the fixture's pixels in the specimen plane


def _measure(measured: Measured, sil: np.ndarray) -> tuple[object, object]:
    s = MeasureSettings()
    hull = visual_hull(measured.P, sil, measured.hull.grid, min_count=s.min_count(len(sil)))  # type: ignore[attr-defined]
    return hull, measure_hull(hull, s)


def _regions(measured: Measured, sil: np.ndarray) -> tuple[list[qc.Region], region_repair.Repair, object]:
    hull, m = _measure(measured, sil)
    regions = region_repair.find_regions(
        sil, measured.P, hull, m.mesh.vertices, m.mesh.faces, um_per_px=UM_PER_PX, min_width_px=4.0
    )  # type: ignore[attr-defined]
    reported = (m.volume_mm3, m.surface_area_mm2)  # type: ignore[attr-defined]
    return regions, region_repair.repair(sil, measured.P, hull, MeasureSettings(), reported, regions), m


def test_a_view_that_cuts_the_tail_tip_short_loses_a_region_the_repair_restores(measured: Measured) -> None:
    sil = measured.silhouettes.copy()
    cols = np.flatnonzero(sil[4].any(axis=0))
    cut = cols[-1] - 80  # the last 80 px of the specimen in view 4 (of ~400): a tail the segmentation cut short
    sil[4][:, cut:] = False
    regions, rep, m = _regions(measured, sil)
    lost = [r for r in regions if r.kind == "lost"]
    assert [r.view for r in lost] == [4]
    r = lost[0]
    assert r.bbox[0] >= cut - 2 and r.bbox[0] + r.bbox[2] <= cols[-1] + 2  # where the tip was cut
    assert r.pixels == int(r.mask.sum()) > 50 and r.area_um2 == r.pixels * UM_PER_PX**2  # type: ignore[union-attr]
    assert not [x for x in regions if x.kind == "added" and x.view != 4]  # the other views are not blamed
    full = measured.measurement.volume_mm3  # type: ignore[attr-defined]
    assert m.volume_mm3 < full  # type: ignore[attr-defined]
    assert abs(rep.volume_mm3 - full) < 0.5 * (full - m.volume_mm3)  # type: ignore[operator, attr-defined]
    stated = SimpleNamespace(U_volume_mm3=0.001, U_area_mm2=0.001)
    (flag,) = qc.region_flags(regions, rep.delta_volume_mm3, rep.delta_area_mm2, stated)
    assert flag.code == "view_loses_region" and flag.views == (4,) and flag.severity == "check"
    assert f"{r.pixels} px" in flag.message and "um^2" in flag.message
    wide = SimpleNamespace(U_volume_mm3=1.0, U_area_mm2=10.0)  # a repair within the stated uncertainty: a note
    assert qc.region_flags(regions, rep.delta_volume_mm3, rep.delta_area_mm2, wide)[0].severity == "note"
    assert qc.verdict_of(qc.region_flags(regions, rep.delta_volume_mm3, rep.delta_area_mm2, wide)) == "ok"


def test_a_view_with_a_band_along_its_edge_adds_a_region_the_others_reject(measured: Measured) -> None:
    sil = measured.silhouettes.copy()
    v = 2
    rows = np.flatnonzero(sil[v].any(axis=1))
    cols = np.flatnonzero(sil[v].any(axis=0))
    mid = slice(cols[0] + 100, cols[0] + 260)
    top = rows[0]
    band = np.zeros_like(sil[v])
    band[max(top - 8, 0) : top + 2, mid] = True  # an 8-px band above the body over 160 columns (a wall's shadow)
    sil[v] |= band
    regions, rep, _ = _regions(measured, sil)
    added = [r for r in regions if r.kind == "added"]
    assert {r.view for r in added} == {v}
    assert sum(r.pixels for r in added) > 0.5 * int((band & ~measured.silhouettes[v]).sum())
    assert not [r for r in regions if r.kind == "lost"]
    flags = qc.region_flags(
        regions, rep.delta_volume_mm3, rep.delta_area_mm2, SimpleNamespace(U_volume_mm3=0.0, U_area_mm2=0.0)
    )
    assert [f.code for f in flags] == ["view_adds_region"] and flags[0].views == (v,)


def test_consistent_silhouettes_have_no_region(measured: Measured) -> None:
    regions, rep, _ = _regions(measured, measured.silhouettes)
    assert regions == [] and rep.delta_volume_mm3 == 0.0


def test_the_report_boxes_each_region_in_its_view() -> None:
    from vastcal.report.document import _regions_by_view

    r = qc.Region(3, "lost", 120, 120 * UM_PER_PX**2, (10, 20, 30, 4), 1e-4)
    boxes = _regions_by_view({"details": {"view_regions": {"regions": [r.as_dict()]}}})
    assert boxes == {
        3: [{"kind": "lost", "x": 10, "y": 20, "width": 30, "height": 4, "title": "lost: 120 px (14,520 um^2)"}]
    }
    assert _regions_by_view({}) == {}
