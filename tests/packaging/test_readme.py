"""The README as a user's guide: its links lead somewhere, CI's command is in it verbatim, and its Python
API example runs as printed (on a small simulated session)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def _anchor(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    return re.sub(r"\s", "-", re.sub(r"[^\w\s-]", "", heading.strip().lower()))


def test_ci_command_is_in_the_readme_verbatim() -> None:
    ci = (ROOT / ".ci" / "run").read_text()
    line = 'pip install -e ".[test]" && python -m pytest -n auto --dist worksteal'
    assert line in ci and line in README


def test_every_link_of_the_readme_and_docs_resolves() -> None:
    broken = []
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = doc.read_text(encoding="utf-8")
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+://", target):
                continue
            path, _, frag = target.partition("#")
            dest = (doc.parent / path) if path else doc
            if not dest.exists():
                broken.append(f"{doc.name}: {target}")
            elif frag and dest.is_file():
                anchors = {_anchor(h) for h in re.findall(r"^#+ (.+)$", dest.read_text(encoding="utf-8"), flags=re.M)}
                if frag not in anchors:
                    broken.append(f"{doc.name}: {target} (no such heading)")
    assert not broken, broken


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_python_api_example_runs_as_printed(tmp_path: Path) -> None:
    (block,) = re.findall(r"## Python API.*?```python\n(.*?)```", README, flags=re.S)
    from vastcal.config import load_config
    from vastcal.pipeline import acquire_simulated

    acquire_simulated(load_config(None), tmp_path / "S.h5", views=6)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    r = subprocess.run(
        [sys.executable, "-c", block], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=540
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert re.search(r"volume 0\.\d+ mm³, area \d+\.\d+ mm²", r.stdout), r.stdout
    assert (tmp_path / "S.ply").is_file() and (tmp_path / "S-report" / "report.html").is_file()
