"""The cost's thread count: VASTCAL_THREADS, else the usable CPUs (bounded); slices all run, errors surface."""

from __future__ import annotations

import pytest

from vastcal.calibrate import threads


def test_thread_count_comes_from_the_environment_or_the_cpus(monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
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
