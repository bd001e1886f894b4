"""The anatomy stored in a session, shown in the report and tables, exported as OME-Zarr."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from vastcal import cli
from vastcal.anatomy import TABLE_COLUMNS, table_fields
from vastcal.anatomy_session import load_anatomy, load_tomogram
from vastcal.session import Session


def test_run_is_stored_as_nxdata_with_um_axes(organ_session: Path):
    with Session.open(organ_session) as s:
        g = s.latest_result("anatomy")
        assert g is not None and s.stages_run()["anatomy"] == ["run_000"]
        t = g["tomogram"]
        assert t.attrs["NX_class"] == "NXdata" and t.attrs["signal"] == "attenuation"
        assert t["attenuation"].attrs["units"] == "1/um" and all(t[a].attrs["units"] == "um" for a in "xyz")
        grid, att, labels = load_tomogram(g)
        assert att.shape == labels.shape == grid.shape and set(np.unique(labels)) == {0, 1, 2, 3}
        assert np.diff(t["x"][...]) == pytest.approx(grid.size)
        rec = load_anatomy(g)
    names = {f["name"]: f for f in rec["features"]}
    assert names["eye_1_volume"]["found"] and names["yolk_volume"]["unit"] == "mm3"
    assert rec["reconstruction_run"] == "run_000"


def test_report_shows_the_anatomy_and_its_columns(organ_session: Path, tmp_path: Path):
    from vastcal.report import write_report

    page = write_report(organ_session, tmp_path / "r")
    html = page.read_text()
    assert 'id="anatomy"' in html and "eye 1 volume" in html and "data:image/svg+xml;base64," in html
    doc = json.loads((tmp_path / "r" / "report.json").read_text())
    assert doc["measurement"]["anatomy"]["features"]
    with (tmp_path / "r" / "report.csv").open() as fh:
        row = next(csv.DictReader(fh))
    assert float(row["yolk_volume_mm3"]) == pytest.approx(0.01677, rel=0.1) and float(row["U_yolk_volume_mm3"]) > 0
    assert set(TABLE_COLUMNS) <= set(row)


def test_table_fields_leave_not_found_measures_empty_with_the_reason():
    rec = {
        "features": [
            {"name": "body_length", "found": False, "reason": "the tip is not imaged"},
            {"name": "yolk_volume", "found": True, "value": 0.01, "U": 0.001},
        ]
    }
    f = table_fields(rec)
    assert f["body_length_um"] is None and f["U_body_length_um"] is None
    assert f["yolk_volume_mm3"] == 0.01 and "the tip is not imaged" in f["anatomy_not_found"]
    assert all(v is None for v in table_fields(None).values())


def test_export_ome_zarr_opens_with_ome_zarr_and_has_um_scales(organ_session: Path, tmp_path: Path):
    pytest.importorskip("ome_zarr")
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Reader

    out = tmp_path / "organs.ome.zarr"
    assert cli.main(["export", str(organ_session), "--ome-zarr", str(out)]) == 0
    with Session.open(organ_session) as s:
        grid, att, _ = load_tomogram(s.latest_result("anatomy"))
    nodes = list(Reader(parse_url(str(out)))())
    image = nodes[0]
    ms = image.metadata
    assert [a["name"] for a in ms["axes"]] == ["z", "y", "x"] and {a["unit"] for a in ms["axes"]} == {"micrometer"}
    scales = [t[0]["scale"] for t in ms["coordinateTransformations"]]
    assert scales[0] == pytest.approx([grid.size] * 3) and len(scales) >= 2
    assert scales[1] == pytest.approx([2 * grid.size] * 3)
    level0 = np.asarray(image.data[0])
    assert level0.shape == att.shape[::-1] and np.allclose(level0, np.transpose(att, (2, 1, 0)))
    assert (out / "labels" / "organs").is_dir()


def test_export_refuses_an_existing_output_and_a_session_without_tomogram(organ_session, tmp_path, capsys):
    pytest.importorskip("ome_zarr")
    out = tmp_path / "x.ome.zarr"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert cli.main(["export", str(organ_session), "--ome-zarr", str(out)]) == 2
    assert cli.main(["export", str(organ_session), "--ome-zarr", str(out), "--force"]) == 2
    assert (out / "notes.txt").read_text() == "mine"
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "not an OME-Zarr folder" in err[-1]
    import h5py

    with h5py.File(organ_session, "a") as f:  # a session measured without anatomy: no tomogram
        del f["/entry/vastcal/anatomy"]
    assert cli.main(["export", str(organ_session), "--ome-zarr", str(tmp_path / "y.ome.zarr")]) != 0
    assert "no tomogram" in capsys.readouterr().err


def test_a_damaged_anatomy_run_is_left_out_of_the_report(organ_session: Path, tmp_path: Path):
    import h5py

    from vastcal.report import write_report

    with h5py.File(organ_session, "a") as f:
        del f["/entry/vastcal/anatomy/run_000/tomogram/attenuation"]
    html = write_report(organ_session, tmp_path / "r").read_text()
    assert 'id="anatomy"' not in html and "volume" in html
