"""napari reader (npe2) for vastcal sessions: the tomogram, the visual hull and the organs as layers.

The manifest ``vastcal/napari.yaml`` (entry point group ``napari.manifest``) registers :func:`get_reader` for
``*.h5``. napari calls it with the path; it answers with :func:`read_session` when the file is a vastcal session
holding a tomogram (``anatomy/run_NNN``), and None otherwise, so that napari tries its other readers.

:func:`read_session` returns napari *layer data tuples* ``(data, kwargs, layer_type)`` — plain numpy arrays and
dictionaries: this module imports neither napari nor npe2, and neither does any other part of vastcal.

Layers, all on the tomogram's grid, with axes (z, y, x) in world micrometres (x = the rotation axis; the same
order as ``vastcal export --ome-zarr`` writes) and ``scale`` = the voxel edge in µm, ``translate`` = the world
position (µm) of the first voxel's centre:

* ``tomogram``: image, float32 attenuation in 1/µm (:mod:`vastcal.anatomy_session`);
* ``hull``: labels, 1 inside the visual hull of the reconstruction the tomogram was made from (omitted when that
  reconstruction is not stored or its grid differs);
* ``organs``: labels, 1 eye 1, 2 eye 2, 3 yolk (:data:`vastcal.anatomy_session.ORGAN_LABELS`).

Every layer's ``metadata`` holds the session path, the anatomy run, the voxel size (``voxel_size_um``) and the
anatomy record; with napari ≥ 0.6 the layers also get ``units`` (micrometre) and ``axis_labels``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import Any

import h5py
import numpy as np

log = logging.getLogger(__name__)

LayerData = tuple[np.ndarray, dict[str, Any], str]
"""A napari layer data tuple: (data, layer keyword arguments, layer type)."""

AXIS_LABELS = ("z", "y", "x")


def _has_tomogram(path: Path) -> bool:
    """Whether ``path`` is an HDF5 file with a stored tomogram (cheap: no data read)."""
    from vastcal.session.schema import VASTCAL

    try:
        if not path.is_file() or not h5py.is_hdf5(path):
            return False
        with h5py.File(path, "r", locking=False) as f:
            g = f.get(f"{VASTCAL}/anatomy")
            return isinstance(g, h5py.Group) and any("tomogram" in g[r] for r in g)
    except OSError:
        return False


def get_reader(path: str | list[str]) -> Callable[[str | list[str]], list[LayerData]] | None:
    """napari's reader hook: :func:`read_session` for a vastcal session with a tomogram, else None."""
    paths = [path] if isinstance(path, str | Path) else list(path)
    if not paths or not all(str(p).endswith(".h5") and _has_tomogram(Path(p)) for p in paths):
        return None
    return read_session


def _napari_at_least(major: int, minor: int) -> bool:
    """Whether the installed napari is at least ``major.minor`` (read from its metadata, without importing it)."""
    try:
        parts = metadata.version("napari").split(".")[:2]
        return (int(parts[0]), int("".join(c for c in parts[1] if c.isdigit()) or 0)) >= (major, minor)
    except (metadata.PackageNotFoundError, ValueError, IndexError):
        return False


def _hull_of(session: Any, anatomy_group: h5py.Group, shape: tuple[int, ...]) -> np.ndarray | None:
    """The visual hull (x, y, z bool) of the reconstruction the tomogram came from, or None."""
    from vastcal.result_groups import load_reconstruction
    from vastcal.session import read_attrs

    run = str(read_attrs(anatomy_group).get("reconstruction_run", ""))
    g = session.result("reconstruction", run) if run else None
    if g is None:
        log.warning("%s: reconstruction %r of the tomogram not stored; no hull layer", session.path, run)
        return None
    occ = load_reconstruction(g).occupancy
    if occ.shape != shape:
        log.warning("%s: reconstruction %s is on another grid than the tomogram; no hull layer", session.path, run)
        return None
    return occ


def session_layers(path: str | Path, run: str | None = None) -> list[LayerData]:
    """The layers of a session's tomogram (module docstring): the latest anatomy run, or ``run``.

    Raises:
        NotASessionError: the file is not a vastcal session.
        MissingStageError: the session holds no tomogram (or no run ``run``).
    """
    from vastcal.anatomy_session import ORGAN_NAMES, load_anatomy, load_tomogram
    from vastcal.errors import MissingStageError
    from vastcal.export import zyx
    from vastcal.session import Session

    with Session.open(path) as s:
        g = s.result("anatomy", run)
        if g is None or "tomogram" not in g:
            raise MissingStageError(f"{path}: no tomogram stored{f' as anatomy/{run}' if run else ''}")
        grid, att, labels = load_tomogram(g)
        record = load_anatomy(g)
        hull = _hull_of(s, g, att.shape)
        name = g.name.rsplit("/", 1)[-1]
    common: dict[str, Any] = {
        "scale": [float(grid.size)] * 3,
        "translate": [float(v) for v in np.asarray(grid.origin, float)[::-1]],
    }
    if _napari_at_least(0, 6):
        common.update(units=["micrometer"] * 3, axis_labels=list(AXIS_LABELS))
    meta = {"session": str(path), "anatomy_run": name, "voxel_size_um": float(grid.size), "anatomy": record}
    img = zyx(att)
    inside = img[img > 0]
    top = float(np.percentile(inside, 99.9)) if inside.size else 1.0
    layers: list[LayerData] = [
        (
            img,
            {
                **common,
                "name": "tomogram",
                "colormap": "gray_r",
                "contrast_limits": [0.0, max(top, 1e-6)],
                "metadata": {**meta, "units": "1/um"},
            },
            "image",
        )
    ]
    if hull is not None:
        layers.append(
            (zyx(hull).astype(np.uint8), {**common, "name": "hull", "opacity": 0.15, "metadata": meta}, "labels")
        )
    names = {0: "none", **ORGAN_NAMES}
    organ_features = {"index": list(names), "organ": list(names.values())}
    layers.append(
        (
            zyx(labels),
            {**common, "name": "organs", "opacity": 0.5, "features": organ_features, "metadata": meta},
            "labels",
        )
    )
    return layers


def read_session(path: str | list[str]) -> list[LayerData]:
    """napari's reader function: the layers of every session in ``path`` (:func:`session_layers`)."""
    paths = [path] if isinstance(path, str | Path) else list(path)
    return [layer for p in paths for layer in session_layers(p)]
