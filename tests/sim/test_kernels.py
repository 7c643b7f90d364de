"""The compiled kernels give exactly the numpy reference paths' results (bit for bit).

Two ways: each kernel against its reference on many states (including crowded random ones that
force collisions and ties), and whole trajectories of the simulator with the kernels on and off
(every state array after every step).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import step_kernels, view_kernel
from mivecc_env.sim.core import Simulator, collision_pairs, collision_pairs_reference
from mivecc_env.sim.virtual_lane import build_view, build_view_reference

pytestmark = pytest.mark.skipif(not view_kernel.HAVE_NUMBA, reason="numba not installed")

STATE = ("active", "lane", "s", "v", "a", "t_arrive", "t_enter", "vid", "exited", "collided",
         "collision_events", "sum_travel_velocity", "sum_travel_velocity_no_wait",
         "sum_trip_time", "sum_wait_time", "sum_speed_samples", "vehicle_steps")


def _no_kernels(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(view_kernel, "HAVE_NUMBA", False)
    monkeypatch.setattr(step_kernels, "HAVE_NUMBA", False)


def _assert_same_view(a, b) -> None:
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        assert x.dtype == y.dtype, f.name
        np.testing.assert_array_equal(x, y, err_msg=f.name)


def _actions(sim: Simulator, rng: np.random.Generator, scheme: str):
    if scheme == "E":
        return None, None
    shape = sim.active.shape
    edge = np.where(rng.random(shape) < 0.7, rng.uniform(-3, 3, shape), np.nan)
    cloud = np.where(rng.random(shape) < 0.5, rng.uniform(-3, 3, shape), np.nan)
    return edge, (cloud if scheme == "EEC" else None)


CASES = [
    (MiVeCCConfig(rows=3, cols=3, density_vplh=2100, scheme="EEC"), 3),
    (MiVeCCConfig(rows=2, cols=1, density_vplh=1500, scheme="EE"), 7),
    (MiVeCCConfig(rows=1, cols=1, density_vplh=2100, control="signalized"), 2),
    (MiVeCCConfig(rows=1, cols=2, density_vplh=900, scheme="E", projection_window_m=140.0), 2),
]


@pytest.mark.parametrize(("cfg", "batch"), CASES)
def test_trajectory_identical_with_and_without_kernels(
    cfg: MiVeCCConfig, batch: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    fast = Simulator(cfg, batch_size=batch, seed=11)
    with monkeypatch.context() as m:
        _no_kernels(m)
        ref = Simulator(cfg, batch_size=batch, seed=11)
    rng_f, rng_r = np.random.default_rng(5), np.random.default_rng(5)
    for step in range(500):
        fast.step(*_actions(fast, rng_f, cfg.scheme))
        with monkeypatch.context() as m:
            _no_kernels(m)
            ref.step(*_actions(ref, rng_r, cfg.scheme))
        for name in STATE:
            np.testing.assert_array_equal(getattr(fast, name), getattr(ref, name),
                                          err_msg=f"{name} at step {step}")
        np.testing.assert_array_equal(fast.safety.sv, ref.safety.sv)
        np.testing.assert_array_equal(fast.safety.ttc, ref.safety.ttc)
        for name in ("count", "sum_time_s", "sum_length_m"):
            np.testing.assert_array_equal(getattr(fast.passing, name),
                                          getattr(ref.passing, name), err_msg=name)
    _assert_same_view(fast.view, ref.view)
    assert fast.in_network.sum() > 0


def test_capacity_growth_identical_with_and_without_kernels(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """From 8 slots the capacity grows several times (the compiled entry plan counts free
    slots only up to what enters): the same sizes at the same steps, the same states."""
    cfg = MiVeCCConfig(rows=3, cols=3, density_vplh=2100, scheme="E")
    fast = Simulator(cfg, batch_size=3, seed=4, capacity=8)
    with monkeypatch.context() as m:
        _no_kernels(m)
        ref = Simulator(cfg, batch_size=3, seed=4, capacity=8)
    sizes = set()
    for step in range(400):
        fast.step()
        with monkeypatch.context() as m:
            _no_kernels(m)
            ref.step()
        sizes.add(fast.capacity)
        for name in STATE:
            np.testing.assert_array_equal(getattr(fast, name), getattr(ref, name),
                                          err_msg=f"{name} at step {step}")
    assert len(sizes) >= 3


def _crowded(cfg: MiVeCCConfig, batch: int, per_env: int, seed: int):
    """Random vehicles on random lanes (many close pairs, exact ties of positions)."""
    sim = Simulator(cfg, batch_size=batch, seed=seed, capacity=per_env)
    rng = np.random.default_rng(seed)
    n_lanes = sim.network.n_lanes
    sim.active[:] = rng.random(sim.active.shape) < 0.8
    sim.lane[:] = rng.integers(0, n_lanes, sim.active.shape)
    length = sim.network.lane_length[sim.lane]
    s = rng.uniform(0, 1, sim.active.shape) * length
    s[:, ::7] = np.round(s[:, ::7])  # exact ties between vehicles and projections
    sim.s[:] = np.minimum(s, length - 1e-9)
    sim.v[:] = rng.uniform(6, 13, sim.active.shape)
    sim.a[:] = rng.uniform(-3, 3, sim.active.shape)
    return sim


@pytest.mark.parametrize("seed", range(6))
def test_kernels_match_references_on_crowded_states(seed: int) -> None:
    wide = MiVeCCConfig(rows=1, cols=2, projection_window_m=140.0)  # overlapping windows
    for cfg in (MiVeCCConfig(rows=3, cols=3), wide,
                MiVeCCConfig(rows=2, cols=2, sv_acc_source="front")):
        sim = _crowded(cfg, batch=4, per_env=120, seed=seed)
        args = (sim.network, cfg.projection_window_m, cfg.projection_clear_m, sim.active,
                sim.lane, sim.s)
        view = build_view(*args)
        _assert_same_view(view, build_view_reference(*args))

        d, ttc, acc = step_kernels.safety_inputs(
            sim.v.ravel(), sim.a.ravel(), view.vehicle, view.point_vehicle, view.front_point,
            view.back_point, view.d_front, view.d_back, cfg.sv_acc_source == "ego")
        ref = sim._safety_inputs_reference(view)
        for x, y in zip((d, ttc, acc), ref, strict=True):
            np.testing.assert_array_equal(x, y)

        rng = np.random.default_rng(seed)
        s_new = view.s + rng.uniform(0, 1.5, view.n_vehicles)
        out = rng.random(view.n_vehicles) < 0.1
        got = collision_pairs(sim.network, view, s_new, out, cfg.vehicle_length_m)
        want = collision_pairs_reference(sim.network, view, s_new, out, cfg.vehicle_length_m)
        assert want.shape[0] > 0
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("source", ["ego", "front"])
def test_fused_safety_matches_safety_value(seed: int, source: str) -> None:
    """``safety_fast`` (gathers, logs, tanh only where 0 < TTC < 1 s, fix-up of those) gives
    ``safety_value`` of the reference inputs bit for bit, sensitive vehicles included."""
    from mivecc_env.sim.safety import safety_value

    cfg = MiVeCCConfig(rows=2, cols=2, sv_acc_source=source)
    sim = _crowded(cfg, batch=3, per_env=150, seed=seed)
    sim.v[:] = np.random.default_rng(seed).uniform(0, 15, sim.v.shape)  # fast closing too
    view = build_view(sim.network, cfg.projection_window_m, cfg.projection_clear_m, sim.active,
                      sim.lane, sim.s)
    sv, ttc = step_kernels.safety_fast(
        sim.v.ravel(), sim.a.ravel(), view.vehicle, view.point_vehicle, view.front_point,
        view.back_point, view.d_front, view.d_back, cfg)
    d, ttc_ref, acc = sim._safety_inputs_reference(view)
    assert ((ttc_ref > 0) & (ttc_ref < 1)).sum() >= 5  # the tanh path is exercised
    assert np.isinf(view.d_front).any()
    np.testing.assert_array_equal(ttc, ttc_ref)
    np.testing.assert_array_equal(sv, safety_value(d, ttc_ref, view.d_front, acc, cfg))


def test_empty_network_view() -> None:
    sim = Simulator(MiVeCCConfig(rows=1, cols=1), batch_size=3)
    args = (sim.network, 10.0, 5.0, sim.active, sim.lane, sim.s)
    _assert_same_view(build_view(*args), build_view_reference(*args))


@pytest.mark.parametrize("cfg", [
    MiVeCCConfig(rows=2, cols=2, density_vplh=1800, scheme="EEC", edge_sv_gate=0.0,
                 end_rule="literal", entry_accel_mps2=2.0),
    MiVeCCConfig(rows=1, cols=2, density_vplh=1200, scheme="EE"),
])
def test_compiled_motion_matches_reference_with_raw_edge_and_float32(
    cfg: MiVeCCConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The compiled rule/fusion/motion kernel: SV gate, literal rule, entry action, raw edge
    actions per environment, and float32 actions (which take the reference's own path)."""
    fast = Simulator(cfg, batch_size=3, seed=4)
    with monkeypatch.context() as m:
        _no_kernels(m)
        ref = Simulator(cfg, batch_size=3, seed=4)
    rng_f, rng_r = np.random.default_rng(9), np.random.default_rng(9)
    for step in range(300):
        for sim, rng in ((fast, rng_f), (ref, rng_r)):
            edge, cloud = _actions(sim, rng, cfg.scheme)
            raw = rng.random(3) < 0.3
            if step % 3 == 0:
                edge = edge.astype(np.float32)
            with monkeypatch.context() as m:
                if sim is ref:
                    _no_kernels(m)
                sim.step(edge, cloud, raw_edge=raw)
        for name in STATE:
            np.testing.assert_array_equal(getattr(fast, name), getattr(ref, name),
                                          err_msg=f"{name} at step {step}")
        for name in ("count", "sum_time_s", "sum_length_m"):
            np.testing.assert_array_equal(getattr(fast.passing, name),
                                          getattr(ref.passing, name), err_msg=name)
    assert fast.in_network.sum() > 0 and fast.passing.count.sum() > 0


@pytest.mark.parametrize("seed", range(3))
def test_released_check_on_the_rows_with_events_equals_the_whole_batch(seed: int) -> None:
    """``Simulator`` runs the released check only on the environments with a strict event;
    per environment that gives what a check of the whole batch gives."""
    from mivecc_env.sim import released_check
    from mivecc_env.sim.core import _rows_of_slots

    cfg = MiVeCCConfig(rows=2, cols=2)
    sim = _crowded(cfg, batch=5, per_env=60, seed=seed)
    rng = np.random.default_rng(seed)
    slots = np.flatnonzero(sim.active)
    prev = (slots, np.maximum(sim.s.ravel()[slots] - rng.uniform(0, 2, slots.size), 0.0))
    whole = released_check.flagged_count(sim.network, cfg, sim.active, sim.lane, sim.s, prev)
    assert whole.sum() > 0
    envs = np.array([0, 2, 3])
    part = released_check.flagged_count(
        sim.network, cfg, sim.active[envs], sim.lane[envs], sim.s[envs],
        _rows_of_slots(prev, envs, 5, sim.capacity))
    np.testing.assert_array_equal(part, whole[envs])


def test_view_buffers_reused_keep_the_previous_view() -> None:
    """The simulator's view lives in reused buffers (view_kernel.ViewWorkspace): every view
    equals a fresh reference build, and the view before a step or a partial reset is still
    intact after it; the buffers grow with the capacity."""
    cfg = MiVeCCConfig(rows=2, cols=2, density_vplh=2100.0)
    sim = Simulator(cfg, batch_size=3, seed=4, capacity=8)
    for t in range(120):
        before = sim.view
        kept = dataclasses.replace(
            before, **{f.name: getattr(before, f.name).copy() for f in dataclasses.fields(before)})
        if t % 37 == 36:
            sim.reset_at([t % 3], [t])
        else:
            sim.step()
        _assert_same_view(before, kept)  # the view one build back is untouched by this one
        args = (sim.network, cfg.projection_window_m, cfg.projection_clear_m, sim.active,
                sim.lane, sim.s)
        _assert_same_view(sim.view, build_view_reference(*args))
    assert sim.capacity > 8 and sim.view.n_vehicles > 0


def test_keep_clear_kernel_matches_its_reference(monkeypatch: pytest.MonkeyPatch) -> None:
    """The signals' keep-clear check, compiled and in numpy: on every step of 3x3 actuated
    signals at 1500 veh/lane/h (where boxes get blocked) and on random leader chains with
    positions on the stop lines."""
    from mivecc_env.sim import signals

    seen = {"asked": 0, "blocked": 0}
    compiled = signals.box_blocked

    def both(asked, s, v, leader, line, c):
        out = compiled(asked, s, v, leader, line, c)
        np.testing.assert_array_equal(
            out, signals.box_blocked_reference(asked, s, v, leader, line, c))
        seen["asked"] += asked.size
        seen["blocked"] += int(out.sum())
        return out

    monkeypatch.setattr(signals, "box_blocked", both)
    cfg = MiVeCCConfig(rows=3, cols=3, density_vplh=1500, control="signalized",
                       signal_controller="actuated")
    sim = Simulator(cfg, batch_size=2, seed=1)
    for _ in range(1500):
        sim.step()
    assert seen["blocked"] > 0 and seen["asked"] > 100 * seen["blocked"]
    rng = np.random.default_rng(3)
    for _ in range(50):
        n = int(rng.integers(1, 300))
        s = rng.choice(np.arange(0.0, 60.0, 2.0), n)  # coarse: many exactly on a stop line
        v = rng.choice([0.0, 0.5, 1.0, 3.0], n)
        leader = rng.integers(-1, n, n)
        asked = np.flatnonzero(rng.random(n) < 0.7)
        line = rng.choice(np.arange(0.0, 60.0, 2.0), asked.size)
        np.testing.assert_array_equal(compiled(asked, s, v, leader, line, cfg),
                                      signals.box_blocked_reference(asked, s, v, leader, line,
                                                                    cfg))
