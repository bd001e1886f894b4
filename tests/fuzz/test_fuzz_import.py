"""Fuzzed import folders: seeded folders of images of random sizes, types and channels, with
corrupt, truncated, empty, mislabelled, oversized-header, mixed-size or non-regular entries, and
masks, angle files, camera files and options that are sometimes valid and sometimes hostile.
``import_folder`` must either write a session that holds exactly the images, or raise a
VastcalError; never another exception, never a hang; the inputs never change, and a failed import
leaves no output (nor a temporary file) behind."""

from __future__ import annotations

import random
import sys
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # hostile_files (--import-mode=importlib)
from hostile_files import png_claiming  # noqa: E402

from vastcal.errors import VastcalError
from vastcal.importer import CameraFile, ImportSettings, import_folder
from vastcal.session import Session

CASES = 70


def _image(rng: random.Random, h: int, w: int, dtype: type, channels: int) -> np.ndarray:
    g = np.random.default_rng(rng.randrange(2**32))
    top = 255 if dtype is np.uint8 else 4095
    shape = (h, w) if channels == 1 else (h, w, channels)
    return g.integers(0, top + 1, shape).astype(dtype)


def _camera(rng: random.Random, k: int, n: int) -> np.ndarray:
    a = 2 * np.pi * k / n
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    K = np.array([[1000.0, 0, 15], [0, 1000.0, 10], [0, 0, 1]])
    return K @ np.c_[R, [0.0, 0.0, 1000.0 + rng.random()]]


def _build_case(rng: random.Random, root: Path) -> tuple[dict, int]:
    """Make the inputs of one case under ``root``; return import_folder's keyword arguments and the image count."""
    folder = root / "imgs"
    folder.mkdir()
    n = rng.randint(1, 6)
    h, w = rng.choice([(1, 1), (8, 8), (20, 30), (33, 17)])
    dtype = rng.choice([np.uint8, np.uint16])
    channels = rng.choice([1, 1, 3, 4])
    suffix = rng.choice(
        [".png", ".tif", ".png", {1: ".pgm", 3: ".ppm"}.get(channels, ".png"), ".bmp" if dtype is np.uint8 else ".png"]
    )
    for i in range(n):
        ok = cv2.imwrite(str(folder / f"v{i}{suffix}"), _image(rng, h, w, dtype, channels))
        assert ok
    files = sorted(folder.iterdir())
    for _ in range(rng.choice([0, 0, 1, 2])):  # damage
        victim = rng.choice(files)
        kind = rng.randrange(10)
        if kind == 0:
            victim.write_bytes(victim.read_bytes()[: rng.randrange(1, 40)])
        elif kind == 1:
            victim.write_bytes(b"")
        elif kind == 2:
            victim.write_bytes(bytes(rng.randrange(256) for _ in range(200)))
        elif kind == 3:
            (folder / "zz_huge.png").write_bytes(png_claiming(rng.choice([100_000, 70_000, 2**31 - 1]), 100_000))
        elif kind == 4:
            (folder / "zz_dir.png").mkdir(exist_ok=True)
        elif kind == 5 and Path("/dev/zero").exists() and not (folder / "zz_dev.png").is_symlink():
            (folder / "zz_dev.png").symlink_to("/dev/zero")
        elif kind == 6:
            cv2.imwrite(str(folder / "zz_other.png"), _image(rng, h + 1, w, dtype, channels))
        elif kind == 7:
            cv2.imwrite(str(folder / "zz_float.tif"), np.ones((h, w), np.float32))
        elif kind == 8:
            (folder / "zz_text.png").write_text("not an image\n")
        else:
            cv2.imwrite(
                str(folder / "zz_type.png"), _image(rng, h, w, np.uint16 if dtype is np.uint8 else np.uint8, channels)
            )
    n_files = len(
        [p for p in folder.iterdir() if p.suffix.lower() in (".png", ".tif", ".pgm", ".ppm", ".bmp") and p.is_file()]
    )
    kwargs: dict = {}
    if rng.random() < 0.3:
        masks = root / "masks"
        masks.mkdir()
        mh = h if rng.random() < 0.8 else h + 2
        for i in range(n if rng.random() < 0.8 else n + 1):
            cv2.imwrite(str(masks / f"m{i}.png"), (_image(rng, mh, w, np.uint8, 1) > 128).astype(np.uint8) * 255)
        kwargs["masks"] = masks
    if rng.random() < 0.4:
        values: list[str] = [f"{360.0 * i / max(n_files, 1):.6f}" for i in range(n_files)]
        if values and rng.random() < 0.6:
            values[rng.randrange(len(values))] = rng.choice(
                ["nan", "inf", "-inf", "1e999", "abc", values[0], "", "1 2 3"]
            )
        if rng.random() < 0.2:
            values.append("7")
        (root / "angles.txt").write_text("\n".join(values) + "\n")
        kwargs["angles"] = root / "angles.txt"
    if rng.random() < 0.4:
        rows = []
        for i in range(n_files):
            P = _camera(rng, i, max(n_files, 1))
            if rng.random() < 0.15:
                P = rng.choice(
                    [np.zeros((3, 4)), np.full((3, 4), np.nan), np.where(P != 0, np.inf, 0.0), np.ones((3, 4))]
                )
            rows.append(f"v{i} " + " ".join(f"{x:.9g}" for x in P.ravel()))
        text = "\n".join(rows) + "\n"
        if rng.random() < 0.15:
            text = rng.choice([text[: len(text) // 2], "\x89PNG\r\n\x1a\n\x00\x00binary", ""])
        (root / "cams.txt").write_text(text, errors="surrogateescape")
        origin = rng.choice([0.0, 0.5, 1.0, 1.0, float("nan"), 2.0, -0.5])
        kwargs["cameras"] = CameraFile(root / "cams.txt", pixel_origin=origin)
    if rng.random() < 0.25:
        kwargs["settings"] = ImportSettings(roi_offset=rng.choice([(0, 0), (5, 7), (-1, 0), (0, 10**9)]))
    return kwargs, n_files


@pytest.mark.parametrize("seed", range(CASES))
def test_fuzzed_import_folder_is_a_session_or_one_vastcal_error(tmp_path: Path, fz: ModuleType, seed: int) -> None:
    rng = random.Random(seed)
    inputs = tmp_path / "in"
    inputs.mkdir()
    kwargs, n_files = _build_case(rng, inputs)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    out = out_dir / "S.h5"
    before = fz.tree_hashes(inputs)
    try:
        with fz.deadline(fz.CASE_TIMEOUT_S, f"import_folder (seed {seed})"):
            import_folder(inputs / "imgs", out, **kwargs)
    except VastcalError as exc:
        msg = str(exc)
        assert "\n" not in msg and len(msg) <= 600, f"seed {seed}: {msg[:300]!r}"
        left = [p.name for p in out_dir.iterdir() if not (p.name.startswith(".") and p.name.endswith(".lock"))]
        assert left == [], f"seed {seed}: a failed import left {left} ({msg})"
    else:
        with Session.open(out) as s:
            assert s.n_views == n_files, f"seed {seed}"
            first = s.frame(0)
            assert first.size > 0
    assert fz.tree_hashes(inputs) == before, f"seed {seed}: the import changed its inputs"
