"""Figures of a real larva's tomogram and organs for the docs: views with the organs outlined, and slices.

    python benchmarks/zf_anatomy_figures.py zf1.h5 --views 8 3 --name zf1 [--images docs/images]

For a session holding a tomogram (``vastcal reconstruct S.h5 --anatomy``), writes two small PNGs to ``--images``:

* ``NAME-views.png``: the frames of ``--views`` (a dorsal and a lateral view, say), cropped to the specimen, with each
  organ of the tomogram (eye 1 orange, eye 2 green, yolk blue) outlined where its voxels project through the
  session's cameras (the reconstruction's own: calibrated, or imported with ``--cameras imported``);
* ``NAME-slices.png``: the report's three orthogonal slices through the eyes with the organs outlined.

It prints the anatomy record's measures (value ± U, k = 2, or not found with the reason).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # this checkout's vastcal first

COLOURS = {1: "tab:orange", 2: "tab:green", 3: "tab:blue"}


def _save_png(fig: Any, path: Path, dpi: int = 110) -> None:
    fig.savefig(path, format="png", dpi=dpi, metadata={"Software": None})


def organ_outline(P: np.ndarray, points_um: np.ndarray, shape: tuple[int, int], voxel_px: float) -> np.ndarray:
    """(H, W) float: 1 where the voxel centres ``points_um`` project (each spread over a voxel's footprint)."""
    from scipy import ndimage

    from vastcal.tomogram import project_points

    uv = np.rint(project_points(P, points_um)).astype(int)
    ok = (uv[:, 0] >= 0) & (uv[:, 0] < shape[1]) & (uv[:, 1] >= 0) & (uv[:, 1] < shape[0])
    out = np.zeros(shape, bool)
    out[uv[ok, 1], uv[ok, 0]] = True
    r = max(1, int(np.ceil(voxel_px / 2)))
    return ndimage.binary_closing(ndimage.binary_dilation(out, iterations=r), iterations=r).astype(float)


def organ_hulls(inputs: Any, frames: Any, grid: Any, labels: np.ndarray, saturation: dict[str, float]) -> dict:
    """Voxel indices (M, 3) of the visual hull of each saturated organ (the measure the anatomy uses for it), by
    label value."""
    from vastcal.anatomy_session import ORGAN_LABELS
    from vastcal.organ_hull import HULL_FRACTION, SATURATED_SHARE, frame_optical_density, organ_hull

    n = len(inputs.P)
    inside = [np.asarray(inputs.silhouettes[i]) >= 0.5 for i in range(n)]
    od = [frame_optical_density(np.asarray(frames[i]), inside[i]) for i in range(n)]
    out = {}
    for name, share in saturation.items():
        value = ORGAN_LABELS[name]
        if share > SATURATED_SHARE and (labels == value).any():
            h = organ_hull(inputs.P, od, inside, labels == value, grid, HULL_FRACTION)
            out[value] = np.argwhere(h.mask)
    return out


def views_figure(session: Path, views: list[int], out: Path) -> None:
    """``NAME-views.png`` (module docstring)."""
    from matplotlib.figure import Figure

    from vastcal.anatomy_session import load_anatomy, load_tomogram
    from vastcal.reconstruct import session_inputs
    from vastcal.session import Session
    from vastcal.session_frames import SessionFrames

    with Session.open(session) as s:
        g = s.latest_result("anatomy")
        grid, _, labels = load_tomogram(g)
        source = str(load_anatomy(g).get("camera_source", "")) or str(dict(g.attrs).get("camera_source", ""))
        imported = "imported" in source or "calibration" not in source
        inputs = session_inputs(s, calibration_run="imported" if imported else None, use_masks=True)
        frames = SessionFrames(s)
        imgs = [np.asarray(frames[v]) for v in views]
        sils = [np.asarray(inputs.silhouettes[v]) >= 0.5 for v in views]
        hulls = organ_hulls(inputs, frames, grid, labels, load_anatomy(g).get("organ_saturation", {}))
    fig = Figure(figsize=(7.2, 1.5 * len(views)), dpi=110, layout="constrained")
    for row, (v, img, sil) in enumerate(zip(views, imgs, sils)):
        ax = fig.add_subplot(len(views), 1, row + 1)
        rr, cc = np.nonzero(sil)
        r0, r1 = max(rr.min() - 15, 0), min(rr.max() + 15, img.shape[0])
        c0, c1 = max(cc.min() - 15, 0), min(cc.max() + 15, img.shape[1])
        grey = img.mean(axis=2) if img.ndim == 3 else img
        ax.imshow(grey[r0:r1, c0:c1], cmap="gray", interpolation="nearest")
        P = inputs.P[v]
        centre = np.asarray(grid.origin) + (np.asarray(grid.shape) - 1) / 2 * grid.size
        px = np.linalg.norm(P[:2, :3] @ np.array([grid.size, 0, 0])) / (P[2, :3] @ centre + P[2, 3])
        for value, colour in COLOURS.items():
            pts = np.asarray(grid.origin) + np.argwhere(labels == value) * grid.size
            if len(pts):
                m = organ_outline(P, pts, grey.shape, px)[r0:r1, c0:c1]
                ax.contour(m, levels=[0.5], colors=colour, linewidths=0.9)
            if value in hulls:
                m = organ_outline(P, np.asarray(grid.origin) + hulls[value] * grid.size, grey.shape, px)[r0:r1, c0:c1]
                ax.contour(m, levels=[0.5], colors=colour, linewidths=0.9, linestyles="dashed")
        ax.set_title(
            f"view {v}: organs projected: the tomogram's regions (solid; eye 1 orange, eye 2 green, yolk blue)"
            + (", the saturated organs' hulls (dashed)" if hulls else ""),
            fontsize=7,
        )
        ax.set_axis_off()
    _save_png(fig, out)


def slices_figure(session: Path, out: Path) -> None:
    """``NAME-slices.png``: the report's slices (:func:`vastcal.report.anatomy_section.slices_figure`), as PNG."""
    from vastcal.anatomy_session import load_anatomy, load_tomogram
    from vastcal.report import anatomy_section
    from vastcal.session import Session

    with Session.open(session) as s:
        g = s.latest_result("anatomy")
        tomo, record = load_tomogram(g), load_anatomy(g)
    with mock.patch.object(anatomy_section.figures, "svg_data_uri", lambda fig: _save_png(fig, out)):
        anatomy_section.slices_figure(tomo, record)


def print_measures(session: Path) -> None:
    """The anatomy record's measures, one a line."""
    from vastcal.anatomy_session import load_anatomy
    from vastcal.session import Session

    with Session.open(session) as s:
        rec = load_anatomy(s.latest_result("anatomy"))
    for f in rec["features"]:
        if f.get("found"):
            v, u = f["value"], f["U"]
            text = f"{np.round(v, 1).tolist()} ± {u[0]:.1f}" if isinstance(v, list) else f"{v:.5g} ± {u:.2g}"
            print(f"  {f['name']:20} {text} {f['unit']} ({f.get('method', '')})")
        else:
            print(f"  {f['name']:20} not found: {f.get('reason', '')}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session", type=Path)
    ap.add_argument("--views", type=int, nargs="+", default=[0])
    ap.add_argument("--name", required=True, help="file prefix of the figures")
    ap.add_argument("--images", type=Path, default=REPO / "docs" / "images")
    a = ap.parse_args(argv)
    a.images.mkdir(parents=True, exist_ok=True)
    views_figure(a.session, a.views, a.images / f"{a.name}-views.png")
    slices_figure(a.session, a.images / f"{a.name}-slices.png")
    print(f"{a.session}:")
    print_measures(a.session)
    for kind in ("views", "slices"):
        p = a.images / f"{a.name}-{kind}.png"
        print(f"wrote {p} ({p.stat().st_size // 1024} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
