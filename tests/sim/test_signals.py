"""Signalized baseline: fixed-time heads, stopping at red, moving on green, no collisions."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import signals
from mivecc_env.sim.core import Simulator

CFG = MiVeCCConfig(rows=1, cols=1, control="signalized", density_vplh=600)
# stop line: 5 + 2 + 1 = 8 m before the centre at s = 150 on every lane of the 1x1 grid
LINE = 142.0


def test_stop_line_offset() -> None:
    assert signals.stop_line_offset_m(CFG) == 8.0


@pytest.mark.parametrize(
    ("t", "ew", "ns"),
    [
        # green 30, yellow 3, all-red 2: half-cycle 35 s, cycle 70 s
        (0.0, signals.GREEN, signals.RED),
        (29.9, signals.GREEN, signals.RED),
        (30.0, signals.YELLOW, signals.RED),
        (33.0, signals.RED, signals.RED),  # all-red
        (35.0, signals.RED, signals.GREEN),
        (65.0, signals.RED, signals.YELLOW),
        (68.5, signals.RED, signals.RED),
        (70.0, signals.GREEN, signals.RED),
    ],
)
def test_phase_plan(t: float, ew: int, ns: int) -> None:
    assert signals.phase_states(CFG, t).tolist() == [[ew, ns]]


def test_green_wave_offset() -> None:
    # offset 10 s per (row + col): intersection (0, 1) is 10 s behind (0, 0)
    cfg = MiVeCCConfig(rows=1, cols=2, control="signalized", signal_offset_s=10.0)
    states = signals.phase_states(cfg, 5.0)
    assert states[0].tolist() == [signals.GREEN, signals.RED]
    # local time (5 - 10) mod 70 = 65: east-west red, north-south yellow (65..68)
    assert states[1].tolist() == [signals.RED, signals.YELLOW]


@dataclass
class Recording:
    """What a 2000-step 1x1 signalized run did, step by step."""

    red_crossings: int = 0
    stopped_in_red: int = 0
    min_accel: float = 0.0
    max_accel: float = 0.0
    # vid -> time its head turned green while it was standing before the line
    waiting_at_green: dict[int, float] = field(default_factory=dict)
    # vid -> first time seen past the line (or exited)
    crossed_at: dict[int, float] = field(default_factory=dict)
    sim: Simulator | None = None


@pytest.fixture(scope="module")
def recording() -> Recording:
    rec = Recording()
    sim = Simulator(CFG, seed=0)
    for _ in range(2000):
        t0 = sim.time_s
        before = signals.phase_states(CFG, t0)[0]
        after = signals.phase_states(CFG, t0 + CFG.dt_s)[0]
        m = sim.active[0].copy()
        vid, lane, s0, v0 = sim.vid[0].copy(), sim.lane[0].copy(), sim.s[0].copy(), sim.v[0].copy()
        phase = np.where(lane < 2, 0, 1)  # east/west lanes 0, 1 follow phase 0
        red = before[phase] == signals.RED
        for k in np.flatnonzero(m & red & (v0 < 0.1) & (s0 < LINE)):
            rec.stopped_in_red += 1
            if after[phase[k]] == signals.GREEN:
                rec.waiting_at_green[int(vid[k])] = t0 + CFG.dt_s
        sim.step()
        same = m & sim.active[0] & (sim.vid[0] == vid)
        s1 = sim.s[0]
        rec.red_crossings += int(np.sum(same & red & (s0 < LINE) & (s1 >= LINE)))
        gone = m & ~same  # exited (no collisions expected)
        for k in np.flatnonzero((same & (s0 < LINE) & (s1 >= LINE)) | gone):
            rec.crossed_at.setdefault(int(vid[k]), sim.time_s)
        a = sim.a[0, sim.active[0]]
        if a.size:
            rec.min_accel = min(rec.min_accel, float(a.min()))
            rec.max_accel = max(rec.max_accel, float(a.max()))
    rec.sim = sim
    return rec


def test_vehicles_stop_during_red(recording: Recording) -> None:
    assert recording.stopped_in_red > 100  # vehicle-steps standing before a red line
    assert len(recording.waiting_at_green) >= 4


def test_nobody_crosses_a_red_stop_line(recording: Recording) -> None:
    assert recording.red_crossings == 0


def test_standing_vehicles_move_on_green(recording: Recording) -> None:
    # every vehicle standing at a red line when it turns green crosses within that green (30 s)
    end = 2000 * CFG.dt_s
    checked = 0
    for vid, t_green in recording.waiting_at_green.items():
        if t_green + CFG.signal_green_s > end:
            continue
        assert vid in recording.crossed_at, vid
        assert recording.crossed_at[vid] - t_green < CFG.signal_green_s
        checked += 1
    assert checked >= 4


def test_no_collisions_and_traffic_flows(recording: Recording) -> None:
    sim = recording.sim
    assert sim is not None
    assert sim.collided.tolist() == [0]
    assert sim.collision_events.tolist() == [0]
    # 200 s at 600 veh/lane/h on 4 lanes: about 4 * 200 / 6.4 = 125 arrivals
    assert sim.exited[0] > 60
    np.testing.assert_array_equal(sim.arrived, sim.queued + sim.in_network + sim.exited)
    assert recording.max_accel <= CFG.a_max_mps2 + 1e-9
    assert np.all(sim.v[0, sim.active[0]] >= 0.0)


def test_signalized_acceleration_is_bounded(recording: Recording) -> None:
    assert recording.min_accel >= -CFG.idm_max_decel_mps2 - 1e-9
