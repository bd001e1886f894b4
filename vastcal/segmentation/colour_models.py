"""Colour models of specimen (foreground) and background, and the posterior p_f of every pixel.

Every pixel value x (RGB or grey, scaled to [0, 1] by the pixel type's maximum) is explained
by one of two full-covariance Gaussians, N(x; μ_f, Σ_f) and N(x; μ_b, Σ_b), with prior π_f for
the foreground. The posterior

    p_f(x) = π_f N_f(x) / (π_f N_f(x) + (1 − π_f) N_b(x)),   p_b = 1 − p_f

is what the probabilistic-inference calibration samples (paper, Sec. 2). It is computed in the
log domain and clamped to [ε, 1 − ε] (ε = 1e-4 by default), so that no single pixel can
veto a voxel with log 0 = −∞.

Where the models come from
--------------------------
* :func:`fit_from_mask` — a rough mask on one view (nonzero = specimen).
* :func:`fit_from_scribbles` — a label image on one view: 0 unknown, 1 specimen, 2 background. The marked
  background is its dominant colour (one Gaussian), or a :class:`GaussianMixture` of its materials, each
  present only where the marks saw it; :mod:`.marks` chooses by the marks themselves.
* :func:`fit_automatic` — no user input. Assumptions, stated so they can be checked:

  1. The image border (the outer ``border_frac`` of rows and columns of every view) is mostly
     background — at least half of its pixels. This holds for a larva in a capillary (bright
     background) and for a statuette on a turntable (dark background): the *colour* of the
     background is never assumed, only its place.
  2. The background is one colour cluster: it is fitted robustly (median, then a few rounds of
     refitting on the pixels within the 97.5 % Mahalanobis quantile), so border pixels of
     other things (capillary walls, a bright ceiling corner) are rejected as outliers.
  3. The specimen is whatever lies far from that cluster: pixels beyond the 99.9 % quantile of
     the background Gaussian, over all views, give the initial foreground Gaussian and prior;
     a few EM rounds of the two-Gaussian mixture over all views then refine both (the border's
     background may be brighter or more uniform than the field's: vignetting, saturation).
  4. The colours alone say whether the specimen is seen in transmitted light (:attr:`ColourModel.absorbing`):
     absorption only removes light, so an absorbing specimen is in no channel brighter than its background.
     A white part of a reflecting specimen is far from a blue backdrop in chroma even where its brightness is
     close, and the two Gaussians keep it specimen; only the rules of transmitted light, applied to a specimen
     that merely looked darker on the whole, would drop it (docs/decisions/0022).

  When the two clusters do not separate (Bhattacharyya distance below ``min_separation``),
  when almost nothing differs from the background, or when the images are blank or saturated,
  :class:`~vastcal.errors.ColourModelError` says so in one line.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import cv2
import h5py
import numpy as np

from vastcal.errors import ColourModelError, UserInputError
from vastcal.segmentation._pixel_features import FrameStack, Space, as_stack, check_images, features, image_space
from vastcal.segmentation.gaussians import CHI2_999, Gaussian, GaussianMixture, bhattacharyya

log = logging.getLogger(__name__)

#: How a marked background is modelled (:func:`fit_from_scribbles`).
Background = Literal["dominant", "mixture"]

#: Pixels closer to the background colour than this multiple of its 99.9 % Mahalanobis radius² are
#: background whatever the specimen model says (faint halos, dust, a dim corner of the field).
BACKGROUND_GATE = 3.0

#: Pixels whose posteriors are computed at once (:meth:`ColourModel.log_foreground_probability_of_features`).
PIXEL_CHUNK = 1 << 20

#: Pixels whose features the automatic colour model is fitted from at most (:func:`fit_automatic`): views
#: evenly spread over the revolution, as many as fit (all 21 views of a 1024 × 1024 revolution; 73 of 360 on
#: 1024 × 320 frames). The fit draws ``max_samples`` pixels from them: more views add no information about two
#: colour clusters, only memory (a float32 feature per pixel and channel).
MAX_FIT_PIXELS = 24_000_000

#: Marked background pixels a :class:`GaussianMixture` is fitted from at most (drawn reproducibly): enough for
#: five full-covariance RGB components many times over, and a fit of well under a second.
MAX_MIXTURE_SAMPLES = 20_000

#: Marked background pixels this close to the marked specimen (px, Chebyshev) are left out of a mixture background's
#: fit and places (:func:`fit_from_scribbles`): a hand-drawn outline's error, and the pixels the blur mixes.
MARK_EDGE_PX = 3


@dataclass(frozen=True)
class ColourModel:
    """Foreground and background Gaussians, the foreground prior and the feature space.

    Attributes:
        fg: the specimen's Gaussian over features in [0, 1].
        bg: the background's Gaussian, or a :class:`GaussianMixture` of its materials (models fitted from a
            user's mask or scribbles).
        prior_fg: π_f, prior probability of a specimen pixel.
        space: ``"rgb"`` or ``"grey"`` (the images it applies to).
        source: how it was learned (``"automatic"``, ``"mask:view 3"``, ``"scribbles:view 0"``).
        eps: clamp of the posteriors, p in [eps, 1 − eps].
    """

    fg: Gaussian
    bg: Gaussian | GaussianMixture
    prior_fg: float
    space: Space
    source: str = "automatic"
    eps: float = 1e-4

    @property
    def absorbing(self) -> bool:
        """True when the specimen is seen in transmitted light, i.e. it absorbs what the background passes.

        Absorption only removes light (Beer–Lambert: a transmittance ≤ 1 in every channel), so an absorbing
        specimen is darker than its background on the whole and in no channel brighter than the background's
        own spread (its mean plus one standard deviation of that channel). A specimen brighter than that in any
        channel reflects or scatters light of its own: a statue on a dark turntable, and equally an orange toy
        whose mean is darker than a brightly lit blue backdrop on the whole. The rules of transmitted light
        (translucent sheets, enclosed pale tissue, soft rims: :func:`.probability_maps.specimen_maps`) apply
        only to an absorbing specimen.
        """
        fg, bg = np.asarray(self.fg.mean, float), np.asarray(self.bg.mean, float)
        spread = np.sqrt(np.diag(np.asarray(self.bg.cov, float)))
        return bool(fg.sum() < bg.sum() and np.all(fg <= bg + spread))

    @property
    def separation(self) -> float:
        """Bhattacharyya distance between the foreground and background Gaussians."""
        return bhattacharyya(self.fg, self.bg)

    def log_foreground_probability(self, images: np.ndarray) -> np.ndarray:
        """Clamped log p_f for every pixel, float32 (N, H, W) (or (H, W) for one image).

        Raises:
            UserInputError: images of the wrong colour space.
        """
        return self.log_foreground_probability_of_features(self.features(images))

    def features(self, images: np.ndarray) -> np.ndarray:
        """The images' features (:func:`features`) after checking their colour space.

        Raises:
            UserInputError: images of the wrong colour space.
        """
        if image_space(np.asarray(images)) != self.space:
            raise UserInputError(f"colour model is {self.space} but the images are {image_space(np.asarray(images))}")
        return features(images)

    def log_foreground_probability_of_features(self, f: np.ndarray) -> np.ndarray:
        """Clamped log p_f, float32 (…, H, W), of features (…, H, W, C) from :meth:`features`.

        Computed in chunks of :data:`PIXEL_CHUNK` pixels: its temporaries (float64 distances among them)
        stay a few tens of MB however many views the stack holds.
        """
        f = np.asarray(f)
        c = f.shape[-1]
        flat = f.reshape(-1, c)
        out = np.empty(flat.shape[0], np.float32)
        present = self.bg.present(*f.shape[-3:-1]) if isinstance(self.bg, GaussianMixture) and f.ndim >= 3 else None
        for s in range(0, flat.shape[0], PIXEL_CHUNK):
            where = None
            if present is not None:  # the chunk's pixels' places in their frames
                where = present[:, np.arange(s, min(s + PIXEL_CHUNK, flat.shape[0])) % present.shape[1]]
            out[s : s + PIXEL_CHUNK] = self._log_foreground_chunk(flat[s : s + PIXEL_CHUNK], where)
        return out.reshape(f.shape[:-1])

    def _log_foreground_chunk(self, f: np.ndarray, where: np.ndarray | None = None) -> np.ndarray:
        """Clamped log p_f (M,) float32 of features (M, C); ``where`` (K, M): the background components present."""
        lf = self.fg.log_pdf(f) + np.float32(np.log(self.prior_fg))
        lb = (self.bg.log_pdf(f, where) if where is not None else self.bg.log_pdf(f)) + np.float32(
            np.log1p(-self.prior_fg)
        )
        # log p_f = −log(1 + exp(lb − lf)), stable for either sign of the difference.
        diff = np.clip(lb - lf, -80.0, 80.0)
        logp = -np.logaddexp(np.float32(0.0), diff)
        # A pixel whose colour the background model explains (within BACKGROUND_GATE × its 99.9 % radius²) is
        # background, however broad the specimen's Gaussian is: the specimen's colours are multimodal (black eyes,
        # grey body, clear fin), so its single Gaussian is wide and would otherwise claim faint halos.
        logp = np.where(
            self.bg.mahalanobis2(f) < BACKGROUND_GATE * CHI2_999[f.shape[-1]], np.float32(np.log(self.eps)), logp
        )
        return np.clip(logp, np.log(self.eps), np.log1p(-self.eps)).astype(np.float32)

    def foreground_probability(self, images: np.ndarray) -> np.ndarray:
        """Posterior p_f of the specimen for every pixel, float32 (N, H, W), clamped to [ε, 1 − ε]."""
        return np.exp(self.log_foreground_probability(images)).astype(np.float32)

    # -- storage -------------------------------------------------------------------------------
    def to_group(self, group: h5py.Group) -> None:
        """Write ``fg_mean``, ``fg_cov``, ``bg_mean``, ``bg_cov`` and attrs space, prior, source, eps.

        A mixture background also writes ``bg_weights`` (K,), ``bg_means`` (K, C) and ``bg_covs`` (K, C, C);
        ``bg_mean``/``bg_cov`` are then its dominant component's, and ``bg_regions`` (K, H, W) bool each
        component's place.
        """
        for name, g in (("fg", self.fg), ("bg", self.bg)):
            group.create_dataset(f"{name}_mean", data=np.asarray(g.mean, float))
            group.create_dataset(f"{name}_cov", data=np.asarray(g.cov, float))
        if isinstance(self.bg, GaussianMixture):
            group.create_dataset("bg_weights", data=np.asarray(self.bg.weights, float))
            group.create_dataset("bg_means", data=np.stack([np.asarray(g.mean, float) for g in self.bg.parts]))
            group.create_dataset("bg_covs", data=np.stack([np.asarray(g.cov, float) for g in self.bg.parts]))
            if self.bg.regions is not None:
                group.create_dataset(
                    "bg_regions", data=np.asarray(self.bg.regions, bool), compression="gzip", shuffle=True
                )
        group.attrs["space"] = self.space
        group.attrs["prior"] = float(self.prior_fg)
        group.attrs["source"] = self.source
        group.attrs["eps"] = float(self.eps)
        group.attrs["units"] = "pixel value / type maximum (features in [0, 1])"
        group.attrs["bhattacharyya"] = float(self.separation)

    @classmethod
    def from_group(cls, group: h5py.Group) -> ColourModel:
        """Read a model written by :meth:`to_group` (e.g. ``run["colour_model"]``)."""

        def s(v: object) -> str:
            """An HDF5 string attribute as ``str``."""
            return v.decode() if isinstance(v, bytes) else str(v)

        bg: Gaussian | GaussianMixture = Gaussian(group["bg_mean"][...], group["bg_cov"][...])
        if "bg_weights" in group:
            bg = GaussianMixture(
                np.asarray(group["bg_weights"][...], float),
                tuple(Gaussian(mu, cov) for mu, cov in zip(group["bg_means"][...], group["bg_covs"][...])),
                np.asarray(group["bg_regions"][...], bool) if "bg_regions" in group else None,
            )
        return cls(
            Gaussian(group["fg_mean"][...], group["fg_cov"][...]),
            bg,
            float(group.attrs["prior"]),
            s(group.attrs["space"]),  # type: ignore[arg-type]
            s(group.attrs.get("source", "stored")),
            float(group.attrs.get("eps", 1e-4)),
        )


def _checked(model: ColourModel, min_separation: float) -> ColourModel:
    """``model``, logged; :class:`~vastcal.errors.ColourModelError` when its Bhattacharyya distance is below
    ``min_separation``."""
    sep = model.separation
    log.info(
        "colour model (%s, %s): fg mean %s, bg mean %s, prior %.3f, Bhattacharyya %.2f",
        model.source,
        model.space,
        np.round(model.fg.mean, 3),
        np.round(model.bg.mean, 3),
        model.prior_fg,
        sep,
    )
    if not np.isfinite(sep) or sep < min_separation:
        raise ColourModelError(
            f"specimen and background colours do not separate (Bhattacharyya distance {sep:.2f} < {min_separation}); "
            "give a rough mask or scribbles of one view (calibrate --mask VIEW:FILE or --scribbles VIEW:FILE)"
        )
    return model


def _prior(p: float) -> float:
    """A foreground prior π_f kept within [0.02, 0.5]."""
    return float(np.clip(p, 0.02, 0.5))


def fit_from_mask(
    image: np.ndarray,
    mask: np.ndarray,
    *,
    view: int = 0,
    min_separation: float = 0.5,
    background: Background = "dominant",
    others: Sequence[np.ndarray] = (),
) -> ColourModel:
    """Colour models from a rough mask (H, W), nonzero = specimen, on one image (H, W[, 3]).

    ``background``, ``others``: as in :func:`fit_from_scribbles`.

    Raises:
        UserInputError: the mask's size differs from the image's.
        ColourModelError: a mask with (almost) no specimen or no background, or no separation.
    """
    return fit_from_scribbles(
        image,
        mask_labels(image, mask, view=view),
        view=view,
        min_separation=min_separation,
        background=background,
        others=others,
        _source=f"mask:view {view}",
    )


def mask_labels(image: np.ndarray, mask: np.ndarray, *, view: int = 0) -> np.ndarray:
    """A mask (H, W[, C]), nonzero = specimen, as scribble labels (H, W) uint8: 1 specimen, 2 background.

    Raises:
        UserInputError: the mask's size differs from the image's (H, W[, 3]).
    """
    mask = np.asarray(mask)
    if mask.ndim == 3:
        mask = mask.max(axis=2)
    if mask.shape != image.shape[:2]:
        raise UserInputError(
            f"mask is {mask.shape[1]} x {mask.shape[0]} px but view {view} is {image.shape[1]} x {image.shape[0]} px"
        )
    return np.where(mask > 0, 1, 2).astype(np.uint8)


def fit_from_scribbles(
    image: np.ndarray,
    labels: np.ndarray,
    *,
    view: int = 0,
    min_separation: float = 0.5,
    background: Background = "dominant",
    others: Sequence[np.ndarray] = (),
    _source: str | None = None,
) -> ColourModel:
    """Colour models from scribbles: a label image (H, W) with 0 unknown, 1 specimen, 2 background.

    The marked background holds other things than the backdrop (capillary walls and the dim strips beside
    them, a turntable and its lit patches). ``background="dominant"`` fits one Gaussian to its dominant
    cluster (:meth:`Gaussian.fit_robust`): the other materials are left to the specimen's wide Gaussian and
    to the silhouette rules, which clear walls and stray regions — but not a turntable joined to the
    specimen. ``"mixture"`` gives every material its own component (:meth:`GaussianMixture.fit`), each present
    only where the marks saw it (:meth:`GaussianMixture.localised`; a material as pale as a clear fin would
    otherwise take the fin) and only if it holds that place in ``others`` (other views' images,
    :meth:`GaussianMixture.held_still`: a shadow the specimen casts does not). :func:`.marks.fit_from_marks` fits
    both and keeps the one whose silhouette of the marked view agrees better with the marks.

    The prior π_f is the specimen fraction among labelled pixels when the labels cover the whole
    image (a mask), otherwise it is estimated from the posterior mean over the image.

    Raises:
        UserInputError: labels of the wrong size.
        ColourModelError: fewer than a few pixels of either class, or no separation.
    """
    labels = np.asarray(labels)
    if labels.ndim == 3:
        labels = labels.max(axis=2)
    if labels.shape != image.shape[:2]:
        raise UserInputError(
            f"scribbles are {labels.shape[1]} x {labels.shape[0]} px "
            f"but view {view} is {image.shape[1]} x {image.shape[0]} px"
        )
    stray = np.setdiff1d(np.unique(labels), [0, 1, 2])
    if stray.size:
        raise UserInputError(
            f"scribbles of view {view}: expected labels 0 (unknown), 1 (specimen), 2 (background); "
            f"found {', '.join(map(str, stray[:5].tolist()))}"
        )
    check_images(np.asarray(image)[None])
    f = features(image)
    fg_px, bg_px = f[labels == 1], f[labels == 2]
    if fg_px.shape[0] < 20 or bg_px.shape[0] < 20:
        raise ColourModelError(
            f"view {view}: the mask/scribbles mark {fg_px.shape[0]} specimen and {bg_px.shape[0]} background pixels; "
            "need at least 20 of each"
        )
    # One Gaussian widened over every marked material would swallow the pale parts of the specimen.
    fg = Gaussian.fit(fg_px)
    bg: Gaussian | GaussianMixture
    if background == "mixture":
        # The marks' edge is rough, and the pixels along the specimen's outline mix it with the backdrop: away from
        # them, or a material of their blend colour grows along the outline.
        k = 2 * MARK_EDGE_PX + 1
        marked = (labels == 2) & (cv2.dilate((labels == 1).astype(np.uint8), np.ones((k, k), np.uint8)) == 0)
        if np.count_nonzero(marked) < 20:
            marked = labels == 2
        sample = f[marked]
        if sample.shape[0] > MAX_MIXTURE_SAMPLES:
            sample = sample[np.random.default_rng(0).choice(sample.shape[0], MAX_MIXTURE_SAMPLES, replace=False)]
        bg = GaussianMixture.fit(sample)
        if not np.all(labels > 0):  # scribbles: a stroke on the turntable stands for the turntable it lies on
            unmarked = ColourModel(fg, bg, 0.5, image_space(np.asarray(image))).log_foreground_probability_of_features(
                f
            ) < np.log(0.5)
            marked = marked | ((labels == 0) & unmarked)
        bg = bg.localised(f, marked).held_still(f, [features(o) for o in others])
    elif background == "dominant":
        bg = Gaussian.fit_robust(bg_px)
    else:
        raise UserInputError(f"background model {background!r}: expected 'dominant' or 'mixture'")
    if np.all(labels > 0):
        prior = fg_px.shape[0] / labels.size
    else:
        tmp = ColourModel(fg, bg, 0.5, image_space(np.asarray(image)))
        prior = float(tmp.foreground_probability(np.asarray(image)[None]).mean())
    return _checked(
        ColourModel(fg, bg, _prior(prior), image_space(np.asarray(image)), _source or f"scribbles:view {view}"),
        min_separation,
    )


def border_pixels(images: np.ndarray, border_frac: float = 0.03) -> np.ndarray:
    """Features (M, C) of the outer ``border_frac`` of rows and columns of every view (≥ 2 px)."""
    return _border_of(features(images), border_frac)


def _border_of(f: np.ndarray, border_frac: float) -> np.ndarray:
    """Features (M, C) of the outer ``border_frac`` of rows and columns of features (N, H, W, C) (≥ 2 px)."""
    n, h, w = f.shape[:3]
    by, bx = max(2, int(round(border_frac * h))), max(2, int(round(border_frac * w)))
    parts = [
        f[:, :by].reshape(-1, f.shape[-1]),
        f[:, -by:].reshape(-1, f.shape[-1]),
        f[:, by:-by, :bx].reshape(-1, f.shape[-1]),
        f[:, by:-by, -bx:].reshape(-1, f.shape[-1]),
    ]
    return np.concatenate(parts)


def fit_automatic(
    images: np.ndarray | FrameStack,
    *,
    border_frac: float = 0.03,
    min_separation: float = 0.5,
    max_samples: int = 200_000,
    em_rounds: int = 10,
    seed: int = 0,
    max_pixels: int = MAX_FIT_PIXELS,
) -> ColourModel:
    """Colour models with no user input (assumptions in the module docstring).

    Args:
        images: (N, H, W[, 3]) views, or a lazy :class:`FrameStack` of them (only the views used are read).
        border_frac: fraction of rows/columns at each edge taken as mostly background.
        min_separation: least Bhattacharyya distance accepted between the two Gaussians.
        max_samples: pixels drawn (reproducibly, from ``seed``) for each fit.
        em_rounds: EM rounds refining both Gaussians on all views' pixels (:func:`em_refine`).
        max_pixels: the views' pixels used at most; beyond it an evenly spread subset of the views (:func:`fit_views`).

    Raises:
        ColourModelError: blank or saturated views, nothing unlike the background, or no separation.
    """
    stack = as_stack(images)
    rng = np.random.default_rng(seed)
    views = fit_views(stack.shape[0], int(np.prod(stack.shape[1:3])), max_pixels)
    subset = views.size < stack.shape[0]
    if subset:
        log.info(
            "colour model: fitted on %d of %d views (evenly spread, at most %d pixels)",
            views.size,
            stack.shape[0],
            max_pixels,
        )
    images = np.asarray(stack[views] if subset else stack)
    check_images(stack if subset else images)  # every view; read once when all are fitted
    f = features(images)  # once: the background flattening is the costly part
    border = _border_of(f, border_frac)
    if border.shape[0] > max_samples:
        border = border[rng.choice(border.shape[0], max_samples, replace=False)]
    bg = Gaussian.fit_robust(border)
    f = f.reshape(-1, border.shape[1])
    sample = f[rng.choice(f.shape[0], min(max_samples, f.shape[0]), replace=False)]
    far = bg.mahalanobis2(sample) > CHI2_999[border.shape[1]]
    frac = float(far.mean())
    if far.sum() < 50 or frac < 1e-3:
        raise ColourModelError(f"no specimen found: only {100 * frac:.2f}% of pixels differ from the background colour")
    model = em_refine(
        ColourModel(Gaussian.fit(sample[far]), bg, _prior(frac), image_space(images), "automatic"), sample, em_rounds
    )
    return _checked(model, min_separation)


def fit_views(n_views: int, pixels_per_view: int, max_pixels: int = MAX_FIT_PIXELS) -> np.ndarray:
    """Indices of the views (sorted) an automatic colour model is fitted from: all when their pixels fit
    ``max_pixels``, else as many as fit (at least 3), evenly spread over the stack's order (a revolution)."""
    k = int(np.clip(max_pixels // max(int(pixels_per_view), 1), min(3, n_views), n_views))
    if k >= n_views:
        return np.arange(n_views)
    return np.unique(np.floor(np.arange(k) * n_views / k).astype(np.intp))


def em_refine(model: ColourModel, samples: np.ndarray, rounds: int) -> ColourModel:
    """A few EM rounds of the two-Gaussian mixture on feature samples (M, C), from ``model``.

    The border fit sees only the border's illumination; EM lets the background Gaussian widen to
    the whole field's (vignetting, a brighter capillary interior) while the specimen keeps its own.
    """
    wide = np.asarray(samples, np.float64)  # the fits' precision, converted once for all rounds
    for _ in range(rounds):
        lf = model.fg.log_pdf(samples) + np.log(model.prior_fg)
        lb = model.bg.log_pdf(samples) + np.log1p(-model.prior_fg)
        r = np.exp(-np.logaddexp(0.0, np.clip(lb - lf, -80, 80)))  # responsibility of the foreground
        model = ColourModel(
            Gaussian.fit(wide, r),
            Gaussian.fit(wide, 1 - r),
            _prior(float(r.mean())),
            model.space,
            model.source,
            model.eps,
        )
    return model
