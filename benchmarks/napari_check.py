"""napari, headless: a session's tomogram through both routes — its OME-Zarr export and vastcal's session reader.

    pip install napari pyqt5 napari-ome-zarr      # not vastcal's dependencies: a viewer's own environment
    QT_QPA_PLATFORM=offscreen python benchmarks/napari_check.py S.h5 [--images docs/images] [--name zf1]

For a session holding a tomogram (``vastcal run`` or ``vastcal reconstruct --anatomy``) it

1. writes the OME-Zarr export (``vastcal export --ome-zarr``) into a temporary folder and opens it in
   ``napari.Viewer(show=False)`` with the ``napari-ome-zarr`` plugin;
2. opens the session itself with vastcal's reader (the npe2 manifest ``vastcal/napari.yaml``, registered here
   when vastcal is not installed in napari's environment);
3. checks that both routes give the tomogram the voxel edge in µm as its scale (z, y, x) and the same world
   position, and that the organ labels come along;
4. saves a screenshot of each route's canvas (3-D rendering of the tomogram with the organs, and a slice through
   the eyes) to ``--images`` when the offscreen OpenGL allows, and says what failed when it does not.

Exit status: 0 when every check passed, 1 otherwise.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # this checkout's vastcal first

log = logging.getLogger("napari_check")


def _register_reader() -> None:
    """Make napari know vastcal's reader even when vastcal is not installed in its environment."""
    from npe2 import PluginManager, PluginManifest

    pm = PluginManager.instance()
    if "vastcal" not in pm._manifests:
        pm.register(PluginManifest.from_file(REPO / "vastcal" / "napari.yaml"))


def _check_layers(route: str, layers: list[Any], voxel_um: float, origin_zyx: np.ndarray) -> list[str]:
    """Problems with one route's layers: the tomogram's scale and position, the organ labels."""
    problems = []
    names = [ly.name for ly in layers]
    images = [ly for ly in layers if ly.__class__.__name__ == "Image"]
    labels = [ly for ly in layers if ly.__class__.__name__ == "Labels"]
    if not images:
        return [f"{route}: no image layer ({names})"]
    img = images[0]
    if not np.allclose(img.scale[-3:], voxel_um, rtol=1e-6):
        problems.append(f"{route}: tomogram scale {list(img.scale)}, expected {voxel_um} µm on each axis")
    first = np.asarray(img.data_to_world(np.zeros(img.ndim)), float)[-3:]  # scale, translate and affine applied
    if not np.allclose(first, origin_zyx, atol=1e-3 * voxel_um):
        where = f"{route}: first voxel at {first.round(2).tolist()} µm, expected {origin_zyx.round(2).tolist()}"
        if route == "ome-zarr":  # napari-ome-zarr reads only a dataset's first coordinate transformation (the scale)
            print(f"note: {where}: the reader dropped the OME-NGFF translation (the scale is read)")
        else:
            problems.append(where)
    if not labels:
        problems.append(f"{route}: no organ labels ({names})")
    units = getattr(img, "units", None)
    print(
        f"{route}: layers {names}; tomogram {img.data.shape if img.ndim == 3 else img.level_shapes[0]} "
        f"scale {[round(float(s), 3) for s in img.scale]} {[str(u) for u in units] if units else ''} "
        f"first voxel at {first.round(1).tolist()} µm"
    )
    return problems


def _render(viewer: Any) -> np.ndarray:
    """The canvas drawn into an offscreen framebuffer (RGB). ``viewer.screenshot`` grabs the window's framebuffer,
    which a viewer that is not shown leaves black; vispy's own render does not need the window."""
    canvas = viewer.window._qt_viewer.canvas._scene_canvas
    return np.asarray(canvas.render(size=SHOT_SIZE))[..., :3]


SHOT_SIZE = (540, 300)
"""Width, height (px) of each half of a screenshot."""


def _screenshot(viewer: Any, path: Path, eyes_z_index: int | None) -> str:
    """A 3-D view and a slice through the eyes side by side as one small PNG; '' or what failed."""
    try:
        import imageio.v3 as iio

        img = viewer.layers[0]
        img.contrast_limits = [0.0, float(np.percentile(np.asarray(img.data if img.ndim == 3 else img.data[0]), 99.9))]
        img.colormap = "gray_r"
        viewer.dims.ndisplay = 3
        viewer.camera.angles = (-20.0, 25.0, 70.0)
        viewer.reset_view()
        three_d = _render(viewer)
        viewer.dims.ndisplay = 2
        if eyes_z_index is not None:
            viewer.dims.set_point(0, viewer.layers[0].data_to_world([eyes_z_index, 0, 0])[0])
        viewer.reset_view()
        flat = _render(viewer)
        if max(three_d.max(), flat.max()) == 0:
            return "the offscreen OpenGL drew nothing (every pixel black)"
        iio.imwrite(path, np.concatenate([three_d, flat], axis=1), extension=".png", optimize=True)
        return ""
    except Exception as exc:  # noqa: BLE001 - an OpenGL failure of any kind is reported, not raised
        return f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"


def _open_in_viewer(path: Path, plugin: str, shot: Path, eyes_z: int | None) -> tuple[list[Any], str]:
    """The layers ``plugin`` reads from ``path`` in ``napari.Viewer(show=False)`` and the screenshot's failure ('' when
    saved). When the viewer cannot draw (no OpenGL context offscreen), the layers come from napari's ``ViewerModel``
    (the same readers and layers, without a canvas) and the failure is returned."""
    import napari
    from napari.components import ViewerModel

    try:
        viewer = napari.Viewer(show=False)
    except Exception as exc:  # noqa: BLE001 - the Qt/OpenGL failure is reported
        failed = f"napari.Viewer(show=False): {type(exc).__name__}: {exc}"
    else:
        try:
            layers = list(viewer.open(str(path), plugin=plugin))
            return layers, _screenshot(viewer, shot, eyes_z)
        except Exception as exc:  # noqa: BLE001 - the Qt/OpenGL failure is reported
            failed = f"drawing the layers: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        finally:
            try:
                viewer.close()
            except Exception:  # noqa: BLE001, S110 - a viewer that failed to draw may fail to close too
                pass
    from napari.plugins import _initialize_plugins

    _initialize_plugins()
    model = ViewerModel()
    return list(model.open(str(path), plugin=plugin)), failed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session", type=Path)
    ap.add_argument("--images", type=Path, default=REPO / "docs" / "images", help="where the screenshots go")
    ap.add_argument("--name", default="", help="screenshot file prefix (default: the session's stem)")
    a = ap.parse_args(argv)
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    import napari

    from vastcal.anatomy_session import load_tomogram
    from vastcal.export import export_ome_zarr
    from vastcal.session import Session

    with Session.open(a.session) as s:
        grid, _, labels = load_tomogram(s.latest_result("anatomy"))
    origin_zyx = np.asarray(grid.origin, float)[::-1]
    eyes = np.argwhere(np.isin(labels, (1, 2)))
    eyes_z = int(np.median(eyes[:, 2])) if len(eyes) else None
    print(f"napari {napari.__version__}; {a.session}: tomogram {grid.shape} (x, y, z) voxels of {grid.size:.3f} µm")
    _register_reader()
    problems, shots = [], {}
    name = a.name or a.session.stem
    a.images.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        zarr_path = export_ome_zarr(a.session, Path(tmp) / "tomogram.ome.zarr")
        for route, path, plugin in (("ome-zarr", zarr_path, "napari-ome-zarr"), ("session", a.session, "vastcal")):
            shot = a.images / f"{name}-napari-{route}.png"
            layers, failed = _open_in_viewer(path, plugin, shot, eyes_z)
            problems += _check_layers(route, layers, grid.size, origin_zyx)
            shots[route] = f"not saved: {failed}" if failed else f"{shot} ({shot.stat().st_size // 1024} kB)"
    for route, what in shots.items():
        print(f"screenshot, {route}: {what}")
    for p in problems:
        print(f"FAILED {p}")
    print("every check passed" if not problems else f"{len(problems)} check(s) failed")
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
