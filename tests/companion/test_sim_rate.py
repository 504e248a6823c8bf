"""The sim-rate estimate (companion.vehicle.sim_rate): late bursts cannot fool it."""

from __future__ import annotations

import random

import pytest

from companion.vehicle.sim_rate import SimRateEstimator, envelope_at, upper_envelope


def feed(est: SimRateEstimator, points):
    for wall, sim in points:
        est.add(wall, sim)


def steady(rate: float, wall0: float, wall1: float, hz: float = 80.0, sim0: float = 0.0):
    """Stamps of a clock at ``rate`` seen the moment they are sent: (wall, sim) pairs."""
    n = int((wall1 - wall0) * hz)
    return [(wall0 + i / hz, sim0 + rate * i / hz) for i in range(n)]


def test_a_steady_clock_gives_its_rate_and_none_before_the_window_spans_enough():
    est = SimRateEstimator()
    feed(est, steady(4.0, 0.0, 1.0))
    assert est.rate is None  # one second of wall is not enough to say
    feed(est, steady(4.0, 1.0, 5.0, sim0=4.0))
    assert est.rate == pytest.approx(4.0, rel=1e-9)


@pytest.mark.parametrize("stall_s", [1.0, 2.5, 70.0])
def test_the_backlog_of_a_stalled_loop_read_in_a_burst_does_not_raise_the_rate(stall_s):
    """The loop stood still (70 s of wall, at 4x, in a pre-flight re-plan), then read all the
    stamps sent meanwhile in half a second."""
    est = SimRateEstimator()
    feed(est, steady(4.0, 0.0, 10.0))  # fresh: 4x
    assert est.rate == pytest.approx(4.0)
    n = int(80 * stall_s)
    end = 10.0 + stall_s + 0.5
    backlog = [(10.0 + stall_s + 0.5 * k / n, 40.0 + 4.0 * (stall_s + 0.5) * k / n) for k in range(n)]
    for wall, sim in backlog + steady(4.0, end, end + 20.0, sim0=4.0 * end):
        est.add(wall, sim)
        assert 3.5 < est.rate < 4.5, (wall, sim, est.rate)
    assert est.rate == pytest.approx(4.0, rel=1e-3)


def test_the_old_smoothing_would_have_read_the_burst_as_a_fast_clock():
    """What the estimate replaces: two arrivals 0.2 s of wall apart inside the burst span 110 s
    of stamps, a rate of 560 (the take-off bound then came out at 6.66 s of wall at 4x)."""
    backlog = [(80.0 + 0.5 * k / 5600, 40.0 + 280.0 * k / 5600) for k in range(5600)]
    (w0, s0), (w1, s1) = backlog[0], backlog[2240]
    assert (s1 - s0) / (w1 - w0) > 100


def test_jittery_late_arrivals_of_a_busy_machine_keep_the_rate():
    rng = random.Random(7)
    est = SimRateEstimator()
    pts = []
    for i in range(2000):  # 25 s at 80 Hz, each seen 0-200 ms late, often in clumps
        sim = 20.0 * i / 80.0
        late = rng.choice([0.0, 0.0, rng.uniform(0, 0.2), rng.uniform(0.1, 0.2)])
        pts.append((i / 80.0 + late, sim))
    pts.sort()
    wall_mono, sims = [], []
    for wall, sim in pts:  # delivered in order of arrival, stamps kept monotonic as one link does
        if sims and sim < sims[-1]:
            continue
        wall_mono.append(wall)
        sims.append(sim)
    feed(est, zip(wall_mono, sims))
    assert est.rate == pytest.approx(20.0, rel=0.05)


def test_a_slower_clock_is_followed_within_a_window_and_a_reboot_restarts():
    est = SimRateEstimator()
    feed(est, steady(4.0, 0.0, 12.0))
    feed(est, steady(2.0, 12.0, 30.0, sim0=48.0))  # the loaded machine slowed PX4 down
    assert est.rate == pytest.approx(2.0, rel=1e-3)
    est.add(30.1, 1.0)  # the clock went back: a reboot
    assert est.rate is None


def test_upper_envelope_lies_on_or_above_every_point():
    rng = random.Random(3)
    pts = sorted((rng.uniform(0, 10), rng.uniform(0, 10)) for _ in range(200))
    hull = upper_envelope(pts)
    assert hull[0] == pts[0] and hull[-1] == pts[-1]
    for x, y in pts:
        assert envelope_at(hull, x) >= y - 1e-9
