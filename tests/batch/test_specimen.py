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
