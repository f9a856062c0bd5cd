"""The one timing helper: seconds per stage summed over its runs, stages in the order they first ran, the total
last. A fake clock makes the sums exact; the real clock is checked for ordering and signs only."""

import itertools

import pytest

from rpmnet_jax import stopwatch


@pytest.fixture()
def fake_clock(monkeypatch):
    """``time.perf_counter`` as seen by the stopwatch: 0, 1, 2, ... one tick per call."""
    ticks = itertools.count()
    monkeypatch.setattr(stopwatch.time, "perf_counter", lambda: float(next(ticks)))


def test_stages_are_summed_in_the_order_they_first_ran(fake_clock):
    clock = stopwatch.Stopwatch()  # tick 0
    with clock.stage("prepare"):  # ticks 1, 2
        pass
    with clock.stage("refine"):  # ticks 3, 4
        pass
    with clock.stage("prepare"):  # ticks 5, 6
        pass
    with pytest.raises(RuntimeError), clock.stage("score"):  # ticks 7, 8: counted though it raised
        raise RuntimeError("boom")
    assert clock.seconds == {"prepare": 2.0, "refine": 1.0, "score": 1.0}
    assert list(clock.seconds) == ["prepare", "refine", "score"]
    timings = clock.timings()  # tick 9
    assert list(timings) == ["prepare", "refine", "score", "total"] and timings["total"] == 9.0


def test_the_real_clock_gives_non_negative_seconds():
    clock = stopwatch.Stopwatch()
    with clock.stage("a"):
        sum(range(1000))
    with clock.stage("b"):
        pass
    timings = clock.timings()
    assert list(timings) == ["a", "b", "total"]
    assert all(v >= 0.0 for v in timings.values()) and clock.cpu_elapsed() >= 0.0
    assert timings["total"] >= timings["a"] + timings["b"]  # the stages ran inside the stopwatch's life
