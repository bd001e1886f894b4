"""Sessions read by tools nobody here wrote: ``nxtomo`` and ``silx`` open every kind of session.

Acquired (simulated rig, Mono12 and RGB8), imported (grey and colour PNGs) and schema-2 sessions
written before RGB frames became planes (``data/schema2_*.h5``, written by vastcal.session at commit
61ea861 with ``data/make_schema2_fixtures.py.txt``). Results: the hull is an NXdata on x, y, z axes in
µm, the mesh an NXoff_geometry.
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from vastcal.session import SCHEMA_VERSION, Session, SessionWriter

nxtomo_app = pytest.importorskip(
    "nxtomo.application.nxtomo", reason="nxtomo is in the test extras (pip install -e '.[test]')"
)
silx_io = pytest.importorskip("silx.io", reason="silx is in the test extras (pip install -e '.[test]')")
from silx.io import nxdata as silx_nxdata  # noqa: E402

HERE = Path(__file__).resolve().parent
DATA = HERE / "data"
sys.path.insert(0, str(HERE.parent / "reconstruct"))  # phantom_views


def _fixture_frames(shape: tuple[int, ...]) -> np.ndarray:
    """The frames the schema-2 fixtures hold (see make_schema2_fixtures.py.txt)."""
    return np.random.default_rng(7).integers(0, 255, size=(4,) + shape, dtype=np.uint8)


def _small_rig(pixel_format: str):  # type: ignore[no-untyped-def]
    from vastcal.config import load_config

    cfg = load_config(None)
    roi = dataclasses.replace(cfg.camera.roi, x=448, y=448, width=96, height=64)
    return dataclasses.replace(
        cfg,
        camera=dataclasses.replace(cfg.camera, roi=roi, pixel_format=pixel_format),
        acquisition=dataclasses.replace(cfg.acquisition, views=4),
    )


@pytest.fixture(scope="module", params=["Mono12", "RGB8"])
def acquired(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    from vastcal.pipeline import acquire_simulated

    cfg = _small_rig(request.param)
    path = tmp_path_factory.mktemp(f"acq-{request.param}") / "S.h5"
    acquire_simulated(cfg, path)
    return path, cfg


def _nxtomo(path: Path):  # type: ignore[no-untyped-def]
    return nxtomo_app.NXtomo().load(str(path), "entry", detector_data_as="as_numpy_array")


def _um(q: object) -> float:
    return float(q.to("um").magnitude)  # type: ignore[attr-defined]


def _check_with_silx(path: Path, n: int, plane_shape: tuple[int, int]) -> None:
    """silx follows the default attributes to /entry/data: a valid NXdata plotted against the angle."""
    with silx_io.open(str(path)) as f:
        default = silx_nxdata.get_default(f)
        assert default is not None and default.is_valid, "silx finds the default NXdata"
        assert default.signal.shape == (n,) + plane_shape
        assert default.axes_dataset_names[0] == "rotation_angle"
        assert default.axes[0].attrs["units"] == "degree"
        np.testing.assert_array_equal(default.axes[0][()], f["/entry/sample/rotation_angle"][()])
        assert f["/entry/sample/x_pixel_size"].attrs["units"] == "um"


def test_acquired_sessions_load_with_nxtomo_and_silx(acquired: tuple[Path, object]) -> None:
    path, cfg = acquired
    with Session.open(path) as s:
        frames, angles, shape = s.projections(), s.angles_deg, s.frame_shape
        assert s.version == SCHEMA_VERSION
    rgb = cfg.camera.pixel_format == "RGB8"  # type: ignore[attr-defined]
    assert shape == (64, 96, 3) if rgb else shape == (64, 96), "vastcal readers still get the RGB frames"
    nx = _nxtomo(path)
    green = frames[..., 1] if rgb else frames
    np.testing.assert_array_equal(nx.instrument.detector.data, green)
    np.testing.assert_allclose(nx.sample.rotation_angle.to("degree").magnitude, angles)
    optics = cfg.optics  # type: ignore[attr-defined]
    assert _um(nx.instrument.detector.x_pixel_size) == pytest.approx(optics.pixel_size_um), (
        "detector: the sensor's own pixel"
    )
    assert _um(nx.sample.x_pixel_size) == pytest.approx(optics.pixel_size_um / optics.magnification), (
        "sample: the effective pixel"
    )
    assert _um(nx.sample.y_pixel_size) == pytest.approx(optics.pixel_size_um / optics.magnification)
    _check_with_silx(path, len(frames), shape[:2])  # type: ignore[arg-type]
    if rgb:
        with h5py.File(path, "r") as f:
            c = f["/entry/vastcal/colour"]
            np.testing.assert_array_equal(c["red"][()], frames[..., 0])
            np.testing.assert_array_equal(c["blue"][()], frames[..., 2])
            assert c["green"].id == f["/entry/instrument/detector/data"].id, "green is a link, not a copy"


@pytest.mark.parametrize("colour", [False, True])
def test_imported_sessions_load_with_nxtomo_and_silx(tmp_path: Path, colour: bool) -> None:
    cv2 = pytest.importorskip("cv2")
    from vastcal.importer import import_folder

    rng = np.random.default_rng(3)
    frames = rng.integers(0, 255, size=(3, 20, 28) + ((3,) if colour else ()), dtype=np.uint8)
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i, im in enumerate(frames):
        cv2.imwrite(str(folder / f"v{i:02d}.png"), im[..., ::-1] if colour else im)  # OpenCV writes BGR
    out = tmp_path / "I.h5"
    import_folder(folder, out)
    with Session.open(out) as s:
        np.testing.assert_array_equal(s.projections(), frames)
        effective = s.pixel_size_um[0]
    nx = _nxtomo(out)
    np.testing.assert_array_equal(nx.instrument.detector.data, frames[..., 1] if colour else frames)
    assert _um(nx.sample.x_pixel_size) == pytest.approx(effective)
    _check_with_silx(out, 3, (20, 28))


@pytest.mark.parametrize("name, shape", [("schema2_rgb.h5", (12, 16, 3)), ("schema2_mono.h5", (12, 16))])
def test_schema2_sessions_still_read_and_resume_rewrites_them_in_the_current_layout(
    tmp_path: Path, name: str, shape: tuple[int, ...]
) -> None:
    old = Path(shutil.copy(DATA / name, tmp_path / name))
    frames = _fixture_frames(shape)
    with Session.open(old) as s:
        assert s.version == 2 and s.frame_shape == shape
        np.testing.assert_array_equal(s.projections(), frames)
        np.testing.assert_array_equal(s.frame(3), frames[3])
        assert s.pixel_size_um == (2.75, 2.75), "schema 2: the effective pixel was the detector's"
        assert s.sensor_pixel_um == ((5.5, 5.5) if len(shape) == 3 else None)
        crc = s.view_table()["frame_crc32"]
        s.verify()
        new = tmp_path / "rebuilt.h5"
        SessionWriter.rebuild(s, new)  # what --resume and a stage on a killed session do
    with Session.open(new) as s:
        assert s.version == SCHEMA_VERSION and s.frame_shape == shape
        np.testing.assert_array_equal(s.projections(), frames)
        assert s.pixel_size_um == (2.75, 2.75) and s.sensor_pixel_um == ((5.5, 5.5) if len(shape) == 3 else None)
        np.testing.assert_array_equal(s.view_table()["frame_crc32"], crc)
        s.verify()
    nx = _nxtomo(new)
    np.testing.assert_array_equal(nx.instrument.detector.data, frames[..., 1] if len(shape) == 3 else frames)
    assert _um(nx.sample.x_pixel_size) == pytest.approx(2.75)


def test_hull_is_nxdata_in_um_and_mesh_is_nxoff_geometry(tmp_path: Path) -> None:
    from phantom_views import make_session, render_views

    from vastcal.reconstruct import reconstruct_session
    from vastcal.result_groups import load_mesh, load_reconstruction
    from vastcal.simulators.camera.phantom import zebrafish_phantom

    views = render_views(zebrafish_phantom(), 6, width=256, height=96, pixel_um=22.0, seed=3)
    path = make_session(tmp_path / "S.h5", views, masks=True, cameras=True)
    reconstruct_session(path, voxel_size_um=60.0)
    with Session.open(path) as s:
        hull = load_reconstruction(s.latest_result("reconstruction"))
        mesh = load_mesh(s.latest_result("measurement"))
        rec_name, meas_name = s.latest_result("reconstruction").name, s.latest_result("measurement").name
    g = hull.grid
    with silx_io.open(str(path)) as f:
        nxd = silx_nxdata.NXdata(f[rec_name])
        assert nxd.is_valid and nxd.signal.name == rec_name + "/counts" and nxd.signal.ndim == 3
        assert nxd.axes_dataset_names == ["x", "y", "z"]
        for a, ax in enumerate(nxd.axes):
            assert ax.attrs["units"] == "um"
            np.testing.assert_allclose(ax[()], g.origin[a] + np.arange(g.shape[a]) * g.size)
        np.testing.assert_array_equal(nxd.signal[()], hull.counts)
        assert f[rec_name].parent.attrs["NX_class"] == "NXcollection"
        m = f[meas_name + "/mesh"]
        assert m.attrs["NX_class"] == "NXoff_geometry" and m["vertices"].attrs["units"] == "um"
        order, starts = m["winding_order"][()], m["faces"][()]
        assert starts.ndim == 1 and order.shape == (3 * len(starts),) and np.all(np.diff(starts) == 3)
        np.testing.assert_array_equal(order.reshape(-1, 3), mesh.faces)
        assert 0 <= order.min() and order.max() < len(m["vertices"])


def test_a_mesh_stored_before_nxoff_geometry_still_loads(tmp_path: Path) -> None:
    from vastcal.session.nexus import read_triangles, write_off_geometry

    tri = np.array([[0, 1, 2], [0, 2, 3]])
    with h5py.File(tmp_path / "m.h5", "w") as f:
        old = f.create_group("old")
        old["vertices"] = np.zeros((4, 3), np.float32)
        old["faces"] = tri.astype(np.int32)
        write_off_geometry(f.create_group("new"), np.zeros((4, 3)), tri)
        np.testing.assert_array_equal(read_triangles(old), tri)
        np.testing.assert_array_equal(read_triangles(f["new"]), tri)
        f["new/faces"][1] = 2  # a quad-and-more polygon mesh is not ours
        with pytest.raises(ValueError, match="triangle"):
            read_triangles(f["new"])


@pytest.mark.parametrize("damage", ["delete blue", "short blue", "wrong dtype red"])
def test_a_damaged_colour_plane_is_named_in_one_error(tmp_path: Path, damage: str) -> None:
    from vastcal.errors import NotASessionError

    path = tmp_path / "S.h5"
    frames = np.random.default_rng(5).integers(0, 255, size=(3, 8, 10, 3), dtype=np.uint8)
    with SessionWriter.create(
        path,
        frame_shape=(8, 10, 3),
        dtype=np.uint8,
        rig_yaml="name: t\n",
        plan={"views": 3},
        pixel_size_um=(2.0, 2.0),
        live=False,
    ) as w:
        for i in range(3):
            w.append_view(frames[i], 120.0 * i)
    with h5py.File(path, "r+") as f:
        c = f["/entry/vastcal/colour"]
        if damage == "delete blue":
            del c["blue"]
        elif damage == "short blue":
            del c["blue"]
            c["blue"] = frames[:2, ..., 2]
        else:
            del c["red"]
            c["red"] = frames[..., 0].astype(np.uint16)
    with pytest.raises(NotASessionError, match="damaged session") as err:
        Session.open(path)
    assert "\n" not in str(err.value)
