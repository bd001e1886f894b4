"""Writing a session: :class:`SessionWriter` creates it, appends views one at a time and ends it.

The layout is :mod:`vastcal.session.schema`'s; what a kill at any instant can lose is in
:mod:`vastcal.session`'s docstring.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import re
import uuid
from pathlib import Path
from typing import Any, TypedDict, Unpack

import h5py
import numpy as np

from vastcal.errors import OutputExistsError, SessionError
from vastcal.outputs import check_output_file
from vastcal.session._attrs import attr_str, json_default, set_attrs
from vastcal.session._files import PathLock, abandon, place_atomically, remove_stale_copies
from vastcal.session._reader import SessionReader
from vastcal.session.schema import (
    DETECTOR,
    ENTRY,
    STAGE_GROUPS,
    STOP_RECORD_BYTES,
    VASTCAL,
    VIEW_COLUMNS,
    SessionLayout,
    frame_crc,
    now_utc,
    write_layout,
)

log = logging.getLogger(__name__)


class LayoutFields(TypedDict, total=False):
    """The keyword arguments of :meth:`SessionWriter.create` that describe the file (see :class:`SessionLayout`)."""

    frame_shape: tuple[int, ...]
    dtype: np.dtype | str
    rig_yaml: str
    plan: dict[str, Any]
    pixel_size_um: tuple[float, float]
    roi_offset_px: tuple[int, int]
    title: str
    start_info: dict[str, Any] | None
    sensor_pixel_um: tuple[float, float] | None


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
        force: bool = False,
        live: bool = True,
        durable: bool = True,
        lock: PathLock | None = None,
        **layout: Unpack[LayoutFields],
    ) -> SessionWriter:
        """Create a new session file with zero views.

        Args:
            layout: what the file holds before its first view — ``frame_shape`` (H, W) or (H, W, 3) px,
                ``dtype`` (uint8 or uint16), ``rig_yaml``, ``plan``, ``pixel_size_um`` (x, y) on the
                specimen, and optionally ``roi_offset_px``, ``title``, ``start_info``, ``sensor_pixel_um``
                (see :class:`~vastcal.session.schema.SessionLayout`).
            force: replace an existing (regular) file.
            live: grow the file in place in SWMR mode (acquisition); otherwise stage it and
                rename it into place at a successful :meth:`finish` (import).
            durable: ``fsync`` each view before committing it (power cuts, not only kills).
            lock: the path's writer lock, when the caller took it already (before homing a stage).

        Raises:
            OutputExistsError: the file exists and ``force`` is false.
            SessionBusyError: another process is writing the same path.
        """
        fields = dict(layout)
        fields["frame_shape"] = tuple(fields["frame_shape"])
        fields["dtype"] = np.dtype(fields["dtype"])
        fields["start_info"] = fields.get("start_info") or {}
        spec = SessionLayout(**fields)  # type: ignore[arg-type]
        p = check_output_file(path, force=force)
        p.parent.mkdir(parents=True, exist_ok=True)
        lock = (lock or PathLock(p)).acquire()
        try:
            remove_stale_copies(p)
            tmp = p.with_name(f".{p.name}.partial")
            if not live:
                h5 = h5py.File(tmp, "w", libver="latest")
                try:
                    write_layout(h5, spec)
                except BaseException:
                    h5.close()
                    tmp.unlink(missing_ok=True)
                    raise
                return cls(h5, p, lock=lock, staged_from=tmp, replace=force, durable=False)
            _write_skeleton(tmp, lambda h5: write_layout(h5, spec))
            h5 = h5py.File(tmp, "r+", libver="latest")
            return cls._go_live(h5, tmp, p, lock, durable, replace=force)
        except BaseException:
            lock.release()
            raise

    @classmethod
    def _go_live(cls, h5: h5py.File, tmp: Path, p: Path, lock: PathLock, durable: bool, replace: bool) -> SessionWriter:
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
            remove_stale_copies(p)
            with SessionReader.open(p) as src:
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
        cls, src: SessionReader, tmp: Path, ending: dict[str, Any] | None = None, keep_open: bool = False
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
            layout = SessionLayout(
                frame_shape=src.frame_shape,
                dtype=src.dtype,
                rig_yaml=src.rig_yaml,
                plan=src.plan_raw(),
                pixel_size_um=src.pixel_size_um,
                roi_offset_px=src.roi_offset_px,
                title=attr_str(h5[ENTRY]["title"][()]),
                start_record=src.start_record_raw(),
                sensor_pixel_um=src.sensor_pixel_um,
            )
            write_layout(out, layout)
            if history:
                res = out[VASTCAL].create_group("resumed")
                for k, rec in enumerate(history):
                    set_attrs(res.create_group(f"stop_{k:03d}"), rec)
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
                out[VASTCAL]["stop_record"][()] = np.bytes_(json.dumps(src.stop_record, default=json_default).encode())
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
                f"{self.path}: a {frame.shape} {frame.dtype} frame does not fit this session's "
                f"{self._frame_shape} {data.dtype} "
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
        abandon(self._h5)
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
        values["frame_crc32"] = frame_crc(frame)
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
        set_attrs(g, {"source": source, **(attrs or {})})

    def finish(self, exit_status: str, reason: str = "", **extra: Any) -> None:
        """Write the stop record (``success``, ``abort`` or ``fail``) and the end time.

        A staged session is renamed into place when the status is ``success`` and discarded
        otherwise (its source can be imported again).
        """
        if exit_status not in ("success", "abort", "fail"):
            raise ValueError(f"exit_status must be success, abort or fail, got {exit_status!r}")
        self._check_usable()
        record = {
            "exit_status": exit_status,
            "reason": reason,
            "views_written": self.n_views,
            "time": now_utc(),
            **extra,
        }
        text = json.dumps(record, default=json_default)
        if len(text.encode()) > STOP_RECORD_BYTES:  # a very long reason is cut, never the record
            record["reason"] = reason[: STOP_RECORD_BYTES // 2] + " …"
            text = json.dumps(record, default=json_default)[:STOP_RECORD_BYTES]
        try:
            # The datasets stay open until the flush: HDF5 writes a small dataset's value when the dataset is flushed
            # or closed, and a failed write at a close (a full disk) would only be an ignored error in a destructor.
            end_time, stop = self._h5[ENTRY]["end_time"], self._h5[VASTCAL]["stop_record"]
            end_time[()] = np.bytes_(now_utc()[:40])
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
                    abandon(self._h5)
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
