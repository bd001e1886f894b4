"""vastcal acquire --simulate: a new larva every time unless a seed is given (--seed N, or the rig file's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vastcal.cli import main
from vastcal.config import CONFIG_DIR
from vastcal.session import Session


def _acquire(path: Path, *extra: str) -> tuple[np.ndarray, int, bool]:
    assert main(["acquire", "--simulate", "-o", str(path), "--views", "3", *extra]) == 0
    with Session.open(path) as s:
        sim = s.rig_config().simulation
        return s.projections(), sim.seed, sim.larva_varies


def test_each_simulated_acquisition_is_a_new_larva_unless_a_seed_is_given(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a, seed_a, varies = _acquire(tmp_path / "a.h5")
    note = capsys.readouterr().err.strip().splitlines()[-1]
    assert note == f"simulated larva and stage errors drawn from seed {seed_a}: --seed {seed_a} acquires the same again"
    b, seed_b, _ = _acquire(tmp_path / "b.h5", "-q")
    assert varies and seed_a != seed_b and not np.array_equal(a, b)
    assert capsys.readouterr().err == ""  # -q: no note
    c, seed_c, _ = _acquire(tmp_path / "c.h5", "-q", "--seed", str(seed_a))
    assert seed_c == seed_a and np.array_equal(a, c), "the printed seed acquires the same session again"


def test_a_seed_in_the_rig_file_is_kept(tmp_path: Path) -> None:
    rig = tmp_path / "rig.yaml"
    rig.write_text((CONFIG_DIR / "simulated.yaml").read_text().replace("  seed: 1\n", "  seed: 5\n"))
    a, seed_a, varies = _acquire(tmp_path / "a.h5", "-q", "--config", str(rig))
    b, seed_b, _ = _acquire(tmp_path / "b.h5", "-q", "--config", str(rig))
    assert seed_a == seed_b == 5 and np.array_equal(a, b) and not varies  # the file decides the larva, too


def test_seed_is_refused_where_it_cannot_apply(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _acquire(tmp_path / "a.h5", "-q")
    capsys.readouterr()
    assert main(["acquire", "--resume", str(tmp_path / "a.h5"), "--seed", "3"]) == 2
    assert (
        main(["acquire", "--config", str(CONFIG_DIR / "vast-rig.yaml"), "-o", str(tmp_path / "r.h5"), "--seed", "3"])
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("vastcal: error: --seed: ") for line in err), err
    assert "keeps its seed" in err[0] and "real rig" in err[1] and not (tmp_path / "r.h5").exists()
