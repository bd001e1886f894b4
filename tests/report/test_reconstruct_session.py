"""reconstruct_session: inputs chosen from the session, runs stored with units, errors that name the command."""

from __future__ import annotations

import sys
import types
from pathlib import Path

import h5py
import numpy as np
import pytest

from vastcal.cli import main
from vastcal.errors import MissingStageError, UserInputError
from vastcal.measure import read_ply
from vastcal.reconstruct import reconstruct_session
from vastcal.session import Session, read_attrs


def test_runs_are_stored_with_units_and_provenance(measured_session: Path, small_views: object) -> None:
    with Session.open(measured_session) as s:
        assert s.stages_run()["reconstruction"] == ["run_000"] and s.stages_run()["measurement"] == ["run_000"]
        rec, meas = s.latest_result("reconstruction"), s.latest_result("measurement")
        ra, ma = read_attrs(rec), read_attrs(meas)
        assert rec["counts"].dtype == np.uint8 and rec["grid_origin_um"].attrs["units"] == "um"
        assert ra["calibration_run"] == "run_000" and ra["n_views"] == 9 and ra["voxel_size_um"] > 0
        assert meas["volume_mm3"].attrs["units"] == "mm^3" and meas["surface_area_mm2"].attrs["units"] == "mm^2"
        assert ma["volume_mm3"] == pytest.approx(float(meas["volume_mm3"][()]))
        assert ma["provenance"]["reconstruction_run"] == "run_000" and ma["provenance"]["calibration_run"] == "run_000"
        assert ma["provenance"]["silhouette_source"] == "masks (imported)"  # the fake calibration has no colour model
        assert meas["mesh"]["vertices"].attrs["units"] == "um"
        assert s.frame(0).shape == (160, 512)  # images untouched
    hull_truth = small_views.hull_volume_mm3  # type: ignore[attr-defined]
    assert ma["volume_mm3"] == pytest.approx(hull_truth, rel=0.03)  # binary masks, coarse grid, 9 views


def test_imported_cameras_and_a_mesh_file(session_factory, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    path = session_factory(masks=True, cameras=True)
    m = reconstruct_session(path, voxel_size_um=25.0, mesh_path=tmp_path / "fish.ply")
    assert m.voxel_size_um == pytest.approx(25.0)
    assert m.provenance["camera_source"] == "cameras (imported)" and m.provenance["calibration_run"] is None
    assert read_ply(tmp_path / "fish.ply").n_faces == m.mesh.n_faces


def test_no_cameras_names_the_calibrate_command(session_factory) -> None:  # type: ignore[no-untyped-def]
    path = session_factory(masks=True, cameras=False)
    with pytest.raises(MissingStageError, match=r"run 'vastcal calibrate .*s0\.h5' first"):
        reconstruct_session(path)
    assert main(["reconstruct", str(path)]) == 1


def test_bad_arguments_are_user_errors(session_factory, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    path = session_factory(masks=False, cameras=True)
    with pytest.raises(UserInputError, match="holds no masks"):
        reconstruct_session(path, use_masks=True)
    with pytest.raises(MissingStageError, match="no silhouettes"):
        reconstruct_session(path)
    with pytest.raises(UserInputError, match="no calibration run 'run_007'"):
        reconstruct_session(path, calibration_run="run_007")
    with pytest.raises(UserInputError, match="positive"):
        reconstruct_session(path, voxel_size_um=-1.0)
    with pytest.raises(UserInputError, match=r"\.ply or \.stl"):
        reconstruct_session(path, mesh_path=tmp_path / "x.obj")


def test_silhouettes_from_the_calibration_colour_model(
    session_factory, monkeypatch: pytest.MonkeyPatch, small_views: object
) -> None:  # type: ignore[no-untyped-def]
    """The calibration engineer's contract: ColourModel.from_group(g).foreground_probability(images) → (N, H, W)."""
    path = session_factory(masks=False, cameras=False, calibration=True)
    with h5py.File(path, "a") as f:  # test set-up: mark the stored calibration run as having a colour model
        f["/entry/vastcal/calibration/run_000"].create_group("colour_model")

    class FakeModel:
        @classmethod
        def from_group(cls, group: object) -> FakeModel:
            return cls()

        def foreground_probability(self, images: np.ndarray) -> np.ndarray:
            return np.clip((230.0 - images.astype(np.float32)) / 150.0, 0, 1)  # inverts the session's frames

    mod = types.ModuleType("vastcal.segmentation.colour_models")
    mod.ColourModel = FakeModel  # type: ignore[attr-defined]
    import vastcal.segmentation.probability_maps as probability_maps  # the real grouping: how many views at once

    monkeypatch.setitem(sys.modules, "vastcal.segmentation.colour_models", mod)
    monkeypatch.setattr(  # no static blobs here
        probability_maps, "specimen_maps", lambda model, images, **kw: model.foreground_probability(images)
    )
    m = reconstruct_session(path, target_voxels=300_000)
    assert m.provenance["silhouette_source"].startswith("colour_model of calibration/run_000")
    assert m.volume_mm3 == pytest.approx(small_views.hull_volume_mm3, rel=0.03)  # type: ignore[attr-defined]


def test_an_empty_hull_names_the_session_file(session_factory) -> None:  # type: ignore[no-untyped-def]
    import h5py

    from vastcal.errors import EmptyHullError
    from vastcal.session import VASTCAL

    path = session_factory(masks=True, cameras=True)
    with h5py.File(path, "a") as f:
        f[VASTCAL]["masks"][2] = 0  # one view sees nothing: every voxel is carved away
    with pytest.raises(EmptyHullError) as info:
        reconstruct_session(path)
    assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value)
