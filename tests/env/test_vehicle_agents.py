"""Vehicles as agents (``mivecc_env.vehicle_agents``, ``BatchedMiVeCCEnv.step_vehicles``): who the
agents are, what they observe, and that their accelerations are executed unmodified."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_agents.comaddpg_settings import vehicle_agent_fields
from mivecc_env.batched import BatchedMiVeCCEnv
from mivecc_env.vehicle_agents import (
    observe_vehicles,
    vehicle_accelerations,
    vehicle_commands,
)


def _env(batch: int = 2, **kw) -> BatchedMiVeCCEnv:
    env = BatchedMiVeCCEnv(batch_size=batch, rows=2, cols=2, densities=[1500.0] * batch,
                           **{**vehicle_agent_fields(), **kw})
    env.reset(seed=list(range(3, 3 + batch)))
    for _ in range(250):  # fill the network
        env.step_commands(None, None)
    return env


def test_agents_are_the_vehicles_in_the_control_areas_in_environment_order() -> None:
    env = _env()
    sim = env.sim
    agents = observe_vehicles(sim, 8)
    view = sim.view
    area = sim.network.control_area(view.lane, view.s)
    assert len(agents) == int((area >= 0).sum()) > 20
    assert np.all(np.diff(agents.env) >= 0)
    assert set(agents.slot.tolist()) == set(view.vehicle[area >= 0].tolist())
    for b in range(2):
        rows = agents.rows_of(b)
        assert np.all(agents.env[rows] == b) and (rows.stop - rows.start) == int(
            ((area >= 0) & (view.env == b)).sum())
    assert agents.obs.shape == (len(agents), 8, 3) and agents.obs.dtype == np.float32
    assert np.abs(agents.obs).max() <= 1.0
    np.testing.assert_array_equal(agents.vid, sim.vid.ravel()[agents.slot])
    np.testing.assert_array_equal(agents.velocity, sim.v.ravel()[agents.slot])


def test_an_agent_sees_what_its_edge_node_column_shows() -> None:
    """With k = K_edge an agent's observation is its column of the edge state graph."""
    env = _env(observe={"edge"})
    step = env.step_commands(None, None)
    graphs = env._edge
    agents = observe_vehicles(env.sim, env.k_edge)
    row_of_slot = {int(s): i for i, s in enumerate(agents.slot)}
    checked = 0
    for b, node, col in zip(*np.nonzero(step.edge_mask), strict=True):
        i = row_of_slot[int(graphs.slot[b, node, col])]
        np.testing.assert_array_equal(agents.obs[i], step.edge_obs[b, node, :, col, :])
        checked += 1
    assert checked > 20


def test_reference_rows_name_the_agents_they_show() -> None:
    agents = observe_vehicles(_env().sim, 8)
    i, r = np.nonzero(agents.ref_agent >= 0)
    assert i.size > 50
    j = agents.ref_agent[i, r]
    assert np.all(j != i) and np.all(agents.env[j] == agents.env[i])
    # velocity and acceleration of a reference row are those of the agent it names
    np.testing.assert_array_equal(agents.obs[i, r + 1, 1:], agents.obs[j, 0, 1:])
    # padding rows (all zero) name no agent; a row that names none and is not padding shows a
    # vehicle just outside every control area (a crossing vehicle projected into this one)
    padding = np.all(agents.obs[:, 1:] == 0.0, axis=-1)
    assert np.all(agents.ref_agent[padding] == -1)
    assert (agents.ref_agent[~padding] == -1).mean() < 0.1


def test_commands_act_unmodified_on_the_agents_and_the_rules_drive_the_others() -> None:
    env = _env()
    sim = env.sim
    agents = observe_vehicles(sim, 8)
    accel = np.where(np.arange(len(agents)) % 2 == 0, -3.0, 3.0)
    cmd = vehicle_commands(agents, accel, 2)
    assert cmd.shape == sim.active.shape
    assert np.isnan(cmd).sum() == cmd.size - len(agents)
    v0 = agents.velocity.copy()
    others = np.setdiff1d(sim.view.vehicle, agents.slot)
    env.step_vehicles(cmd)
    c = sim.config
    expected = np.clip(v0 + accel * c.dt_s, c.velocity_floor_mps, c.v_max_mps)
    still = sim.active.ravel()[agents.slot] & (sim.vid.ravel()[agents.slot] == agents.vid)
    np.testing.assert_allclose(sim.v.ravel()[agents.slot][still], expected[still], rtol=0,
                               atol=1e-12)
    # a plain E step of the same state moves the vehicles outside the areas alike
    twin = _env(scheme="E")
    twin.step_commands(None, None)
    np.testing.assert_array_equal(twin.sim.v.ravel()[others], sim.v.ravel()[others])


def test_step_vehicles_refuses_bad_input() -> None:
    env = _env(batch=1)
    agents = observe_vehicles(env.sim, 8)
    cmd = vehicle_commands(agents, np.zeros(len(agents)), 1)
    for bad, message in ((cmd[:, :-1], "accel: must have shape"),
                         (np.where(np.isnan(cmd), np.nan, 3.5), r"accel: must be within"),
                         (np.where(np.isnan(cmd), np.nan, np.inf), "accel: .*inf")):
        with pytest.raises(ValueError, match=message):
            env.step_vehicles(bad)
    with pytest.raises(ValueError, match=r"accel: expected shape \(\d+,\)"):
        vehicle_commands(agents, np.zeros(len(agents) + 1), 1)
    with pytest.raises(ValueError, match="k: must be an integer >= 2"):
        observe_vehicles(env.sim, 1)
    for fields in ({"scheme": "E"}, {"control": "signalized", "scheme": "E"}):
        other = BatchedMiVeCCEnv(rows=1, cols=1, **{**vehicle_agent_fields(), **fields})
        other.reset(seed=0)
        with pytest.raises(ValueError, match="step_vehicles: needs scheme 'EE' or 'EEC'"):
            other.step_vehicles(np.full(other.sim.active.shape, np.nan))
    released = BatchedMiVeCCEnv(rows=1, cols=1, **{**vehicle_agent_fields(), "model": "released"})
    released.reset(seed=0)
    with pytest.raises(ValueError, match="step_vehicles: needs header_rule, sections, speed_reset "
                                         "off"):
        released.step_vehicles(np.full(released.sim.active.shape, np.nan))
    with pytest.raises(ValueError, match="policy returned NaN or inf"):
        vehicle_accelerations(lambda obs: np.full(len(obs), np.nan), agents, 1, 3.0)
    with pytest.raises(ValueError, match="policy returned shape"):
        vehicle_accelerations(lambda obs: np.zeros(len(obs) + 1), agents, 1, 3.0)


@pytest.mark.parametrize(("rows", "cols", "densities"),
                         [(1, 1, (600.0, 2100.0, 1500.0)), (2, 3, (900.0, 1800.0, 300.0))])
def test_a_batch_of_vehicle_agent_runs_equals_its_single_runs(rows, cols, densities) -> None:
    """Environment b of a batch stepped by vehicle agents = the B = 1 run of its seed and
    demand, bit for bit (an elementwise policy of each agent's own observation)."""
    def policy(obs: np.ndarray) -> np.ndarray:
        return 3.0 * np.tanh(5.0 * (obs[:, 0, 0].astype(np.float64) + obs[:, 1, 0]))

    def make(b_densities, seeds):
        env = BatchedMiVeCCEnv(batch_size=len(seeds), rows=rows, cols=cols,
                               densities=list(b_densities), observe=(), **vehicle_agent_fields())
        env.reset(seed=list(seeds))
        return env

    seeds = (5, 6, 7)
    batch = make(densities, seeds)
    singles = [make([d], [s]) for d, s in zip(densities, seeds, strict=True)]
    for _ in range(400):
        for env in (batch, *singles):
            agents = observe_vehicles(env.sim, 8)
            accel = vehicle_accelerations(policy, agents, env.batch_size, 3.0)
            env.step_vehicles(vehicle_commands(agents, accel, env.batch_size))
    collided = 0
    for b, single in enumerate(singles):
        for key, value in single.summary().items():
            assert np.array_equal(batch.summary()[key][b], value[0], equal_nan=True), key
        mine, theirs = batch.sim.vehicle_table(b), single.sim.vehicle_table(0)
        for key in ("vid", "lane", "s", "v"):
            np.testing.assert_array_equal(mine[key], theirs[key])
        collided += int(single.summary()["collisions"][0])
    assert collided > 0  # the policy is no safe one: collisions are part of what must match


def test_the_graphs_name_each_reference_row_alike_on_both_paths() -> None:
    from mivecc_env.sim import graph_kernel
    from mivecc_env.sim.state_graph import build_graphs

    if not graph_kernel.HAVE_NUMBA:
        pytest.skip("needs numba for the compiled path")
    sim = _env().sim
    c, net, view = sim.config, sim.network, sim.view
    decision = np.arange(0, view.env.size, 3)
    v, a = sim.v.ravel()[view.vehicle], sim.a.ravel()[view.vehicle]
    out = {}
    for kernel in (True, False):
        refs = np.full((decision.size, 39), 99, dtype=np.int64)  # more rows than neighbours
        g = build_graphs(net, view, v, a, decision, np.arange(decision.size),
                         np.zeros(decision.size, dtype=np.int64), decision.size, 1, 40, 150.0,
                         c, use_kernel=kernel, references=refs)
        out[kernel] = (g.obs, refs)
    np.testing.assert_array_equal(out[True][0], out[False][0])
    np.testing.assert_array_equal(out[True][1], out[False][1])
    assert (out[True][1] >= 0).sum() > 100 and (out[True][1] == -1).any()
