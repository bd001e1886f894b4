"""The session file: one HDF5 file per revolution, NeXus NXtomo core plus vastcal groups.

Layout (``SCHEMA_VERSION`` 3)::

    /                                 attrs: creator="vastcal", vastcal_session_version, default="entry"
    /entry                 NXentry    definition="NXtomo", version=1.5 (NXtomo paths), title, start_time, end_time
      instrument/          NXinstrument
        detector/          NXdetector
          data             (N, H, W) uint8|uint16, one frame per chunk, growable; for RGB sessions the
                           GREEN plane (attr channel="green"), red and blue in vastcal/colour
          image_key        (N,) int32   0 projection, 1 flat, 2 dark
          image_key_control(N,) int32   same (the nxtomo reader prefers it)
          x_pixel_size     µm (attr units="um"): the sensor's own (physical) pixel pitch, when known
          y_pixel_size     µm
          count_time       (N,) s, exposure read back
      sample/              NXsample
        rotation_angle     (N,) degree — the **commanded** angle of every frame
        x_pixel_size       µm: the effective pixel on the specimen (sensor pitch / magnification);
        y_pixel_size       µm  what reconstruction and measurement use
      data/                NXdata       signal data, axes [rotation_angle, ., .]; links to data,
                                        rotation_angle, image_key
      vastcal/             NXcollection attrs: schema_version
        rig                string: the resolved rig YAML
        plan               attrs: views, usteps_per_revolution, …
        colour/            RGB sessions only: red, blue (N, H, W) planes like data; green = a hard
                           link to the detector data (no byte stored twice)
        views/             per-view table, one growable column per quantity, each with units,
                           including frame_crc32 (CRC-32 of the frame bytes, H x W [x 3] interleaved)
        committed_views    (1,) int: views 0 .. n-1 are complete (the commit record)
        start              attrs: uid, time, host, versions, …
        stop_record        JSON: exit_status (success|abort|fail), reason, views_written, time;
                           empty while the writer is at work (or after it was killed)
        resumed/stop_NNN   earlier endings of a resumed acquisition
        masks              optional (N, H, W) uint8 silhouettes (0/255), imported
        cameras/           optional known cameras: P (N, 3, 4), 0-based pixels of the stored frames; P_given
                           (as the file gave them); attrs source, names, pixel_origin, roi_offset, length_unit
                           (+ _source), circular_fit_rms_px (or circular_fit_error), vastcal.importer
        geometry           attrs: roi_x, roi_y (offset of the stored frames on the sensor, px)
        calibration/run_NNN, reconstruction/run_NNN, measurement/run_NNN   later stages
                           (a reconstruction run is an NXdata of the silhouette counts on x, y, z
                           axes in µm; a measurement's mesh is an NXoff_geometry, see vastcal.nexus)

Why RGB frames are stored as three planes: NXtomo's detector data is N x H x W (NeXus readers such
as ``nxtomo`` refuse N x H x W x 3), so the green plane is the detector data — the channel a Bayer
sensor samples twice and the one that carries most of the luminance — and red and blue sit beside it
with the same chunking. Nothing is stored twice (a luminance plane beside the RGB frames would add a
third to the file), vastcal's readers (:meth:`Session.frame`, :meth:`Session.projections`) put the
planes back together, and a view's three planes are written before its commit record like any frame.

Schema 2 (RGB frames N x H x W x 3 in the detector data; the effective pixel in
``detector/x_pixel_size``, the sensor pitch in ``detector/real_x_pixel_size``) and schema 1 (no commit
record, stop record as group attributes) are read as before; ``--resume`` and the copy a stage makes
of a killed session rewrite them in the current layout.

Crash consistency — what a kill at any instant can and cannot lose:

* Acquisition grows ``S.h5`` in HDF5 SWMR mode: every object exists before the first view, and
  HDF5 orders its metadata writes so that the file is readable after any prefix of them. A view
  is *committed* by one write of ``committed_views`` after its frame, its record and its CRC-32
  are written, flushed and fsync-ed. A kill loses at most the view in flight; committed views
  are never touched again. Readers (``vastcal info`` while acquiring, or after a kill) open the
  file in SWMR mode and see exactly the committed views.
* ``--resume`` verifies every committed frame against its CRC-32 and copies them, bit for bit,
  into a new file that replaces the old one in one rename.
* Import writes a hidden temporary file and renames it into place when complete.
* Later stages never write ``S.h5`` in place: a run is added to a copy of the file that then
  replaces it in one rename (copy-on-write), so a kill while a run is stored loses that run only;
  the images are copied bit for bit.
* One writer per path: a lock (``flock`` on ``.NAME.lock``) makes a second writer fail at once.
"""

from __future__ import annotations

import datetime as _dt
import errno
import json
import logging
import os
import platform
import re
import shutil
import socket
import uuid
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from vastcal import __version__
from vastcal.errors import (
    NotASessionError,
    OutputExistsError,
    SessionCorruptError,
    SessionError,
    SessionIncompleteError,
)
from vastcal.outputs import check_output_file
from vastcal.session_files import PathLock, place_atomically

log = logging.getLogger(__name__)

SCHEMA_VERSION = 3
CREATOR = "vastcal"
ENTRY = "/entry"
DETECTOR = "/entry/instrument/detector"
VASTCAL = "/entry/vastcal"
NXTOMO_PATHS_VERSION = 1.5
"""NXtomo paths version (``/entry@version``, a float as the nxtomo package reads it): 1.5 is the first
with both the detector pixel (``detector/x_pixel_size``) and the effective one (``sample/x_pixel_size``)."""
STAGE_GROUPS = ("calibration", "reconstruction", "measurement")
STOP_RECORD_BYTES = 8192
RESULTS_LOCK_TIMEOUT_S = 60.0


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat()


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
    ViewColumn("frame_crc32", "u4", "CRC-32 of the frame bytes as stored", 0),
)


def _set_attrs(obj: h5py.HLObject, attrs: dict[str, Any]) -> None:
    for k, v in attrs.items():
        if v is None:
            continue
        if isinstance(v, (dict, list, tuple)) and not (
            isinstance(v, (list, tuple)) and v and all(isinstance(x, (int, float)) for x in v)
        ):
            v = json.dumps(v)
        obj.attrs[k] = v


def _attr_str(v: Any) -> Any:
    return v.decode() if isinstance(v, bytes) else v


def _os_error(exc: BaseException, path: Path) -> OSError:
    """An OSError naming the session (h5py names the file it opened, and reports errno in its text)."""
    code = getattr(exc, "errno", None)
    if not code:
        found = re.search(r"errno = (\d+)", str(exc))
        code = int(found.group(1)) if found else errno.EIO
    return OSError(code, os.strerror(code), str(path))


def _write_skeleton(tmp: Path, layout: Any) -> None:
    """Build a file in memory with ``layout(h5)`` and write its bytes to ``tmp`` with plain I/O.

    HDF5 does not always report a failed write while it builds a file (a full disk), and closing
    such a file crashes it; bytes written by Python fail loudly and leave nothing half-made.
    """
    mem = h5py.File(f"skeleton-{uuid.uuid4()}", "w", driver="core", backing_store=False, libver="latest")
    try:
        layout(mem)
        mem.flush()
        image = mem.id.get_file_image()
    finally:
        mem.close()
    try:
        with open(tmp, "wb") as f:
            f.write(image)
            f.flush()
            os.fsync(f.fileno())
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


_ABANDONED: list[h5py.File] = []
"""Files whose write failed (a full disk): HDF5 crashes (segmentation fault) when such a file is
closed or freed, so they are kept open and never touched again; the committed part on disk stays
as it was. A command-line run then ends with ``os._exit`` (no library clean-up)."""


def _abandon(f: h5py.File | None) -> None:
    if f is not None:
        _ABANDONED.append(f)


def _frame_crc(frame: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(frame).data) & 0xFFFFFFFF


def _scalar_string(group: h5py.Group, name: str, size: int) -> h5py.Dataset:
    """A fixed-length string dataset whose storage exists before SWMR starts (rewritten in place)."""
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
    tid = h5py.h5t.C_S1.copy()
    tid.set_size(size)
    sid = h5py.h5s.create(h5py.h5s.SCALAR)
    dsid = h5py.h5d.create(group.id, name.encode(), tid, sid, dcpl=dcpl)
    ds = h5py.Dataset(dsid)
    ds[()] = b""
    return ds


class SessionWriter:
    """Creates a session and appends views one at a time (acquisition and import).

    Two ways of writing (chosen at :meth:`create`):

    * **live** (acquisition): the file appears at its name with zero views and then grows in HDF5
      SWMR mode, so readers (``vastcal info``) can follow it, and a kill at *any* write leaves a
      file whose committed views are intact. A view is committed by one write of
      ``/entry/vastcal/committed_views`` that happens only after its frame, its per-view record and
      its CRC-32 are written, flushed and ``fsync``-ed; readers see exactly the committed views.
    * **staged** (import): everything is written to a hidden temporary file that replaces the
      name in one atomic rename at :meth:`finish` with ``success``; a failure leaves no output.

    Use as a context manager; :meth:`finish` writes the stop record. If the context exits
    with an exception and no stop record was written, the stop record says ``fail`` (or
    ``abort`` for KeyboardInterrupt) with the exception text as reason.
    """

    def __init__(
        self,
        h5: h5py.File,
        path: Path,
        *,
        lock: PathLock,
        staged_from: Path | None = None,
        replace: bool = False,
        durable: bool = True,
    ) -> None:
        self._h5 = h5
        self.path = path
        self._lock = lock
        self._staged_from = staged_from  # the temporary file of a staged write
        self._replace = replace
        self._durable = durable
        self._finished = False
        self._failed: OSError | None = None  # a write failed: the file is never written or closed again
        det, views = h5[DETECTOR], h5[VASTCAL]["views"]
        # Growable 1-D datasets written once per view, looked up once (hot path of acquisition).
        self._data = det["data"]
        colour = h5[VASTCAL].get("colour")
        # RGB: the planes written for each view, red, green (the detector data) and blue; None for mono.
        self._planes = (colour["red"], self._data, colour["blue"]) if colour is not None else None
        self._frame_shape = tuple(self._data.shape[1:]) + ((3,) if colour is not None else ())
        self._columns = {c.name: views[c.name] for c in VIEW_COLUMNS}
        self._keys = (det["image_key"], det["image_key_control"])
        self._count_time = det["count_time"]
        self._angle = h5[ENTRY]["sample"]["rotation_angle"]
        self._committed = h5[VASTCAL]["committed_views"]
        self._n = int(self._committed[0])

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
        live: bool = True,
        durable: bool = True,
        lock: PathLock | None = None,
        sensor_pixel_um: tuple[float, float] | None = None,
    ) -> SessionWriter:
        """Create a new session file with zero views.

        Args:
            frame_shape: (H, W) or (H, W, 3) of every frame, pixels.
            dtype: pixel type (uint8 or uint16).
            rig_yaml: resolved rig configuration (YAML text) stored verbatim.
            plan: what will be acquired (JSON-able), e.g. ``{"views": 21, ...}``.
            pixel_size_um: (x, y) pixel pitch on the specimen, µm.
            roi_offset_px: (x, y) offset of the stored frames on the sensor, px.
            start_info: extra start-record attributes (device descriptions …).
            force: replace an existing (regular) file.
            live: grow the file in place in SWMR mode (acquisition); otherwise stage it and
                rename it into place at a successful :meth:`finish` (import).
            durable: ``fsync`` each view before committing it (power cuts, not only kills).
            lock: the path's writer lock, when the caller took it already (before homing a stage).
            sensor_pixel_um: (x, y) pitch of the sensor itself, µm (``real_x_pixel_size``), when known.

        Raises:
            OutputExistsError: the file exists and ``force`` is false.
            SessionBusyError: another process is writing the same path.
        """
        p = check_output_file(path, force=force)
        p.parent.mkdir(parents=True, exist_ok=True)
        lock = (lock or PathLock(p)).acquire()
        try:
            tmp = p.with_name(f".{p.name}.partial")
            layout = (
                tuple(frame_shape),
                np.dtype(dtype),
                rig_yaml,
                plan,
                pixel_size_um,
                roi_offset_px,
                title,
                start_info or {},
                None,
                sensor_pixel_um,
            )
            if not live:
                h5 = h5py.File(tmp, "w", libver="latest")
                try:
                    cls._layout(h5, *layout)
                except BaseException:
                    h5.close()
                    tmp.unlink(missing_ok=True)
                    raise
                return cls(h5, p, lock=lock, staged_from=tmp, replace=force, durable=False)
            _write_skeleton(tmp, lambda h5: cls._layout(h5, *layout))
            h5 = h5py.File(tmp, "r+", libver="latest")
            return cls._go_live(h5, tmp, p, lock, durable, replace=force)
        except BaseException:
            lock.release()
            raise

    @classmethod
    def _go_live(
        cls, h5: h5py.File, tmp: Path, p: Path, lock: PathLock, durable: bool, replace: bool
    ) -> SessionWriter:
        """Switch the finished skeleton ``tmp`` to SWMR writing, then rename it to ``p``.

        The file appears under its name only once it is in SWMR mode, so no reader (and no
        resume) can ever meet it in the one-write window between "open for writing" and "SWMR".
        """
        try:
            h5.flush()
            h5.swmr_mode = True
            place_atomically(tmp, p, replace=replace)
        except BaseException:
            h5.close()
            tmp.unlink(missing_ok=True)
            raise
        return cls(h5, p, lock=lock, durable=durable)

    @staticmethod
    def _layout(
        h5: h5py.File,
        frame_shape: tuple[int, ...],
        dtype: np.dtype,
        rig_yaml: str,
        plan: dict[str, Any],
        pixel_size_um: tuple[float, float],
        roi_offset_px: tuple[int, int],
        title: str,
        start_info: dict[str, Any],
        start_record: dict[str, Any] | None = None,
        sensor_pixel_um: tuple[float, float] | None = None,
    ) -> None:
        """Every object the file will ever hold, so that SWMR appends create nothing new."""
        h5.attrs["creator"] = CREATOR
        h5.attrs["vastcal_session_version"] = SCHEMA_VERSION
        h5.attrs["default"] = "entry"
        entry = h5.create_group(ENTRY)
        entry.attrs["NX_class"] = "NXentry"
        entry.attrs["default"] = "data"
        entry.attrs["version"] = NXTOMO_PATHS_VERSION
        entry["definition"] = "NXtomo"
        entry["title"] = title or "vastcal session"
        entry["start_time"] = _now()
        _scalar_string(entry, "end_time", 40)
        inst = entry.create_group("instrument")
        inst.attrs["NX_class"] = "NXinstrument"
        det = inst.create_group("detector")
        det.attrs["NX_class"] = "NXdetector"
        rgb = len(frame_shape) == 3
        plane = tuple(frame_shape[:2])  # NXtomo detector data is N x H x W: RGB frames are stored as planes

        def planes(group: h5py.Group, name: str) -> h5py.Dataset:
            ds = group.create_dataset(
                name, shape=(0,) + plane, maxshape=(None,) + plane, dtype=dtype, chunks=(1,) + plane
            )
            ds.attrs["interpretation"] = "image"
            return ds

        d = planes(det, "data")
        if rgb:
            d.attrs["channel"] = "green"
            d.attrs["long_name"] = "green plane of RGB frames (red and blue in /entry/vastcal/colour)"
        for name in ("image_key", "image_key_control"):
            det.create_dataset(name, shape=(0,), maxshape=(None,), dtype="i4", chunks=(1024,))
        ct = det.create_dataset("count_time", shape=(0,), maxshape=(None,), dtype="f8", chunks=(1024,))
        ct.attrs["units"] = "s"
        if (
            sensor_pixel_um is not None
        ):  # the detector's own pixel (NXtomo >= 1.5); absent when the optics are not known
            for name, v in (("x_pixel_size", sensor_pixel_um[0]), ("y_pixel_size", sensor_pixel_um[1])):
                det[name] = float(v)
                det[name].attrs["units"] = "um"
        sample = entry.create_group("sample")
        sample.attrs["NX_class"] = "NXsample"
        for name, v in (("x_pixel_size", pixel_size_um[0]), ("y_pixel_size", pixel_size_um[1])):
            sample[name] = float(v)  # the effective pixel on the specimen plane
            sample[name].attrs["units"] = "um"
        ra = sample.create_dataset("rotation_angle", shape=(0,), maxshape=(None,), dtype="f8", chunks=(1024,))
        ra.attrs["units"] = "degree"
        data = entry.create_group("data")
        data.attrs["NX_class"] = "NXdata"
        data.attrs["signal"] = "data"
        data.attrs["axes"] = ["rotation_angle", ".", "."]  # viewers show angle, not frame index
        data.attrs["rotation_angle_indices"] = 0
        data["data"] = d
        data["rotation_angle"] = ra
        data["image_key"] = det["image_key"]

        vc = entry.create_group("vastcal")
        vc.attrs["NX_class"] = "NXcollection"
        vc.attrs["schema_version"] = SCHEMA_VERSION
        vc["rig"] = rig_yaml
        if rgb:
            colour = vc.create_group("colour")
            colour.attrs["NX_class"] = "NXcollection"
            colour.attrs["meaning"] = (
                "RGB frames as planes: frame i = stack(red[i], green[i], blue[i]) on the last axis"
            )
            planes(colour, "red")
            colour["green"] = d  # a hard link: the detector data is the green plane
            planes(colour, "blue")
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
        committed = vc.create_dataset(
            "committed_views", shape=(1,), maxshape=(1,), dtype="i8", chunks=(1,), fillvalue=0
        )
        committed[0] = 0
        committed.attrs["units"] = "views"
        committed.attrs["meaning"] = "views 0 .. n-1 are complete; rows beyond belong to a view cut short"
        stop = _scalar_string(vc, "stop_record", STOP_RECORD_BYTES)
        stop.attrs["meaning"] = (
            "JSON stop record (exit_status success|abort|fail, reason, views_written, time); empty while writing"
        )
        start = vc.create_group("start")
        _set_attrs(
            start,
            start_record
            or {
                "uid": str(uuid.uuid4()),
                "time": _now(),
                "host": socket.gethostname(),
                "versions": software_versions(),
                **start_info,
            },
        )

    # -- resume ---------------------------------------------------------------------------
    @classmethod
    def resume(cls, path: str | Path, durable: bool = True) -> SessionWriter:
        """Reopen an incomplete session to append more views.

        The committed views are checked against their CRC-32 and copied, bit for bit, into a new
        file that replaces the old one in one rename; the old ending (its stop record, or
        "killed" when it had none) is kept under ``/entry/vastcal/resumed``. Rows of a view cut
        short by a kill are dropped. Nothing of the original is touched before the rename.

        Raises:
            NotASessionError: not a vastcal session.
            OutputExistsError: the session is complete (exit status success).
            SessionCorruptError: a committed frame fails its checksum.
            SessionBusyError: another process is writing it.
        """
        p = Path(path)
        lock = PathLock(p).acquire()
        try:
            with Session.open(p) as src:
                if src.exit_status == "success":
                    raise OutputExistsError(f"{p}: the session is complete (exit_status success); nothing to resume")
                n = src.n_views
                tmp = p.with_name(f".{p.name}.partial")
                h5 = cls.rebuild(
                    src,
                    tmp,
                    ending=src.stop_record
                    or {"exit_status": "incomplete", "reason": "the writer was killed", "views_written": n},
                    keep_open=True,
                )
            log.info("%s: resuming after %d committed views", p, n)
            return cls._go_live(h5, tmp, p, lock, durable, replace=True)
        except BaseException:
            lock.release()
            raise

    @classmethod
    def rebuild(
        cls, src: Session, tmp: Path, ending: dict[str, Any] | None = None, keep_open: bool = False
    ) -> h5py.File | None:
        """Write a copy of ``src`` at ``tmp``: its committed views (CRC-checked, bit for bit),
        masks, cameras, stage runs and history, plus ``ending`` appended to the resume history.
        Returns the open file when ``keep_open``, else closes it and returns None.

        Raises:
            SessionCorruptError: a committed frame fails its checksum.
        """
        src.verify()
        h5, n = src.h5, src.n_views
        det = h5[DETECTOR]
        history = src.resume_history() + ([ending] if ending else [])
        out = h5py.File(tmp, "w", libver="latest")
        try:
            cls._layout(
                out,
                src.frame_shape,
                src.dtype,
                src.rig_yaml,
                src.plan_raw(),
                src.pixel_size_um,
                src.roi_offset_px,
                _attr_str(h5[ENTRY]["title"][()]),
                {},
                start_record=src.start_record_raw(),
                sensor_pixel_um=src.sensor_pixel_um,
            )
            if history:
                res = out[VASTCAL].create_group("resumed")
                for k, rec in enumerate(history):
                    _set_attrs(res.create_group(f"stop_{k:03d}"), rec)
            for name in ("masks", "cameras", *STAGE_GROUPS):
                if name in h5[VASTCAL]:
                    h5.copy(h5[VASTCAL][name], out[VASTCAL], name=name)
            writer = cls(out, Path(tmp), lock=PathLock(Path(tmp)), durable=False)
            table = src.view_table()
            keys = det["image_key"][:n]
            origin = (0,) * (det["data"].ndim - 1)
            for i in range(n):
                if src.colour_planes is not None:  # planes as stored, stacked (unfiltered chunks: bit for bit)
                    frame = src.frame(i)
                else:
                    raw = det["data"].id.read_direct_chunk((i,) + origin)[1]
                    frame = np.frombuffer(raw, dtype=src.dtype).reshape(src.frame_shape)
                cols = {c.name: table[c.name][i] for c in VIEW_COLUMNS if c.name in table and c.name != "frame_crc32"}
                writer._write_view(i, frame, float(cols.pop("commanded_angle_deg")), int(keys[i]), cols)
            writer._set_committed(n)
            if src.stop_record and not ending:
                out[VASTCAL]["stop_record"][()] = np.bytes_(json.dumps(src.stop_record, default=_json_default).encode())
            if keep_open:
                return out
            out.close()
            return None
        except BaseException:
            out.close()
            tmp.unlink(missing_ok=True)
            raise

    # -- appending ------------------------------------------------------------------------
    @property
    def n_views(self) -> int:
        """Views committed so far."""
        return self._n

    def append_view(self, frame: np.ndarray, angle_deg: float, image_key: int = 0, **columns: Any) -> int:
        """Append one frame and its per-view record, make them durable, then commit; returns its index.

        ``columns`` fill the per-view table (see :data:`VIEW_COLUMNS`; missing ones get their
        fill value, e.g. ``readback_usteps=-1`` for imported images). Unknown names raise.
        """
        data = self._data
        if frame.shape != self._frame_shape or frame.dtype != data.dtype:
            raise SessionError(
                f"{self.path}: a {frame.shape} {frame.dtype} frame does not fit this session's {self._frame_shape} {data.dtype} "
                "frames (was the rig's ROI or pixel format changed?)"
            )
        unknown = set(columns) - set(self._columns) | ({"frame_crc32"} & set(columns))
        if unknown:
            raise ValueError(f"unknown per-view columns: {sorted(unknown)}")
        self._check_usable()
        i = self._n
        try:
            self._write_view(i, frame, angle_deg, image_key, columns)
            self._h5.flush()
            if self._durable:
                os.fdatasync(self._h5.id.get_vfd_handle())  # the view is on disk before the commit names it
            self._set_committed(i + 1)
        except (OSError, RuntimeError) as exc:  # h5py reports a full disk as either
            self._fail(exc)
        return i

    def _check_usable(self) -> None:
        if self._failed is not None:
            raise OSError(
                self._failed.errno, f"{self.path}: an earlier write failed ({self._failed}); nothing more is written"
            )

    def _fail(self, exc: BaseException) -> None:
        """Stop touching the file after a failed write; its committed views stay as they are."""
        self._failed = _os_error(exc, self.path)
        _abandon(self._h5)
        log.info(
            "%s: writing failed (%s); the file is left as it was after the last committed view",
            self.path,
            self._failed.strerror,
        )
        raise self._failed from exc

    def _write_view(self, i: int, frame: np.ndarray, angle_deg: float, image_key: int, columns: dict[str, Any]) -> None:
        """Row ``i`` of every per-view dataset (not yet committed)."""
        values = {c.name: columns.get(c.name, c.fill) for c in VIEW_COLUMNS}
        values["commanded_angle_deg"] = angle_deg
        values["frame_crc32"] = _frame_crc(frame)
        for col in VIEW_COLUMNS:
            v = values[col.name]
            _put(self._columns[col.name], i, v.encode() if isinstance(v, str) else v)
        for ds in self._keys:
            _put(ds, i, image_key)
        _put(self._count_time, i, values["exposure_us"] * 1e-6)
        _put(self._angle, i, angle_deg)
        # One frame (or one colour plane) = one chunk, written directly (no selection machinery, no conversion).
        if self._planes is None:
            _put_chunk(self._data, i, frame)
        else:
            planes = np.ascontiguousarray(np.moveaxis(frame, -1, 0))  # (3, H, W): one transposing copy
            for ds, image in zip(self._planes, planes):
                _put_chunk(ds, i, image)

    def _set_committed(self, n: int) -> None:
        self._committed[0] = n
        self._h5.flush()
        self._n = n

    def _require_staged(self, what: str) -> None:
        if self._staged_from is None:
            raise SessionError(f"{self.path}: {what} can only be written while importing (a staged session)")

    def write_masks(self, masks: np.ndarray) -> None:
        """Store silhouettes (N, H, W), nonzero = specimen, as uint8 0/255 (staged sessions)."""
        self._require_staged("masks")
        m = (np.asarray(masks) > 0).astype(np.uint8) * 255
        self._h5[VASTCAL].create_dataset(
            "masks", data=m, chunks=(1,) + m.shape[1:], compression="gzip", compression_opts=1
        )

    def write_cameras(
        self, P: np.ndarray, source: str, attrs: dict[str, Any] | None = None, P_given: np.ndarray | None = None
    ) -> None:
        """Store known cameras P (N, 3, 4) in 0-based pixels of the stored frames (staged sessions).

        ``P_given`` keeps the matrices exactly as the source gave them (its own pixel convention).
        """
        self._require_staged("cameras")
        g = self._h5[VASTCAL].create_group("cameras")
        g.create_dataset("P", data=np.asarray(P, float))
        if P_given is not None:
            g.create_dataset("P_given", data=np.asarray(P_given, float))
        g["P"].attrs["convention"] = "world (specimen units) -> 0-based pixels of the stored frames"
        _set_attrs(g, {"source": source, **(attrs or {})})

    def finish(self, exit_status: str, reason: str = "", **extra: Any) -> None:
        """Write the stop record (``success``, ``abort`` or ``fail``) and the end time.

        A staged session is renamed into place when the status is ``success`` and discarded
        otherwise (its source can be imported again).
        """
        if exit_status not in ("success", "abort", "fail"):
            raise ValueError(f"exit_status must be success, abort or fail, got {exit_status!r}")
        self._check_usable()
        record = {"exit_status": exit_status, "reason": reason, "views_written": self.n_views, "time": _now(), **extra}
        text = json.dumps(record, default=_json_default)
        if len(text.encode()) > STOP_RECORD_BYTES:  # a very long reason is cut, never the record
            record["reason"] = reason[: STOP_RECORD_BYTES // 2] + " …"
            text = json.dumps(record, default=_json_default)[:STOP_RECORD_BYTES]
        try:
            # The datasets stay open until the flush: HDF5 writes a small dataset's value when the dataset is flushed
            # or closed, and a failed write at a close (a full disk) would only be an ignored error in a destructor.
            end_time, stop = self._h5[ENTRY]["end_time"], self._h5[VASTCAL]["stop_record"]
            end_time[()] = np.bytes_(_now()[:40])
            stop[()] = np.bytes_(text.encode())
            self._h5.flush()
        except (OSError, RuntimeError) as exc:
            self._fail(exc)
        self._finished = True
        if self._staged_from is not None:
            self._h5.close()
            if exit_status == "success":
                place_atomically(self._staged_from, self.path, replace=self._replace)
            else:
                self._staged_from.unlink(missing_ok=True)
            self._staged_from = None

    def close(self) -> None:
        """Close the file and release the path (idempotent). An unfinished staged file is discarded."""
        try:
            if self._failed is None and self._h5.id.valid:
                try:
                    self._h5.flush()  # HDF5 may have deferred a failed write: it fails again here, not in close
                except (OSError, RuntimeError) as exc:
                    self._failed = _os_error(exc, self.path)
                    _abandon(self._h5)
                else:
                    self._h5.close()
            if self._staged_from is not None:
                self._staged_from.unlink(missing_ok=True)
                self._staged_from = None
        finally:
            self._lock.release()

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> None:
        try:
            if not self._finished and self._failed is None and self._h5.id.valid:
                if exc_type is None:
                    self.finish("success")
                elif issubclass(exc_type, KeyboardInterrupt):
                    self.finish("abort", "interrupted by the operator")
                else:
                    self.finish("fail", f"{exc_type.__name__}: {exc}")
        finally:
            self.close()


def _plain(v: Any) -> Any:
    """A NumPy scalar or array as the Python value JSON and callers expect (others unchanged)."""
    if isinstance(v, np.generic):
        item = v.item()
        if isinstance(item, np.generic):  # long double, complex long double …: no Python twin
            return float(item.real) if np.issubdtype(item.dtype, np.number) else str(item)
        return item
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


def _json_default(v: Any) -> Any:
    plain = _plain(v)
    return str(plain) if plain is v else plain


def _open_h5_for_reading(p: Path) -> tuple[h5py.File, bool]:
    """Open read-only; a file being written (or left by a killed writer) is read in SWMR mode.

    Returns the file and whether it was opened in SWMR mode.
    """
    try:
        return h5py.File(p, "r"), False
    except OSError as exc:
        msg = str(exc)
        if "already open for write" in msg or "consistency flags" in msg or "SWMR" in msg:
            return h5py.File(p, "r", swmr=True), True
        raise


class Session:
    """A session opened for reading, and for adding the results of later stages.

    Opening checks that the file is HDF5, is not truncated and was written by vastcal;
    it never modifies the images. Use :meth:`open` and close it (or use ``with``).

    Results of later stages are added copy-on-write: with ``mode="a"``, :meth:`new_result_group`
    writes into a copy of the file, and :meth:`close` (or the end of a ``with`` block without an
    exception) renames that copy over the session, so a kill while a run is being stored leaves
    the images and the earlier runs exactly as they were.
    """

    def __init__(self, h5: h5py.File, path: Path, writable: bool = False, live: bool = False) -> None:
        self._h5 = h5
        self.path = path
        self.live = live  # opened in SWMR mode: a writer is at work, or was killed
        self._writable = writable
        vc = h5[VASTCAL]
        self.version = int(h5.attrs.get("vastcal_session_version", 0))  # schema version of the file
        colour = vc.get("colour")
        self._planes: tuple[h5py.Dataset, h5py.Dataset, h5py.Dataset] | None = (
            (colour["red"], h5[DETECTOR]["data"], colour["blue"]) if colour is not None else None
        )
        if "committed_views" in vc:
            self._n = int(vc["committed_views"][0])
        else:  # schema 1: every frame counts
            self._n = int(h5[DETECTOR]["data"].shape[0])
        self._staging: h5py.File | None = None
        self._staging_path: Path | None = None
        self._lock: PathLock | None = None

    @classmethod
    def open(cls, path: str | Path, mode: str = "r") -> Session:
        """Open and validate a session (``mode`` ``"r"`` or ``"a"`` to add results).

        Raises:
            NotASessionError: missing file, not HDF5, truncated, damaged, or not written by vastcal.
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
            h5, live = _open_h5_for_reading(p)
        except OSError as exc:
            msg = str(exc).splitlines()[0]
            hint = (
                "truncated or damaged"
                if "truncat" in msg or "signature" in msg or "eof" in msg.lower()
                else "cannot open"
            )
            raise NotASessionError(f"{p}: {hint} HDF5 file ({msg})") from None
        try:
            if _attr_str(h5.attrs.get("creator", "")) != CREATOR or VASTCAL not in h5 or DETECTOR + "/data" not in h5:
                raise NotASessionError(
                    f"{p}: HDF5 file not written by vastcal (no /entry/vastcal group); import images with 'vastcal import'"
                )
            version = int(h5.attrs.get("vastcal_session_version", 0))
            if version > SCHEMA_VERSION:
                raise NotASessionError(
                    f"{p}: session schema version {version} is newer than this vastcal understands ({SCHEMA_VERSION})"
                )
            s = cls(h5, p, writable=(mode == "a"), live=live)
            s._validate()
        except NotASessionError:
            h5.close()
            raise
        except (KeyError, OSError, ValueError, TypeError, IndexError) as exc:
            h5.close()
            raise NotASessionError(
                f"{p}: damaged session ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"
            ) from None
        return s

    def _validate(self) -> None:
        """Structure of the committed part: ranks, types and lengths every reader relies on."""
        p, h5, n = self.path, self._h5, self._n
        data = h5[DETECTOR]["data"]
        if (
            data.ndim not in (3, 4)
            or (data.ndim == 4 and data.shape[3] != 3)
            or data.dtype not in (np.uint8, np.uint16)
        ):
            raise NotASessionError(
                f"{p}: damaged session: frames are {data.shape} {data.dtype}; expected N x H x W[x 3] uint8 or uint16"
            )
        for c, plane in enumerate(self._planes or ()):
            if (
                not isinstance(plane, h5py.Dataset)
                or data.ndim != 3
                or plane.shape[1:] != data.shape[1:]
                or plane.dtype != data.dtype
                or plane.shape[0] < n
            ):
                shape = getattr(plane, "shape", "?")
                raise NotASessionError(
                    f"{p}: damaged session: colour plane {'RGB'[c]} is {shape}; expected {n} x {data.shape[1]} x {data.shape[2]} "
                    f"{data.dtype} like the detector data"
                )
        if n < 0 or data.shape[0] < n:
            raise NotASessionError(f"{p}: damaged session: {n} committed views but {data.shape[0]} frames")
        angles = h5[ENTRY]["sample"]["rotation_angle"]
        if angles.ndim != 1 or angles.dtype.kind != "f":
            raise NotASessionError(
                f"{p}: damaged session: /entry/sample/rotation_angle is {angles.dtype} {angles.shape}; expected float degrees"
            )
        n_angles = angles.shape[0]
        if "committed_views" in h5[VASTCAL]:
            if n_angles < n:
                raise NotASessionError(f"{p}: damaged session: {n} committed views but {n_angles} rotation angles")
        elif n_angles < n or n_angles > n + 1 or (n_angles == n + 1 and "stop" in h5[VASTCAL]):
            # Schema 1: one extra record without its frame is an append cut short (kill mid-view): tolerated.
            raise NotASessionError(f"{p}: damaged session: {n} frames but {n_angles} rotation angles")
        if not np.all(np.isfinite(angles[:n])):
            raise NotASessionError(f"{p}: damaged session: non-finite rotation angles")
        keys = h5[DETECTOR]["image_key"]
        if keys.shape[0] < n:
            raise NotASessionError(f"{p}: damaged session: {n} views but {keys.shape[0]} image keys")
        # Each of these raises KeyError/ValueError/TypeError when absent or malformed (reported as damage).
        self.roi_offset_px  # noqa: B018
        ps = self.pixel_size_um
        if not all(np.isfinite(v) and v > 0 for v in ps):
            raise NotASessionError(f"{p}: damaged session: pixel size {ps} µm; expected positive numbers")
        self.plan  # noqa: B018
        self.start_record  # noqa: B018
        n_proj = int(np.count_nonzero(keys[:n] == 0))
        vc = h5[VASTCAL]
        if "cameras" in vc:
            _check_cameras(p, "/entry/vastcal/cameras/P", vc["cameras"]["P"], n_proj)
        if "masks" in vc:
            m = vc["masks"]
            if m.ndim != 3 or m.shape[0] < n_proj or m.shape[1:] != data.shape[1:3]:
                raise NotASessionError(
                    f"{p}: damaged session: /entry/vastcal/masks is {m.shape}; expected {n_proj} x {data.shape[1]} x {data.shape[2]}"
                )
        for stage in STAGE_GROUPS:
            for name, run in vc[stage].items() if stage in vc else ():
                if not isinstance(run, h5py.Group):
                    raise NotASessionError(f"{p}: damaged session: /entry/vastcal/{stage}/{name} is not a group")
                if stage == "calibration" and "P" in run:
                    _check_cameras(p, f"/entry/vastcal/{stage}/{name}/P", run["P"], n_proj)

    def verify(self) -> None:
        """Check every committed frame against its CRC-32 (schema 2 sessions).

        Raises:
            SessionCorruptError: naming the first view that fails.
        """
        views = self._h5[VASTCAL]["views"]
        if "frame_crc32" not in views:
            return
        crc = views["frame_crc32"][: self._n]
        for i in range(self._n):
            if _frame_crc(self.frame(i)) != int(crc[i]):
                raise SessionCorruptError(f"{self.path}: view {i}: the frame does not match the CRC-32 written with it")

    def close(self) -> None:
        """Commit staged results (if any), then close (idempotent)."""
        try:
            self._commit_results()
        finally:
            self._close_files()

    def _close_files(self) -> None:
        self.discard_results()
        if self._lock is not None:
            self._lock.release()
            self._lock = None
        if self._h5.id.valid:
            self._h5.close()

    def discard_results(self) -> None:
        """Forget the results staged since opening; the session file stays as it was.

        The staged copy is not closed (a failed write there may be why it is discarded, and HDF5
        crashes when such a file is closed); its name is removed, so nothing of it remains visible.
        """
        if self._staging is not None:
            _abandon(self._staging)
            self._staging = None
        if self._staging_path is not None:
            self._staging_path.unlink(missing_ok=True)
            self._staging_path = None

    def __enter__(self) -> Session:
        return self

    def __exit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> None:
        if exc_type is not None:
            self.discard_results()
        self.close()

    # -- images and angles ------------------------------------------------------------------
    @property
    def h5(self) -> h5py.File:
        """The underlying h5py file of the images (read-only)."""
        return self._h5

    @property
    def n_views(self) -> int:
        """Number of committed frames (all image keys)."""
        return self._n

    @property
    def frame_shape(self) -> tuple[int, ...]:
        """(H, W) or (H, W, 3) of the frames as :meth:`frame` returns them."""
        return tuple(self._h5[DETECTOR]["data"].shape[1:]) + ((3,) if self._planes is not None else ())

    @property
    def colour_planes(self) -> tuple[h5py.Dataset, h5py.Dataset, h5py.Dataset] | None:
        """The red, green and blue (N, H, W) planes of an RGB session (schema 3), else None.

        Green is the detector data. Schema-2 RGB sessions keep (N, H, W, 3) frames and give None.
        """
        return self._planes

    @property
    def dtype(self) -> np.dtype:
        """Pixel type of the frames."""
        return self._h5[DETECTOR]["data"].dtype

    @property
    def image_key(self) -> np.ndarray:
        """(N,) 0 projection, 1 flat, 2 dark."""
        return self._h5[DETECTOR]["image_key"][: self._n]

    @property
    def projection_indices(self) -> np.ndarray:
        """Indices of the projection frames (image_key 0)."""
        return np.flatnonzero(self.image_key == 0)

    def frame(self, i: int) -> np.ndarray:
        """Frame ``i`` as stored."""
        if not 0 <= i < self._n:
            raise IndexError(f"{self.path}: view {i} out of range (0..{self._n - 1})")
        if self._planes is not None:
            out = np.empty(self.frame_shape, self.dtype)
            for c, ds in enumerate(self._planes):
                out[..., c] = ds[i]
            return out
        return self._h5[DETECTOR]["data"][i]

    def projections(self) -> np.ndarray:
        """All projection frames (image_key 0), (N, H, W[, 3])."""
        idx = self.projection_indices
        data = self._h5[DETECTOR]["data"]
        if self._planes is not None:
            out = np.empty((len(idx),) + self.frame_shape, self.dtype)
            for c, ds in enumerate(self._planes):
                for k, i in enumerate(idx):
                    out[k, ..., c] = ds[i]
            return out
        if len(idx) == self._n:
            return data[: self._n]
        return np.stack([data[i] for i in idx]) if len(idx) else np.empty((0,) + data.shape[1:], data.dtype)

    def iter_frames(self) -> Iterator[np.ndarray]:
        """Committed frames one at a time (for memory-light readers)."""
        for i in range(self._n):
            yield self.frame(i)

    @property
    def angles_deg(self) -> np.ndarray:
        """Commanded rotation angle of every projection, degrees."""
        return self._h5[ENTRY]["sample"]["rotation_angle"][: self._n][self.projection_indices]

    @property
    def pixel_size_um(self) -> tuple[float, float]:
        """(x, y) effective pixel pitch on the specimen, µm (``sample/x_pixel_size``; schema <= 2: the detector's)."""
        g = self._h5[ENTRY]["sample"] if self.version >= 3 else self._h5[DETECTOR]
        return float(g["x_pixel_size"][()]), float(g["y_pixel_size"][()])

    @property
    def sensor_pixel_um(self) -> tuple[float, float] | None:
        """(x, y) pitch of the sensor's own pixels, µm, or None when not recorded."""
        det = self._h5[DETECTOR]
        names = ("x_pixel_size", "y_pixel_size") if self.version >= 3 else ("real_x_pixel_size", "real_y_pixel_size")
        if not all(k in det for k in names):
            return None
        return float(det[names[0]][()]), float(det[names[1]][()])

    @property
    def roi_offset_px(self) -> tuple[int, int]:
        """(x, y) offset of the stored frames on the sensor, px."""
        g = self._h5[VASTCAL]["geometry"].attrs
        return int(g["roi_x"]), int(g["roi_y"])

    @property
    def rig_yaml(self) -> str:
        """The resolved rig configuration stored at creation."""
        return _attr_str(self._h5[VASTCAL]["rig"][()])

    def rig_config(self) -> Any:
        """The stored rig configuration parsed into a :class:`~vastcal.config.RigConfig`."""
        import yaml

        from vastcal.config import parse_config

        return parse_config(yaml.safe_load(self.rig_yaml), source=f"{self.path}:/entry/vastcal/rig")

    @property
    def plan(self) -> dict[str, Any]:
        """The plan attributes."""
        return {k: _decode_json(v) for k, v in self._h5[VASTCAL]["plan"].attrs.items()}

    def plan_raw(self) -> dict[str, Any]:
        """The plan attributes as stored (for copying)."""
        return {k: _attr_str(v) for k, v in self._h5[VASTCAL]["plan"].attrs.items()}

    def view_table(self) -> dict[str, np.ndarray]:
        """The per-view table of the committed views, one array per column."""
        views = self._h5[VASTCAL]["views"]
        return {k: views[k][: self._n] for k in views}

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

    def start_record_raw(self) -> dict[str, Any]:
        """The start record's attributes as stored (for copying)."""
        return {k: _attr_str(v) for k, v in self._h5[VASTCAL]["start"].attrs.items()}

    @property
    def stop_record(self) -> dict[str, Any] | None:
        """The stop record, or None while the writer is at work (or after it was killed)."""
        vc = self._h5[VASTCAL]
        if "stop_record" in vc:
            text = _attr_str(vc["stop_record"][()])
            if not text:
                return None
            try:
                rec = json.loads(text)
            except ValueError:
                raise NotASessionError(f"{self.path}: damaged session: unreadable stop record") from None
            return rec if isinstance(rec, dict) else None
        if "stop" in vc:  # schema 1
            return {k: _decode_json(v) for k, v in vc["stop"].attrs.items()}
        return None

    def resume_history(self) -> list[dict[str, Any]]:
        """Earlier endings of a resumed acquisition, oldest first."""
        res = self._h5[VASTCAL].get("resumed")
        return [read_attrs(res[k]) for k in sorted(res)] if res is not None else []

    @property
    def exit_status(self) -> str:
        """``success``, ``abort``, ``fail``, or ``incomplete`` when no stop record exists."""
        rec = self.stop_record
        return str(rec.get("exit_status", "incomplete")) if rec else "incomplete"

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
            raise SessionIncompleteError(
                f"{self.path}: session is {self.exit_status}: {n} of {planned} views; "
                f"finish it with 'vastcal acquire --resume {self.path}'"
            )
        if n < min_views:
            raise SessionIncompleteError(f"{self.path}: {n} projection views; at least {min_views} needed")

    # -- results of later stages -------------------------------------------------------------
    def _results_for_reading(self) -> h5py.File:
        return self._staging if self._staging is not None else self._h5

    def stages_run(self) -> dict[str, list[str]]:
        """Names of the stored runs of each later stage, oldest first."""
        vc = self._results_for_reading()[VASTCAL]
        return {k: sorted(vc[k].keys()) for k in STAGE_GROUPS if k in vc}

    def _staged(self) -> h5py.File:
        """The writable copy of the session that :meth:`close` renames over it (copy-on-write)."""
        if self._staging is not None:
            return self._staging
        if not self._writable:
            raise ValueError("session opened read-only; open with mode='a' to add results")
        lock = PathLock(self.path, timeout_s=RESULTS_LOCK_TIMEOUT_S).acquire()
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.partial")
        try:
            if self.live:  # not closed cleanly (SWMR flags set): rebuild rather than copy
                SessionWriter.rebuild(self, tmp)
            else:
                shutil.copyfile(self.path, tmp)
            staging = _open_unbuffered(tmp)
        except BaseException:
            tmp.unlink(missing_ok=True)
            lock.release()
            raise
        self._lock, self._staging, self._staging_path = lock, staging, tmp
        return staging

    def new_result_group(self, stage: str) -> h5py.Group:
        """Create ``/entry/vastcal/<stage>/run_NNN`` (next free number) for a stage's result.

        The group is written into a copy of the session that replaces it at :meth:`close`.
        """
        if stage not in STAGE_GROUPS:
            raise ValueError(f"unknown stage {stage!r}")
        f = self._staged()
        g = f[VASTCAL].require_group(stage)
        g.attrs["schema_version"] = SCHEMA_VERSION
        g.attrs["NX_class"] = "NXcollection"  # NeXus readers look inside for the runs (a hull run is an NXdata)
        numbers = [int(k[4:]) for k in g if k.startswith("run_") and k[4:].isdigit()]
        name = f"run_{max(numbers, default=-1) + 1:03d}"  # after the newest, also once older runs were pruned
        run = g.create_group(name)
        run.attrs["time"] = _now()
        run.attrs["versions"] = json.dumps(software_versions())
        return run

    def remove_result_group(self, group: h5py.Group) -> None:
        """Drop a staged run that could not be completed."""
        if self._staging is not None and group.file == self._staging:
            del self._staging[group.name]

    def latest_result(self, stage: str) -> h5py.Group | None:
        """The newest run of ``stage``, or None."""
        runs = self.stages_run().get(stage)
        return self._results_for_reading()[VASTCAL][stage][runs[-1]] if runs else None

    def result(self, stage: str, name: str | None = None) -> h5py.Group | None:
        """Run ``name`` of ``stage`` (the latest when ``name`` is None), or None."""
        if name is None:
            return self.latest_result(stage)
        g = self._results_for_reading()[VASTCAL].get(stage)
        return g[name] if g is not None and name in g else None

    def flush(self) -> None:
        """Flush pending writes of later stages (they replace the session file at :meth:`close`)."""
        if self._staging is not None:
            self._staging.flush()

    def _commit_results(self) -> None:
        """Rename the staged copy over the session (fsync-ed): the new runs appear in one step."""
        if self._staging is None or self._staging_path is None:
            return
        try:
            self._staging.flush()
        except (OSError, RuntimeError):
            self.discard_results()
            raise
        self._staging.close()
        self._staging = None
        place_atomically(self._staging_path, self.path, replace=True)
        self._staging_path = None
        log.debug("stored results in %s", self.path)


def _open_unbuffered(path: Path) -> h5py.File:
    """Open ``path`` for writing with no raw-data buffering (sieve buffer and chunk cache off): a dataset's values are
    written by the call that sets them, so that a failed write (a full disk) raises there. Buffered, HDF5 writes them
    when the dataset is closed, and h5py reports a failure at that point only as an ignored error in a destructor."""
    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_sieve_buf_size(0)
    fapl.set_cache(0, 0, 0, 0.0)  # metadata cache elements (ignored), chunk slots, chunk bytes, preemption
    return h5py.File(h5py.h5f.open(os.fsencode(path), h5py.h5f.ACC_RDWR, fapl=fapl))


def _check_cameras(p: Path, where: str, ds: Any, n: int) -> None:
    """Cameras must be (n, 3, 4), finite, with a full-rank left 3 x 3 block."""
    if not isinstance(ds, h5py.Dataset) or ds.dtype.kind not in "fi" or ds.shape != (n, 3, 4):
        shape = getattr(ds, "shape", "?")
        raise NotASessionError(f"{p}: damaged session: {where} is {shape}; expected {n} x 3 x 4 numbers")
    P = ds[...].astype(float)
    if not np.all(np.isfinite(P)):
        raise NotASessionError(f"{p}: damaged session: {where} holds NaN or infinite values")
    with np.errstate(all="ignore"):
        det = np.linalg.det(P[:, :, :3])
    if not np.all(np.isfinite(det)) or np.any(np.abs(det) < 1e-300):
        raise NotASessionError(f"{p}: damaged session: {where} holds a degenerate camera (singular 3 x 3 block)")


def _put_chunk(ds: h5py.Dataset, i: int, image: np.ndarray) -> None:
    """Write ``image`` as chunk ``i`` of a dataset chunked one image per chunk, growing it if needed."""
    if ds.shape[0] < i + 1:
        ds.resize((i + 1,) + ds.shape[1:])
    ds.id.write_direct_chunk((i,) + (0,) * image.ndim, np.ascontiguousarray(image))  # the array's buffer: no copy


def _put(ds: h5py.Dataset, i: int, value: Any) -> None:
    """Set element ``i`` of a 1-D dataset, growing it to ``i + 1`` elements if needed."""
    if ds.shape[0] < i + 1:
        ds.resize((i + 1,))
    ds[i] = value


def _decode_json(v: Any) -> Any:
    v = _attr_str(v)
    if isinstance(v, str) and v[:1] in "[{":
        try:
            return json.loads(v)
        except ValueError:
            return v
    return _plain(v)


def write_attrs(group: h5py.Group, attrs: dict[str, Any]) -> None:
    """Write attributes; dicts and lists of non-numbers are stored as JSON strings."""
    _set_attrs(group, attrs)


def read_attrs(group: h5py.Group) -> dict[str, Any]:
    """Read attributes, decoding the JSON strings that :func:`write_attrs` wrote."""
    return {k: _decode_json(v) for k, v in group.attrs.items()}
