"""The wheel as a lab installs it: built from the project's own files, installed into a fresh virtual
environment outside the checkout (no system site-packages), then ``python -m vastcal --help`` and the
simulated demo (which reads the rig YAML shipped as package data) run from a folder outside the checkout.

The environment gets no pip of its own: the running pip installs into it (``pip --python``), without compiling
every installed module to bytecode (Python compiles what the commands import as they run). Slow all the same (the
dependencies are unpacked); skipped, with the reason, when the package registry cannot be reached.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tomllib
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SOURCES = ("pyproject.toml", "README.md", "LICENSE", "vastcal", "drivers", "simulators", "config")
"""What a wheel is built from: the packages, the folders mapped into them, and the metadata files."""

OFFLINE = re.compile(
    r"NewConnectionError|Name or service not known|Temporary failure in name resolution|"
    r"Network is unreachable|Could not find a version that satisfies the requirement setuptools|"
    r"No matching distribution found for setuptools|ProxyError|Max retries exceeded"
)
"""pip's words for a registry it cannot reach."""

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]


def _mapping() -> tuple[list[str], dict[str, str]]:
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    return list(cfg["packages"]), dict(cfg.get("package-dir", {}))


def _source_dir(package: str, package_dir: dict[str, str]) -> Path:
    """The repository folder that ``package`` is built from (longest mapped prefix wins)."""
    parts = package.split(".")
    for k in range(len(parts), 0, -1):
        prefix = ".".join(parts[:k])
        if prefix in package_dir:
            return ROOT / package_dir[prefix] / Path(*parts[k:])
    return ROOT / Path(*parts)


def _clean_env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "PYTHONSTARTUP")}
    env["OPENBLAS_NUM_THREADS"] = "1"
    return env


def _pip(python: Path | str, *args: str, cwd: Path) -> None:
    r = subprocess.run(
        [str(python), "-m", "pip", "--disable-pip-version-check", *args],
        cwd=cwd,
        env=_clean_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    if r.returncode != 0:
        if OFFLINE.search(r.stdout + r.stderr):
            command = next(a for a in args if a in ("install", "wheel"))
            pytest.skip(
                f"the package registry cannot be reached (pip {command}): {OFFLINE.search(r.stdout + r.stderr)[0]}"
            )
        raise AssertionError(f"pip {' '.join(args)} failed:\n{(r.stdout + r.stderr)[-3000:]}")


def test_every_package_folder_is_listed_in_pyproject() -> None:
    """Packages are listed by hand (the mapped folders rule out automatic discovery): a new sub-package,
    or a data folder inside one, that is not listed would be missing from the wheel."""
    packages, package_dir = _mapping()
    listed = {_source_dir(p, package_dir).resolve() for p in packages}
    roots = {_source_dir(p, package_dir) for p in packages if p.count(".") <= 1}
    missing = []
    for root in roots:
        for d in [root, *(p for p in root.rglob("*") if p.is_dir())]:
            if "__pycache__" in d.parts or d.name.startswith("."):
                continue
            if any(f.is_file() and not f.name.endswith(".pyc") for f in d.iterdir()) and d.resolve() not in listed:
                missing.append(str(d.relative_to(ROOT)))
    assert not missing, (
        f"folders with files that the wheel would leave out (add them to [tool.setuptools] packages): {missing}"
    )


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A wheel built (pip's isolated build) from a copy of the project's own files."""
    work = tmp_path_factory.mktemp("wheel")
    src = work / "src"
    src.mkdir()
    for name in SOURCES:
        p = ROOT / name
        if p.is_dir():
            shutil.copytree(p, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info"))
        else:
            shutil.copy2(p, src / name)
    _pip(sys.executable, "wheel", "--no-deps", "-q", "-w", str(work / "dist"), str(src), cwd=work)
    (whl,) = (work / "dist").glob("vastcal-*.whl")
    return whl


def test_wheel_holds_one_top_level_package_the_rig_files_and_the_licence(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        meta = z.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    tops = {n.split("/")[0] for n in names}
    assert tops == {"vastcal", wheel.name.split("-py3")[0] + ".dist-info"}, tops
    shipped = sorted(n.rsplit("/", 1)[1] for n in names if n.startswith("vastcal/rig_configs/") and n.endswith(".yaml"))
    assert shipped == sorted(p.name for p in (ROOT / "config").glob("*.yaml"))
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    assert "License-Expression: MIT" in meta
    requires = [line for line in meta.splitlines() if line.startswith("Requires-Dist:")]
    for lib in ("harvesters", "genicam"):
        (line,) = [r for r in requires if r.split()[1].startswith(lib)]
        assert 'extra == "rig"' in line, f"{lib} must be in the [rig] extra only: {line}"


@pytest.fixture(scope="module")
def installed(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The ``bin`` folder of a fresh venv (no system site-packages) holding the wheel and its dependencies
    (about 500 MB, left to pytest's own clean-up of old temporary folders: removing it here took ~1 min)."""
    env_dir = tmp_path_factory.mktemp("venv") / "v"
    venv.EnvBuilder(with_pip=False, system_site_packages=False, clear=True).create(env_dir)
    _pip(
        sys.executable,
        "--python",
        str(env_dir / "bin" / "python"),
        "install",
        "-q",
        "--no-compile",
        str(wheel),
        cwd=env_dir,
    )
    return env_dir / "bin"


def _run(exe: Path, *args: str, cwd: Path, timeout: float = 400) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(exe), *args], cwd=cwd, env=_clean_env(), capture_output=True, text=True, timeout=timeout)


def test_installed_wheel_runs_the_demo_outside_the_checkout(installed: Path, tmp_path: Path) -> None:
    py = installed / "python"
    where = _run(
        py,
        "-c",
        "import sysconfig, vastcal, vastcal.config as c; "
        "print(sysconfig.get_paths()['purelib']); print(vastcal.__file__); print(c.DEFAULT_CONFIG)",
        cwd=tmp_path,
    )
    assert where.returncode == 0, where.stderr
    site, module, default = (Path(s) for s in where.stdout.split())
    assert module.is_relative_to(site) and default.is_relative_to(site), (
        "vastcal must come from the venv, not the checkout"
    )
    assert default.is_file()
    assert not {"drivers", "simulators", "config"} & {p.name for p in site.iterdir()}, (
        "generic top-level packages installed"
    )
    assert not any(p.name.startswith(("harvesters", "genicam")) for p in site.iterdir()), (
        "the [rig] extra was not asked for"
    )

    help_ = _run(py, "-m", "vastcal", "--help", cwd=tmp_path)
    assert help_.returncode == 0 and "usage: vastcal" in help_.stdout, help_.stderr

    # Without the [rig] extra a real-rig acquisition is one line naming it (before any device is opened).
    rig = _run(
        installed / "vastcal",
        "acquire",
        "--config",
        str(default.with_name("vast-rig.yaml")),
        "-o",
        "s.h5",
        cwd=tmp_path,
    )
    assert rig.returncode == 1 and rig.stderr.count("\n") == 1 and "pip install 'vastcal[rig]'" in rig.stderr, (
        rig.stderr
    )

    demo = _run(installed / "vastcal", "demo", "--views", "6", "-q", "-o", "demo", cwd=tmp_path)
    assert demo.returncode == 0, demo.stderr[-2000:]
    assert (tmp_path / "demo" / "demo.h5").is_file()
    assert list((tmp_path / "demo").rglob("report.html")), "the demo wrote no report"
