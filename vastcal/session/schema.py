"""The session schema: one HDF5 file per revolution, NeXus NXtomo core plus vastcal groups.

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
                           axes in µm; a measurement's mesh is an NXoff_geometry, see vastcal.session.nexus)

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

:func:`write_layout` creates every object of this layout (so that SWMR appends create nothing new);
:class:`SessionLayout` holds what it needs.
"""

from __future__ import annotations

import datetime as _dt
import importlib.metadata
import platform
import socket
import uuid
import zlib
from dataclasses import dataclass, field
from typing import Any

import h5py
import numpy as np

from vastcal import __version__
from vastcal.session._attrs import set_attrs

SCHEMA_VERSION = 3
CREATOR = "vastcal"
ENTRY = "/entry"
DETECTOR = "/entry/instrument/detector"
VASTCAL = "/entry/vastcal"
NXTOMO_PATHS_VERSION = 1.5
"""NXtomo paths version (``/entry@version``, a float as the nxtomo package reads it): 1.5 is the first
with both the detector pixel (``detector/x_pixel_size``) and the effective one (``sample/x_pixel_size``)."""
STAGE_GROUPS = ("calibration", "reconstruction", "measurement", "anatomy")
STOP_RECORD_BYTES = 8192
"""Room reserved for the JSON stop record (it is rewritten in place while the file is in SWMR mode)."""


def now_utc() -> str:
    """The current time, ISO 8601 in UTC."""
    return _dt.datetime.now(_dt.UTC).isoformat()


def software_versions() -> dict[str, str]:
    """Versions of vastcal and the libraries whose behaviour shapes the results."""
    out = {"vastcal": __version__, "python": platform.python_version(), "hdf5": h5py.version.hdf5_version}
    for pkg in ("numpy", "h5py", "opencv-python-headless", "cma", "scikit-image", "pyserial", "harvesters"):
        try:
            out[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
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


@dataclass(frozen=True)
class SessionLayout:
    """What a new session file holds before its first view.

    Attributes:
        frame_shape: (H, W) or (H, W, 3) of every frame, pixels.
        dtype: pixel type (uint8 or uint16).
        rig_yaml: resolved rig configuration (YAML text) stored verbatim.
        plan: what will be acquired (JSON-able), e.g. ``{"views": 21, ...}``.
        pixel_size_um: (x, y) pixel pitch on the specimen, µm.
        roi_offset_px: (x, y) offset of the stored frames on the sensor, px.
        title: ``/entry/title`` ("vastcal session" when empty).
        start_info: extra start-record attributes (device descriptions …).
        start_record: the whole start record, as stored by an earlier file (a copy keeps it); None makes
            a new one (uid, time, host, versions and ``start_info``).
        sensor_pixel_um: (x, y) pitch of the sensor itself, µm, when known.
    """

    frame_shape: tuple[int, ...]
    dtype: np.dtype
    rig_yaml: str
    plan: dict[str, Any]
    pixel_size_um: tuple[float, float]
    roi_offset_px: tuple[int, int] = (0, 0)
    title: str = ""
    start_info: dict[str, Any] = field(default_factory=dict)
    start_record: dict[str, Any] | None = None
    sensor_pixel_um: tuple[float, float] | None = None

    @property
    def rgb(self) -> bool:
        """Frames are (H, W, 3)."""
        return len(self.frame_shape) == 3

    @property
    def plane(self) -> tuple[int, int]:
        """(H, W) of one stored plane (NXtomo detector data is N x H x W: RGB frames are stored as planes)."""
        return (int(self.frame_shape[0]), int(self.frame_shape[1]))


def write_layout(h5: h5py.File, layout: SessionLayout) -> None:
    """Create every object the file will ever hold, with zero views."""
    h5.attrs["creator"] = CREATOR
    h5.attrs["vastcal_session_version"] = SCHEMA_VERSION
    h5.attrs["default"] = "entry"
    entry = h5.create_group(ENTRY)
    entry.attrs["NX_class"] = "NXentry"
    entry.attrs["default"] = "data"
    entry.attrs["version"] = NXTOMO_PATHS_VERSION
    entry["definition"] = "NXtomo"
    entry["title"] = layout.title or "vastcal session"
    entry["start_time"] = now_utc()
    scalar_string(entry, "end_time", 40)
    data = _write_detector(entry, layout)
    angles = _write_sample(entry, layout)
    _write_nxdata(entry, data, angles)
    _write_vastcal(entry, layout, data)


def scalar_string(group: h5py.Group, name: str, size: int) -> h5py.Dataset:
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


def _planes(group: h5py.Group, name: str, layout: SessionLayout) -> h5py.Dataset:
    """A growable (0, H, W) image dataset, one frame (plane) per chunk."""
    plane = layout.plane
    ds = group.create_dataset(
        name, shape=(0,) + plane, maxshape=(None,) + plane, dtype=np.dtype(layout.dtype), chunks=(1,) + plane
    )
    ds.attrs["interpretation"] = "image"
    return ds


def _growable(group: h5py.Group, name: str, dtype: str, units: str | None = None) -> h5py.Dataset:
    """A growable 1-D dataset of one value per view."""
    ds = group.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(1024,))
    if units is not None:
        ds.attrs["units"] = units
    return ds


def _write_detector(entry: h5py.Group, layout: SessionLayout) -> h5py.Dataset:
    """``instrument/detector``: the frames, image keys, exposure and the sensor pixel; returns the data."""
    inst = entry.create_group("instrument")
    inst.attrs["NX_class"] = "NXinstrument"
    det = inst.create_group("detector")
    det.attrs["NX_class"] = "NXdetector"
    d = _planes(det, "data", layout)
    if layout.rgb:
        d.attrs["channel"] = "green"
        d.attrs["long_name"] = "green plane of RGB frames (red and blue in /entry/vastcal/colour)"
    for name in ("image_key", "image_key_control"):
        _growable(det, name, "i4")
    _growable(det, "count_time", "f8", "s")
    if layout.sensor_pixel_um is not None:  # the detector's own pixel (NXtomo >= 1.5), when the optics are known
        for name, v in (("x_pixel_size", layout.sensor_pixel_um[0]), ("y_pixel_size", layout.sensor_pixel_um[1])):
            det[name] = float(v)
            det[name].attrs["units"] = "um"
    return d


def _write_sample(entry: h5py.Group, layout: SessionLayout) -> h5py.Dataset:
    """``sample``: the effective pixel on the specimen and the commanded angles; returns the angles."""
    sample = entry.create_group("sample")
    sample.attrs["NX_class"] = "NXsample"
    for name, v in (("x_pixel_size", layout.pixel_size_um[0]), ("y_pixel_size", layout.pixel_size_um[1])):
        sample[name] = float(v)  # the effective pixel on the specimen plane
        sample[name].attrs["units"] = "um"
    return _growable(sample, "rotation_angle", "f8", "degree")


def _write_nxdata(entry: h5py.Group, data: h5py.Dataset, angles: h5py.Dataset) -> None:
    """``data``: the NXdata a NeXus viewer plots (links to the frames, angles and image keys)."""
    nxdata = entry.create_group("data")
    nxdata.attrs["NX_class"] = "NXdata"
    nxdata.attrs["signal"] = "data"
    nxdata.attrs["axes"] = ["rotation_angle", ".", "."]  # viewers show angle, not frame index
    nxdata.attrs["rotation_angle_indices"] = 0
    nxdata["data"] = data
    nxdata["rotation_angle"] = angles
    nxdata["image_key"] = entry["instrument/detector/image_key"]


def _write_vastcal(entry: h5py.Group, layout: SessionLayout, data: h5py.Dataset) -> None:
    """``vastcal``: rig, plan, colour planes, geometry, the per-view table, commit and stop records, start."""
    vc = entry.create_group("vastcal")
    vc.attrs["NX_class"] = "NXcollection"
    vc.attrs["schema_version"] = SCHEMA_VERSION
    vc["rig"] = layout.rig_yaml
    if layout.rgb:
        colour = vc.create_group("colour")
        colour.attrs["NX_class"] = "NXcollection"
        colour.attrs["meaning"] = "RGB frames as planes: frame i = stack(red[i], green[i], blue[i]) on the last axis"
        _planes(colour, "red", layout)
        colour["green"] = data  # a hard link: the detector data is the green plane
        _planes(colour, "blue", layout)
    set_attrs(vc.create_group("plan"), layout.plan)
    geo = vc.create_group("geometry")
    geo.attrs["roi_x"], geo.attrs["roi_y"] = int(layout.roi_offset_px[0]), int(layout.roi_offset_px[1])
    geo.attrs["units"] = "px"
    views = vc.create_group("views")
    views.attrs["schema_version"] = SCHEMA_VERSION
    for col in VIEW_COLUMNS:
        _growable(views, col.name, col.dtype, col.units)
    committed = vc.create_dataset("committed_views", shape=(1,), maxshape=(1,), dtype="i8", chunks=(1,), fillvalue=0)
    committed[0] = 0
    committed.attrs["units"] = "views"
    committed.attrs["meaning"] = "views 0 .. n-1 are complete; rows beyond belong to a view cut short"
    stop = scalar_string(vc, "stop_record", STOP_RECORD_BYTES)
    stop.attrs["meaning"] = (
        "JSON stop record (exit_status success|abort|fail, reason, views_written, time); empty while writing"
    )
    start = layout.start_record or {
        "uid": str(uuid.uuid4()),
        "time": now_utc(),
        "host": socket.gethostname(),
        "versions": software_versions(),
        **layout.start_info,
    }
    set_attrs(vc.create_group("start"), start)


def frame_crc(frame: np.ndarray) -> int:
    """CRC-32 of a frame's bytes as stored (H x W [x 3] interleaved): the ``frame_crc32`` column."""
    return zlib.crc32(np.ascontiguousarray(frame).data) & 0xFFFFFFFF
