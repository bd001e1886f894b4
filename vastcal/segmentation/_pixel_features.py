"""Pixel values as colour features: scaling to [0, 1], flattened illumination, and checks of a stack.

A *feature* is a pixel's value divided by the full scale of its type (RGB: C = 3 channels, grey: C = 1),
float32 in [0, 1], after the slow illumination changes of a brightfield background have been divided
out (:func:`flatten_background`). Stacks are (N, H, W[, 3]) arrays, or any :class:`FrameStack` (a lazy,
read-only stack of frames that reads a frame when indexed or iterated, e.g. a session's frames).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, Literal, Protocol, runtime_checkable

import cv2
import numpy as np

from vastcal.errors import ColourModelError

#: The colour space of a stack: ``"rgb"`` for (…, H, W, 3), ``"grey"`` for (…, H, W).
Space = Literal["rgb", "grey"]


@runtime_checkable
class FrameStack(Protocol):
    """A read-only (N, H, W[, 3]) stack of frames that reads them when asked for.

    ``stack[i]`` and ``stack[views]`` (an index array or slice) return arrays of those frames; iterating yields one
    frame at a time; ``len``, ``shape``, ``dtype`` and ``ndim`` need no frame.
    """

    shape: tuple[int, ...]
    dtype: np.dtype

    def __len__(self) -> int:
        """N, the number of frames."""
        ...

    def __getitem__(self, key: Any) -> np.ndarray:
        """Frame ``key`` (H, W[, 3]), or the frames of an index array or slice (k, H, W[, 3])."""
        ...

    def __iter__(self) -> Iterator[np.ndarray]:
        """Every frame (H, W[, 3]) in order, one at a time."""
        ...


def image_space(images: np.ndarray) -> Space:
    """``"rgb"`` for (…, H, W, 3) stacks, ``"grey"`` for (…, H, W)."""
    return "rgb" if images.ndim >= 3 and images.shape[-1] == 3 else "grey"


def features(images: np.ndarray) -> np.ndarray:
    """Pixel values as float32 features in [0, 1]: (…, H, W, C) with C = 3 (RGB) or 1 (grey).

    :func:`scaled_values`, then :func:`flatten_background` (in place: the stack's features are held once).
    """
    return flatten_background(scaled_values(images), inplace=True)


def scaled_values(images: np.ndarray) -> np.ndarray:
    """Pixel values as float32 in [0, 1], (…, H, W, C), before any background correction.

    Integer images are divided by the full scale of their bit depth: 255 for uint8; for wider types
    the smallest 2^k − 1 that holds the data (4095 for Mono12 stored in uint16, 1023 for Mono10), so
    a 12-bit camera's frames span [0, 1] like 8-bit ones. Float images are taken as they are.
    """
    a = np.asarray(images)
    f = a.astype(np.float32)
    np.divide(f, np.float32(value_scale(a)), out=f)  # in place: one float copy of the stack, not two
    return f[..., None] if image_space(a) == "grey" else f


def value_scale(images: np.ndarray) -> float:
    """The full scale that :func:`scaled_values` divides by (1 for float images)."""
    a = np.asarray(images)
    return _scale_of(
        a.dtype, float(a.max()) if a.size and np.issubdtype(a.dtype, np.integer) and a.dtype.itemsize > 1 else None
    )


def _scale_of(dtype: np.dtype, maximum: float | None) -> float:
    """:func:`value_scale` of images of ``dtype`` whose largest value is ``maximum`` (None: none, or not needed)."""
    scale = 1.0
    if np.issubdtype(dtype, np.integer):
        scale = float(np.iinfo(dtype).max)
        if np.dtype(dtype).itemsize > 1 and maximum is not None:
            bits = max(8, int(np.ceil(np.log2(maximum + 1.0))))
            scale = float(2**bits - 1)
    return scale


def as_stack(images: np.ndarray | FrameStack) -> np.ndarray | FrameStack:
    """``images`` as they are when they are a lazy :class:`FrameStack` (read when indexed or iterated), else as an
    array."""
    if isinstance(images, np.ndarray) or not isinstance(images, FrameStack):
        return np.asarray(images)
    return images


#: Percentile of a frame's values above which pixels are clipped before the background's maximum filter: the
#: brightest 0.1 % — a bubble's focused centre, a hot pixel — would otherwise lift the background estimate over the
#: filter's whole window (a bubble 15 % brighter than the field: the larva's contrast +0.3 over 65 × 190 px).
SPECK_PERCENTILE = 99.9


def flatten_background(f: np.ndarray, *, inplace: bool = False) -> np.ndarray:
    """Divide out slow illumination changes behind a dark specimen (features (…, H, W, C) in [0, 1]).

    Brightfield frames are brighter in the middle than at the ends and tinted differently across
    the field; a single Gaussian for "background" then either misses the dim corners or swallows the
    translucent specimen. The background level of each frame is estimated by a grey closing (a
    maximum filter wider than the specimen, then a blur, after the brightest specks are clipped to the frame's
    :data:`SPECK_PERCENTILE` percentile) — which removes everything darker and smaller than the kernel, i.e. the
    specimen and the thin capillary walls — and divided out, so
    the background sits at 1 everywhere. Frames whose border is not clearly at the bright end of
    their range (a bright specimen on a dark background, e.g. a turntable scene, or no specimen at
    all) are returned unchanged. ``inplace``: overwrite ``f`` (float32) instead of returning a new stack.
    """
    if f.ndim < 3:
        return f
    single = f.ndim == 3
    stack = f[None] if single else f
    n, h, w, c = stack.shape
    if h < 16 or w < 16:
        return f
    border = float(np.median(np.concatenate([stack[:, :2].reshape(n, -1, c), stack[:, -2:].reshape(n, -1, c)], 1)))
    p5, p95 = np.percentile(stack[:, ::4, ::4], [5, 95])
    if border - p5 <= 2.0 * (p95 - border):  # the border is not clearly at the bright end
        return f
    ky, kx = 2 * int(0.3 * h) + 1, 2 * int(w / 32) + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (kx, ky))
    out = stack if inplace and stack.dtype == np.float32 else np.empty_like(stack)
    for i in range(n):
        img = stack[i] if c > 1 else stack[i, :, :, 0]
        top = np.float32(np.percentile(img[::2, ::2], SPECK_PERCENTILE))
        bg = cv2.blur(cv2.dilate(np.minimum(img, top), kernel), (kx, kx))
        np.maximum(bg, np.float32(1e-3), out=bg)
        np.divide(img, bg, out=out[i] if c > 1 else out[i, :, :, 0])  # elementwise: in place when out is the stack
    np.clip(out, 0.0, 1.0, out=out)
    return out[0] if single else out


def check_images(images: np.ndarray | FrameStack) -> None:
    """Refuse blank or saturated stacks (N, H, W[, 3]) before anything is fitted.

    Raises:
        ColourModelError: a view whose pixels barely vary, or that is mostly saturated/black.
    """
    a = as_stack(images)
    c = 3 if len(a.shape) >= 3 and a.shape[-1] == 3 else 1
    subs, top = [], None
    for frame in a:  # one view at a time (a lazy stack reads one at a time): no float copy of the whole stack
        v = np.asarray(frame).reshape(-1, c)
        subs.append(v[:: max(1, v.shape[0] // 20000)].copy())  # a copy: a view of the frame would keep it alive
        if v.size:
            m = float(v.max())
            top = m if top is None else max(top, m)
    scale = np.float32(_scale_of(a.dtype, top))  # raw values: saturation is a property of the sensor's output
    for i, raw in enumerate(subs):
        sub = raw.astype(np.float32) / scale
        sat = float(np.mean(np.all(sub >= 0.999, axis=1)))
        if sat > 0.9:
            raise ColourModelError(
                f"view {i} is saturated ({100 * sat:.0f}% of pixels at full scale): reduce the exposure"
            )
        if float(sub.std(axis=0).max()) < 2e-3:
            raise ColourModelError(
                f"view {i} is blank (constant value {float(sub.mean()):.3g}): no specimen can be seen"
            )
