"""The comparators' entry rule (``comparator_entry``): "stop_clearance" (default) and "slowed"
(MiVeCC's clearance, entering slower where the lane's last vehicle is close)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from mivecc_agents.evaluation import evaluate_scheme
from mivecc_env import mivecc_v0
from mivecc_env.config import ConfigError, from_overrides
from mivecc_env.sim import signals


def test_clearance_and_speed_of_each_rule() -> None:
    c = from_overrides(None, control="signalized")
    assert c.comparator_entry == "stop_clearance"
    assert signals.entry_clearance_m(c) == pytest.approx(29.0)  # 10^2 / 4 + 2 + 2
    slowed = from_overrides(None, control="signalized", comparator_entry="slowed")
    assert signals.entry_clearance_m(slowed) == 10.0  # MiVeCC's entry_clearance_m
    no_check = from_overrides(None, control="reservation", comparator_entry="slowed",
                              entry_clearance_m=0.0)
    assert signals.entry_clearance_m(no_check) == 4.0  # never closer than gap + length
    speed = signals.entry_speed(slowed, np.array([np.inf, 40.0, 10.0, 4.0, 3.0]))
    np.testing.assert_allclose(speed, [10.0, 10.0, np.sqrt(2 * 2.0 * 6.0), 0.0, 0.0])
    with pytest.raises(ConfigError, match="comparator_entry"):
        from_overrides(None, comparator_entry="fast")


def _entries(entry: str, control: str = "signalized", steps: int = 1500):
    """(entry speeds, room to stop at entry [m], backlog, collisions) of a 1x1 run at 2100
    veh/lane/h, seed 0: every vehicle's speed when it appeared and the distance it had to the
    nearest vehicle of its lane minus its length and the standstill gap."""
    env = mivecc_v0.parallel_env(rows=1, cols=1, density=2100, max_steps=steps,
                                 control=control, comparator_entry=entry)
    env.reset(seed=0)
    sim, c = env.batched.sim, env.config
    seen: set[int] = set(sim.vid[0][sim.active[0]].tolist())
    speeds, rooms = [], []
    for _ in range(steps):
        env.step({})
        act = sim.active[0]
        for k in np.flatnonzero(act):
            vid = int(sim.vid[0, k])
            if vid in seen:
                continue
            seen.add(vid)
            others = act & (sim.lane[0] == sim.lane[0, k]) & (np.arange(act.size) != k)
            nearest = sim.s[0][others].min() if others.any() else np.inf
            speeds.append(float(sim.v[0, k]))
            rooms.append(nearest - c.vehicle_length_m - c.idm_min_gap_m)
    summary = env.batched.summary()
    return (np.array(speeds), np.array(rooms), int(summary["backlog"][0]),
            int(summary["collisions"][0]))


def test_slowed_entries_can_always_stop_and_let_more_vehicles_in() -> None:
    c = from_overrides(None)
    speeds, rooms, backlog, collisions = _entries("slowed")
    assert speeds.size > 200  # of about 350 arrivals
    assert (speeds <= c.v_init_mps).all()
    assert (speeds < c.v_init_mps - 1.0).sum() > 20  # into a short gap, slower
    # from its entry speed it stops at the comfortable deceleration behind the lane's last
    # vehicle (standing, the worst case)
    assert (speeds**2 / (2 * c.idm_comfort_decel_mps2) <= rooms + 1e-9).all()
    assert collisions == 0
    old_speeds, old_rooms, old_backlog, _ = _entries("stop_clearance")
    assert (old_speeds == c.v_init_mps).all() and (old_rooms >= 25.0 - 1e-9).all()
    assert backlog < old_backlog and speeds.size > old_speeds.size


def test_mivecc_runs_ignore_the_rule() -> None:
    kw = {"rows": 1, "cols": 1, "density": 2100, "steps": 600, "seed": 0, "progress": False}
    keys = ("avg_travel_velocity_mps", "throughput", "backlog", "collisions", "min_pet_s")
    runs = [evaluate_scheme("E", comparator_entry=e, **kw) for e in ("stop_clearance", "slowed")]
    assert [runs[0][k] for k in keys] == [runs[1][k] for k in keys]
    assert runs[1]["comparator_entry"] == "slowed"  # reported with the result


_DIGEST = """
import json, sys
from mivecc_agents.evaluation import evaluate_scheme
out = [[evaluate_scheme(s, g, g, 2100, 400, 1, progress=False, comparator_entry="slowed")[k]
        for k in ("avg_travel_velocity_mps", "throughput", "backlog", "collisions", "min_pet_s")]
       for s, g in (("fixed-time", 3), ("reservation", 3), ("optimisation", 1))]
print(json.dumps(out))
"""


@pytest.mark.slow  # about 30 s: the numpy paths of optimisation and reservation
def test_numpy_path_enters_like_the_kernel() -> None:
    runs = []
    for no_numba in ("0", "1"):
        env = {**os.environ, "MIVECC_NO_NUMBA": no_numba} if no_numba == "1" else {
            k: v for k, v in os.environ.items() if k != "MIVECC_NO_NUMBA"}
        done = subprocess.run([sys.executable, "-c", _DIGEST], env=env, capture_output=True,
                              text=True, timeout=600, check=True)
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    assert runs[0] == runs[1]
