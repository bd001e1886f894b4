"""Run today's fuzz suite (tests/fuzz) against the library code of an earlier commit.

Shows what the fuzz suite finds in code written before the hostile-input checks: the
tree of COMMIT is extracted to a temporary folder, today's ``tests/fuzz`` is copied into it, and
pytest runs there with that tree first on ``PYTHONPATH`` (so ``import vastcal`` is the old code).
Prints, per fuzz module, the cases run, the cases failed and the most common failure messages
(one per failed case, as pytest's short summary gives it).

Usage (from the project root; each run takes under a minute)::

    python benchmarks/fuzz_against_commit.py 3c1a157~1   # config before the NaN/alias/nesting checks
    python benchmarks/fuzz_against_commit.py 7c0f6ee~1   # importer before the header/angle/camera checks
    python benchmarks/fuzz_against_commit.py HEAD        # today: 0 failures expected

Constants that the fuzz modules import and the old tree lacks (``MAX_MESSAGE_CHARS``,
``MAX_ERROR_CHARS``) get stand-ins (300, 500 characters), so that the modules run.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("commit", help="git commit whose library code is fuzzed (e.g. 3c1a157~1)")
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="fuzz-old-") as tmp:
        tree = Path(tmp) / "tree"
        tree.mkdir()
        archive = subprocess.run(["git", "archive", args.commit], cwd=REPO, capture_output=True, check=True).stdout
        tar_path = Path(tmp) / "tree.tar"
        tar_path.write_bytes(archive)
        with tarfile.open(tar_path) as tar:
            tar.extractall(tree, filter="data")
        shutil.rmtree(tree / "tests" / "fuzz", ignore_errors=True)
        shutil.copytree(REPO / "tests" / "fuzz", tree / "tests" / "fuzz")
        rig = tree / "tests" / "fuzz" / "test_fuzz_rig_yaml.py"
        old_config = (tree / "vastcal" / "config.py").read_text()
        if "MAX_MESSAGE_CHARS" not in old_config:
            rig.write_text(
                rig.read_text().replace(
                    "from vastcal.config import CONFIG_DIR, MAX_MESSAGE_CHARS,",
                    "MAX_MESSAGE_CHARS = 300\nfrom vastcal.config import CONFIG_DIR,",
                )
            )
        if "MAX_ERROR_CHARS" not in (tree / "vastcal" / "cli.py").read_text():
            cli_fuzz = tree / "tests" / "fuzz" / "test_fuzz_cli_args.py"
            cli_fuzz.write_text(cli_fuzz.read_text().replace("cli.MAX_ERROR_CHARS", "500"))
        env = dict(os.environ, PYTHONPATH=str(tree), COLUMNS="400")  # wide enough for the failure messages
        for module in sorted((tree / "tests" / "fuzz").glob("test_*.py")):
            proc = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "pytest",
                    "-p",
                    "no:cacheprovider",
                    "-rf",
                    "-o",
                    "addopts=--import-mode=importlib",
                    str(module.relative_to(tree)),
                ],
                cwd=tree,
                env=env,
                capture_output=True,
                text=True,
            )
            summary = (proc.stdout.strip().splitlines() or ["?"])[-1].strip("= ")
            kinds = collections.Counter(_kind(line) for line in proc.stdout.splitlines() if line.startswith("FAILED "))
            print(f"{module.name}: {summary}")
            for kind, count in kinds.most_common(8):
                print(f"    {count:4d} x {kind}")
    return 0


def _kind(line: str) -> str:
    """The failure kind of one ``FAILED test[seed] - message`` line: the exception type, or the
    assertion's text without its seed and paths."""
    text = line.split(" - ", 1)[1] if " - " in line else "?"
    text = re.sub(r"seed \d+: ?", "", text)
    text = re.sub(r"/\S*/", "", text)
    return text[:100]


if __name__ == "__main__":
    sys.exit(main())
