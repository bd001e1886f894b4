"""Calibration speed and memory on a 36-view 720 × 576 turntable set.

No real 36-view 720 × 576 turntable set is at hand (ETH David has 18 views of
640 × 480, Middlebury dinoRing 48 of 640 × 480), so this script synthesises one on ETH David's geometry:
projective pinhole cameras in circular motion, centres on a circle of radius 10 (arbitrary world units, imported
as an unknown length unit like ETH's), ~5° above the object's centre and aimed at the rotation axis, focal
length David's scaled to the frame width (fx ≈ 685 at 640 px → ≈ 771 at 720 px), 36 views at nominal 10° steps.
The stage's steps carry a fixed irregularity (σ 0.2°), so that a view offset by +10° does not land on its
neighbour's commanded angle (the importer refuses one angle twice). The object is a statuette made of seven
ellipsoids (legs, hips, torso, head, a raised and a hanging arm), 1.25 units off the axis, ~4 units tall, ray-cast
per pixel (exact silhouettes, edge pixels anti-aliased by 4 × 4 supersampling), Lambert-shaded by a lamp beside
the camera with a mild surface texture, bright on a dark background, plus Gaussian sensor noise (σ 2 grey levels);
the whole object lies inside every frame. The ambient share of the light is 0.5 (``--ambient``): the darkest
shaded parts are then ~90 grey against a 18–28 background. With 0.3 (~55 grey) the automatic colour model loses
the shadow sides, which face the same way in every view, and the cost's minimum moves off the truth (started at the
true rolls, the calibration left them by 0.3° mean, 1.3° max, to a cost 7 % lower); with 0.5 it stays at the truth.

``--turntable`` stands the figure on a turntable as ETH David's: a disc of radius 3 about the axis, 0.25 thick, its
top where the feet stand, dark grey (albedo 0.22) with paler blotches (up to +0.2) fixed to it, so that they turn
with the figure — between the background's brightness and the figure's, partly taken for the specimen by the
automatic colour model, as the real turntable is. The truth is still the cameras; the cost at the truth rises
twelvefold (0.0245 → 0.29): what a turntable in the silhouettes does to the calibration.
``--mask`` gives the calibration view 0's figure mask (the pixels that see the figure first), as a user's ``vastcal
calibrate --mask 0:FILE`` marks the turntable as background (:mod:`vastcal.segmentation.marks`).

The frames (PNG) and a ``name K R t`` camera file (Middlebury's format, 0-based pixel centres) are imported with
``vastcal.importer.import_folder``; as in benchmarks/calibrate_david.py the commanded angles of 10 views are offset
by +10°, and the coherence cost calibrates the rolls alone (bounds ±15°, no roll prior).

Prints the calibration's wall time (``calibrate_session`` alone), its evaluations and time per evaluation, the
voxels, the process's peak resident memory (``ru_maxrss``) before and after the calibration, each progress phase's
duration (the names ``vastcal calibrate`` shows), the judge cost of the result against that of the true rolls (one
extra judge evaluation: a result costlier than the truth is the search's miss, not the cost's), and the rolls'
errors against the truth (mean / max; "gauge-free" with the median offset removed).
``--chords`` sets the coherence cost's search along the rays' chords: ``bounded`` (as shipped: branch and bound on
chords of ``CHORD_BOUND_MIN_SAMPLES`` or more), ``dense`` (every sample of every chord) or ``verify`` (bounded, each
full search checked against the dense pass: rays whose maximum differs, samples read; slower). Each prints its full
searches per chord length and their mean time.
``--profile`` runs the calibration under cProfile and prints the top functions by cumulative and internal time.
cProfile sees only the main thread, so ``--profile`` sets ``VASTCAL_THREADS=1`` (cost evaluations on the main
thread) unless it is set; profiling also slows the run: take the wall time from a run without it.

    OPENBLAS_NUM_THREADS=1 python benchmarks/turntable_speed.py [--seed N] [--views 36] [--width 720 --height 576]
        [--offset-scan DEG] [--scene-seed N] [--ambient A] [--turntable [--mask]] [--chords bounded|dense|verify]
        [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import resource
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from vastcal.calibrate import objective_coherence as oc
from vastcal.calibrate.run import CalibrationResult
from vastcal.calibration_session import calibrate_session
from vastcal.config import CalibrationBounds
from vastcal.geometry import decompose_circular
from vastcal.importer import import_folder
from vastcal.progress import CalibrationProgress, PhaseProgress
from vastcal.threads import ENV as THREADS_ENV
from vastcal.threads import compute_threads

RADIUS = 10.0  # camera centres' distance from the rotation axis (world units)
CAMERA_HEIGHT = 0.9  # above the object's centre (~5° down-look)
OFF_AXIS = 1.25  # the object's centre from the rotation axis
STEP_JITTER_DEG = 0.2  # σ of the stage's step irregularity
NOISE_GREY = 2.0  # σ of the sensor noise, grey levels
SUPERSAMPLE = 4  # edge pixels: SUPERSAMPLE² rays each
DISC_RADIUS = 3.0  # the turntable (``--turntable``): radius about the axis,
DISC_TOP = -2.1  # the height of its top, where the figure's feet stand,
DISC_THICKNESS = 0.25  # and its thickness (world units)


@dataclass(frozen=True)
class Ellipsoid:
    """{X : |A⁻¹ (X − centre)| ≤ 1} with A = rotation · diag(semi-axes) (``axes``; ``inv`` is A⁻¹)."""

    centre: np.ndarray
    axes: np.ndarray
    inv: np.ndarray


def rotation(axis: str, deg: float) -> np.ndarray:
    """Right-handed rotation by ``deg`` about the world axis ``x``, ``y`` or ``z``."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    r = np.eye(3)
    r[i, i] = r[j, j] = c
    r[i, j], r[j, i] = -s, s
    return r


def statuette(joined: bool = False) -> list[Ellipsoid]:
    """Seven ellipsoids (world z up, the rotation axis through the origin): a figure ~4.1 units tall standing
    ``OFF_AXIS`` from the axis, one arm raised towards the shoulder, the other hanging, the weight on one leg.

    The head and arms float just clear of the torso (the calibration benchmarks' figure); ``joined`` moves them in to
    overlap it — one solid, as a real specimen is, whose visual hull a measurement keeps whole (a reconstruction
    keeps the largest connected part: the floating raised arm is dropped)."""
    parts = [  # (centre relative to the figure, semi-axes, tilt about y then z, degrees)
        ((0.24, 0.0, -1.25), (0.22, 0.24, 0.85), (4.0, 0.0)),  # standing leg
        ((-0.26, 0.05, -1.2), (0.2, 0.22, 0.85), (-12.0, 10.0)),  # free leg, stepping aside
        ((0.0, 0.0, -0.35), (0.5, 0.32, 0.35), (0.0, 0.0)),  # hips
        ((0.0, 0.0, 0.55), (0.55, 0.33, 0.75), (0.0, 8.0)),  # torso
        ((0.05, 0.08, 1.65), (0.26, 0.28, 0.36), (0.0, 25.0)),  # head
        ((0.78, 0.12, 0.9), (0.16, 0.17, 0.62), (-35.0, 20.0)),  # raised arm
        ((-0.74, -0.05, 0.15), (0.15, 0.16, 0.7), (10.0, 0.0)),  # hanging arm
    ]
    if joined:
        parts[4] = ((0.05, 0.08, 1.55),) + parts[4][1:]  # head on the torso
        parts[5] = ((0.62, 0.1, 0.95),) + parts[5][1:]  # raised arm at the shoulder
        parts[6] = ((-0.6, -0.05, 0.2),) + parts[6][1:]  # hanging arm at the side
    where = np.array([OFF_AXIS, 0.0, 0.0])
    out = []
    for centre, axes, (tilt_y, tilt_z) in parts:
        a = rotation("z", tilt_z) @ rotation("y", tilt_y) @ np.diag(axes)
        out.append(Ellipsoid(where + np.asarray(centre), a, np.linalg.inv(a)))
    return out


def cameras(
    n: int, width: int, height: int, rng: np.random.Generator, aim_offset: float = 0.0, spin_deg: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K (3, 3), R (n, 3, 3), t (n, 3) of ``n`` views in circular motion (x right, y down, z forward); the views'
    true angles are the nominal steps plus the stage's irregularity (view 0 exact). The camera is levelled (the axis
    images upright) and aims at the axis, or ``aim_offset`` units beside it (the axis then images beside the principal
    point, as on a turntable nobody centred to the pixel); ``spin_deg`` rolls the camera about its principal ray (the
    axis images slanted by that much)."""
    K = np.array(
        [
            [685.0 * width / 640, 0.0, 322.6 * width / 640],
            [0.0, 685.0 * width / 640, 232.1 * height / 480],
            [0.0, 0.0, 1.0],
        ]
    )
    angles = np.radians(np.arange(n) * 360.0 / n + np.r_[0.0, rng.normal(0.0, STEP_JITTER_DEG, n - 1)])
    R, t = np.empty((n, 3, 3)), np.empty((n, 3))
    for i, a in enumerate(angles):
        centre = np.array([RADIUS * np.cos(a), RADIUS * np.sin(a), CAMERA_HEIGHT])
        beside = aim_offset * np.array([-np.sin(a), np.cos(a), 0.0])  # sideways, perpendicular to the view direction
        forward = (
            np.array([-np.cos(a), -np.sin(a), -CAMERA_HEIGHT / RADIUS]) + beside / RADIUS
        )  # at the axis (or beside it), level with the object's centre
        forward /= np.linalg.norm(forward)
        right = np.cross([0.0, 0.0, -1.0], forward)
        right /= np.linalg.norm(right)
        R[i] = rotation("z", spin_deg) @ np.stack([right, np.cross(forward, right), forward])
        t[i] = -R[i] @ centre
    return K, R, t


def disc_texture(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The turntable's albedo at world (x, y): dark grey with paler blotches fixed to it (they turn with the figure),
    as ETH David's turntable has — between the background's and the figure's brightness."""
    blotches = ((-1.8, 1.2, 0.7), (1.9, -1.5, 0.6), (-0.6, -2.2, 0.5), (2.3, 1.1, 0.45), (0.4, 1.9, 0.55))
    a = np.full(x.shape, 0.22)
    for cx, cy, r in blotches:
        a += 0.2 * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2.0 * r * r))
    return a


def cast(
    rays: np.ndarray, eye: np.ndarray, light: np.ndarray, body: list[Ellipsoid], ambient: float, disc: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(hit, radiance 0..1, figure hit) of world rays (M, 3) from ``eye`` on the union of ``body``: the nearest
    intersection, Lambert-shaded from the direction ``light`` (unit, towards the lamp) plus the ``ambient`` share of the
    light, with a texture fixed to the object. ``disc``: the rays also meet the turntable (:data:`DISC_RADIUS` …),
    textured by :func:`disc_texture`."""
    near = np.full(len(rays), np.inf)
    normal = np.zeros_like(rays)
    table = np.zeros(len(rays), bool)
    if disc:  # its top (normal +z) and its rim (normal radial), the nearer of the two
        with np.errstate(divide="ignore", invalid="ignore"):
            t_top = (DISC_TOP - eye[2]) / rays[:, 2]
        q = eye[:2] + t_top[:, None] * rays[:, :2]
        on_top = (t_top > 0) & (np.einsum("ij,ij->i", q, q) <= DISC_RADIUS**2)
        near[on_top], normal[on_top], table[on_top] = t_top[on_top], (0.0, 0.0, 1.0), True
        a = np.einsum("ij,ij->i", rays[:, :2], rays[:, :2])
        b = rays[:, :2] @ eye[:2]
        disc_c = b * b - a * (eye[:2] @ eye[:2] - DISC_RADIUS**2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_rim = (-b - np.sqrt(np.maximum(disc_c, 0.0))) / a
        z = eye[2] + t_rim * rays[:, 2]
        rim = (disc_c > 0) & (t_rim > 0) & (t_rim < near) & (z <= DISC_TOP) & (z >= DISC_TOP - DISC_THICKNESS)
        near[rim], table[rim] = t_rim[rim], True
        normal[rim] = np.c_[eye[:2] + t_rim[rim, None] * rays[rim, :2], np.zeros(int(rim.sum()))]
    for e in body:
        o = e.inv @ (eye - e.centre)
        d = rays @ e.inv.T
        a = np.einsum("ij,ij->i", d, d)
        b = d @ o
        root = b * b - a * (o @ o - 1.0)
        t = (-b - np.sqrt(np.maximum(root, 0.0))) / a
        closer = (root > 0.0) & (t > 0.0) & (t < near)
        near[closer] = t[closer]
        table[closer] = False
        normal[closer] = (o + t[closer, None] * d[closer]) @ e.inv  # A⁻ᵀ (local point): the surface normal
    seen = np.isfinite(near)
    n = normal[seen] / np.linalg.norm(normal[seen], axis=1, keepdims=True)
    p = eye + near[seen, None] * rays[seen]
    albedo = np.where(
        table[seen],
        disc_texture(p[:, 0], p[:, 1]),
        0.86 + 0.14 * np.sin(7.0 * p[:, 0]) * np.sin(6.0 * p[:, 1] + 1.0) * np.sin(5.0 * p[:, 2]),
    )
    value = np.zeros(len(rays))
    value[seen] = albedo * (ambient + (1.0 - ambient) * np.clip(n @ light, 0.0, None))
    return seen, value, seen & ~table


def bounding_box(
    K: np.ndarray, R: np.ndarray, t: np.ndarray, body: list[Ellipsoid], disc: bool = False
) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1), pixels: a box around the object's image (its ellipsoids' bounding parallelepipeds projected,
    and the turntable's rims with ``disc``)."""
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1)
    corners = np.concatenate([(e.centre[:, None] + e.axes @ signs).T for e in body])
    if disc:  # its two rims, finely sampled and pushed out by a hundredth of the radius (the chords between samples)
        a = np.linspace(0.0, 2.0 * np.pi, 361)
        rim = 1.01 * DISC_RADIUS * np.stack([np.cos(a), np.sin(a)], 1)
        corners = np.concatenate(
            [corners] + [np.c_[rim, np.full(len(a), z)] for z in (DISC_TOP, DISC_TOP - DISC_THICKNESS)]
        )
    p = (corners @ R.T + t) @ K.T
    uv = p[:, :2] / p[:, 2:]
    x0, y0 = np.floor(uv.min(0)).astype(int) - 1
    x1, y1 = np.ceil(uv.max(0)).astype(int) + 2
    return int(x0), int(y0), int(x1), int(y1)


def render(
    K: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    width: int,
    height: int,
    body: list[Ellipsoid],
    rng: np.random.Generator,
    ambient: float,
    disc: bool = False,
) -> np.ndarray:
    """One RGB frame (uint8, H × W × 3): the shaded object on a dark background with sensor noise. Pixel centres
    are at integer coordinates (0-based); rays are cast only within the object's bounding box, and edge pixels
    are the mean of SUPERSAMPLE² rays. Raises ValueError when the box leaves the frame (a cut outline is no
    silhouette edge)."""
    x0, y0, x1, y1 = bounding_box(K, R, t, body, disc)
    if x0 < 1 or y0 < 1 or x1 > width - 1 or y1 > height - 1:
        raise ValueError(f"the object's box ({x0}, {y0})-({x1}, {y1}) px leaves the {width} x {height} frame")
    eye = -R.T @ t
    lamp = np.array([-0.8, -0.6, -0.8])  # up left of the camera
    light = R.T @ lamp / np.linalg.norm(lamp)
    to_world = R.T @ np.linalg.inv(K)
    gy, gx = np.mgrid[y0:y1, x0:x1].astype(float)
    h, v, _ = cast(
        np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)], 1) @ to_world.T, eye, light, body, ambient, disc
    )
    hit = np.zeros((height, width), bool)
    value = np.zeros((height, width))
    hit[y0:y1, x0:x1], value[y0:y1, x0:x1] = h.reshape(gx.shape), v.reshape(gx.shape)
    kernel = np.ones((3, 3), np.uint8)
    edge = (cv2.dilate(hit.astype(np.uint8), kernel) > 0) & (cv2.erode(hit.astype(np.uint8), kernel) == 0)
    ey, ex = np.nonzero(edge)
    sub = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5
    sy, sx = (a.ravel() for a in np.meshgrid(sub, sub, indexing="ij"))
    pix = np.stack([(ex[:, None] + sx).ravel(), (ey[:, None] + sy).ravel(), np.ones(ex.size * sx.size)], 1)
    h, v, _ = cast(pix @ to_world.T, eye, light, body, ambient, disc)
    cover = h.reshape(ex.size, -1).mean(1)
    shade = v.reshape(ex.size, -1).sum(1) / np.maximum(h.reshape(ex.size, -1).sum(1), 1)
    background = np.repeat(18.0 + 10.0 * (np.arange(height) / height)[:, None], width, 1)  # a dim gradient
    grey = background.copy()
    grey[hit] = 255.0 * value[hit]
    grey[ey, ex] = cover * 255.0 * shade + (1.0 - cover) * background[ey, ex]
    tint = np.array([1.0, 0.97, 0.92])  # warm object, RGB
    rgb = grey[..., None] * tint + rng.normal(0.0, NOISE_GREY, (height, width, 3))
    return np.clip(np.round(rgb), 0, 255).astype(np.uint8)


def figure_mask(
    K: np.ndarray, R: np.ndarray, t: np.ndarray, width: int, height: int, body: list[Ellipsoid], disc: bool
) -> np.ndarray:
    """The pixels (H, W) uint8 0/255 whose centre sees the figure first (not the turntable in front of it): the mask a
    user would draw of the view."""
    x0, y0, x1, y1 = bounding_box(K, R, t, body, disc)
    gy, gx = np.mgrid[y0:y1, x0:x1].astype(float)
    eye = -R.T @ t
    _, _, fig = cast(
        np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)], 1) @ (R.T @ np.linalg.inv(K)).T,
        eye,
        np.array([0.0, 0.0, 1.0]),
        body,
        0.5,
        disc,
    )
    out = np.zeros((height, width), np.uint8)
    out[y0:y1, x0:x1] = 255 * fig.reshape(gx.shape)
    return out


def write_set(
    folder: Path,
    n: int,
    width: int,
    height: int,
    scene_seed: int,
    ambient: float,
    disc: bool = False,
    body: list[Ellipsoid] | None = None,
    aim_offset: float = 0.0,
    spin_deg: float = 0.0,
) -> np.ndarray:
    """Render the set into ``folder`` (``images/view_NN.png``) and write ``cameras.txt`` (``name K R t``) and view 0's
    figure mask (``mask_00.png``, :func:`figure_mask`) beside it; returns the cameras (n, 3, 4). ``body``: the figure
    (default :func:`statuette`)."""
    rng = np.random.default_rng(scene_seed)
    K, R, t = cameras(n, width, height, rng, aim_offset, spin_deg)
    body = statuette() if body is None else body
    images = folder / "images"
    images.mkdir()
    lines = [str(n)]
    for i in range(n):
        name = f"view_{i:02d}.png"
        cv2.imwrite(
            str(images / name),
            cv2.cvtColor(render(K, R[i], t[i], width, height, body, rng, ambient, disc), cv2.COLOR_RGB2BGR),
        )
        lines.append(" ".join([name] + [f"{x:.12g}" for x in (*K.ravel(), *R[i].ravel(), *t[i])]))
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    cv2.imwrite(str(folder / "mask_00.png"), figure_mask(K, R[0], t[0], width, height, body, disc))
    return K @ np.concatenate([R, t[:, :, None]], 2)


def peak_mb() -> float:
    """The process's peak resident memory so far, MB (Linux: ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def print_profile(profiler: cProfile.Profile, top: int = 25) -> None:
    """The ``top`` functions by cumulative and by internal time."""
    for key in ("cumulative", "tottime"):
        out = io.StringIO()
        pstats.Stats(profiler, stream=out).sort_stats(key).print_stats(top)
        text = out.getvalue()
        print(f"\n--- profile: top {top} by {key} ---")
        print(text[text.find("   ncalls") :].rstrip())


@dataclass
class ChordStats:
    """The coherence cost's full searches along the chords, per chord length (samples): calls, seconds, and with
    ``verify`` the rays, the rays whose bounded maximum differs from the dense pass's, samples read and in all, and the
    samples read whose value differs from the dense pass's."""

    calls: dict[int, list[float]]
    rays: int = 0
    differ: int = 0
    read: int = 0
    total: int = 0
    values_differ: int = 0


def instrument_chords(mode: str) -> ChordStats:
    """Time every full search of the coherence cost (and set or check its chord search, ``--chords``)."""
    stats = ChordStats({})
    if mode == "dense":
        oc.CHORD_BOUND_MIN_SAMPLES = 10**9
    search, bounded = oc.CoherenceObjective._search_peaks, oc.CoherenceObjective._chord_profiles

    def timed(
        self: oc.CoherenceObjective, th: np.ndarray, around: np.ndarray | None = None, views: np.ndarray | None = None
    ) -> np.ndarray:
        t0 = time.perf_counter()
        out = search(self, th, around, views)
        if around is None:
            stats.calls.setdefault(self.first_stage, []).append(time.perf_counter() - t0)
        return out

    def checked(
        self: oc.CoherenceObjective,
        R: np.ndarray,
        t: np.ndarray,
        Z: np.ndarray,
        P: np.ndarray,
        views: np.ndarray | None = None,
    ) -> np.ndarray:
        out = bounded(self, R, t, Z, P, views)
        if Z.shape[-1] < oc.CHORD_BOUND_MIN_SAMPLES:  # a short chord: the dense pass itself
            return out
        dense = self._sample_min_others(R, t, Z, P, views)
        stats.rays += out[..., 0].size
        stats.differ += int(np.sum(np.argmax(out, axis=-1) != np.argmax(dense, axis=-1)))
        stats.values_differ += int(np.sum(out[np.isfinite(out)] != dense[np.isfinite(out)]))
        stats.read += int(np.isfinite(out).sum())
        stats.total += out.size
        return out

    oc.CoherenceObjective._search_peaks = timed  # type: ignore[method-assign]
    if mode == "verify":
        oc.CoherenceObjective._chord_profiles = checked  # type: ignore[method-assign]
    return stats


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=0, help="the calibration's CMA-ES seed")
    ap.add_argument("--views", type=int, default=36)
    ap.add_argument("--width", type=int, default=720)
    ap.add_argument("--height", type=int, default=576)
    ap.add_argument("--offset-scan", type=float, default=0.0, help="common roll-offset scan step, degrees (0: none)")
    ap.add_argument("--scene-seed", type=int, default=0, help="the stage's irregularity and the sensor noise")
    ap.add_argument(
        "--ambient", type=float, default=0.5, help="ambient share of the light (the rest: Lambert from the lamp)"
    )
    ap.add_argument(
        "--chords",
        choices=["bounded", "dense", "verify"],
        default="bounded",
        help="the coherence cost's search along the chords (see the module docstring)",
    )
    ap.add_argument("--profile", action="store_true", help="run the calibration under cProfile (slower)")
    ap.add_argument(
        "--turntable",
        action="store_true",
        help="stand the figure on a textured grey turntable (see the module docstring)",
    )
    ap.add_argument(
        "--mask", action="store_true", help="the colour model from view 0's figure mask, as `calibrate --mask 0:FILE`"
    )
    ap.add_argument(
        "--aim-offset",
        type=float,
        default=0.0,
        help="the levelled camera aims this many units beside the axis (0.5: ~35 px at 720 x 576): an upright axis "
        "image beside the principal point",
    )
    ap.add_argument(
        "--spin",
        type=float,
        default=0.0,
        help="the camera rolled about its principal ray, degrees (the axis images slanted)",
    )
    a = ap.parse_args()
    n = a.views
    if a.profile and not os.environ.get(THREADS_ENV):
        os.environ[THREADS_ENV] = "1"  # cProfile follows the main thread only
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        t0 = time.perf_counter()
        P = write_set(
            tmp, n, a.width, a.height, a.scene_seed, a.ambient, a.turntable, aim_offset=a.aim_offset, spin_deg=a.spin
        )
        t_render = time.perf_counter() - t0
        motion = decompose_circular(P).motion  # as the session decomposes the imported cameras
        true_rolls = motion.rolls_deg - motion.rolls_deg[0]
        truth = np.concatenate([[motion.yaw_deg, motion.pitch_deg, motion.gamma_deg], true_rolls])
        commanded = true_rolls.copy()
        offset_views = np.unique(np.round(np.linspace(1, n - 1, 10)).astype(int))  # view 0 fixes the gauge
        commanded[offset_views] += 10.0
        (tmp / "angles.txt").write_text("\n".join(f"{x:.6f}" for x in commanded) + "\n")
        session = tmp / "turntable.h5"
        t0 = time.perf_counter()
        import_folder(tmp / "images", session, angles=tmp / "angles.txt", cameras=tmp / "cameras.txt")
        t_import = time.perf_counter() - t0
        print(
            f"{n} views {a.width} x {a.height}: rendered in {t_render:.1f} s, imported in {t_import:.1f} s; "
            f"views offset +10°: {offset_views.tolist()}"
        )
        before = peak_mb()
        chords = instrument_chords(a.chords)
        bar = PhaseProgress("calibrate", enabled=False)
        profiler = cProfile.Profile() if a.profile else None
        settings = {"roll_offset_scan_deg": a.offset_scan, "roll_prior_weight": 0.0}
        t0, mono0 = time.perf_counter(), time.monotonic()  # the phases are timed on the monotonic clock
        if profiler is not None:
            profiler.enable()
        with bar:
            r: CalibrationResult = calibrate_session(
                session,
                method="coherence",
                seed=a.seed,
                free=["rolls"],
                bounds=CalibrationBounds(0.0, 0.0, 0.0, 15.0),
                progress=CalibrationProgress(bar),
                score_thetas=[truth],
                judge_imported_cameras=False,
                mask=(0, cv2.imread(str(tmp / "mask_00.png"), cv2.IMREAD_GRAYSCALE)) if a.mask else None,
                **settings,
            )
        if profiler is not None:
            profiler.disable()
        wall, mono1 = time.perf_counter() - t0, time.monotonic()
        after = peak_mb()
    err = (r.theta_deg[3:] - r.theta_deg[3]) - true_rolls
    d = err - np.median(err)
    print(
        f"coherence seed {a.seed}{' (under cProfile)' if profiler is not None else ''}: calibration {wall:.2f} s wall, "
        f"{r.n_evaluations} evaluations, {1000 * wall / max(r.n_evaluations, 1):.2f} ms per evaluation, "
        f"{r.n_voxels} voxels; "
        f"{compute_threads()} evaluation thread(s), load average {os.getloadavg()[0]:.2f}"
    )
    print(
        f"peak memory (ru_maxrss): {before:.0f} MB before the calibration, {after:.0f} MB after "
        f"(targets: ≤ 30 s, ≤ 600 MB)"
    )
    if bar.records:
        print(
            f"phases (before the first: {bar.records[0].t0 - mono0:.2f} s of set-up; after the last: "
            f"{mono1 - bar.records[-1].t1:.2f} s):"
        )
    for p in bar.records:
        print(f"  {p.name:<48} {p.t1 - p.t0:6.2f} s")
    print(
        f"judge cost: result {r.final_cost:.5f}, true rolls {r.scored_costs[0]:.5f}, commanded angles "
        f"{r.theta0_cost:.5f}"
    )
    print(
        f"angle error (views 1-{n - 1}): mean |e| {np.mean(np.abs(err[1:])):.3f}°, max {np.max(np.abs(err[1:])):.3f}° "
        f"(start: mean {np.mean(np.abs(commanded - true_rolls)[1:]):.2f}°)"
    )
    print(
        f"gauge-free (median offset {np.median(err):+.3f}° removed): mean |e| {np.mean(np.abs(d)):.3f}°, max "
        f"{np.max(np.abs(d)):.3f}°"
    )
    print("per view:", np.round(err, 2).tolist())
    for samples, times in sorted(chords.calls.items()):
        print(
            f"full searches along chords of {samples} samples ({a.chords}): {len(times)}, "
            f"{1000 * np.mean(times):.1f} ms each"
        )
    if a.chords == "verify":
        print(
            f"bounded against dense (chords of {oc.CHORD_BOUND_MIN_SAMPLES} samples or more): {chords.differ} of "
            f"{chords.rays} rays "
            f"with another maximum, {chords.values_differ} samples read with another value; "
            f"{chords.read / max(chords.total, 1):.1%} "
            "of their samples read"
        )
    if profiler is not None:
        print_profile(profiler)


if __name__ == "__main__":
    main()
