"""Figures of the report: inline SVG plots and PNG images (OpenCV), no matplotlib.

* :func:`svg_plot` — a small line/bar plot as a standalone ``<svg>`` string (crisp, a few kB).
* :func:`hull_outline_sheet` — every view's image with the reprojected hull outline (PNG).
* :func:`render_mesh` — a flat-shaded software rendering of the mesh (PNG), z-buffered in numpy.
* :func:`png_data_uri` — a PNG as a ``data:image/png;base64,…`` URI for a self-contained page.

Frames: world µm (x = rotation axis), cameras map world µm to 0-based pixels of the stored frames.
"""

from __future__ import annotations

import base64
import html
import logging
import math
from typing import Sequence

import cv2
import numpy as np

from vastcal.errors import AnalysisError

log = logging.getLogger(__name__)

OUTLINE_BGR = (255, 0, 255)
"""Colour of the reprojected hull outline (magenta: visible on bright and dark)."""


# ---------------------------------------------------------------------------------------------
# PNG
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


def to_display_bgr(frame: np.ndarray) -> np.ndarray:
    """An 8-bit BGR picture of a stored frame (gray or RGB; uint8 or uint16 stretched to its 0.5–99.5 % range)."""
    f = np.asarray(frame)
    if f.dtype != np.uint8:
        lo, hi = np.percentile(f, [0.5, 99.5])
        f = np.clip((f.astype(np.float32) - lo) * (255.0 / max(float(hi - lo), 1e-6)), 0, 255).astype(np.uint8)
    if f.ndim == 2:
        return cv2.cvtColor(f, cv2.COLOR_GRAY2BGR)
    return cv2.cvtColor(f[..., :3], cv2.COLOR_RGB2BGR)


# ---------------------------------------------------------------------------------------------
# Hull outlines
# ---------------------------------------------------------------------------------------------


def hull_mask_in_view(P: np.ndarray, points: np.ndarray, voxel_size_um: float, shape: tuple[int, int]) -> np.ndarray:
    """uint8 mask (H, W): where the hull's voxels (centres ``points`` (M, 3) µm) project in a view.

    Each voxel centre is splatted as a disc of the voxel's projected size, so the mask is the
    hull's silhouette at pixel accuracy.
    """
    h, w = shape
    X = np.concatenate([points, np.ones((len(points), 1))], 1)
    hom = X @ np.asarray(P, float).T
    uv = hom[:, :2] / hom[:, 2:3]
    depth = float(np.median(np.abs(hom[:, 2]))) / float(np.linalg.norm(P[2, :3]))
    f_px = float(np.linalg.norm(P[0, :3]) / np.linalg.norm(P[2, :3]))
    vox_px = voxel_size_um * f_px / max(depth, 1e-9)
    u = np.rint(uv[:, 0]).astype(np.int64)
    v = np.rint(uv[:, 1]).astype(np.int64)
    ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    mask = np.zeros((h, w), np.uint8)
    mask[v[ok], u[ok]] = 255
    k = int(max(3, 2 * math.ceil(vox_px / 2) + 1))
    mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    return mask


FLAG_BGR = (0, 0, 220)
"""Colour of the frame drawn around a view that QC flagged (red)."""


def hull_outline_sheet(frames: np.ndarray, P: np.ndarray, points: np.ndarray, voxel_size_um: float, labels: Sequence[str],
                       *, columns: int = 3, tile_width: int = 480, flagged: Sequence[bool] | None = None) -> np.ndarray:
    """Contact sheet (BGR uint8): every view's frame with the reprojected hull outline.

    Args:
        frames: (N, H, W[, 3]) stored frames.
        P: (N, 3, 4) cameras, world µm → 0-based pixels of the frames.
        points: (M, 3) world centres of hull voxels (boundary voxels suffice), µm.
        voxel_size_um: voxel edge, µm.
        labels: one caption per view.
        flagged: per view, whether QC flagged it (a red frame and a red caption).
    """
    n = len(frames)
    h, w = frames.shape[1:3]
    scale = tile_width / w
    th = max(1, int(round(h * scale)))
    tiles = []
    for i in range(n):
        img = to_display_bgr(frames[i])
        mask = hull_mask_in_view(P[i], points, voxel_size_um, (h, w))
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        small = cv2.resize(img, (tile_width, th), interpolation=cv2.INTER_AREA)
        scaled = [np.rint(c.astype(np.float64) * scale).astype(np.int32) for c in contours]
        cv2.polylines(small, scaled, True, OUTLINE_BGR, 1, cv2.LINE_AA)
        bad = bool(flagged[i]) if flagged is not None and i < len(flagged) else False
        if bad:
            cv2.rectangle(small, (0, 0), (tile_width - 1, th - 1), FLAG_BGR, 3)
        caption = np.full((18, tile_width, 3), 255, np.uint8)
        cv2.putText(caption, str(labels[i]), (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, FLAG_BGR if bad else (40, 40, 40), 1, cv2.LINE_AA)
        tiles.append(np.vstack([caption, small]))
    rows = []
    blank = np.full_like(tiles[0], 255)
    gap = np.full((tiles[0].shape[0], 6, 3), 255, np.uint8)
    for r in range(0, n, columns):
        row = tiles[r:r + columns] + [blank] * (columns - len(tiles[r:r + columns]))
        parts = []
        for j, t in enumerate(row):
            parts += ([gap] if j else []) + [t]
        rows.append(np.hstack(parts))
        rows.append(np.full((6, rows[-1].shape[1], 3), 255, np.uint8))
    return np.vstack(rows[:-1])


# ---------------------------------------------------------------------------------------------
# Mesh rendering
# ---------------------------------------------------------------------------------------------


def _rotation(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Rows: image right, image down, view direction (into the screen), in world coordinates.

    Azimuth turns the specimen about its long axis (world x); elevation tilts it toward the viewer.
    """
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    # Start: right = +x, down = +y, into the screen = +z; turn about x by azimuth, then about right by elevation.
    Rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    Re = np.array([[math.cos(e), 0, math.sin(e)], [0, 1, 0], [-math.sin(e), 0, math.cos(e)]])
    return Re @ Rx


def render_mesh(vertices: np.ndarray, faces: np.ndarray, *, width: int = 900, azimuth_deg: float = 0.0, elevation_deg: float = 0.0,
                colour_bgr: tuple[int, int, int] = (200, 170, 120), scale_bar_um: float | None = 500.0) -> np.ndarray:
    """Flat-shaded orthographic rendering of a mesh (BGR uint8), white background.

    Triangles are rasterised in numpy (barycentric tests on per-triangle pixel stencils) with
    a z-buffer; shading is Lambert from a light over the viewer's shoulder plus ambient.

    Args:
        vertices: (V, 3) world µm.
        faces: (F, 3) indices, outward normals.
        width: image width, px (height follows the mesh's aspect).
        azimuth_deg, elevation_deg: view direction (see :func:`_rotation`).
        scale_bar_um: length of the scale bar drawn bottom-left, µm (None: no bar).
    """
    R = _rotation(azimuth_deg, elevation_deg)
    v = (np.asarray(vertices, float) - np.mean(vertices, axis=0)) @ R.T
    lo, hi = v[:, :2].min(0), v[:, :2].max(0)
    margin = 0.06 * (hi[0] - lo[0]) + 1e-9
    px_per_um = (width - 1) / (hi[0] - lo[0] + 2 * margin)
    height = int(math.ceil((hi[1] - lo[1] + 2 * margin) * px_per_um)) + 1 + (30 if scale_bar_um else 0)
    sx = (v[:, 0] - lo[0] + margin) * px_per_um
    sy = (v[:, 1] - lo[1] + margin) * px_per_um
    sz = v[:, 2]
    f = np.asarray(faces, np.int64)
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    front = normals[:, 2] < 0  # facing the viewer (view direction +z)
    f, normals = f[front], normals[front]
    light = np.array([-0.35, -0.5, -0.8])
    light /= np.linalg.norm(light)
    shade = 0.25 + 0.75 * np.clip(normals @ light, 0, 1)

    x0, y0, z0 = sx[f[:, 0]], sy[f[:, 0]], sz[f[:, 0]]
    x1, y1, z1 = sx[f[:, 1]], sy[f[:, 1]], sz[f[:, 1]]
    x2, y2, z2 = sx[f[:, 2]], sy[f[:, 2]], sz[f[:, 2]]
    bx0 = np.floor(np.minimum(np.minimum(x0, x1), x2)).astype(np.int64)
    by0 = np.floor(np.minimum(np.minimum(y0, y1), y2)).astype(np.int64)
    size = np.maximum(np.ceil(np.maximum(np.maximum(x0, x1), x2)) - bx0, np.ceil(np.maximum(np.maximum(y0, y1), y2)) - by0).astype(np.int64) + 1
    pix_all, depth_all, tri_all = [], [], []
    for k in (2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048):
        sel = np.flatnonzero((size <= k) & (size > k // 2) if k > 2 else size <= k)
        if sel.size == 0:
            continue
        oy, ox = np.mgrid[0:k, 0:k]
        ox, oy = ox.ravel(), oy.ravel()
        chunk = max(1, 4_000_000 // (k * k))
        for s in range(0, sel.size, chunk):
            t = sel[s:s + chunk]
            px = bx0[t, None] + ox[None, :]  # pixel centres sit at integer coordinates
            py = by0[t, None] + oy[None, :]
            d = (y1[t] - y2[t]) * (x0[t] - x2[t]) + (x2[t] - x1[t]) * (y0[t] - y2[t])
            d = np.where(np.abs(d) < 1e-12, 1e-12, d)[:, None]
            l0 = ((y1[t] - y2[t])[:, None] * (px - x2[t][:, None]) + (x2[t] - x1[t])[:, None] * (py - y2[t][:, None])) / d
            l1 = ((y2[t] - y0[t])[:, None] * (px - x2[t][:, None]) + (x0[t] - x2[t])[:, None] * (py - y2[t][:, None])) / d
            l2 = 1.0 - l0 - l1
            eps = -1e-6
            inside = (l0 >= eps) & (l1 >= eps) & (l2 >= eps) & (px >= 0) & (px < width) & (py >= 0) & (py < height)
            ti, si = np.nonzero(inside)
            if ti.size == 0:
                continue
            z = l0[ti, si] * z0[t][ti] + l1[ti, si] * z1[t][ti] + l2[ti, si] * z2[t][ti]
            pix_all.append((py[ti, si] * width + px[ti, si]).astype(np.int64))
            depth_all.append(z)
            tri_all.append(t[ti])
    img = np.full((height, width, 3), 255, np.uint8)
    if pix_all:
        pix = np.concatenate(pix_all)
        depth = np.concatenate(depth_all)
        tri = np.concatenate(tri_all)
        order = np.lexsort((depth, pix))  # by pixel, nearest first
        first = np.r_[True, pix[order][1:] != pix[order][:-1]]
        winners = order[first]
        flat = img.reshape(-1, 3)
        flat[pix[winners]] = (np.asarray(colour_bgr, float)[None, :] * shade[tri[winners], None]).clip(0, 255).astype(np.uint8)
    if scale_bar_um:
        bar = int(round(scale_bar_um * px_per_um))
        yb = height - 14
        cv2.line(img, (12, yb), (12 + bar, yb), (30, 30, 30), 2)
        cv2.putText(img, f"{scale_bar_um:g} um", (18 + bar, yb + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (30, 30, 30), 1, cv2.LINE_AA)
    return img


# ---------------------------------------------------------------------------------------------
# SVG plots
# ---------------------------------------------------------------------------------------------


def nice_ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    """About ``n`` round tick values covering [lo, hi]."""
    if not np.isfinite(lo) or not np.isfinite(hi):
        return np.array([0.0])
    if hi <= lo:
        hi = lo + (abs(lo) if lo else 1.0)
    raw = (hi - lo) / max(n, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = min((m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw), default=10 * mag)
    start = math.floor(lo / step) * step
    return np.arange(start, hi + step * 0.5, step)


def _fmt(v: float) -> str:
    return f"{v:.4g}" if v != 0 else "0"


def svg_plot(x: Sequence[float], y: Sequence[float], *, title: str, xlabel: str, ylabel: str, kind: str = "line",
             width: int = 640, height: int = 260, log_y: bool = False, zero_line: bool = False) -> str:
    """A standalone SVG plot (``kind`` ``"line"``, ``"bar"`` or ``"points"``).

    Args:
        x, y: data (same length, finite values plotted).
        title, xlabel, ylabel: texts (units belong in the labels).
        log_y: plot log10(y) (positive values only), ticks labelled in y.
        zero_line: draw y = 0.
    """
    xa = np.asarray(x, float)
    ya = np.asarray(y, float)
    ok = np.isfinite(xa) & np.isfinite(ya) & ((ya > 0) if log_y else True)
    xa, ya = xa[ok], ya[ok]
    ml, mr, mt, mb = 64, 16, 28, 42
    pw, ph = width - ml - mr, height - mt - mb
    esc = html.escape
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" viewBox="0 0 {width} {height}" '
             f'font-family="sans-serif" font-size="11" role="img" aria-label="{esc(title)}">',
             f'<rect width="{width}" height="{height}" fill="#fff"/>',
             f'<text x="{width / 2:.1f}" y="16" text-anchor="middle" font-size="13" font-weight="bold">{esc(title)}</text>']
    if xa.size == 0:
        parts.append(f'<text x="{width / 2:.1f}" y="{height / 2:.1f}" text-anchor="middle" fill="#666">no data</text></svg>')
        return "".join(parts)
    yv = np.log10(ya) if log_y else ya
    x_lo, x_hi = float(xa.min()), float(xa.max())
    if kind == "bar":
        x_lo, x_hi = x_lo - 0.6, x_hi + 0.6
    if x_hi <= x_lo:
        x_lo, x_hi = x_lo - 1, x_hi + 1
    y_lo, y_hi = float(yv.min()), float(yv.max())
    if kind == "bar" or zero_line:
        y_lo, y_hi = min(y_lo, 0.0), max(y_hi, 0.0)
    if y_hi <= y_lo:
        y_lo, y_hi = y_lo - 1, y_hi + 1
    pad = 0.06 * (y_hi - y_lo)
    y_lo, y_hi = y_lo - pad, y_hi + pad
    yt = nice_ticks(y_lo, y_hi)
    y_lo, y_hi = min(y_lo, float(yt[0])), max(y_hi, float(yt[-1]))

    def X(val: np.ndarray | float) -> np.ndarray:
        return ml + (np.asarray(val, float) - x_lo) / (x_hi - x_lo) * pw

    def Y(val: np.ndarray | float) -> np.ndarray:
        return mt + ph - (np.asarray(val, float) - y_lo) / (y_hi - y_lo) * ph

    parts.append(f'<rect x="{ml}" y="{mt}" width="{pw}" height="{ph}" fill="none" stroke="#999"/>')
    for t in yt:
        if y_lo - 1e-12 <= t <= y_hi + 1e-12:
            yy = float(Y(t))
            label = _fmt(10 ** t) if log_y else _fmt(float(t))
            parts.append(f'<line x1="{ml}" y1="{yy:.1f}" x2="{ml + pw}" y2="{yy:.1f}" stroke="#eee"/>'
                         f'<text x="{ml - 5}" y="{yy + 4:.1f}" text-anchor="end">{label}</text>')
    for t in nice_ticks(x_lo, x_hi, 8):
        if x_lo - 1e-12 <= t <= x_hi + 1e-12:
            xx = float(X(t))
            parts.append(f'<line x1="{xx:.1f}" y1="{mt + ph}" x2="{xx:.1f}" y2="{mt + ph + 4}" stroke="#999"/>'
                         f'<text x="{xx:.1f}" y="{mt + ph + 16}" text-anchor="middle">{_fmt(float(t))}</text>')
    if zero_line or kind == "bar":
        parts.append(f'<line x1="{ml}" y1="{float(Y(0.0)):.1f}" x2="{ml + pw}" y2="{float(Y(0.0)):.1f}" stroke="#444"/>')
    if kind == "bar":
        bw = max(1.0, 0.7 * pw / max(len(xa), 1))
        for xi, yi in zip(xa, yv):
            y0, y1 = sorted((float(Y(0.0)), float(Y(yi))))
            parts.append(f'<rect x="{float(X(xi)) - bw / 2:.1f}" y="{y0:.1f}" width="{bw:.1f}" height="{max(y1 - y0, 0.5):.1f}" '
                         f'fill="{"#3b6fb6" if yi >= 0 else "#c0504d"}"/>')
    elif kind == "points":
        parts += [f'<circle cx="{float(X(a)):.1f}" cy="{float(Y(b)):.1f}" r="2.5" fill="#3b6fb6"/>' for a, b in zip(xa, yv)]
    else:
        pts = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(X(xa), Y(yv)))
        parts.append(f'<polyline points="{pts}" fill="none" stroke="#3b6fb6" stroke-width="1.5"/>')
    parts.append(f'<text x="{ml + pw / 2:.1f}" y="{height - 8}" text-anchor="middle">{esc(xlabel)}</text>')
    parts.append(f'<text x="14" y="{mt + ph / 2:.1f}" text-anchor="middle" transform="rotate(-90 14 {mt + ph / 2:.1f})">{esc(ylabel)}</text>')
    parts.append("</svg>")
    return "".join(parts)
