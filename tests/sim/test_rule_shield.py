"""The safety shield (``safety_shield``): safe following on every virtual lane, v_min frame."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mivecc_agents.evaluation import evaluate_scheme
from mivecc_env.config import ConfigError, MiVeCCConfig
from mivecc_env.sim import rule_shield
from mivecc_env.sim.core import Simulator
from tests.sim._scenario import EAST, SOUTH, WEST, hand_sim, place

SHIELD = MiVeCCConfig(rows=1, cols=1, safety_shield=True)


def ranks(sim: Simulator) -> np.ndarray:
    return sim.vid.ravel()[sim.view.vehicle]


def caps(vehicles: list[tuple[int, float, float]]) -> np.ndarray:
    sim = hand_sim(SHIELD)
    place(sim, vehicles)
    view = sim.view
    return rule_shield.shield_bounds(view, sim.v.ravel()[view.vehicle], ranks(sim), sim.config)[0]


def test_own_lane_cap_is_the_stopping_point_bound_in_the_vmin_frame() -> None:
    # Follower at 48 m, 13 m/s (u = 7 above v_min = 6); leader at 60 m at v_min (u = 0, it
    # cannot slow down further). The largest a keeps s1 + u1^2 / (2 * 3) = 60 - 3 with
    # u1 = 7 + 0.1 a and s1 = 48 + (7 + u1) / 2 * 0.1:
    # u1^2 / 6 + 0.05 u1 - 8.65 = 0.
    u1 = (-0.05 + math.sqrt(0.05**2 + 4 * 8.65 / 6)) / (2 / 6)
    expected = (u1 - 7.0) / 0.1
    got = caps([(EAST, 48.0, 13.0), (EAST, 60.0, 6.0)])
    assert got[0] == pytest.approx(expected, rel=1e-9)
    assert 0.5 < got[0] < 0.6
    assert got[1] == np.inf  # nothing ahead of the leader


def test_far_leader_does_not_constrain() -> None:
    # Beyond the horizon ((13 - 6)^2 / 6 + 1.3 + 3 = 12.47 m) nothing can bind.
    assert rule_shield.horizon_m(SHIELD) == pytest.approx(49 / 6 + 1.3 + 3.0)
    assert caps([(EAST, 40.0, 13.0), (EAST, 53.0, 6.0)])[0] == np.inf


def test_a_projected_crossing_vehicle_constrains_only_its_follower() -> None:
    # 1x1: east and south lanes cross at s_E = 145, s_S = 155. East is 15 m before the point,
    # south 13 m before: projected onto the east lane 2 m ahead of the east vehicle, closer than
    # the 3 m gap, so east must brake; on the south lane east is 2 m behind: south is free.
    got = caps([(EAST, 130.0, 10.0), (SOUTH, 142.0, 10.0)])
    assert got[0] < -SHIELD.a_max_mps2
    assert got[1] == np.inf
    alone = caps([(EAST, 130.0, 10.0)])
    assert alone[0] == np.inf


@pytest.mark.parametrize("speed", [10.0, 6.0])  # 6 m/s: both at v_min, neither can slow down
def test_a_broken_pair_brakes_the_follower_and_pulls_the_leader(speed: float) -> None:
    sim = hand_sim(SHIELD)
    place(sim, [(EAST, 130.0, speed), (SOUTH, 142.0, speed), (WEST, 60.0, speed)])
    view = sim.view
    v = sim.v.ravel()[view.vehicle]
    cap, pulled = rule_shield.shield_bounds(view, v, ranks(sim), sim.config)
    assert pulled.tolist() == [False, True, False]
    assert cap[0] < -SHIELD.a_max_mps2 and cap[1] == np.inf
    accel = rule_shield.apply_shield(np.array([2.0, -3.0, -1.0]), view, v, ranks(sim), sim.config)
    assert accel.tolist() == [-SHIELD.a_max_mps2, SHIELD.a_max_mps2, -1.0]


def test_a_pulled_vehicle_keeps_its_own_gap_and_pulls_its_leader() -> None:
    # South is pulled by east but has its own leader 6 m ahead at v_min: its own bound wins
    # (it may not close on its leader), and that leader is pulled in turn.
    sim = hand_sim(SHIELD)
    place(sim, [(EAST, 130.0, 10.0), (SOUTH, 142.0, 10.0), (SOUTH, 148.0, 6.0)])
    view = sim.view
    v = sim.v.ravel()[view.vehicle]
    cap, pulled = rule_shield.shield_bounds(view, v, ranks(sim), sim.config)
    assert pulled.tolist() == [False, True, True]
    assert -SHIELD.a_max_mps2 < cap[1] < SHIELD.a_max_mps2 and cap[2] == np.inf
    accel = rule_shield.apply_shield(np.zeros(3), view, v, ranks(sim), sim.config)
    assert accel.tolist() == [-SHIELD.a_max_mps2, cap[1], SHIELD.a_max_mps2]


@pytest.mark.parametrize("order", [(EAST, SOUTH), (SOUTH, EAST)])
def test_a_tie_has_one_leader_on_both_lanes(order: tuple[int, int]) -> None:
    # Both 10 m before their shared conflict point (east's at 145, south's at 155), both at
    # v_min: one point on both virtual lanes. The larger vehicle id (the second placed) leads.
    start = {EAST: 135.0, SOUTH: 145.0}
    sim = hand_sim(SHIELD)
    place(sim, [(lane, start[lane], 6.0) for lane in order])
    view = sim.view
    cap, pulled = rule_shield.shield_bounds(view, sim.v.ravel()[view.vehicle], ranks(sim),
                                            sim.config)
    assert pulled.tolist() == [False, True]
    assert cap[0] < -SHIELD.a_max_mps2 and cap[1] == np.inf


def test_an_unbroken_pair_pulls_nobody() -> None:
    # The same south pair without the east vehicle: south keeps its bound, nobody is pulled.
    sim = hand_sim(SHIELD)
    place(sim, [(SOUTH, 142.0, 10.0), (SOUTH, 148.0, 6.0)])
    view = sim.view
    _, pulled = rule_shield.shield_bounds(view, sim.v.ravel()[view.vehicle], ranks(sim), sim.config)
    assert not pulled.any()


def test_released_rules_at_v_min_no_longer_collide() -> None:
    # Without the pull, two vehicles of this episode travelled 40 steps side by side at the
    # released model's v_min = 5 m/s, 2 m apart on a virtual lane, and collided at step 2743
    # (MiVeCC-E, 3x3, 2100 veh/lane/h, seed 3; benchmarks/trace_collisions.py).
    result = evaluate_scheme("E", 3, 3, 2100, 2800, 3, progress=False, model="released",
                             safety_shield=True)
    assert result["collisions"] == 0
    assert result["min_distance_m"] > 2.0


def test_gap_must_cover_a_crossing_pair() -> None:
    with pytest.raises(ConfigError, match=r"shield_gap_m: must be at least sqrt\(2\)"):
        MiVeCCConfig(safety_shield=True, shield_gap_m=2.5)
    MiVeCCConfig(shield_gap_m=2.5)  # only checked when the shield is on
    with pytest.raises(ConfigError, match="safety_shield: acts on the MiVeCC rules only"):
        MiVeCCConfig(safety_shield=True, control="signalized")
    MiVeCCConfig(vehicle_length_m=3.0)


def plus3_collisions(model: str, shield: bool, steps: int) -> int:
    """Collided vehicles of a 3x3 run at 2100 veh/lane/h whose edges command +3 m/s^2 to every
    vehicle on every step (more aggressive than the EE+3 ceiling)."""
    config = MiVeCCConfig(rows=3, cols=3, density_vplh=2100, scheme="EE", safety_shield=shield,
                          model=model)
    sim = Simulator(config, seed=0)
    for _ in range(steps):
        sim.step(edge_accel=np.full(sim.active.shape, 3.0))
    return int(sim.collided.sum())


@pytest.mark.parametrize("model", ["paper", "released"])
def test_shield_removes_the_collisions_of_an_aggressive_edge(model: str) -> None:
    assert plus3_collisions(model, shield=False, steps=1200) > 0
    assert plus3_collisions(model, shield=True, steps=1200) == 0


def test_batch_equals_single_runs() -> None:
    config = MiVeCCConfig(rows=2, cols=2, density_vplh=2100, scheme="EE", safety_shield=True,
                          model="released")
    batch = Simulator(config, batch_size=2, seed=[3, 4])
    singles = [Simulator(config, seed=s) for s in (3, 4)]
    for _ in range(400):
        batch.step(edge_accel=np.full(batch.active.shape, 3.0))
        for sim in singles:
            sim.step(edge_accel=np.full(sim.active.shape, 3.0))
    for k, sim in enumerate(singles):
        mine, theirs = sim.vehicle_table(0), batch.vehicle_table(k)
        assert mine["vid"].size > 20
        order_mine, order_theirs = np.argsort(mine["vid"]), np.argsort(theirs["vid"])
        for name in ("vid", "s", "v", "a"):
            np.testing.assert_array_equal(theirs[name][order_theirs], mine[name][order_mine])


def test_environments_run_under_the_shield() -> None:
    import warnings

    from pettingzoo.test import parallel_api_test

    from mivecc_env import mivecc_v0

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # image-like observation advice
        parallel_api_test(mivecc_v0.parallel_env(rows=1, cols=2, density=1800, scheme="EEC",
                                                 safety_shield=True, max_cycles=40),
                          num_cycles=50)
    env = mivecc_v0.parallel_env(rows=1, cols=1, density=2100, scheme="EE", model="released",
                                 safety_shield=True, max_steps=300)
    env.reset(seed=0)
    for _ in range(300):
        actions = {a: np.full(env.action_space(a).shape, 3.0, dtype=np.float32)
                   for a in env.agents}
        *_, infos = env.step(actions)
    summary = infos["cloud_0"]
    assert summary["collisions"] == 0 and summary["throughput"] > 0


@pytest.mark.parametrize("model", ["paper", "released"])
def test_compiled_scan_equals_the_numpy_reference(model: str) -> None:
    from mivecc_env.sim import shield_kernel

    if not shield_kernel.HAVE_NUMBA:
        pytest.skip("numba not installed")
    config = MiVeCCConfig(rows=3, cols=3, density_vplh=2100, scheme="EE", model=model,
                          safety_shield=True)
    sim = Simulator(config, batch_size=2, seed=[0, 1])
    rng = np.random.default_rng(0)
    checked = 0
    for t in range(600):
        sim.step(edge_accel=rng.uniform(-3, 3, sim.active.shape))
        if t % 50 != 49:
            continue
        view = sim.view
        u = np.maximum(sim.v.ravel()[view.vehicle] - config.v_min_mps, 0.0)
        args = (view.own_point, view.point_run_start, view.point_run_end, view.point_pos,
                view.point_vehicle, view.s, u, sim.vid.ravel()[view.vehicle],
                rule_shield.horizon_m(config), rule_shield.TIE_M, config.shield_gap_m,
                config.a_max_mps2, config.dt_s)
        fast, ref = shield_kernel.scan(*args), rule_shield.scan_reference(*args)
        for a, b in zip(fast, ref, strict=True):
            np.testing.assert_array_equal(a, b)
        checked += int(np.isfinite(ref[0]).sum())
    assert checked > 100
