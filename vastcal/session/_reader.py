"""Reading a session: :class:`SessionReader` opens and validates it and reads images, metadata and stored runs.

Opening never modifies the file; a file being written (or left by a killed writer) is read in SWMR
mode and shows exactly its committed views.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Self

import h5py
import numpy as np
import yaml

from vastcal.config import RigConfig, parse_config
from vastcal.errors import NotASessionError, SessionCorruptError, SessionIncompleteError
from vastcal.session._attrs import attr_str, decode_json, read_attrs
from vastcal.session._files import writer_pid
from vastcal.session.schema import CREATOR, DETECTOR, ENTRY, SCHEMA_VERSION, STAGE_GROUPS, VASTCAL, frame_crc

log = logging.getLogger(__name__)


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
        if "truncated file" not in msg or writer_pid(p) is None:
            raise
        # A live writer may have allocated space it has not written yet (the superblock's end of file lies beyond
        # the file's size for a moment): a SWMR reader takes that. Only then: HDF5's SWMR reader retries a file truly
        # cut short for a long time before it gives up.
        try:
            return h5py.File(p, "r", swmr=True), True
        except OSError:
            raise exc from None


class SessionReader:
    """A session opened for reading (:class:`vastcal.session.Session` adds the runs of later stages).

    Opening checks that the file is HDF5, is not truncated and was written by vastcal;
    it never modifies the images. Use :meth:`open` and close it (or use ``with``).
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

    @classmethod
    def open(cls, path: str | Path, mode: str = "r") -> Self:
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
            if attr_str(h5.attrs.get("creator", "")) != CREATOR or VASTCAL not in h5 or DETECTOR + "/data" not in h5:
                raise NotASessionError(
                    f"{p}: HDF5 file not written by vastcal (no /entry/vastcal group); "
                    "import images with 'vastcal import'"
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
                    f"{p}: damaged session: colour plane {'RGB'[c]} is {shape}; "
                    f"expected {n} x {data.shape[1]} x {data.shape[2]} "
                    f"{data.dtype} like the detector data"
                )
        if n < 0 or data.shape[0] < n:
            raise NotASessionError(f"{p}: damaged session: {n} committed views but {data.shape[0]} frames")
        angles = h5[ENTRY]["sample"]["rotation_angle"]
        if angles.ndim != 1 or angles.dtype.kind != "f":
            raise NotASessionError(
                f"{p}: damaged session: /entry/sample/rotation_angle is {angles.dtype} {angles.shape}; "
                "expected float degrees"
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
                    f"{p}: damaged session: /entry/vastcal/masks is {m.shape}; "
                    f"expected {n_proj} x {data.shape[1]} x {data.shape[2]}"
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
            if frame_crc(self.frame(i)) != int(crc[i]):
                raise SessionCorruptError(f"{self.path}: view {i}: the frame does not match the CRC-32 written with it")

    def close(self) -> None:
        """Close the file (idempotent)."""
        if self._h5.id.valid:
            self._h5.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> None:
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
        return attr_str(self._h5[VASTCAL]["rig"][()])

    def rig_config(self) -> RigConfig:
        """The stored rig configuration parsed into a :class:`~vastcal.config.RigConfig`."""
        return parse_config(yaml.safe_load(self.rig_yaml), source=f"{self.path}:/entry/vastcal/rig")

    @property
    def plan(self) -> dict[str, Any]:
        """The plan attributes."""
        return {k: decode_json(v) for k, v in self._h5[VASTCAL]["plan"].attrs.items()}

    def plan_raw(self) -> dict[str, Any]:
        """The plan attributes as stored (for copying)."""
        return {k: attr_str(v) for k, v in self._h5[VASTCAL]["plan"].attrs.items()}

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
        return {k: decode_json(v) for k, v in self._h5[VASTCAL]["start"].attrs.items()}

    def start_record_raw(self) -> dict[str, Any]:
        """The start record's attributes as stored (for copying)."""
        return {k: attr_str(v) for k, v in self._h5[VASTCAL]["start"].attrs.items()}

    @property
    def stop_record(self) -> dict[str, Any] | None:
        """The stop record, or None while the writer is at work (or after it was killed)."""
        vc = self._h5[VASTCAL]
        if "stop_record" in vc:
            text = attr_str(vc["stop_record"][()])
            if not text:
                return None
            try:
                rec = json.loads(text)
            except ValueError:
                raise NotASessionError(f"{self.path}: damaged session: unreadable stop record") from None
            return rec if isinstance(rec, dict) else None
        if "stop" in vc:  # schema 1
            return {k: decode_json(v) for k, v in vc["stop"].attrs.items()}
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
            pid = writer_pid(self.path) if self.exit_status == "incomplete" else None
            if pid is not None:
                raise SessionIncompleteError(
                    f"{self.path}: the session is being written (vastcal pid {pid or '?'}: {n} of {planned} views "
                    "so far); wait for the acquisition to finish"
                )
            raise SessionIncompleteError(
                f"{self.path}: session is {self.exit_status}: {n} of {planned} views; "
                f"finish it with 'vastcal acquire --resume {self.path}'"
            )
        if n < min_views:
            raise SessionIncompleteError(f"{self.path}: {n} projection views; at least {min_views} needed")

    # -- runs of later stages ------------------------------------------------------------------
    def _results_for_reading(self) -> h5py.File:
        """The file the stored runs are read from (:class:`~vastcal.session.Session` reads its staged copy)."""
        return self._h5

    def stages_run(self) -> dict[str, list[str]]:
        """Names of the stored runs of each later stage, oldest first."""
        vc = self._results_for_reading()[VASTCAL]
        return {k: sorted(vc[k].keys()) for k in STAGE_GROUPS if k in vc}

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
