"""The cost's thread count: VASTCAL_THREADS, else the usable CPUs (bounded); slices all run, errors surface."""

from __future__ import annotations

import pytest

from vastcal import threads


def test_thread_count_comes_from_the_environment_or_the_cpus(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setenv(threads.ENV, "3")
    assert threads.compute_threads() == 3
    monkeypatch.setenv(threads.ENV, "0")
    assert threads.compute_threads() == 1
    monkeypatch.setenv(threads.ENV, "many")
    assert threads.compute_threads() == 1 and "not a whole number" in caplog.text
    monkeypatch.delenv(threads.ENV)
    assert 1 <= threads.compute_threads() <= threads.MAX_THREADS


@pytest.mark.parametrize("n", ["1", "2"])
def test_every_slice_runs_and_an_error_in_one_is_raised(monkeypatch: pytest.MonkeyPatch, n: str) -> None:
    monkeypatch.setenv(threads.ENV, n)
    done: list[int] = []
    threads.run_slices(done.append, range(7))
    assert sorted(done) == list(range(7))

    def fail(i: int) -> None:
        if i == 3:
            raise ValueError("slice 3")

    with pytest.raises(ValueError, match="slice 3"):
        threads.run_slices(fail, range(5))


def test_voxel_sampling_is_the_same_on_threads(monkeypatch: pytest.MonkeyPatch) -> None:
    """The PI and VR objectives' sampler shares a batch's candidates among threads: the same numbers."""
    import numpy as np

    from vastcal.calibrate.sampling import Atlas, Projector

    rng = np.random.default_rng(1)
    K = np.array([[800.0, 0.0, 64.0], [0.0, 800.0, 32.0], [0.0, 0.0, 1.0]])
    atlas = Atlas.from_stack(rng.random((8, 64, 128), dtype=np.float32))
    proj = Projector(K, 50_000.0, rng.uniform(-300.0, 300.0, (5000, 3)))
    theta = np.concatenate([[0.1, -0.2, 0.05], np.arange(8) * 45.0])[None] + rng.normal(0.0, 0.3, (7, 11))
    got = {}
    for n in ("1", "3"):
        monkeypatch.setenv(threads.ENV, n)
        got[n] = proj.sample(atlas, theta)
    assert np.array_equal(got["1"], got["3"])
