"""TIFFs as labs write them: LZW, Deflate, JPEG and PackBits stacks, 1-bit masks (CCITT, WhiteIsZero), and a
truncated file refused in one line with nothing printed by tifffile."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

tifffile = pytest.importorskip("tifffile")
pytest.importorskip("imagecodecs", reason="imagecodecs (a dependency of vastcal) decodes compressed TIFFs")

from vastcal.cli import main  # noqa: E402
from vastcal.errors import ImportDataError  # noqa: E402
from vastcal.image_files import read_tiff  # noqa: E402
from vastcal.importer import CameraFile, ImportSettings, import_folder  # noqa: E402
from vastcal.session import Session  # noqa: E402

MAX_PIXELS = 16384 * 16384


def _stack(n: int = 3, shape: tuple[int, int] = (64, 96)) -> np.ndarray:
    """A smooth stack (JPEG keeps it within a few grey levels) with a bright blob that moves per view."""
    y, x = np.mgrid[: shape[0], : shape[1]]
    return np.stack(
        [(60 + 0.5 * x + 120 * (((x - 20 - 20 * k) ** 2 + (y - 32) ** 2) < 150)).astype(np.uint8) for k in range(n)]
    )


@pytest.mark.parametrize("compression", ["lzw", "adobe_deflate", "deflate", "packbits", "jpeg"])
def test_compressed_stacks_are_read_view_by_view(compression: str, tmp_path: Path) -> None:
    frames = _stack()
    tifffile.imwrite(tmp_path / "s.tif", frames, photometric="minisblack", compression=compression)
    with tifffile.TiffFile(tmp_path / "s.tif") as tif:
        assert (
            tif.pages[0].compression.name.lower().replace("_", "")
            in {
                "lzw": "lzw",
                "adobe_deflate": "adobedeflate",
                "deflate": "deflate",
                "packbits": "packbits",
                "jpeg": "jpeg",
            }[compression]
        )
    views, _ = read_tiff(tmp_path / "s.tif", MAX_PIXELS)
    assert views.shape == frames.shape and views.dtype == np.uint8
    if compression == "jpeg":  # lossy
        assert np.abs(views.astype(int) - frames).mean() < 3
    else:
        np.testing.assert_array_equal(views, frames)


@pytest.mark.parametrize("photometric", ["minisblack", "miniswhite"])
def test_a_one_bit_mask_is_read_as_it_is_displayed(photometric: str, tmp_path: Path) -> None:
    """1-bit masks become 0/255: white (255) where the image is white, whichever way its bits count."""
    white = _stack(1)[0] > 150  # the blob
    bits = white if photometric == "minisblack" else ~white
    tifffile.imwrite(tmp_path / "m.tif", bits, photometric=photometric)
    views, _ = read_tiff(tmp_path / "m.tif", MAX_PIXELS)
    assert views.dtype == np.uint8 and set(np.unique(views)) == {0, 255}
    np.testing.assert_array_equal(views[0] == 255, white)


def test_the_ccitt_mask_of_the_second_larva_is_imported(zebrafish2_dir: Path, tmp_path: Path) -> None:
    """silhouettes/081.tif is a 1-bit CCITT RLE WhiteIsZero image among 8-bit PackBits masks: imported with them."""
    with tifffile.TiffFile(zebrafish2_dir / "silhouettes" / "081.tif") as tif:
        page = tif.pages[0]
        assert page.compression == 2 and page.bitspersample == 1 and page.photometric == 0  # CCITT RLE, WhiteIsZero
    out = tmp_path / "zf2.h5"
    import_folder(
        zebrafish2_dir / "images",
        out,
        masks=zebrafish2_dir / "silhouettes",
        cameras=CameraFile(zebrafish2_dir / "authors_par_pi.txt", pixel_origin=1),
        settings=ImportSettings(roi_offset=(0, 387)),
    )
    with Session.open(out) as s:
        masks = np.asarray(s.masks)
    assert masks.shape == (21, 250, 1024) and masks.dtype == np.uint8
    last = masks[-1] > 0
    assert set(np.unique(masks[-1])) == {0, 255}
    assert 0.10 < last.mean() < 0.14  # the larva, not its background (88 % of the bits are set)
    neighbour = masks[-2] > 0  # 077.tif, an 8-bit PackBits mask of the neighbouring view
    assert (last & neighbour).sum() / (last | neighbour).sum() > 0.6


def test_a_truncated_tiff_is_one_error_line_and_tifffile_prints_nothing(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    tifffile.imwrite(tmp_path / "full.tif", _stack(), photometric="minisblack", compression="lzw")
    data = (tmp_path / "full.tif").read_bytes()
    (tmp_path / "cut.tif").write_bytes(data[: len(data) // 2])  # the later pages' directories are gone
    with pytest.raises(ImportDataError, match=r"cut\.tif: cannot read this TIFF: damaged or truncated \(invalid page"):
        read_tiff(tmp_path / "cut.tif", MAX_PIXELS)
    capfd.readouterr()
    assert main(["-q", "import", str(tmp_path / "cut.tif"), "-o", str(tmp_path / "s.h5")]) == 2
    out = capfd.readouterr()
    lines = (out.err + out.out).strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vastcal: error: ") and "cut.tif" in lines[0], lines
    assert "tifffile" not in lines[0] and not (tmp_path / "s.h5").exists()
