"""The session file: one HDF5 file per revolution, NeXus NXtomo core plus vastcal groups.

Layout (``SCHEMA_VERSION`` 1)::

    /                                 attrs: creator="vastcal", vastcal_session_version
    /entry                 NXentry    definition="NXtomo", title, start_time, end_time
      instrument/          NXinstrument
        detector/          NXdetector
          data             (N, H, W[, 3]) uint8|uint16, one frame per chunk, growable
          image_key        (N,) int32   0 projection, 1 flat, 2 dark
          image_key_control(N,) int32   same (the nxtomo reader prefers it)
          x_pixel_size     µm (attr units="um"), pixel pitch on the specimen (sensor pitch / magnification)
          y_pixel_size     µm
          count_time       (N,) s, exposure read back
      sample/              NXsample
        rotation_angle     (N,) degree — the **commanded** angle of every frame
      data/                NXdata       links to data, rotation_angle, image_key
      vastcal/             NXcollection attrs: schema_version
        rig                string: the resolved rig YAML
        plan               attrs: views, usteps_per_revolution, …
        views/             per-view table, one growable column per quantity, each with units
        start              attrs: uid, time, host, versions, …
        stop               attrs: exit_status (success|abort|fail), reason, views_written, time
        masks              optional (N, H, W) uint8 silhouettes (0/255), imported
        cameras/           optional known cameras: P (N, 3, 4), 0-based pixels of the stored frames
        geometry           attrs: roi_x, roi_y (offset of the stored frames on the sensor, px)
        calibration/run_NNN, reconstruction/run_NNN, measurement/run_NNN   later stages

Writing is incremental: :meth:`SessionWriter.append_view` grows every dataset by one view,
writes it and flushes, so a process killed between two views leaves a file that opens and
holds every completed view; the missing ``stop`` record marks it incomplete.
Nothing here overwrites an existing file unless ``force=True``.
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import os
import platform
import socket
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import h5py
import numpy as np

from vastcal import __version__
from vastcal.errors import NotASessionError, OutputExistsError, SessionError, SessionIncompleteError

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1
CREATOR = "vastcal"
ENTRY = "/entry"
DETECTOR = "/entry/instrument/detector"
VASTCAL = "/entry/vastcal"
STAGE_GROUPS = ("calibration", "reconstruction", "measurement")


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat()


def software_versions() -> dict[str, str]:
    """Versions of vastcal and the libraries whose behaviour shapes the results."""
    import importlib.metadata as md

    out = {"vastcal": __version__, "python": platform.python_version(), "hdf5": h5py.version.hdf5_version}
    for pkg in ("numpy", "h5py", "opencv-python-headless", "cma", "scikit-image", "pyserial", "harvesters"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return out


@dataclass(frozen=True)
class ViewColumn:
    """One column of the per-view table."""

    name: str
    dtype: Any
    units: str
    fill: Any


VIEW_COLUMNS: tuple[ViewColumn, ...] = (
    ViewColumn("commanded_angle_deg", "f8", "degree", np.nan),
    ViewColumn("commanded_usteps", "i8", "microstep", -1),
    ViewColumn("readback_usteps", "i8", "microstep", -1),
    ViewColumn("host_time_s", "f8", "s since 1970-01-01 UTC", np.nan),
    ViewColumn("device_time_s", "f8", "s (device clock)", np.nan),
    ViewColumn("frame_id", "i8", "", -1),
    ViewColumn("exposure_us", "f8", "us", np.nan),
    ViewColumn("gain_db", "f8", "dB", np.nan),
    ViewColumn("move_s", "f8", "s", np.nan),
    ViewColumn("stage_warnings", "S32", "", b""),
)


def _set_attrs(obj: h5py.HLObject, attrs: dict[str, Any]) -> None:
    for k, v in attrs.items():
        if v is None:
            continue
        if isinstance(v, (dict, list, tuple)) and not (isinstance(v, (list, tuple)) and v and all(isinstance(x, (int, float)) for x in v)):
            v = json.dumps(v)
        obj.attrs[k] = v


def _attr_str(v: Any) -> Any:
    return v.decode() if isinstance(v, bytes) else v


def check_writable_output(path: str | Path, force: bool) -> Path:
    """Refuse to replace an existing file unless ``force``; return the path.

    Raises:
        OutputExistsError: the file exists and ``force`` is false.
    """
    p = Path(path)
    if p.exists() and not force:
        raise OutputExistsError(f"{p}: file exists; pass --force to overwrite it")
    return p


class SessionWriter:
    """Creates a session and appends views one at a time (acquisition and import).

    Use as a context manager; :meth:`finish` writes the stop record. If the context exits
    with an exception and no stop record was written, the stop record says ``fail`` (or
    ``abort`` for KeyboardInterrupt) with the exception text as reason.
    """

    def __init__(self, h5: h5py.File, path: Path) -> None:
        self._h5 = h5
        self.path = path
        self._finished = "stop" in h5[VASTCAL]
        det, views = h5[DETECTOR], h5[VASTCAL]["views"]
        # Growable 1-D datasets written once per view, looked up once (hot path of acquisition).
        self._data = det["data"]
        self._columns = {c.name: views[c.name] for c in VIEW_COLUMNS}
        self._keys = (det["image_key"], det["image_key_control"])
        self._count_time = det["count_time"]
        self._angle = h5[ENTRY]["sample"]["rotation_angle"]

    # -- creation -------------------------------------------------------------------------
    @classmethod
    def create(
        cls,
        path: str | Path,
        *,
        frame_shape: tuple[int, ...],
        dtype: np.dtype | str,
        rig_yaml: str,
        plan: dict[str, Any],
        pixel_size_um: tuple[float, float],
        roi_offset_px: tuple[int, int] = (0, 0),
        title: str = "",
        start_info: dict[str, Any] | None = None,
        force: bool = False,
    ) -> "SessionWriter":
        """Create a new session file with zero views.

        Args:
            frame_shape: (H, W) or (H, W, 3) of every frame, pixels.
            dtype: pixel type (uint8 or uint16).
            rig_yaml: resolved rig configuration (YAML text) stored verbatim.
            plan: what will be acquired (JSON-able), e.g. ``{"views": 21, ...}``.
            pixel_size_um: (x, y) pixel pitch on the specimen, µm.
            roi_offset_px: (x, y) offset of the stored frames on the sensor, px.
            start_info: extra start-record attributes (device descriptions …).
            force: replace an existing file.

        Raises:
            OutputExistsError: the file exists and ``force`` is false.
        """
        p = check_writable_output(path, force)
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(p.name + ".partial")
        h5 = h5py.File(tmp, "w")
        try:
            cls._layout(h5, tuple(frame_shape), np.dtype(dtype), rig_yaml, plan, pixel_size_um, roi_offset_px, title, start_info or {})
            h5.flush()
        except BaseException:
            h5.close()
            tmp.unlink(missing_ok=True)
            raise
        h5.close()
        os.replace(tmp, p)  # the empty skeleton appears atomically
        return cls(h5py.File(p, "r+"), p)

    @staticmethod
    def _layout(h5: h5py.File, frame_shape: tuple[int, ...], dtype: np.dtype, rig_yaml: str, plan: dict[str, Any],
                pixel_size_um: tuple[float, float], roi_offset_px: tuple[int, int], title: str, start_info: dict[str, Any]) -> None:
        h5.attrs["creator"] = CREATOR
        h5.attrs["vastcal_session_version"] = SCHEMA_VERSION
        h5.attrs["default"] = "entry"
        entry = h5.create_group(ENTRY)
        entry.attrs["NX_class"] = "NXentry"
        entry.attrs["default"] = "data"
        entry.attrs["version"] = 1.3  # NXtomo paths version, as the nxtomo package reads it (a float)
        entry["definition"] = "NXtomo"
        entry["title"] = title or "vastcal session"
        entry["start_time"] = _now()
        inst = entry.create_group("instrument")
        inst.attrs["NX_class"] = "NXinstrument"
        det = inst.create_group("detector")
        det.attrs["NX_class"] = "NXdetector"
        chunk = (1,) + frame_shape
        d = det.create_dataset("data", shape=(0,) + frame_shape, maxshape=(None,) + frame_shape, dtype=dtype, chunks=chunk)
        d.attrs["interpretation"] = "image"
        for name in ("image_key", "image_key_control"):
            det.create_dataset(name, shape=(0,), maxshape=(None,), dtype="i4", chunks=(1024,))
        ct = det.create_dataset("count_time", shape=(0,), maxshape=(None,), dtype="f8", chunks=(1024,))
        ct.attrs["units"] = "s"
        for name, v in (("x_pixel_size", pixel_size_um[0]), ("y_pixel_size", pixel_size_um[1])):
            det[name] = float(v)
            det[name].attrs["units"] = "um"
        sample = entry.create_group("sample")
        sample.attrs["NX_class"] = "NXsample"
        ra = sample.create_dataset("rotation_angle", shape=(0,), maxshape=(None,), dtype="f8", chunks=(1024,))
        ra.attrs["units"] = "degree"
        data = entry.create_group("data")
        data.attrs["NX_class"] = "NXdata"
        data.attrs["signal"] = "data"
        data["data"] = d
        data["rotation_angle"] = ra
        data["image_key"] = det["image_key"]

        vc = entry.create_group("vastcal")
        vc.attrs["NX_class"] = "NXcollection"
        vc.attrs["schema_version"] = SCHEMA_VERSION
        vc["rig"] = rig_yaml
        g = vc.create_group("plan")
        _set_attrs(g, plan)
        geo = vc.create_group("geometry")
        geo.attrs["roi_x"], geo.attrs["roi_y"] = int(roi_offset_px[0]), int(roi_offset_px[1])
        geo.attrs["units"] = "px"
        views = vc.create_group("views")
        views.attrs["schema_version"] = SCHEMA_VERSION
        for col in VIEW_COLUMNS:
            ds = views.create_dataset(col.name, shape=(0,), maxshape=(None,), dtype=col.dtype, chunks=(1024,))
            ds.attrs["units"] = col.units
        start = vc.create_group("start")
        _set_attrs(start, {"uid": str(uuid.uuid4()), "time": _now(), "host": socket.gethostname(),
                           "versions": software_versions(), **start_info})

    # -- resume ---------------------------------------------------------------------------
    @classmethod
    def resume(cls, path: str | Path) -> "SessionWriter":
        """Reopen an incomplete session to append more views.

        Raises:
            NotASessionError: not a vastcal session.
            SessionIncompleteError: never raised; a *complete* session raises ``OutputExistsError``.
        """
        s = Session.open(path)  # validates
        s.close()
        h5 = h5py.File(path, "r+")
        if "stop" in h5[VASTCAL]:
            status = _attr_str(h5[VASTCAL]["stop"].attrs.get("exit_status", ""))
            if status == "success":
                h5.close()
                raise OutputExistsError(f"{path}: the session is complete (exit_status success); nothing to resume")
            resumes = h5[VASTCAL].require_group("resumed")  # keep the history of earlier endings
            old = h5[VASTCAL]["stop"]
            rec = resumes.create_group(f"stop_{len(resumes):03d}")
            _set_attrs(rec, {k: _attr_str(v) for k, v in old.attrs.items()})
            del h5[VASTCAL]["stop"]
            h5.flush()
        writer = cls(h5, Path(path))
        writer._drop_unfinished_view()
        return writer

    def _drop_unfinished_view(self) -> None:
        """Cut per-view records beyond the last complete frame (an append cut short by a kill)."""
        n = self.n_views
        for ds in (*self._columns.values(), *self._keys, self._count_time, self._angle):
            if ds.shape[0] > n:
                ds.resize((n,))
        self._h5.flush()

    # -- appending ------------------------------------------------------------------------
    @property
    def n_views(self) -> int:
        """Frames written so far."""
        return int(self._h5[DETECTOR]["data"].shape[0])

    def append_view(self, frame: np.ndarray, angle_deg: float, image_key: int = 0, **columns: Any) -> int:
        """Append one frame and its per-view record, then flush; returns its index.

        ``columns`` fill the per-view table (see :data:`VIEW_COLUMNS`; missing ones get their
        fill value, e.g. ``readback_usteps=-1`` for imported images). Unknown names raise.
        """
        data = self._data
        if frame.shape != data.shape[1:] or frame.dtype != data.dtype:
            raise SessionError(f"{self.path}: a {frame.shape} {frame.dtype} frame does not fit this session's {data.shape[1:]} {data.dtype} "
                               "frames (was the rig's ROI or pixel format changed?)")
        unknown = set(columns) - set(self._columns)
        if unknown:
            raise ValueError(f"unknown per-view columns: {sorted(unknown)}")
        i = data.shape[0]
        values = {c.name: columns.get(c.name, c.fill) for c in VIEW_COLUMNS}
        values["commanded_angle_deg"] = angle_deg
        for col in VIEW_COLUMNS:
            v = values[col.name]
            _append(self._columns[col.name], i, v.encode() if isinstance(v, str) else v)
        for ds in self._keys:
            _append(ds, i, image_key)
        _append(self._count_time, i, values["exposure_us"] * 1e-6)
        _append(self._angle, i, angle_deg)
        # The frame last: a view counts once its frame is in place. One frame = one chunk,
        # written directly (no selection machinery, no conversion).
        data.resize((i + 1,) + data.shape[1:])
        data.id.write_direct_chunk((i,) + (0,) * frame.ndim, np.ascontiguousarray(frame).tobytes())
        self._h5.flush()
        return i

    def write_masks(self, masks: np.ndarray) -> None:
        """Store silhouettes (N, H, W), nonzero = specimen, as uint8 0/255."""
        m = (np.asarray(masks) > 0).astype(np.uint8) * 255
        self._h5[VASTCAL].create_dataset("masks", data=m, chunks=(1,) + m.shape[1:], compression="gzip", compression_opts=1)
        self._h5.flush()

    def write_cameras(self, P: np.ndarray, source: str, attrs: dict[str, Any] | None = None, P_given: np.ndarray | None = None) -> None:
        """Store known cameras P (N, 3, 4) in 0-based pixels of the stored frames.

        ``P_given`` keeps the matrices exactly as the source gave them (its own pixel convention).
        """
        g = self._h5[VASTCAL].create_group("cameras")
        g.create_dataset("P", data=np.asarray(P, float))
        if P_given is not None:
            g.create_dataset("P_given", data=np.asarray(P_given, float))
        g["P"].attrs["convention"] = "world (specimen units) -> 0-based pixels of the stored frames"
        _set_attrs(g, {"source": source, **(attrs or {})})
        self._h5.flush()

    def finish(self, exit_status: str, reason: str = "", **extra: Any) -> None:
        """Write the stop record (``success``, ``abort`` or ``fail``) and the end time."""
        if exit_status not in ("success", "abort", "fail"):
            raise ValueError(f"exit_status must be success, abort or fail, got {exit_status!r}")
        vc = self._h5[VASTCAL]
        if "stop" in vc:
            del vc["stop"]
        stop = vc.create_group("stop")
        _set_attrs(stop, {"exit_status": exit_status, "reason": reason, "views_written": self.n_views, "time": _now(), **extra})
        entry = self._h5[ENTRY]
        if "end_time" in entry:
            del entry["end_time"]
        entry["end_time"] = _now()
        self._h5.flush()
        self._finished = True

    def close(self) -> None:
        """Close the file (idempotent)."""
        if self._h5.id.valid:
            self._h5.close()

    def __enter__(self) -> "SessionWriter":
        return self

    def __exit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> None:
        try:
            if not self._finished and self._h5.id.valid:
                if exc_type is None:
                    self.finish("success")
                elif issubclass(exc_type, KeyboardInterrupt):
                    self.finish("abort", "interrupted by the operator")
                else:
                    self.finish("fail", f"{exc_type.__name__}: {exc}")
        finally:
            self.close()


class Session:
    """A session opened for reading, and for adding the results of later stages.

    Opening checks that the file is HDF5, is not truncated and was written by vastcal;
    it never modifies the images. Use :meth:`open` and close it (or use ``with``).
    """

    def __init__(self, h5: h5py.File, path: Path) -> None:
        self._h5 = h5
        self.path = path

    @classmethod
    def open(cls, path: str | Path, mode: str = "r") -> "Session":
        """Open and validate a session (``mode`` ``"r"`` or ``"a"`` to add results).

        Raises:
            NotASessionError: missing file, not HDF5, truncated, or not written by vastcal.
        """
        p = Path(path)
        if not p.is_file():
            raise NotASessionError(f"{p}: no such session file")
        try:
            is_h5 = h5py.is_hdf5(p)
        except OSError as exc:
            raise NotASessionError(f"{p}: cannot read: {exc}") from None
        if not is_h5:
            raise NotASessionError(f"{p}: not an HDF5 file (expected a vastcal session .h5)")
        try:
            h5 = h5py.File(p, "r+" if mode == "a" else "r")
        except OSError as exc:
            msg = str(exc).splitlines()[0]
            hint = "truncated or damaged" if "truncat" in msg or "signature" in msg or "eof" in msg.lower() else "cannot open"
            raise NotASessionError(f"{p}: {hint} HDF5 file ({msg})") from None
        try:
            if _attr_str(h5.attrs.get("creator", "")) != CREATOR or VASTCAL not in h5 or DETECTOR + "/data" not in h5:
                raise NotASessionError(f"{p}: HDF5 file not written by vastcal (no /entry/vastcal group); import images with 'vastcal import'")
            version = int(h5.attrs.get("vastcal_session_version", 0))
            if version > SCHEMA_VERSION:
                raise NotASessionError(f"{p}: session schema version {version} is newer than this vastcal understands ({SCHEMA_VERSION})")
            n = h5[DETECTOR]["data"].shape[0]
            n_angles = h5[ENTRY]["sample"]["rotation_angle"].shape[0]
            if n_angles < n or (n_angles > n + 1) or (n_angles == n + 1 and "stop" in h5[VASTCAL]):
                # One extra record without its frame is an append cut short (kill mid-view): tolerated.
                raise NotASessionError(f"{p}: damaged session: {n} frames but {n_angles} rotation angles")
        except NotASessionError:
            h5.close()
            raise
        except (KeyError, OSError, ValueError) as exc:
            h5.close()
            raise NotASessionError(f"{p}: damaged session ({exc})") from None
        return cls(h5, p)

    def close(self) -> None:
        """Close the file (idempotent)."""
        if self._h5.id.valid:
            self._h5.close()

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- images and angles ------------------------------------------------------------------
    @property
    def h5(self) -> h5py.File:
        """The underlying h5py file (for stages that add groups)."""
        return self._h5

    @property
    def n_views(self) -> int:
        """Number of frames stored (all image keys)."""
        return int(self._h5[DETECTOR]["data"].shape[0])

    @property
    def frame_shape(self) -> tuple[int, ...]:
        """(H, W) or (H, W, 3)."""
        return tuple(self._h5[DETECTOR]["data"].shape[1:])

    @property
    def dtype(self) -> np.dtype:
        """Pixel type of the frames."""
        return self._h5[DETECTOR]["data"].dtype

    @property
    def image_key(self) -> np.ndarray:
        """(N,) 0 projection, 1 flat, 2 dark."""
        return self._h5[DETECTOR]["image_key"][: self.n_views]

    @property
    def projection_indices(self) -> np.ndarray:
        """Indices of the projection frames (image_key 0)."""
        return np.flatnonzero(self.image_key == 0)

    def frame(self, i: int) -> np.ndarray:
        """Frame ``i`` as stored."""
        return self._h5[DETECTOR]["data"][i]

    def projections(self) -> np.ndarray:
        """All projection frames (image_key 0), (N, H, W[, 3])."""
        idx = self.projection_indices
        data = self._h5[DETECTOR]["data"]
        if len(idx) == data.shape[0]:
            return data[...]
        return np.stack([data[i] for i in idx]) if len(idx) else np.empty((0,) + data.shape[1:], data.dtype)

    def iter_frames(self) -> Iterator[np.ndarray]:
        """Frames one at a time (for memory-light readers)."""
        data = self._h5[DETECTOR]["data"]
        for i in range(data.shape[0]):
            yield data[i]

    @property
    def angles_deg(self) -> np.ndarray:
        """Commanded rotation angle of every projection, degrees."""
        return self._h5[ENTRY]["sample"]["rotation_angle"][: self.n_views][self.projection_indices]

    @property
    def pixel_size_um(self) -> tuple[float, float]:
        """(x, y) pixel pitch on the specimen, µm."""
        det = self._h5[DETECTOR]
        return float(det["x_pixel_size"][()]), float(det["y_pixel_size"][()])

    @property
    def roi_offset_px(self) -> tuple[int, int]:
        """(x, y) offset of the stored frames on the sensor, px."""
        g = self._h5[VASTCAL]["geometry"].attrs
        return int(g["roi_x"]), int(g["roi_y"])

    @property
    def rig_yaml(self) -> str:
        """The resolved rig configuration stored at creation."""
        return _attr_str(self._h5[VASTCAL]["rig"][()])

    def rig_config(self) -> "Any":
        """The stored rig configuration parsed into a :class:`~vastcal.config.RigConfig`."""
        import yaml

        from vastcal.config import parse_config

        return parse_config(yaml.safe_load(self.rig_yaml), source=f"{self.path}:/entry/vastcal/rig")

    @property
    def plan(self) -> dict[str, Any]:
        """The plan attributes."""
        return {k: _decode_json(v) for k, v in self._h5[VASTCAL]["plan"].attrs.items()}

    def view_table(self) -> dict[str, np.ndarray]:
        """The per-view table, one array per column."""
        views = self._h5[VASTCAL]["views"]
        return {k: views[k][: self.n_views] for k in views}

    @property
    def masks(self) -> np.ndarray | None:
        """Imported silhouettes (N, H, W) uint8 0/255 for the projections, or None."""
        if "masks" not in self._h5[VASTCAL]:
            return None
        return self._h5[VASTCAL]["masks"][...]

    @property
    def known_cameras(self) -> np.ndarray | None:
        """Imported cameras P (N, 3, 4), 0-based pixels of the stored frames, or None."""
        if "cameras" not in self._h5[VASTCAL]:
            return None
        return self._h5[VASTCAL]["cameras"]["P"][...]

    # -- status -------------------------------------------------------------------------------
    @property
    def start_record(self) -> dict[str, Any]:
        """Attributes of the start record."""
        return {k: _decode_json(v) for k, v in self._h5[VASTCAL]["start"].attrs.items()}

    @property
    def stop_record(self) -> dict[str, Any] | None:
        """Attributes of the stop record, or None if the writer never finished."""
        if "stop" not in self._h5[VASTCAL]:
            return None
        return {k: _decode_json(v) for k, v in self._h5[VASTCAL]["stop"].attrs.items()}

    @property
    def exit_status(self) -> str:
        """``success``, ``abort``, ``fail``, or ``incomplete`` when no stop record exists."""
        rec = self.stop_record
        return str(rec["exit_status"]) if rec else "incomplete"

    @property
    def is_complete(self) -> bool:
        """True when the writer finished with success and every planned view is present."""
        planned = self.plan.get("views")
        return self.exit_status == "success" and (planned is None or len(self.projection_indices) >= int(planned))

    def require_complete(self, min_views: int = 1) -> None:
        """Raise unless the session has finished successfully with at least ``min_views`` projections.

        Raises:
            SessionIncompleteError: with the exit status and counts in the message.
        """
        n = len(self.projection_indices)
        if not self.is_complete:
            planned = self.plan.get("views", "?")
            raise SessionIncompleteError(f"{self.path}: session is {self.exit_status}: {n} of {planned} views; "
                                         f"finish it with 'vastcal acquire --resume {self.path}'")
        if n < min_views:
            raise SessionIncompleteError(f"{self.path}: {n} projection views; at least {min_views} needed")

    # -- results of later stages -------------------------------------------------------------
    def stages_run(self) -> dict[str, list[str]]:
        """Names of the stored runs of each later stage, oldest first."""
        vc = self._h5[VASTCAL]
        return {k: sorted(vc[k].keys()) for k in STAGE_GROUPS if k in vc}

    def new_result_group(self, stage: str) -> h5py.Group:
        """Create ``/entry/vastcal/<stage>/run_NNN`` (next free number) for a stage's result."""
        if stage not in STAGE_GROUPS:
            raise ValueError(f"unknown stage {stage!r}")
        if self._h5.mode != "r+":
            raise ValueError("session opened read-only; open with mode='a' to add results")
        g = self._h5[VASTCAL].require_group(stage)
        g.attrs["schema_version"] = SCHEMA_VERSION
        name = f"run_{len(g):03d}"
        run = g.create_group(name)
        run.attrs["time"] = _now()
        run.attrs["versions"] = json.dumps(software_versions())
        return run

    def latest_result(self, stage: str) -> h5py.Group | None:
        """The newest run of ``stage``, or None."""
        runs = self.stages_run().get(stage)
        return self._h5[VASTCAL][stage][runs[-1]] if runs else None

    def result(self, stage: str, name: str | None = None) -> h5py.Group | None:
        """Run ``name`` of ``stage`` (the latest when ``name`` is None), or None."""
        if name is None:
            return self.latest_result(stage)
        g = self._h5[VASTCAL].get(stage)
        return g[name] if g is not None and name in g else None

    def flush(self) -> None:
        """Flush pending writes of later stages."""
        self._h5.flush()


def _append(ds: h5py.Dataset, i: int, value: Any) -> None:
    """Grow a 1-D dataset to ``i + 1`` elements and set element ``i``."""
    ds.resize((i + 1,))
    ds[i] = value


def _decode_json(v: Any) -> Any:
    v = _attr_str(v)
    if isinstance(v, str) and v[:1] in "[{":
        try:
            return json.loads(v)
        except ValueError:
            return v
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


def write_attrs(group: h5py.Group, attrs: dict[str, Any]) -> None:
    """Write attributes; dicts and lists of non-numbers are stored as JSON strings."""
    _set_attrs(group, attrs)


def read_attrs(group: h5py.Group) -> dict[str, Any]:
    """Read attributes, decoding the JSON strings that :func:`write_attrs` wrote."""
    return {k: _decode_json(v) for k, v in group.attrs.items()}
