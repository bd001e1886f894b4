"""Figures of the report: matplotlib plots (SVG), full-resolution view overlays and the mesh for the 3D viewer.

* :func:`drift_plot`, :func:`agreement_plot`, :func:`convergence_plot` — matplotlib (object API,
  no pyplot state, Agg/SVG canvases) rendered to SVG with the text as paths, returned as a
  ``data:image/svg+xml;base64,…`` URI: crisp at any zoom, µ ° ³ drawn by matplotlib's own font.
* :func:`view_overlay` — one view at full resolution (JPEG data URI) and the reprojected hull
  outline as an SVG path in that view's pixel coordinates (drawn over the image by the page,
  so it stays one screen pixel wide at any zoom).
* :func:`mesh_payload` — the mesh for the page's WebGL viewer: little-endian float32 vertices
  and uint16/uint32 faces, base64, decimated by vertex clustering when it is large.

Frames: world µm (x = rotation axis); cameras map world µm to 0-based pixels of the stored
frames, whose pixel (u, v) covers [u − ½, u + ½] × [v − ½, v + ½].
"""

from __future__ import annotations

import base64
import io
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from matplotlib import rc_context
from matplotlib.figure import Figure

from vastcal.errors import AnalysisError

log = logging.getLogger(__name__)

OUTLINE_COLOUR = "#ff00ff"
"""Colour of the reprojected hull outline (magenta: visible on bright and dark)."""
FLAG_COLOUR = "#c62828"
"""Colour of what QC flagged (views, bars)."""
BAR_COLOUR = "#3b6fb6"

_RC = {
    "svg.fonttype": "path",
    "svg.hashsalt": "vastcal-report",
    "font.size": 9.0,
    "axes.titlesize": 10.0,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "grid.color": "#e6e6e6",
    "grid.linewidth": 0.6,
    "axes.axisbelow": True,
}
"""matplotlib settings of every plot (text as paths: the page needs no font; a fixed hash salt: reproducible files)."""


# ---------------------------------------------------------------------------------------------
# Encoding
# ---------------------------------------------------------------------------------------------


def png_bytes(image: np.ndarray) -> bytes:
    """Encode an 8-bit gray or BGR image as PNG.

    Raises:
        AnalysisError: OpenCV cannot encode it.
    """
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image))
    if not ok:
        raise AnalysisError("cannot encode a report figure as PNG")
    return buf.tobytes()


def png_data_uri(image: np.ndarray) -> str:
    """``data:image/png;base64,…`` of an 8-bit image."""
    return "data:image/png;base64," + base64.b64encode(png_bytes(image)).decode("ascii")


def jpeg_data_uri(image: np.ndarray, quality: int = 90) -> str:
    """``data:image/jpeg;base64,…`` of an 8-bit gray or BGR image.

    Raises:
        AnalysisError: OpenCV cannot encode it.
    """
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(image), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise AnalysisError("cannot encode a report view as JPEG")
    return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


def svg_data_uri(fig: Figure) -> str:
    """A matplotlib figure as ``data:image/svg+xml;base64,…`` (no metadata block, text as paths)."""
    buf = io.BytesIO()
    with rc_context(_RC):
        fig.savefig(buf, format="svg", metadata={"Creator": None, "Date": None, "Format": None, "Type": None})
    return "data:image/svg+xml;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def to_display_bgr(frame: np.ndarray) -> np.ndarray:
    """An 8-bit BGR picture of a stored frame (gray or RGB; other depths stretched to their 0.5–99.5 % range)."""
    f = np.asarray(frame)
    if f.dtype != np.uint8:
        lo, hi = np.percentile(f, [0.5, 99.5])
        f = np.clip((f.astype(np.float32) - lo) * (255.0 / max(float(hi - lo), 1e-6)), 0, 255).astype(np.uint8)
    if f.ndim == 2:
        return cv2.cvtColor(f, cv2.COLOR_GRAY2BGR)
    return cv2.cvtColor(f[..., :3], cv2.COLOR_RGB2BGR)


# ---------------------------------------------------------------------------------------------
# Plots
# ---------------------------------------------------------------------------------------------


def _figure(width_in: float = 7.2, height_in: float = 2.6) -> Figure:
    with rc_context(_RC):
        return Figure(figsize=(width_in, height_in), dpi=100, layout="constrained")


def drift_plot(delta_deg: Sequence[float], *, u_per_view_deg: float | None = None, status: str = "") -> str:
    """Bar plot of the calibrated − commanded angle per view (degrees); SVG data URI.

    Args:
        delta_deg: per view, degrees (view 0 defines 0°).
        u_per_view_deg: when the data do not determine the rolls, the prior's width: drawn as a ± band.
        status: the drift status (``measured``, ``undetermined``…), in the title.
    """
    d = np.asarray(delta_deg, float)
    with rc_context(_RC):
        fig = _figure()
        ax = fig.add_subplot()
        x = np.arange(d.size)
        up = np.nan_to_num(d) >= 0
        for sel, colour, label in (
            (up, BAR_COLOUR, "calibrated angle beyond the commanded one"),
            (~up, "#c0504d", "calibrated angle short of the commanded one"),
        ):
            if sel.any():
                ax.bar(x[sel], d[sel], width=0.7, color=colour, label=label)
        if u_per_view_deg:
            ax.axhspan(
                -u_per_view_deg,
                u_per_view_deg,
                color="#999999",
                alpha=0.18,
                lw=0,
                label=f"± {u_per_view_deg:.3g}°: the range the images cannot decide (roll prior)",
            )
        ax.legend(loc="upper right", frameon=False, fontsize="small")
        ax.axhline(0.0, color="#444444", lw=0.8)
        ax.set_xlabel("view")
        ax.set_ylabel("calibrated − commanded (°)")
        ax.set_title("Stage angle per view" + (f" — {status}" if status else ""))
        ax.set_xlim(-0.6, max(d.size - 0.4, 0.6))
        ax.xaxis.get_major_locator().set_params(integer=True)
    return svg_data_uri(fig)


def agreement_plot(
    iou: Sequence[float | None],
    distance_px: Sequence[float | None],
    *,
    disagree_px: float | None = None,
    fail_iou: float | None = None,
    flagged: Sequence[bool] = (),
) -> str:
    """Per-view agreement of silhouette and reprojected hull: IoU and mean boundary distance (px); SVG data URI.

    Flagged views are drawn red; the QC thresholds as dashed lines.
    """
    n = max(len(iou), len(distance_px))
    x = np.arange(n)
    iou_a = np.array([np.nan if v is None else float(v) for v in iou] + [np.nan] * (n - len(iou)))
    dist_a = np.array([np.nan if v is None else float(v) for v in distance_px] + [np.nan] * (n - len(distance_px)))
    bad = np.array([bool(flagged[i]) if i < len(flagged) else False for i in range(n)])
    colours = [FLAG_COLOUR if b else BAR_COLOUR for b in bad]
    with rc_context(_RC):
        fig = _figure(height_in=3.4)
        a1, a2 = fig.subplots(2, 1, sharex=True)
        a1.bar(x, dist_a, width=0.7, color=colours)
        if disagree_px:
            a1.axhline(disagree_px, color=FLAG_COLOUR, ls="--", lw=0.9, label=f"flag above {disagree_px:.2f} px")
            a1.legend(loc="upper right", frameon=False)
        a1.set_ylabel("boundary distance (px)")
        a1.set_title("Silhouette against the reprojected hull, per view (red: flagged by QC)")
        a2.scatter(x, iou_a, s=14, color=colours, zorder=3)
        if fail_iou:
            a2.axhline(fail_iou, color=FLAG_COLOUR, ls="--", lw=0.9, label=f"fail below IoU {fail_iou:g}")
            a2.legend(loc="lower right", frameon=False)
        lo = float(np.nanmin(iou_a)) if np.isfinite(iou_a).any() else 0.0
        a2.set_ylim(min(lo - 0.02, fail_iou - 0.05 if fail_iou else 1.0), 1.005)
        a2.set_ylabel("IoU")
        a2.set_xlabel("view")
        a2.set_xlim(-0.6, max(n - 0.4, 0.6))
        a2.xaxis.get_major_locator().set_params(integer=True)
    return svg_data_uri(fig)


def convergence_plot(
    evaluations: Sequence[float],
    cost: Sequence[float],
    *,
    title: str = "Best cost during calibration",
    runs: Sequence[dict[str, Any]] = (),
) -> str:
    """Best cost so far against the number of cost evaluations; SVG data URI.

    Log scale when every cost is positive and they span more than a factor 20. The stored trace
    concatenates the optimiser's runs (every resolution level of every start). ``runs``
    (:func:`vastcal.report.words.optimiser_runs`) cut it where each run ends and name it in the legend — one colour per
    start, dashed for its coarser levels; without them a new line begins where the best-so-far cost rises, named
    ``optimiser run 1``, ``2``…  The last point is the stored pose's cost.
    """
    ev = np.asarray(evaluations, float)
    c = np.asarray(cost, float)
    ok = np.isfinite(ev) & np.isfinite(c)
    ev, c = ev[ok], c[ok]
    with rc_context(_RC):
        fig = _figure()
        ax = fig.add_subplot()
        if c.size:
            segments = _trace_segments(ev, c, runs)
            for seg, label, colour, style in segments:
                ax.step(
                    ev[seg], c[seg], where="post", lw=1.4, color=colour, ls=style,
                    label=label if len(segments) > 1 else None,
                )  # fmt: skip
            ax.plot(ev[-1:], c[-1:], "o", color="#222222", ms=4, label="final (stored pose)")
            ax.legend(loc="upper right", frameon=False, ncols=min(len(segments) + 1, 3), fontsize="small")
            if np.all(c > 0) and c.max() / c.min() > 20:
                ax.set_yscale("log")
        else:
            ax.text(0.5, 0.5, "no data", ha="center", va="center", transform=ax.transAxes, color="#666666")
        ax.set_xlabel("cost evaluations")
        ax.set_ylabel("best cost so far")
        ax.set_title(title)
    return svg_data_uri(fig)


def _trace_segments(
    ev: np.ndarray, c: np.ndarray, runs: Sequence[dict[str, Any]]
) -> list[tuple[np.ndarray, str, str, str]]:
    """(indices, label, colour, line style) of each optimiser run in a cost trace (see :func:`convergence_plot`)."""
    ends = [r.get("end_evaluations") for r in runs]
    if runs and all(isinstance(e, (int, float)) for e in ends[:-1]) and len(runs) > 1:
        which = np.searchsorted(np.asarray(ends[:-1], float), ev, side="left")
        n_levels = max(int(r["level"]) for r in runs[:-1]) + 1
        out = []
        for j, r in enumerate(runs):
            seg = np.flatnonzero(which == j)
            if seg.size:
                colour = f"C{int(r['start']) % 10}" if r.get("start") is not None else "#444444"
                coarse = r.get("level") is not None and int(r["level"]) < n_levels - 1
                out.append((seg, str(r["label"]), colour, "--" if coarse else "-"))
        return out
    # a best-so-far cost that rises again starts the next optimiser run (another start, or the next
    # resolution level, whose costs are not comparable with the previous level's): one line per run
    cuts = np.flatnonzero(np.diff(c) > 0) + 1
    return [
        (seg, f"optimiser run {j + 1}", f"C{j % 10}", "-") for j, seg in enumerate(np.split(np.arange(c.size), cuts))
    ]


# ---------------------------------------------------------------------------------------------
# View overlays
# ---------------------------------------------------------------------------------------------


def hull_mask_in_view(P: np.ndarray, points: np.ndarray, voxel_size_um: float, shape: tuple[int, int]) -> np.ndarray:
    """uint8 mask (H, W): where the hull's voxels (centres ``points`` (M, 3) µm) project in a view.

    Each voxel centre is splatted as a disc of the voxel's projected size, so the mask is the
    hull's silhouette at pixel accuracy.
    """
    h, w = shape
    P = np.asarray(P, float)

    def project(xyz: np.ndarray) -> np.ndarray:
        hom = np.concatenate([xyz, np.ones((len(xyz), 1))], 1) @ P.T
        return hom[:, :2] / hom[:, 2:3]

    uv = project(np.asarray(points, float))
    # the voxel's image size: largest displacement of a voxel step along a world axis (any camera, affine too)
    sample = np.asarray(points, float)[:: max(1, len(points) // 200)]
    steps = [np.linalg.norm(project(sample + voxel_size_um * e) - project(sample), axis=1) for e in np.eye(3)]
    vox_px = float(np.median(np.max(steps, axis=0))) if len(sample) else 1.0
    u = np.rint(uv[:, 0]).astype(np.int64)
    v = np.rint(uv[:, 1]).astype(np.int64)
    ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    mask = np.zeros((h, w), np.uint8)
    mask[v[ok], u[ok]] = 255
    if vox_px > 64:  # a voxel this large in the image: a very coarse grid (or cameras in another unit than the hull)
        log.warning("a hull voxel spans %.0f px in a view: the outline is drawn with 64 px discs", vox_px)
        vox_px = 64.0
    k = int(max(3, 2 * math.ceil(vox_px / 2) + 1))
    mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    return mask


@dataclass(frozen=True)
class ViewOverlay:
    """One view for the overlay sheet: the frame at full resolution and the hull outline over it.

    ``outline_path`` is an SVG path in the frame's pixel coordinates with the SVG convention
    (pixel (u, v) is the unit square from (u, v) to (u + 1, v + 1)), so it overlays an
    ``<svg viewBox="0 0 width height">`` laid exactly on the image.
    """

    image_uri: str
    outline_path: str
    width: int
    height: int


def outline_path(mask: np.ndarray, *, tolerance_px: float = 0.3) -> str:
    """SVG path ``d`` of a mask's outer contours: through the boundary pixels' centres (+½ in SVG coordinates),
    smoothed along the contour (σ = 1 px) and simplified to ``tolerance_px``."""
    contours, _ = cv2.findContours(np.ascontiguousarray(mask), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    parts = []
    kernel = (
        np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0
    )  # binomial, σ = 1 px along the contour: removes the pixel staircase
    for c in contours:
        pts = c.reshape(-1, 2).astype(np.float32)
        if len(pts) >= 8:
            wrapped = np.concatenate([pts[-2:], pts, pts[:2]])
            pts = np.stack([np.convolve(wrapped[:, k], kernel, mode="valid") for k in range(2)], 1).astype(np.float32)
        c = cv2.approxPolyDP(pts.reshape(-1, 1, 2), tolerance_px, True).reshape(-1, 2).astype(float) + 0.5
        if len(c) < 2:
            continue
        parts.append("M" + " L".join(f"{x:.1f} {y:.1f}" for x, y in c) + " Z")
    return " ".join(parts)


def view_overlay(
    frame: np.ndarray, P: np.ndarray, points: np.ndarray, voxel_size_um: float, *, quality: int = 90
) -> ViewOverlay:
    """One view's frame (full resolution, JPEG ``quality``) and the outline of the hull reprojected through ``P``.

    Args:
        frame: (H, W[, 3]) stored frame.
        P: (3, 4) camera, world µm → 0-based pixels.
        points: (M, 3) world centres of hull voxels (boundary voxels suffice), µm.
        voxel_size_um: voxel edge, µm.
    """
    img = to_display_bgr(frame)
    h, w = img.shape[:2]
    mask = hull_mask_in_view(P, points, voxel_size_um, (h, w))
    return ViewOverlay(jpeg_data_uri(img, quality), outline_path(mask), int(w), int(h))


# ---------------------------------------------------------------------------------------------
# Mesh for the 3D viewer
# ---------------------------------------------------------------------------------------------


def cluster_decimate(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """Fewer than ``max_faces`` triangles by vertex clustering (display only: the measurement never uses it).

    Vertices are merged per cubic cell (their mean); faces that collapse are dropped. The cell
    grows by 1.25× from 1/400 of the bounding box's largest side until the count fits.
    """
    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64)
    if len(f) <= max_faces or len(v) == 0:
        return v, f
    lo = v.min(0)
    cell = float(np.ptp(v, axis=0).max()) / 400.0 or 1.0
    while True:
        key = np.floor((v - lo) / cell).astype(np.int64)
        _, inverse = np.unique(key, axis=0, return_inverse=True)
        inverse = inverse.ravel()
        m = int(inverse.max()) + 1
        counts = np.bincount(inverse, minlength=m).astype(float)
        nv = np.stack([np.bincount(inverse, weights=v[:, k], minlength=m) for k in range(3)], 1) / counts[:, None]
        nf = inverse[f]
        keep = (nf[:, 0] != nf[:, 1]) & (nf[:, 1] != nf[:, 2]) & (nf[:, 0] != nf[:, 2])
        nf = nf[keep]
        first = np.unique(np.sort(nf, axis=1), axis=0, return_index=True)[1]
        nf = nf[np.sort(first)]  # duplicates dropped, winding kept
        if len(nf) <= max_faces:
            return nv, nf
        cell *= 1.25


def mesh_payload(vertices: np.ndarray, faces: np.ndarray, *, max_faces: int = 60_000) -> dict[str, object]:
    """The mesh for the page's viewer: base64 of little-endian float32 vertices (µm) and uint16 (≤ 65536 vertices) or
    uint32 faces.

    Returns a dict with ``vertices_b64``, ``faces_b64``, ``index_type`` (``u2`` or ``u4``), ``n_vertices``,
    ``n_faces`` (shown), ``n_faces_measured`` (the stored mesh) and ``extent_um`` (bounding box sides).
    """
    v, f = cluster_decimate(vertices, faces, max_faces)
    v32 = np.ascontiguousarray(v, dtype="<f4")
    index_type = "u2" if len(v32) <= 65536 else "u4"  # 16-bit indices halve the faces when they can
    fi = np.ascontiguousarray(f, dtype="<" + index_type)
    return {
        "vertices_b64": base64.b64encode(v32.tobytes()).decode("ascii"),
        "faces_b64": base64.b64encode(fi.tobytes()).decode("ascii"),
        "index_type": index_type,
        "n_vertices": int(len(v32)),
        "n_faces": int(len(fi)),
        "n_faces_measured": int(len(faces)),
        "extent_um": [float(x) for x in (np.ptp(v, axis=0) if len(v) else np.zeros(3))],
    }
