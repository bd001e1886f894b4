"""vastcal acquire's progress: named phases (preparing, the views, finishing) with the views' ETA, in
plain lines when stderr is not a terminal; the library tells each phase's name before its work."""

from __future__ import annotations

import threading
from pathlib import Path
from types import ModuleType

import pytest

from vastcal.acquire import acquire
from vastcal.rig import connect_rig

VIEWS = 6


def test_the_library_names_each_phase_before_its_work_and_counts_the_views_in_their_own(
    tmp_path: Path, acq: ModuleType
) -> None:
    cfg = acq.small_config(views=VIEWS)
    events: list[tuple] = []
    out = tmp_path / "s.h5"
    with connect_rig(cfg, truth_path=acq.truth_path(out)) as rig:
        result = acquire(
            rig.stage,
            rig.camera,
            cfg,
            out,
            cancel=threading.Event(),
            start_info=rig.start_info,
            on_view=rig.on_view,
            progress=lambda done, total, el: events.append(("view", done, total)),
            phase=lambda name: events.append(("phase", name)),
        )
    assert result.exit_status == "success"
    assert [e[1] for e in events if e[0] == "phase"] == [
        "preparing the camera and stage",
        f"acquiring {VIEWS} views",
        "finishing the session",
    ]
    counting = events.index(("phase", f"acquiring {VIEWS} views"))
    assert events[counting + 1 : counting + 1 + VIEWS] == [
        ("view", k, VIEWS) for k in range(1, VIEWS + 1)
    ]  # every view inside its phase
    assert events[-1] == ("phase", "finishing the session")


@pytest.mark.slow
def test_cli_acquire_writes_named_phase_lines_with_an_eta_and_no_terminal_codes_to_a_log(
    tmp_path: Path, acq: ModuleType
) -> None:
    config = acq.write_config(acq.small_config(views=VIEWS), tmp_path / "rig.yaml")
    run = acq.cli("acquire", "--simulate", "--config", str(config), "-o", "S.h5", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    lines = [ln for ln in run.stderr.splitlines() if ln.startswith("acquire:")]
    assert "\r" not in run.stderr and "\x1b" not in run.stderr
    starts = [ln.removeprefix("acquire: ").removesuffix(" ...") for ln in lines if ln.endswith(" ...")]
    assert starts == ["preparing the camera and stage", f"acquiring {VIEWS} views", "finishing the session"]
    for name in starts:  # every phase that starts also ends, with its time
        assert any(ln.startswith(f"acquire: {name}  done in ") for ln in lines), name
    counted = [ln for ln in lines if ln.startswith(f"acquire: acquiring {VIEWS} views  ") and " % " in ln]
    assert counted and all(" elapsed  ETA " in ln for ln in counted)
    assert not any(
        "ETA ?" in ln for ln in counted[1:]
    )  # from the second view on its ETA is the views left x the time per view
