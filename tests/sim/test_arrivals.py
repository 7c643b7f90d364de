"""Arrivals: Poisson with a 1 s headway floor, common random numbers, queues that never drop."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.arrivals import ArrivalProcess
from mivecc_env.sim.core import Simulator
from tests.sim._scenario import EAST


def drain(proc: ArrivalProcess, env: int, lane: int) -> list[float]:
    """Pop every queued vehicle of one lane, returning its arrival times in queue order."""
    out = []
    mask = np.zeros((proc.batch, proc.n_lanes), dtype=bool)
    mask[env, lane] = True
    while proc.queued[env, lane] > 0:
        out.append(float(proc.head_arrival_time()[env, lane]))
        proc.pop(mask)
    return out


def test_rate_with_headway_floor() -> None:
    # 900 veh/h: exponential gaps of mean 4 s, floored at 1 s. E[max(1, X)] = 1 + 4 e^-0.25
    # = 4.1152 s, so 3600 s give 874.8 arrivals per lane, 10497.7 on 12 lanes.
    # Var[max(1, X)] = 1 + e^-0.25 (2*4 + 2*16) - 4.1152^2 = 15.217 s^2; the renewal count
    # has variance t Var / mean^3 = 786 per lane, so sd = sqrt(12 * 786) = 97 on 12 lanes.
    proc = ArrivalProcess(1, 12, 900.0, 1.0)
    proc.reset([np.random.SeedSequence(2024)])
    proc.advance(3600.0)
    total = int(proc.arrived.sum())
    assert abs(total - 10497.7) < 4 * 97
    assert proc.queued.sum() == total  # nobody entered: everybody is still queued


def test_rate_without_floor_is_poisson() -> None:
    # floor 0: 12 lanes x 900 veh/h x 1 h = 10800, Poisson sd sqrt(10800) = 104
    proc = ArrivalProcess(1, 12, 900.0, 0.0)
    proc.reset([np.random.SeedSequence(7)])
    proc.advance(3600.0)
    assert abs(int(proc.arrived.sum()) - 10800) < 4 * 104


def test_headway_floor_and_queue_growth() -> None:
    # 2100 veh/h for 600 s with nobody entering: ~300 per lane, beyond the initial 256-slot
    # ring buffer, so the buffer must grow without losing or reordering anyone
    proc = ArrivalProcess(2, 4, 2100.0, 1.0)
    proc.reset([np.random.SeedSequence(1), np.random.SeedSequence(2)])
    proc.advance(600.0)
    assert proc.times.shape[2] > 256
    for env in range(2):
        for lane in range(4):
            n = int(proc.arrived[env, lane])
            times = np.array(drain(proc, env, lane))
            assert times.size == n > 200
            assert times[0] >= 1.0  # the first gap is floored too
            assert np.all(np.diff(times) >= 1.0 - 1e-9)
            assert times[-1] <= 600.0
    assert proc.queued.sum() == 0


def test_stream_does_not_depend_on_pop_timing() -> None:
    # popping early (small queues) or late (one big queue) yields the same arrival times
    def times(pop_every: float) -> list[float]:
        proc = ArrivalProcess(1, 1, 1800.0, 1.0)
        proc.reset([np.random.SeedSequence(5)])
        out: list[float] = []
        t = 0.0
        while t < 400.0:
            t += pop_every
            proc.advance(t)
            out += drain(proc, 0, 0)
        return out

    early, late = times(0.1), times(400.0)
    assert early == late
    assert len(early) > 100


def test_different_seeds_differ() -> None:
    a = ArrivalProcess(1, 4, 900.0, 1.0)
    a.reset([np.random.SeedSequence(1)])
    b = ArrivalProcess(1, 4, 900.0, 1.0)
    b.reset([np.random.SeedSequence(2)])
    a.advance(300.0)
    b.advance(300.0)
    assert drain(a, 0, 0) != drain(b, 0, 0)


def test_lanes_have_independent_streams() -> None:
    proc = ArrivalProcess(1, 2, 900.0, 1.0)
    proc.reset([np.random.SeedSequence(3)])
    proc.advance(300.0)
    assert drain(proc, 0, 0) != drain(proc, 0, 1)


def test_seed_count_checked() -> None:
    proc = ArrivalProcess(2, 4, 900.0, 1.0)
    with pytest.raises(ValueError, match="seeds"):
        proc.reset([1])


def _lane_arrivals(config: MiVeCCConfig, steps: int, seed: int,
                   edge: float | None = None) -> tuple[np.ndarray, dict[int, list[float]]]:
    """(B, lanes) arrival counts after each step and the t_arrive of entering vehicles."""
    sim = Simulator(config, seed=seed)
    counts = []
    entered: dict[int, list[float]] = {lane: [] for lane in range(sim.network.n_lanes)}
    seen: set[int] = set()
    rng = np.random.default_rng(0)
    for _ in range(steps):
        action = None if edge is None else rng.uniform(-3, 3, (1, sim.capacity))
        sim.step(action, action)
        counts.append(sim.arrivals.arrived.copy())
        m = sim.active[0]
        for vid, lane, t in zip(sim.vid[0, m], sim.lane[0, m], sim.t_arrive[0, m], strict=True):
            if vid not in seen:
                seen.add(int(vid))
                entered[int(lane)].append(float(t))
    return np.array(counts), entered


def test_common_random_numbers_across_schemes() -> None:
    # the same seed and density give the same arrivals whatever the vehicles do
    base = MiVeCCConfig(rows=1, cols=1, density_vplh=1500)
    other = base.replace(scheme="EEC", end_rule="literal", same_lane_rule=True)
    counts_a, entered_a = _lane_arrivals(base, 600, seed=11)
    counts_b, entered_b = _lane_arrivals(other, 600, seed=11, edge=1.0)
    np.testing.assert_array_equal(counts_a, counts_b)
    for lane in entered_a:
        k = min(len(entered_a[lane]), len(entered_b[lane]))
        assert k > 5
        assert entered_a[lane][:k] == entered_b[lane][:k]
    counts_c, _ = _lane_arrivals(base, 600, seed=12)
    assert not np.array_equal(counts_a, counts_c)


def test_blocked_entry_queues_and_never_drops() -> None:
    # A vehicle held at s = 5 m on the eastbound lane blocks its entry (clearance 10 m) for
    # 100 s: the queue grows; once released, the queue drains first in, first out, every
    # vehicle with its own arrival time.
    cfg = MiVeCCConfig(rows=1, cols=1, density_vplh=2100)
    sim = Simulator(cfg, seed=3)
    # the lane's arrival times from an independent process with the same stream
    ref = ArrivalProcess(1, sim.network.n_lanes, 2100.0, 1.0)
    ref.reset(sim._seed_sequences(3))
    ref.advance(400.0)
    expected = drain(ref, 0, EAST)

    sim.active[0, 0], sim.lane[0, 0], sim.vid[0, 0] = True, EAST, -99
    queue = []
    for _ in range(1000):
        sim.s[0, 0], sim.v[0, 0] = 5.0, 10.0
        sim._refresh_view()
        sim.step()
        assert sim.active[0, 0]  # nothing entered behind it, nothing hit it
        queue.append(int(sim.arrivals.queued[0, EAST]))
    assert queue[-1] > 30
    assert all(b >= a for a, b in itertools.pairwise(queue))  # only grows
    assert sim.arrivals.entered[0, EAST] == 0

    sim.active[0, 0] = False  # release the entry
    sim._refresh_view()
    times: dict[int, float] = {}
    for _ in range(2000):
        sim.step()
        m = sim.active[0] & (sim.lane[0] == EAST)
        for vid, t in zip(sim.vid[0, m], sim.t_arrive[0, m], strict=True):
            times.setdefault(int(vid), float(t))
    entered = [times[v] for v in sorted(times)]
    n = int(sim.arrivals.entered[0, EAST])
    assert n > queue[-1]  # the backlog drained and more came
    assert int(sim.arrivals.queued[0, EAST]) < 5
    # first in, first out, none skipped: a vehicle enters at the end of a step, after the
    # collision check, so each one is seen at least once
    assert len(entered) == n
    assert entered == expected[:n]


def test_arrival_times_are_blocks_of_cumulative_gaps() -> None:
    """The stream is pinned, whatever the draw size: gap i = max(exponential draw i of the
    lane's generator, headway); times accumulate in blocks of 32 (each block: the last time
    before it + the running sum of its gaps), exactly."""
    proc = ArrivalProcess(1, 3, 1800.0, 1.0)
    seed = np.random.SeedSequence(99)
    proc.reset([seed])
    proc.advance(1000.0)  # several draws per lane
    for lane, child in enumerate(np.random.SeedSequence(99).spawn(3)):  # the same children
        n = int(proc.arrived[0, lane])
        assert n > 200
        gaps = np.maximum(np.random.default_rng(child).exponential(2.0, n + 64), 1.0)
        want, last = [], 0.0
        for start in range(0, gaps.size, 32):
            block = last + np.cumsum(gaps[start:start + 32])
            want.extend(block.tolist())
            last = block[-1]
        got = drain(proc, 0, lane)
        assert got == want[:n]
