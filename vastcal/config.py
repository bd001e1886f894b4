"""Rig configuration: YAML in, typed and validated dataclasses out.

A rig description names the stage, the camera, the optics, the acquisition plan and the
calibration/reconstruction settings. It is loaded with :func:`yaml.safe_load` and checked
field by field; every mistake becomes a :class:`~vastcal.errors.ConfigError` whose one-line
message names the file, the key path and what was expected, e.g.::

    config/vast-rig.yaml: camera.exposure_us: expected a number > 0, got -5

Units are in the key names (``_us`` microseconds, ``_um`` micrometres, ``_deg`` degrees,
``_s`` seconds, ``_px`` pixels, ``_db`` decibel) so that a YAML file reads unambiguously.

The embedded default is ``config/simulated.yaml`` (no hardware). :func:`load_config` with
``None`` loads it; :func:`dump_config` gives the resolved YAML that a session stores.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib.resources
import json
import logging
import math
import reprlib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

from vastcal.errors import ConfigError

log = logging.getLogger(__name__)


def _shipped_config_dir() -> Path:
    """Folder of the shipped rig YAML: the package data of ``vastcal.rig_configs`` (``config/`` of the
    repository, mapped by ``pyproject.toml``), found with :mod:`importlib.resources` so that it works from a
    wheel as from a checkout. An editable install made before that mapping existed falls back to the
    repository's ``config/``."""
    try:
        return Path(str(importlib.resources.files("vastcal.rig_configs")))
    except ModuleNotFoundError:
        return Path(__file__).resolve().parent.parent / "config"


CONFIG_DIR = _shipped_config_dir()
"""Folder of the shipped rig descriptions (``config/`` of the repository; ``vastcal/rig_configs`` installed)."""

DEFAULT_CONFIG = CONFIG_DIR / "simulated.yaml"
"""The embedded default rig: fully simulated, no hardware."""


FREE_NAMES = ("yaw", "pitch", "gamma", "rolls", "all")
"""Names of the parameter groups calibration may free (``calibration.free``, ``--free``)."""


MAX_CONFIG_BYTES = 1 << 20
"""Largest rig file read, bytes (a rig description is a few kB; anything larger is not one)."""

MAX_NESTING = 50
"""Deepest nesting of mappings/lists accepted in a rig file (the schema needs 3)."""

MAX_NODES = 100_000
"""Most values a rig file may expand to, counting every alias expansion (a "billion laughs"
document of a few hundred bytes expands to 10^9 values)."""

MAX_MESSAGE_CHARS = 300
"""Longest error message about a rig file; longer ones end in an ellipsis."""

_REPR = reprlib.Repr()
_REPR.maxstring = _REPR.maxother = 60
_REPR.maxlevel, _REPR.maxlist, _REPR.maxdict = 2, 4, 4


def _show(value: Any) -> str:
    """A short repr of a value given in a rig file (bounded length and depth, for one-line messages)."""
    return _REPR.repr(value)


def _clip(text: str, limit: int = MAX_MESSAGE_CHARS) -> str:
    """``text`` on one line and at most ``limit`` characters."""
    text = " ".join(text.split("\n"))
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _range(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False) -> dict[str, Any]:
    """Field metadata giving an allowed numeric range (inclusive unless ``lo_open``)."""
    return {"lo": lo, "hi": hi, "lo_open": lo_open}


@dataclass(frozen=True)
class StageConfig:
    """Rotation stage on a serial line (Zaber ASCII protocol).

    ``url`` is any pyserial URL: ``/dev/ttyUSB0``, ``socket://host:port``, ``rfc2217://…``, or
    ``sim://zaber`` for the in-process simulator.
    """

    protocol: Literal["zaber-ascii"] = "zaber-ascii"
    url: str = "sim://zaber"
    baudrate: int = field(default=115200, metadata=_range(300, 4_000_000))
    device: int = field(default=1, metadata=_range(1, 99))
    axis: int = field(default=1, metadata=_range(1, 9))
    checksums: bool = True
    reply_timeout_s: float = field(default=0.5, metadata=_range(0.0, 60.0, lo_open=True))
    home_on_start: bool = True
    home_timeout_s: float = field(default=60.0, metadata=_range(0.0, 3600.0, lo_open=True))
    settle_s: float = field(default=0.02, metadata=_range(0.0, 10.0))
    position_tolerance_usteps: int = field(default=0, metadata=_range(0, 1_000_000))
    maxspeed: int | None = field(default=None, metadata=_range(1, None))
    """Optional speed to set on open, in device units (read back and recorded either way)."""


@dataclass(frozen=True)
class RoiConfig:
    """Camera region of interest in full-sensor pixels (0-based offsets)."""

    x: int = field(default=0, metadata=_range(0, 100_000))
    y: int = field(default=0, metadata=_range(0, 100_000))
    width: int = field(default=1024, metadata=_range(1, 100_000))
    height: int = field(default=1024, metadata=_range(1, 100_000))


@dataclass(frozen=True)
class CameraConfig:
    """GenICam GenTL camera through harvesters, or the numpy simulator."""

    driver: Literal["genicam", "simulated"] = "simulated"
    cti: str | None = None
    """Path of the GenTL producer (``.cti``); ``None`` uses the ``GENICAM_GENTL64_PATH`` search."""
    serial_number: str | None = None
    """Device to open; ``None`` opens the first device the producer lists."""
    pixel_format: Literal[
        "Mono8",
        "Mono12",
        "Mono12Packed",
        "Mono12p",
        "Mono16",
        "RGB8",
        "BayerRG8",
        "BayerGR8",
        "BayerBG8",
        "BayerGB8",
        "RGBa8",
    ] = "Mono12"
    exposure_us: float = field(default=5000.0, metadata=_range(0.0, 60_000_000.0, lo_open=True))
    gain_db: float = field(default=0.0, metadata=_range(0.0, 48.0))
    fetch_timeout_s: float = field(default=2.0, metadata=_range(0.0, 600.0, lo_open=True))
    packet_size: int | None = field(default=None, metadata=_range(576, 16000))
    """GigE packet size in bytes; must not exceed the network path's MTU (default: leave as is)."""
    roi: RoiConfig = field(default_factory=RoiConfig)


@dataclass(frozen=True)
class OpticsConfig:
    """Imaging geometry that fixes the intrinsic matrix K.

    The focal length in pixels is ``working_distance_um * magnification / pixel_size_um``
    (a telecentric-like microscope imaged as a pinhole at the working distance), unless
    ``focal_length_px`` is given. The principal point is in full-sensor pixels (0-based);
    ``None`` means the sensor centre.

    The ranges below only keep values finite and positive; whether they are plausible — a sensor pitch of
    1–30 µm, a pixel on the specimen no finer than optics resolve, a field of view a lens has — is checked
    before acquisition and import by :func:`vastcal.plausibility.check_optics` (``--accept-units`` skips it).
    """

    pixel_size_um: float = field(default=5.5, metadata=_range(0.0, 1000.0, lo_open=True))
    magnification: float = field(default=1.0, metadata=_range(0.0, 1000.0, lo_open=True))
    working_distance_um: float = field(default=65000.0, metadata=_range(0.0, 1e7, lo_open=True))
    focal_length_px: float | None = field(default=None, metadata=_range(0.0, None, lo_open=True))
    sensor_width_px: int = field(default=1024, metadata=_range(1, 100_000))
    sensor_height_px: int = field(default=1024, metadata=_range(1, 100_000))
    principal_point_px: tuple[float, float] | None = None


@dataclass(frozen=True)
class AcquisitionConfig:
    """The revolution to acquire: ``views`` frames at absolute targets round(k·cycle/views)."""

    views: int = field(default=21, metadata=_range(3, 100_000))
    flat_frames: int = field(default=0, metadata=_range(0, 1000))
    dark_frames: int = field(default=0, metadata=_range(0, 1000))
    sync_each_view: bool = True
    """fdatasync every view before committing it: committed views survive a power cut, not only a
    killed process (costs the disk's sync latency per view; false keeps kill-safety only)."""


@dataclass(frozen=True)
class CalibrationBounds:
    """Half-widths of the search box around θ0, in degrees (γ: axis placement angle)."""

    yaw_deg: float = field(default=3.0, metadata=_range(0.0, 45.0))
    pitch_deg: float = field(default=3.0, metadata=_range(0.0, 45.0))
    gamma_deg: float = field(default=1.0, metadata=_range(0.0, 45.0))
    roll_deg: float = field(default=5.0, metadata=_range(0.0, 90.0))


@dataclass(frozen=True)
class Level:
    """One resolution level of the coarse-to-fine search (``calibration.levels``, coarsest first)."""

    width_px: int = field(metadata=_range(8, 100_000))
    """Width the specimen maps are resized to (area averaging), pixels; never upsampled."""
    voxels: int = field(metadata=_range(100, 100_000_000))
    """Approximate number of voxels in the specimen region at this level."""
    sigma0: float = field(metadata=_range(0.0, 1.0, lo_open=True))
    """Initial CMA-ES step, as a fraction of each parameter's half-width."""
    max_evaluations: int = field(metadata=_range(1, 10_000_000))
    """Evaluation budget of this level."""
    edge_lines: int = field(default=48, metadata=_range(1, 10_000))
    """Lines across the axis image along which the coherence cost finds each view's silhouette edges."""
    groups: tuple[str, ...] | None = None
    """Parameter groups this level optimises (null: all free ones); e.g. the axis first, rolls later."""
    scaled_steps: bool = False
    """Start CMA-ES with per-coordinate steps inversely proportional to how far each coordinate moves the specimen's
    image (:meth:`vastcal.calibrate.parameters.ParameterSpace.image_sensitivity`) instead of equal box fractions."""
    max_initial_step_px: float | None = None
    """Cap of each coordinate's initial CMA-ES step, pixels of image motion at this level (null: no cap). The coherence
    cost searches every candidate's rays around the population mean's maxima, a few pixels wide: a population spread
    wider than that under-rates the far candidates."""


DEFAULT_LEVELS = (
    Level(256, 4000, 0.3, 1200, 32, ("yaw", "pitch", "gamma"), max_initial_step_px=8.0),
    Level(512, 16000, 0.05, 800, 48, scaled_steps=True),
)
"""The axis first on quarter-size maps, then everything on half-size maps with scaled steps (docs/calibration.md)."""

RENAMED_KEYS = {
    "calibration.prior_weight": "roll_prior_weight",
    "calibration.offset_scan_deg": "roll_offset_scan_deg",
}
"""Rig-file keys read under their current name (sessions store the rig file they were made with)."""

RENAMED_VALUES = {"calibration.pi_form": {"loglik": "log_likelihood", "count": "voxel_count"}}
"""Rig-file values read under their current name (the PI forms' former short names)."""

REMOVED_KEYS = {
    "calibration.photometric_yaw": "docs/decisions/0050-photometric-yaw-removed.md",
    "calibration.photometric_sirt_iterations": "docs/decisions/0050-photometric-yaw-removed.md",
    "calibration.vr_blur_px": "docs/decisions/0016-the-papers-costs-as-published.md",
    "calibration.eps": "docs/decisions/0016-the-papers-costs-as-published.md",
}
"""Rig-file keys of settings that no longer exist, with the record of why: read and ignored."""


@dataclass(frozen=True)
class CalibrationSettings:
    """Every setting of a calibration: the rig file's ``calibration:`` section, key for key (stored with every run).

    Angles in degrees, image distances in pixels of the level, costs dimensionless.
    """

    method: Literal["coherence", "pi", "vr"] = "coherence"
    """coherence: vastcal's silhouette-coherence cost (default); pi: the paper's objective as published; vr: voxel
    residual (:data:`vastcal.calibrate.methods.OBJECTIVES`)."""
    free: tuple[str, ...] = ("yaw", "pitch", "gamma", "rolls")
    seed: int = field(default=0, metadata=_range(0, 2**31 - 1))
    """CMA-ES seed of the first start; start s uses seed + 10 s."""
    bounds: CalibrationBounds = field(default_factory=CalibrationBounds)
    starts: int = field(default=1, metadata=_range(1, 1000))
    """Independent coarse-to-fine runs; the one of lowest judged cost is kept."""
    levels: tuple[Level, ...] = DEFAULT_LEVELS
    tolx: float = field(default=2e-4, metadata=_range(0.0, 1.0))
    """CMA-ES stops when its steps fall below this fraction of the half-widths."""
    tolfun: float = field(default=1e-8, metadata=_range(0.0, 1.0))
    """CMA-ES stops when the cost varies less than this."""
    popsize: int | None = None
    """CMA-ES population (null: cma's default 4 + 3 ln F)."""
    level_handover: float = field(default=0.1, metadata=_range(0.0, 1.0))
    """Every level but the last ends when its step moves the image by less than this share of the smallest initial
    step the next level starts with (0: on ``tolx`` only; docs/calibration.md, "Where a coarse level hands over")."""
    threshold: float = field(default=0.5, metadata=_range(0.0, 1.0))
    """p_f above which a pixel belongs to a rough silhouette (the region, VR)."""
    pi_form: Literal["voxel_count", "log_likelihood"] = "voxel_count"
    """``method: pi``'s cost over the voxels: voxel_count (the share of voxels whose log-ratio is positive, as the
    authors coded it) or log_likelihood (the mean log-ratio, the paper's equation): vastcal.calibrate.objective_pi."""
    coherence_sigma_px: float = field(default=0.1, metadata=_range(0.0, 100.0, lo_open=True))
    """Softness of the coherence penalty."""
    coherence_trim: int = field(default=1, metadata=_range(0, 100))
    """A ray point's residual is the (trim + 1)-th smallest signed distance over the other views."""
    roll_prior_weight: float = field(default=0.05, metadata=_range(0.0, 100.0))
    """Weight of the Gaussian prior (rolls around the commanded angles, yaw around its start) relative to the data
    cost; 0 = none (for commanded angles known to be wrong). Silhouettes of convex cross-sections hardly constrain
    the individual rolls: without it CMA-ES wanders along those flat directions."""
    roll_prior_deg: float = field(default=1.0, metadata=_range(0.0, 90.0, lo_open=True))
    """Sigma of the roll prior: the stage's expected step error."""
    yaw_prior_deg: float = field(default=0.5, metadata=_range(0.0, 45.0))
    """Sigma of the yaw prior (0 = none): a nearly orthographic microscope hardly sees the yaw."""
    region_tolerance: float = field(default=0.1, metadata=_range(0.0, 1.0))
    """Cap of the first level's region tolerance, fraction of the image height (keeps static structures out)."""
    refine_tolerance_px: float = field(default=2.0, metadata=_range(0.0, 1000.0))
    """Tolerance of the region of later levels, carved around the previous level's solution."""
    roll_offset_scan_deg: float = field(default=0.0, metadata=_range(0.0, 5.0))
    """Step of the common roll-offset scan after the first level; 0 = off (``--offset-scan``)."""
    roll_scan: bool = True
    """After every level but the last, score every free roll over its whole box and move the views left in another
    basin (:mod:`vastcal.calibrate.stage_roll_scan`; the coherence cost). Rolls whose box lies within one basin are
    not scanned, so on a microscope it costs nothing."""
    polish: bool = True
    """After the starts, a per-view compass search of every free roll (:mod:`vastcal.calibrate.stage_polish`)."""
    polish_steps_deg: tuple[float, ...] = (0.2, 0.1, 0.05, 0.025)
    """The polish's steps, largest first."""
    polish_zooms: int = field(default=2, metadata=_range(0, 10))
    """Zoom stages of the polish's cost along every edge ray, so that its trials are read as finely as θ."""
    memory_mb: float = field(default=1536.0, metadata=_range(256.0, 1e7))
    """Memory budget, MB: the specimen maps are made for as many views at once as fit in it."""
    prior_from: str | None = None
    """Results folder of an earlier ``vastcal batch`` on this rig: its ``rig_health.json`` becomes the start and the
    prior's centre (:func:`vastcal.rig_health.load_rig_prior`); null = none."""

    def to_json(self) -> str:
        """JSON of every setting."""
        return json.dumps(dataclasses.asdict(self))


@dataclass(frozen=True)
class ReconstructionConfig:
    """Settings of the visual hull; ``voxel_size_um`` ``None`` picks it from the specimen extent."""

    voxel_size_um: float | None = field(default=None, metadata=_range(0.0, None, lo_open=True))
    target_voxels: int = field(default=5_000_000, metadata=_range(1000, 500_000_000))
    memory_mb: float = field(default=1536.0, metadata=_range(256.0, 1e7))
    """Memory budget of a reconstruction, MB: the specimen maps are made for as many views at once as half of it
    holds (interleaved sub-revolutions, :func:`vastcal.segmentation.grouped_specimen_maps`)."""


@dataclass(frozen=True)
class SimulationConfig:
    """How the simulated rig draws its hidden truth (never read by calibration).

    Truth values are drawn uniformly within ± these limits from ``seed``.
    """

    seed: int = field(default=1, metadata=_range(0, 2**31 - 1))
    max_drift_deg: float = field(default=2.0, metadata=_range(0.0, 30.0))
    max_tilt_deg: float = field(default=1.0, metadata=_range(0.0, 10.0))
    max_axis_offset_um: float = field(default=60.0, metadata=_range(0.0, 10_000.0))
    max_specimen_offset_um: float = field(default=0.0, metadata=_range(0.0, 1_000.0))
    """Largest distance of the specimen's own axis from the rotation axis, µm (it lies against the
    capillary wall); 0 = a coaxial specimen."""
    usteps_per_revolution: int = field(default=1_152_000, metadata=_range(360, 100_000_000))
    backlash_usteps: int = field(default=0, metadata=_range(0, 100_000))
    noise: float = field(default=1.0, metadata=_range(0.0, 100.0))
    """Shot-noise scale (1 = physical Poisson noise at the configured full well)."""

    # -- specimen and scene realism (simulators/camera/larva.py, scene.py). Each is drawn
    # from ``seed``; false / 0 switches it off (the defaults: the fixed 3 mm phantom, a clean scene).
    larva_varies: bool = False
    """Draw the larva's age in ``age_dpf``, and from it length, height, flattening, yolk and contrast;
    false = the fixed 3 mm phantom (:func:`vastcal.simulators.camera.phantom.zebrafish_phantom`)."""
    age_dpf: tuple[float, float] = (3.0, 5.0)
    """Range of the larva's age, days post fertilisation (length 3.0 mm at 3 dpf to 4.5 mm at 5 dpf)."""
    fin_fold: bool = False
    """A translucent median fin fold (not part of the measured body)."""
    fin_fold_height_um: tuple[float, float] = (60.0, 140.0)
    """Range of the fin fold's largest height beyond the body, µm."""
    pectoral_fins: bool = False
    """Two thin translucent pectoral fins beside the yolk (not part of the measured body)."""
    melanophores: float = field(default=0.0, metadata=_range(0.0, 1000.0))
    """Mean number of melanophores (dark specks just under the skin, mostly dorsal/ventral), Poisson."""
    refractive_index: tuple[float, float] = (1.0, 1.0)
    """Range of the tissue's refractive index relative to the medium: refraction at the body's surface
    deviates grazing rays out of the objective's aperture, a dark outline (1 = none)."""
    wall_contact_probability: float = field(default=0.0, metadata=_range(0.0, 1.0))
    """Chance that the larva lies against the capillary wall (its edge 0.5-3 µm from the wall)."""
    tail_out_of_frame_probability: float = field(default=0.0, metadata=_range(0.0, 1.0))
    """Chance that the larva is shifted along the axis so that its tail runs out of the frame."""
    pale_tail_tip_probability: float = field(default=0.0, metadata=_range(0.0, 1.0))
    """Chance that the larva's tail tip is pale: its contrast falls over the last 15-25 % of the length to
    0.15-0.4 of the body's (still part of the measured body)."""
    wall_band_probability: float = field(default=0.0, metadata=_range(0.0, 1.0))
    """Chance that a larva lying against the wall touches it with its dorsal side and shows a pale band
    there: tissue 8-20 µm deep at 0.3-0.6 of the body's contrast, the dorsal pigment below it."""
    debris: float = field(default=0.0, metadata=_range(0.0, 100.0))
    """Mean number of dark debris particles floating in the capillary (Poisson); they drift between views."""
    bubbles: float = field(default=0.0, metadata=_range(0.0, 100.0))
    """Mean number of small air bubbles (bright centre, dark rim) in the capillary (Poisson); they drift."""
    illumination_gradient: float = field(default=0.0, metadata=_range(0.0, 0.5))
    """Largest relative brightness change from the frame centre to its edge (drawn in ±, per direction)."""
    vignetting: float = field(default=0.0, metadata=_range(0.0, 0.5))
    """Largest relative darkening at the sensor's corners (drawn in [0, vignetting])."""
    defocus_blur_px: tuple[float, float] = (0.0, 0.0)
    """Range of the Gaussian σ of the defocus blur, px (0 = in focus)."""


@dataclass(frozen=True)
class RigConfig:
    """A whole rig description; see ``config/vast-rig.yaml`` for a commented example."""

    name: str = "simulated"
    stage: StageConfig = field(default_factory=StageConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    optics: OpticsConfig = field(default_factory=OpticsConfig)
    acquisition: AcquisitionConfig = field(default_factory=AcquisitionConfig)
    calibration: CalibrationSettings = field(default_factory=CalibrationSettings)
    reconstruction: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    simulation: SimulationConfig | None = None
    source: str = field(default="<defaults>", compare=False, repr=False)
    """Where this configuration was read from (not a YAML key)."""


_NOT_KEYS = {"source"}


def _describe(tp: Any) -> str:
    """A human name for an annotation, for error messages."""
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return " or ".join(_describe(a) for a in args) + (" or null" if type(None) in typing.get_args(tp) else "")
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_describe(args[0])}"
        return f"a list of {len(args)} values"
    if dataclasses.is_dataclass(tp):
        return "a mapping"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(tp, str(tp))


def _convert(
    value: Any, tp: Any, where: str, fail: typing.Callable[[str, str], ConfigError], meta: dict[str, Any]
) -> Any:
    """Check ``value`` against annotation ``tp`` and return it converted; raise via ``fail``."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _convert(value, inner[0], where, fail, meta)
    if origin is Literal:
        if value not in typing.get_args(tp):
            raise fail(where, f"expected {_describe(tp)}, got {_show(value)}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise fail(where, f"expected {_describe(tp)}, got {_show(value)}")
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{where}[{i}]", fail, {}) for i, v in enumerate(value))
        if len(value) != len(args):
            raise fail(where, f"expected {_describe(tp)}, got {len(value)}")
        return tuple(_convert(v, a, f"{where}[{i}]", fail, {}) for i, (v, a) in enumerate(zip(value, args)))
    if dataclasses.is_dataclass(tp):
        return _build(tp, value, where, fail)
    if tp is bool:
        if not isinstance(value, bool):
            raise fail(where, f"expected true or false, got {_show(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise fail(where, f"expected an integer, got {_show(value)}")
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise fail(where, f"expected a number, got {_show(value)}")
        value = float(value)
    elif tp is str:
        if not isinstance(value, str):
            raise fail(where, f"expected a string, got {_show(value)}")
        return value
    if tp is float and not math.isfinite(value):  # NaN passes every `value < lo` test; inf is no setting
        raise fail(where, f"expected a finite number, got {_show(value)}")
    lo, hi, lo_open = meta.get("lo"), meta.get("hi"), meta.get("lo_open", False)
    # Written as "not inside" so that anything incomparable (NaN) counts as outside.
    too_low = lo is not None and not (value > lo or (not lo_open and value == lo))
    too_high = hi is not None and not value <= hi
    if too_low or too_high:
        parts = ([f"> {lo}" if lo_open else f">= {lo}"] if lo is not None else []) + (
            [f"<= {hi}"] if hi is not None else []
        )
        raise fail(where, f"expected {_describe(tp)} {' and '.join(parts)}, got {_show(value)}")
    return value


def _build(cls: Any, data: Any, where: str, fail: typing.Callable[[str, str], ConfigError]) -> Any:
    """Build dataclass ``cls`` from mapping ``data`` found at key path ``where``."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise fail(where or "<top level>", f"expected a mapping, got {_show(data)}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.name not in _NOT_KEYS}
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        path = f"{where}.{key}" if where else str(key)
        if path in REMOVED_KEYS:
            if value:
                log.warning("%s is no longer a setting (%s); ignored", path, REMOVED_KEYS[path])
            continue
        if path in RENAMED_VALUES and isinstance(value, str):
            value = RENAMED_VALUES[path].get(value, value)
        if path in RENAMED_KEYS:
            former, key = path, RENAMED_KEYS[path]
            path = f"{where}.{key}"
            if key in data:
                raise fail(path, f"given twice (also under its former name {former})")
        if key not in fields:
            close = difflib.get_close_matches(str(key), list(fields), n=1)
            hint = f"; did you mean '{close[0]}'?" if close else f"; known keys: {', '.join(fields)}"
            raise fail(path, f"unknown key{hint}")
        f = fields[key]
        tp = hints[key]
        if typing.get_origin(tp) in (typing.Union, types.UnionType) and value is not None:
            inner = [a for a in typing.get_args(tp) if a is not type(None)]
            if dataclasses.is_dataclass(inner[0]):
                tp = inner[0]
        kwargs[key] = _convert(value, tp, path, fail, dict(f.metadata))
    for name, f in fields.items():
        if name not in kwargs and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise fail(f"{where}.{name}" if where else name, "missing required field")
    return cls(**kwargs)


def check_setting(section: Any, name: str, value: Any, given_as: str) -> Any:
    """Check one override of a rig-file field (e.g. a command-line option) against the field's type
    and range in ``section`` (a config dataclass); returns it converted.

    Raises:
        ConfigError: naming ``given_as`` (e.g. ``--offset-scan``), the expected and the given value.
    """
    f = {fl.name: fl for fl in dataclasses.fields(section)}[name]

    def fail(path: str, what: str) -> ConfigError:
        return ConfigError(_clip(f"{path}: {what}"))

    return _convert(value, typing.get_type_hints(section)[name], given_as, fail, dict(f.metadata))


def parse_config(data: Any, source: str = "<string>") -> RigConfig:
    """Validate a mapping (as from ``yaml.safe_load``) into a :class:`RigConfig`.

    Raises:
        ConfigError: on any unknown key, wrong type, missing field or out-of-range value.
    """

    def fail(path: str, what: str) -> ConfigError:
        return ConfigError(_clip(f"{source}: {_clip(path, 120)}: {what}"))

    cfg = _build(RigConfig, data, "", fail)
    if cfg.camera.driver == "simulated" and cfg.simulation is None:
        cfg = dataclasses.replace(cfg, simulation=SimulationConfig())
    roi, optics = cfg.camera.roi, cfg.optics
    if roi.x + roi.width > optics.sensor_width_px or roi.y + roi.height > optics.sensor_height_px:
        raise fail(
            "camera.roi",
            f"expected the ROI inside the {optics.sensor_width_px} x {optics.sensor_height_px} px sensor, "
            f"got x={roi.x} width={roi.width} y={roi.y} height={roi.height}",
        )
    for name in cfg.calibration.free:
        if name not in FREE_NAMES:
            raise fail("calibration.free", f"expected names from {', '.join(FREE_NAMES)}; got {_show(name)}")
    return dataclasses.replace(cfg, source=source)


class _BoundedLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses documents nested deeper than :data:`MAX_NESTING`
    (PyYAML's composer recurses once per level: 3000 levels raise RecursionError)."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        self._depth += 1
        try:
            if self._depth > MAX_NESTING:
                mark = self.peek_event().start_mark
                raise _TooLarge(f"is nested deeper than {MAX_NESTING} levels (line {mark.line + 1})")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


class _TooLarge(Exception):
    """A rig document beyond the bounds (internal; becomes a ConfigError)."""


def _expanded_size(node: yaml.Node) -> int:
    """Number of values ``node`` expands to, every alias counted in full; raises
    :class:`_TooLarge` past :data:`MAX_NODES` or on a recursive alias (cost: one visit per
    distinct node, whatever the expansion)."""
    sizes: dict[int, int] = {}
    busy: set[int] = set()

    def size(n: yaml.Node) -> int:
        key = id(n)
        if key in sizes:
            return sizes[key]
        if key in busy:
            raise _TooLarge("has an alias that refers to the mapping or list containing it")
        busy.add(key)
        total = 1
        if isinstance(n, yaml.SequenceNode):
            total += sum(size(c) for c in n.value)
        elif isinstance(n, yaml.MappingNode):
            total += sum(size(k) + size(v) for k, v in n.value)
        busy.discard(key)
        if total > MAX_NODES:
            raise _TooLarge(f"expands to more than {MAX_NODES} values (aliases counted in full)")
        sizes[key] = total
        return total

    return size(node)


def _load_yaml(text: str) -> Any:
    """``yaml.safe_load`` with bounded nesting and alias expansion; ``None`` for an empty document."""
    loader = _BoundedLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _expanded_size(node)
        return loader.construct_document(node)
    finally:
        loader.dispose()


def load_config(path: str | Path | None = None) -> RigConfig:
    """Read and validate a rig YAML file; ``None`` loads the embedded simulated rig.

    A file that is not a regular file, larger than :data:`MAX_CONFIG_BYTES`, empty (or just
    ``null``), nested deeper than :data:`MAX_NESTING` or expanding to more than
    :data:`MAX_NODES` values through aliases is refused.

    Raises:
        ConfigError: unreadable file, YAML syntax error, or invalid content (one-line message).
    """
    p = Path(path) if path is not None else DEFAULT_CONFIG
    try:
        if not p.is_file():
            what = "no such file" if not p.exists() else "not a regular file"
            raise ConfigError(f"{p}: cannot read the rig configuration: {what}")
        with p.open("rb") as f:
            raw = f.read(MAX_CONFIG_BYTES + 1)
        if len(raw) > MAX_CONFIG_BYTES:
            raise ConfigError(
                f"{p}: cannot read the rig configuration: larger than {MAX_CONFIG_BYTES} bytes (a rig file is a few kB)"
            )
        text = raw.decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(_clip(f"{p}: cannot read the rig configuration: {exc}")) from None
    try:
        data = _load_yaml(text)
    except _TooLarge as exc:
        raise ConfigError(_clip(f"{p}: refused: the YAML document {exc}")) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or (str(exc).splitlines() or [""])[0]
        raise ConfigError(_clip(f"{p}: YAML syntax error at {where}{problem}")) from None
    if data is None:
        raise ConfigError(
            f"{p}: the rig configuration is empty; expected a mapping of sections (see config/vast-rig.yaml)"
        )
    return parse_config(data, source=str(p))


def config_to_dict(cfg: RigConfig) -> dict[str, Any]:
    """The configuration as plain YAML-able data (tuples become lists), without ``source``."""

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v) if f.name not in _NOT_KEYS}
        if isinstance(v, (tuple, list)):
            return [plain(x) for x in v]
        return v

    return plain(cfg)


def dump_config(cfg: RigConfig) -> str:
    """The resolved configuration as YAML text (what a session stores as its rig snapshot)."""
    return yaml.safe_dump(config_to_dict(cfg), sort_keys=False)
