"""vastcal annotate: specimen metadata in S.specimen.json sidecars (the session file is never touched)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from vastcal.cli import main
from vastcal.specimen import read_specimen


def test_annotate_fields_and_manifest(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    s = tmp_path / "a.h5"
    s.write_bytes(b"session bytes")
    assert main(["annotate", str(s), "--id", "F1", "--age-dpf", "5", "--well", "A1"]) == 0
    (tmp_path / "screen.csv").write_text("session,strain,plate\na.h5,AB,P1\n")
    assert main(["annotate", "--manifest", str(tmp_path / "screen.csv")]) == 0
    assert read_specimen(s) == {"specimen_id": "F1", "age_dpf": 5.0, "strain": "AB", "plate": "P1", "well": "A1"}
    assert s.read_bytes() == b"session bytes"
    before = (tmp_path / "a.specimen.json").read_text()
    (tmp_path / "bad.csv").write_text("session,strain\na.h5,TL\nmissing.h5,AB\n")
    capsys.readouterr()
    assert main(["annotate", "--manifest", str(tmp_path / "bad.csv")]) == 2  # nothing written when a line is bad
    assert main(["annotate", str(s), "--age-dpf", "-1"]) == 2
    assert main(["annotate", str(s)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and "line 3" in err[0] and "age_dpf" in err[1]
    assert (tmp_path / "a.specimen.json").read_text() == before
    assert json.loads(before)["strain"] == "AB"


def test_acquire_specimen_is_stored_in_the_session_and_reaches_the_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from vastcal.batch import table_rows
    from vastcal.specimen import session_specimen

    a = tmp_path / "larva_001.h5"
    assert (
        main(["acquire", "--simulate", "-o", str(a), "--views", "3", "-q", "--specimen", "ID=F1, age_dpf=5,strain=AB"])
        == 0
    )
    assert session_specimen(a) == {"specimen_id": "F1", "age_dpf": 5.0, "strain": "AB"}
    assert not (tmp_path / "larva_001.specimen.json").exists()  # in the session itself, not a sidecar

    # a screen's manifest (YAML): acquire takes the entry of the session it writes
    manifest = tmp_path / "screen.yaml"
    manifest.write_text("larva_002.h5: {id: F2, age_dpf: 6, well: A2}\nlarva_003: {id: F3, treatment: DMSO}\n")
    b = tmp_path / "larva_002.h5"
    assert main(["acquire", "--simulate", "-o", str(b), "--views", "3", "-q", "--specimen", str(manifest)]) == 0
    assert session_specimen(b) == {"specimen_id": "F2", "age_dpf": 6.0, "well": "A2"}

    # the table: the session's own fields, a later sidecar (vastcal annotate) overriding them
    assert main(["annotate", str(b), "--well", "C7"]) == 0
    state = {
        "sessions": {
            p.stem: {"row": {"path": str(p), "status": "ok", "_specimen": session_specimen(p)}} for p in (a, b)
        }
    }
    rows = {r["session"]: r for r in table_rows(state)}
    assert rows["larva_001"]["specimen_id"] == "F1" and rows["larva_001"]["strain"] == "AB"
    assert rows["larva_002"]["well"] == "C7" and rows["larva_002"]["age_dpf"] == 6.0

    capsys.readouterr()
    c = tmp_path / "larva_004.h5"
    for spec in ("age_dpf=old", "colour=red", str(manifest), str(tmp_path / "none.yaml")):
        assert main(["acquire", "--simulate", "-o", str(c), "--views", "3", "-q", "--specimen", spec]) == 2
    assert main(["acquire", "--resume", str(a), "--specimen", "ID=F9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 5 and all(line.startswith("vastcal: error: ") and "--specimen" in line for line in err), err
    assert "age_dpf" in err[0] and "colour" in err[1] and "larva_004.h5" in err[2] and "no such file" in err[3]
    assert not c.exists()  # refused before the stage moved


def test_annotate_from_a_yaml_manifest(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for n in ("a", "b"):
        (tmp_path / f"{n}.h5").write_bytes(b"session bytes")
    (tmp_path / "screen.yaml").write_text("a.h5: {ID: F1, age: 4}\nb.h5: {strain: TL, well: H12}\n")
    assert main(["annotate", "--manifest", str(tmp_path / "screen.yaml")]) == 0
    assert read_specimen(tmp_path / "a.h5") == {"specimen_id": "F1", "age_dpf": 4.0}
    assert read_specimen(tmp_path / "b.h5") == {"strain": "TL", "well": "H12"}
    (tmp_path / "bad.yaml").write_text("a.h5: {strain: AB}\nc.h5: {strain: AB}\n")
    capsys.readouterr()
    assert main(["annotate", "--manifest", str(tmp_path / "bad.yaml")]) == 2
    assert main(["annotate", "--manifest", str(tmp_path / "none.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "c.h5" in err[0] and "no such file" in err[1], err
    assert "strain" not in read_specimen(tmp_path / "a.h5")  # nothing written when an entry is bad


@pytest.mark.parametrize(
    "content",
    [b'{"strain": "AB", ', b"[1, 2]", b"\xff\xfe not text", b'"just a string"'],
    ids=["truncated JSON", "a list", "not UTF-8", "a string"],
)
def test_annotate_refuses_a_corrupt_sidecar_and_keeps_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes
) -> None:
    s, other = tmp_path / "a.h5", tmp_path / "b.h5"
    for p in (s, other):
        p.write_bytes(b"session bytes")
    side = tmp_path / "a.specimen.json"
    side.write_bytes(content)
    capsys.readouterr()
    assert main(["annotate", str(other), str(s), "--strain", "TL"]) == 2
    (tmp_path / "screen.csv").write_text("session,well\nb.h5,A1\na.h5,A2\n")
    assert main(["annotate", "--manifest", str(tmp_path / "screen.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("vastcal: error: ") for line in err), err
    assert all(str(side) in line and "not a specimen sidecar" in line and "JSON object" in line for line in err), err
    assert side.read_bytes() == content  # never replaced
    assert not (tmp_path / "b.specimen.json").exists()  # every sidecar is checked before any is written
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5", "a.specimen.json", "b.h5", "screen.csv"]
    assert read_specimen(s) == {}  # readers that go on without it (the batch table) leave its fields out
