"""vastcal import of image files the way labs store them: multi-page TIFF, OME-TIFF and ImageJ stacks, 8/16-bit
and float pixels, pixel size and angles from metadata, no silent optical defaults, crops without an offset, and a
specimen name per import."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

tifffile = pytest.importorskip("tifffile")

from vastcal.calibration_session import session_camera_model  # noqa: E402
from vastcal.cli import main  # noqa: E402
from vastcal.config import CONFIG_DIR, load_config  # noqa: E402
from vastcal.errors import ImportDataError  # noqa: E402
from vastcal.importer import CameraFile, ImportSettings, import_folder, pixel_size_known  # noqa: E402
from vastcal.info import format_summary, session_summary  # noqa: E402
from vastcal.session import Session  # noqa: E402


def _frames(n: int = 6, shape: tuple[int, ...] = (20, 30), dtype: type = np.uint16, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    top = 255 if dtype is np.uint8 else 60000
    return rng.integers(0, top, size=(n,) + shape).astype(dtype)


def _title(s: Session) -> str:
    t = s.h5["/entry/title"][()]
    return t.decode() if isinstance(t, bytes) else str(t)


def _ome_xml(n: int, h: int, w: int, dtype: str, *, size: str = "", angles: list[float] | None = None) -> str:
    ann = planes = ""
    if angles is not None:
        ann = (
            "<StructuredAnnotations>"
            + "".join(
                f'<MapAnnotation ID="Annotation:{k}"><Value><M K="angle">{a}</M></Value></MapAnnotation>'
                for k, a in enumerate(angles)
            )
            + "</StructuredAnnotations>"
        )
        planes = "".join(
            f'<Plane TheC="0" TheZ="0" TheT="{k}"><AnnotationRef ID="Annotation:{k}"/></Plane>' for k in range(n)
        )
    return (
        '<?xml version="1.0" encoding="UTF-8"?><OME xmlns="http://www.openmicroscopy.org/Schemas/OME/2016-06">'
        f'<Image ID="Image:0"><Pixels ID="Pixels:0" DimensionOrder="XYCZT" Type="{dtype}" '
        f'SizeX="{w}" SizeY="{h}" SizeC="1" SizeZ="1" SizeT="{n}" {size}>'
        '<Channel ID="Channel:0:0" SamplesPerPixel="1"/>'
        f'<TiffData IFD="0" PlaneCount="{n}"/>'
        f"{planes}</Pixels></Image>{ann}</OME>"
    )


def test_a_multipage_tiff_is_every_page_one_session_named_after_the_file(tmp_path: Path) -> None:
    frames = _frames(6)
    tifffile.imwrite(tmp_path / "larva_12.tif", frames, photometric="minisblack")
    import_folder(tmp_path / "larva_12.tif", tmp_path / "s.h5")
    with Session.open(tmp_path / "s.h5") as s:
        assert s.n_views == 6 and s.dtype == np.uint16
        np.testing.assert_array_equal(s.projections(), frames)
        assert _title(s) == "larva_12"
        np.testing.assert_allclose(s.angles_deg, np.arange(6) * 60.0)


def test_a_folder_holding_one_stack_is_that_stack_and_several_stacks_are_refused(tmp_path: Path) -> None:
    (tmp_path / "one").mkdir()
    tifffile.imwrite(tmp_path / "one" / "rev.tif", _frames(4), photometric="minisblack")
    import_folder(tmp_path / "one", tmp_path / "a.h5")
    with Session.open(tmp_path / "a.h5") as s:
        assert s.n_views == 4
    tifffile.imwrite(tmp_path / "one" / "rev2.tif", _frames(4, seed=1), photometric="minisblack")
    with pytest.raises(
        ImportDataError, match=r"rev2?\.tif: a stack of 4 views among 2 image files; import one stack per session"
    ):
        import_folder(tmp_path / "one", tmp_path / "b.h5")
    assert not (tmp_path / "b.h5").exists()


def test_folder_of_images_is_named_after_the_folder_and_name_overrides(tmp_path: Path) -> None:
    for name in ("fish_A", "fish_B"):
        (tmp_path / name).mkdir()
        for i, f in enumerate(_frames(3, dtype=np.uint8)):
            cv2.imwrite(str(tmp_path / name / f"v{i}.png"), f)
        import_folder(tmp_path / name, tmp_path / f"{name}.h5")
    import_folder(tmp_path / "fish_A", tmp_path / "named.h5", settings=ImportSettings(name="larva 3, tank 2"))
    titles = []
    for out in ("fish_A", "fish_B", "named"):
        with Session.open(tmp_path / f"{out}.h5") as s:
            titles.append(_title(s))
    assert titles == ["fish_A", "fish_B", "larva 3, tank 2"]
    with pytest.raises(ImportDataError, match="--name"):
        import_folder(tmp_path / "fish_A", tmp_path / "bad.h5", settings=ImportSettings(name="two\nlines"))


def test_ome_tiff_pixel_size_and_angles_are_read_and_options_override_them(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    n, h, w = 5, 16, 24
    frames = _frames(n, (h, w), np.uint8)
    angles = [3.0, 75.0, 147.0, 219.0, 291.0]
    xml = _ome_xml(
        n,
        h,
        w,
        "uint8",
        size='PhysicalSizeX="650" PhysicalSizeXUnit="nm" PhysicalSizeY="650" PhysicalSizeYUnit="nm"',
        angles=angles,
    )
    path = tmp_path / "rev.ome.tif"
    tifffile.imwrite(path, frames, description=xml, metadata=None, photometric="minisblack")
    import_folder(path, tmp_path / "s.h5")
    with Session.open(tmp_path / "s.h5") as s:
        np.testing.assert_array_equal(s.projections(), frames)
        assert s.pixel_size_um == pytest.approx((0.65, 0.65))
        assert s.plan["pixel_size_source"] == "OME PhysicalSizeX/Y"
        np.testing.assert_allclose(s.angles_deg, angles)
        assert _title(s) == "rev"
    (tmp_path / "angles.txt").write_text("\n".join(str(10.0 + 72.0 * k) for k in range(n)))
    with caplog.at_level(logging.WARNING, logger="vastcal.importer"):
        import_folder(
            path, tmp_path / "t.h5", settings=ImportSettings(pixel_size_um=1.3), angles=tmp_path / "angles.txt"
        )
    with Session.open(tmp_path / "t.h5") as s:
        assert s.pixel_size_um == pytest.approx((1.3, 1.3))
        np.testing.assert_allclose(s.angles_deg, 10.0 + 72.0 * np.arange(n))
    text = caplog.text
    assert "--pixel-size-um 1.3 um overrides rev.ome.tif's OME PhysicalSizeX/Y (0.65 um)" in text
    assert "--angles" in text and "overrides" in text


def test_imagej_hyperstack_resolution_and_two_stack_axes(tmp_path: Path) -> None:
    frames = _frames(4, (12, 18), np.uint16)
    tifffile.imwrite(
        tmp_path / "ij.tif", frames, imagej=True, resolution=(1 / 0.5, 1 / 0.5), metadata={"unit": "um", "axes": "TYX"}
    )
    import_folder(tmp_path / "ij.tif", tmp_path / "s.h5")
    with Session.open(tmp_path / "s.h5") as s:
        np.testing.assert_array_equal(s.projections(), frames)
        assert s.pixel_size_um == pytest.approx((0.5, 0.5))
    tzyx = _frames(6, (12, 18), np.uint16).reshape(3, 2, 12, 18)
    tifffile.imwrite(tmp_path / "tz.tif", tzyx, imagej=True, metadata={"axes": "TZYX"})
    with pytest.raises(ImportDataError, match=r"tz\.tif: 2 stack axes \(T=3, Z=2\); expected one axis of views"):
        import_folder(tmp_path / "tz.tif", tmp_path / "t.h5")


def test_imagej_slice_labels_give_the_angles(tmp_path: Path) -> None:
    labels = ["view 0: angle=0", "view 1: angle=117.5", "view 2: angle=241"]
    tifffile.imwrite(
        tmp_path / "lab.tif", _frames(3, (12, 18)), imagej=True, metadata={"axes": "TYX", "Labels": labels}
    )
    import_folder(tmp_path / "lab.tif", tmp_path / "s.h5")
    with Session.open(tmp_path / "s.h5") as s:
        np.testing.assert_allclose(s.angles_deg, [0.0, 117.5, 241.0])
        assert s.plan["angle_source"] == "lab.tif: ImageJ slice labels"


def test_rgb_stack_is_stored_rgb(tmp_path: Path) -> None:
    frames = _frames(3, (10, 14, 3), np.uint8)
    tifffile.imwrite(tmp_path / "rgb.tif", frames, photometric="rgb")
    import_folder(tmp_path / "rgb.tif", tmp_path / "s.h5")
    with Session.open(tmp_path / "s.h5") as s:
        np.testing.assert_array_equal(s.projections(), frames)


def test_a_print_resolution_is_not_a_pixel_size_and_unknown_optics_are_said(tmp_path: Path) -> None:
    tifffile.imwrite(
        tmp_path / "dpi.tif",
        _frames(3, dtype=np.uint8),
        photometric="minisblack",
        resolution=(72, 72),
        resolutionunit="INCH",
    )
    import_folder(tmp_path / "dpi.tif", tmp_path / "s.h5")
    with Session.open(tmp_path / "s.h5") as s:
        assert not pixel_size_known(s.plan)
        assert session_camera_model(s)[3]["length_unit"] == "px"
    text = format_summary(session_summary(tmp_path / "s.h5"))
    assert "pixel size unknown - measurements in pixels" in text
    import_folder(
        tmp_path / "dpi.tif",
        tmp_path / "c.h5",
        config=load_config(CONFIG_DIR / "guo2019-zebrafish.yaml"),
        settings=ImportSettings(roi_offset=(0, 0)),
    )
    with Session.open(tmp_path / "c.h5") as s:
        assert pixel_size_known(s.plan) and s.plan["pixel_size_source"] == "config"
        assert session_camera_model(s)[3]["length_unit"] == "um"
    assert "pixel 5.5 x 5.5 um" in format_summary(session_summary(tmp_path / "c.h5"))


@pytest.mark.parametrize("lo, hi, expected", [(0.0, 1.0, (0.0, 1.0)), (-5.0, 20.0, (-5.0, 20.0))])
def test_float_images_are_scaled_to_uint16_with_the_range_stated(
    tmp_path: Path, lo: float, hi: float, expected: tuple[float, float]
) -> None:
    rng = np.random.default_rng(1)
    frames = rng.uniform(lo, hi, size=(4, 10, 12)).astype(np.float32)
    frames[0, 0, 0], frames[1, 0, 0] = lo, hi
    tifffile.imwrite(tmp_path / "f.tif", frames, photometric="minisblack")
    import_folder(tmp_path / "f.tif", tmp_path / "s.h5")
    with Session.open(tmp_path / "s.h5") as s:
        got = s.projections()
        assert got.dtype == np.uint16
        a, b = expected
        np.testing.assert_allclose(got, np.rint((frames.astype(float) - a) * 65535 / (b - a)), atol=1)
        assert f"float32 -> uint16: values {a:.6g}..{b:.6g} mapped onto 0..65535" in s.start_record["pixel_conversion"]


def test_float_folder_and_non_finite_pixels(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "img").mkdir()
    for i in range(3):
        tifffile.imwrite(
            tmp_path / "img" / f"v{i}.tif", np.full((8, 9), 0.25 * i, np.float32), photometric="minisblack"
        )
    import_folder(tmp_path / "img", tmp_path / "s.h5")
    with Session.open(tmp_path / "s.h5") as s:
        assert [int(s.frame(i)[0, 0]) for i in range(3)] == [0, 16384, 32768]
    bad = np.ones((8, 9), np.float32)
    bad[2, 5] = np.nan
    tifffile.imwrite(tmp_path / "img" / "v1.tif", bad, photometric="minisblack")
    assert main(["-q", "import", str(tmp_path / "img"), "-o", str(tmp_path / "t.h5")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "v1.tif: 1 NaN or infinite pixel(s) (first at index (2, 5))" in err
    assert not (tmp_path / "t.h5").exists()


def test_integer_types_beyond_16_bit(tmp_path: Path) -> None:
    ok = np.arange(3 * 4 * 5, dtype=np.int32).reshape(3, 4, 5) * 1000
    tifffile.imwrite(tmp_path / "i32.tif", ok, photometric="minisblack")
    import_folder(tmp_path / "i32.tif", tmp_path / "s.h5")
    with Session.open(tmp_path / "s.h5") as s:
        assert s.dtype == np.uint16
        np.testing.assert_array_equal(s.projections(), ok)
    tifffile.imwrite(tmp_path / "neg.tif", ok - 1, photometric="minisblack")
    with pytest.raises(ImportDataError, match=r"neg\.tif: int32 pixels span -1\.\.58999; expected 0\.\.65535"):
        import_folder(tmp_path / "neg.tif", tmp_path / "t.h5")


def test_a_crop_without_its_offset_names_roi_offset(tmp_path: Path) -> None:
    (tmp_path / "img").mkdir()
    for i, f in enumerate(_frames(3, (20, 30), np.uint8)):
        cv2.imwrite(str(tmp_path / "img" / f"v{i}.png"), f)
    # A rig whose camera.roi is not the images' size: where do the images sit on its 1024 x 1024 sensor?
    with pytest.raises(
        ImportDataError, match=r"the images are 30 x 20 px, but the config's camera.roi is 1024 x 250.*--roi-offset X Y"
    ):
        import_folder(tmp_path / "img", tmp_path / "s.h5", config=load_config(CONFIG_DIR / "guo2019-zebrafish.yaml"))
    # Cameras given for the full sensor (principal point (15, 500)) of images cropped from it.
    rows = []
    for k in range(3):
        a = 2 * np.pi * k / 3
        R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        P = np.array([[1000.0, 0, 15], [0, 1000.0, 500], [0, 0, 1]]) @ np.c_[R, [0.0, 0.0, 1000.0]]
        rows.append(f"v{k} " + " ".join(f"{x:.12g}" for x in P.ravel()))
    (tmp_path / "cams.txt").write_text("\n".join(rows) + "\n")
    with pytest.raises(
        ImportDataError,
        match=r"cams.txt put the principal point at \(15.0, 500.0\) px, outside the 30 x 20 px images.*--roi-offset",
    ):
        import_folder(tmp_path / "img", tmp_path / "s.h5", cameras=tmp_path / "cams.txt")
    import_folder(
        tmp_path / "img", tmp_path / "s.h5", cameras=tmp_path / "cams.txt", settings=ImportSettings(roi_offset=(0, 490))
    )
    with Session.open(tmp_path / "s.h5") as s:
        assert s.roi_offset_px == (0, 490)
    assert "pixel size unknown (the imported cameras set the scale)" in format_summary(
        session_summary(tmp_path / "s.h5")
    )


def test_zebrafish_crop_without_its_offset_names_roi_offset(zebrafish_dir: Path, tmp_path: Path) -> None:
    """The zebrafish frames are rows 388-637 of the 1024 x 1024 sensor its cameras were given for."""
    cams = zebrafish_dir / "authors_par_pi.txt"
    with pytest.raises(
        ImportDataError,
        match=r"principal point at \(511.0, 511.0\) px, outside the 1024 x 250 px images.*--roi-offset X Y",
    ):
        import_folder(zebrafish_dir / "images", tmp_path / "a.h5", cameras=CameraFile(cams, pixel_origin=1))
    import_folder(
        zebrafish_dir / "images",
        tmp_path / "b.h5",
        cameras=CameraFile(cams, pixel_origin=1),
        config=load_config(CONFIG_DIR / "guo2019-zebrafish.yaml"),
        settings=ImportSettings(name="ZF1"),
    )
    with Session.open(tmp_path / "b.h5") as s:
        assert s.roi_offset_px == (0, 387) and s.pixel_size_um == pytest.approx((5.5, 5.5)) and _title(s) == "ZF1"


def test_cli_import_options(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    tifffile.imwrite(tmp_path / "rev.tif", _frames(3), photometric="minisblack")
    assert main(["-q", "import", str(tmp_path / "rev.tif"), "-o", str(tmp_path / "a.h5")]) == 0
    assert "pixel size unknown - measurements in pixels" in capsys.readouterr().out
    assert (
        main(
            [
                "-q",
                "import",
                str(tmp_path / "rev.tif"),
                "-o",
                str(tmp_path / "b.h5"),
                "--pixel-size-um",
                "0.8",
                "--name",
                "L7",
            ]
        )
        == 0
    )
    assert "pixel size unknown" not in capsys.readouterr().out
    with Session.open(tmp_path / "b.h5") as s:
        assert s.pixel_size_um == pytest.approx((0.8, 0.8)) and _title(s) == "L7"
    assert main(["-q", "import", str(tmp_path / "rev.tif"), "-o", str(tmp_path / "c.h5"), "--pixel-size-um", "-1"]) == 2
    assert "--pixel-size-um" in capsys.readouterr().err


def test_a_world_in_pixels_is_measured_and_labelled_in_pixels() -> None:
    from vastcal.hull import cameras_in_um
    from vastcal.measure import Measurement, MeasureSettings, Mesh

    P = np.arange(24, dtype=float).reshape(2, 3, 4)
    same, unit = cameras_in_um(P, "px")
    assert unit == "px" and np.array_equal(same, P)
    mesh = Mesh(np.zeros((3, 3)), np.array([[0, 1, 2]], np.int32))
    m = Measurement(
        volume_mm3=2e-3,
        mesh_volume_mm3=2e-3,
        surface_area_mm2=3e-2,
        raw_surface_area_mm2=3e-2,
        n_inside_voxels=10,
        voxel_size_um=1.5,
        n_views=12,
        iso_level=11.5,
        settings=MeasureSettings(),
        mesh=mesh,
        provenance={"length_unit": "px"},
    )
    text = m.summary()
    assert "volume        2e+06 px^3" in text and "surface area  30000 px^2" in text and "mm^3" not in text
    assert "pixel size unknown - measurements in pixels" in text and "--pixel-size-um" in text
