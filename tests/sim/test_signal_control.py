"""Signal phase state machine and the actuated / max-pressure controllers."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import signal_control as sc
from mivecc_env.sim import signals
from mivecc_env.sim.core import Simulator
from mivecc_env.sim.network import GridNetwork
from tests.sim._scenario import EAST, NORTH, SOUTH, WEST, place


def _cfg(**kw) -> MiVeCCConfig:
    return MiVeCCConfig(rows=1, cols=1, control="signalized", **kw)


@pytest.mark.parametrize("offset", [0.0, 10.0, 7.3])
def test_fixed_time_state_machine_reproduces_the_plan(offset: float) -> None:
    cfg = MiVeCCConfig(rows=2, cols=3, control="signalized", signal_offset_s=offset)
    phases = sc.SignalPhases(cfg, GridNetwork.from_config(cfg), batch_size=2)
    counts = sc.approach_counts(phases.network, cfg, _empty_view(), np.zeros(0), 2)
    for n in range(1500):
        expected = signals.phase_states(cfg, n * cfg.dt_s)
        np.testing.assert_array_equal(phases.heads()[0], expected)
        np.testing.assert_array_equal(phases.heads()[1], expected)
        phases.advance(phases.controller_decision(counts))


def _empty_view():
    sim = Simulator(_cfg(), seed=0)
    return sim.view


def test_random_agent_actions_never_break_the_timing() -> None:
    cfg = _cfg(signal_min_green_s=5.0, signal_yellow_s=3.0, signal_all_red_s=2.0)
    phases = sc.SignalPhases(cfg, GridNetwork.from_config(cfg), batch_size=8)
    rng = np.random.default_rng(0)
    dt = cfg.dt_s
    green_len: list[int] = []
    history = []
    for _ in range(3000):
        history.append((phases.phase.copy(), phases.stage.copy()))
        phases.advance(rng.random((8, 1)) < 0.3)
    phase = np.stack([h[0] for h in history])  # (T, 8, 1)
    stage = np.stack([h[1] for h in history])
    for b in range(8):
        st, ph = stage[:, b, 0], phase[:, b, 0]
        runs = np.split(np.arange(st.size), np.flatnonzero(np.diff(st) != 0) + 1)
        for i, run in enumerate(runs[1:-1], start=1):  # complete runs only
            kind = st[run[0]]
            length = run.size * dt
            if kind == sc.STAGE_GREEN:
                green_len.append(run.size)
                assert length >= cfg.signal_min_green_s - 1e-9
                assert st[runs[i + 1][0]] == sc.STAGE_YELLOW
            elif kind == sc.STAGE_YELLOW:
                assert length == pytest.approx(cfg.signal_yellow_s)
                assert st[runs[i + 1][0]] == sc.STAGE_ALL_RED
            else:
                assert length == pytest.approx(cfg.signal_all_red_s)
                nxt = runs[i + 1][0]
                assert st[nxt] == sc.STAGE_GREEN and ph[nxt] != ph[run[0]]
        # never two greens at once: the heads show at most one non-red phase
    heads = phases.heads()
    assert ((heads != signals.RED).sum(axis=2) <= 1).all()
    assert len(green_len) > 50


def _phases_with(vehicles: list[tuple[int, float, float]], **kw) -> tuple:
    cfg = _cfg(**kw)
    sim = Simulator(cfg, seed=0)
    place(sim, vehicles)
    counts = sc.approach_counts(sim.network, cfg, sim.view, sim.view.s, 1)
    return sim.signal_phases, counts


def test_approach_counts_on_constructed_queues() -> None:
    # centre at s = 150, stop line at 142, control radius 75
    _, counts = _phases_with([(EAST, 130.0, 0.0), (EAST, 140.0, 0.0), (WEST, 100.0, 5.0),
                              (NORTH, 160.0, 8.0), (SOUTH, 60.0, 10.0)])
    assert counts["upstream"][0, 0].tolist() == [3, 0]
    assert counts["downstream"][0, 0].tolist() == [0, 1]
    assert counts["calls"][0, 0].tolist() == [3, 0]  # SOUTH at 60 m is outside the area
    assert counts["detected"][0, 0].tolist() == [2, 0]  # detection zone 112..142 m


def test_actuated_gap_out_max_out_and_rest_in_green() -> None:
    cfg = _cfg(signal_controller="actuated", signal_min_green_s=5.0, signal_max_green_s=20.0,
               actuated_gap_s=2.0)
    # phase 0 (east-west) green; a north-south call waits, nothing in the EW detection zones
    phases, counts = _phases_with([(NORTH, 100.0, 0.0)], **_kw(cfg))
    phases.elapsed[:] = 100  # 10 s of green, past the minimum
    phases.gap_steps[:] = 0
    assert not phases.controller_decision(counts)[0, 0]  # no gap yet
    phases.gap_steps[:, :, 0] = 20  # 2 s without a detection: gap-out
    assert phases.controller_decision(counts)[0, 0]
    # continuous detection on the green phase extends it until max-out
    phases.gap_steps[:] = 0
    phases.elapsed[:] = 198
    assert not phases.controller_decision(counts)[0, 0]
    phases.elapsed[:] = 199
    assert phases.controller_decision(counts)[0, 0]
    # without a call on the other phase the green rests
    phases, counts = _phases_with([(EAST, 100.0, 5.0)], **_kw(cfg))
    phases.elapsed[:] = 500
    phases.gap_steps[:] = 100
    assert not phases.controller_decision(counts)[0, 0]


def test_max_pressure_switches_to_the_heavier_phase() -> None:
    cfg = _cfg(signal_controller="max-pressure")
    # east-west green with 1 queued vehicle, north-south has 3 queued: switch
    phases, counts = _phases_with([(EAST, 130.0, 0.0), (NORTH, 130.0, 0.0),
                                   (NORTH, 120.0, 0.0), (SOUTH, 130.0, 0.0)], **_kw(cfg))
    assert phases.controller_decision(counts)[0, 0]
    # downstream vehicles lower the pressure: NS 3 up - 3 down = 0 < EW 1
    phases, counts = _phases_with([(EAST, 130.0, 0.0), (NORTH, 130.0, 0.0),
                                   (NORTH, 120.0, 0.0), (SOUTH, 130.0, 0.0),
                                   (NORTH, 170.0, 9.0), (NORTH, 190.0, 9.0),
                                   (SOUTH, 175.0, 9.0)], **_kw(cfg))
    assert not phases.controller_decision(counts)[0, 0]


def _kw(cfg: MiVeCCConfig) -> dict:
    keys = ("signal_controller", "signal_min_green_s", "signal_max_green_s", "actuated_gap_s")
    return {k: getattr(cfg, k) for k in keys}


@pytest.mark.parametrize("controller", ["actuated", "max-pressure"])
def test_controllers_run_without_collisions(controller: str) -> None:
    cfg = _cfg(signal_controller=controller, density_vplh=900)
    sim = Simulator(cfg, seed=1)
    switches = 0
    prev = sim.signal_phases.phase.copy()
    for _ in range(1500):
        sim.step()
        switches += int((sim.signal_phases.phase != prev).sum())
        prev = sim.signal_phases.phase.copy()
    assert sim.collision_events.tolist() == [0]
    assert sim.exited[0] > 50
    assert switches >= 3


def test_agent_phase_overrides_the_controller() -> None:
    cfg = _cfg(signal_min_green_s=5.0)
    sim = Simulator(cfg, seed=0)
    want = np.array([[1]])  # north-south green as soon as allowed
    for _ in range(50 + 30 + 20 + 1):
        sim.step(signal_phase=want)
    assert sim.signal_phases.phase.tolist() == [[1]]
    assert sim.signal_phases.stage.tolist() == [[sc.STAGE_GREEN]]
    # keep it: -1 hands control back to the fixed-time plan, which ends it after 30 s
    for _ in range(200):
        sim.step(signal_phase=want)
    assert sim.signal_phases.phase.tolist() == [[1]]


def test_bad_signal_actions_are_rejected() -> None:
    sim = Simulator(_cfg(), seed=0)
    with pytest.raises(ValueError, match="signal_phase: expected shape"):
        sim.step(signal_phase=np.zeros((2, 1), dtype=int))
    with pytest.raises(ValueError, match="signal_phase: values"):
        sim.step(signal_phase=np.array([[2]]))
    with pytest.raises(ValueError, match="signal_phase: must hold integers"):
        sim.step(signal_phase=np.array([[0.5]]))
    unsignalized = Simulator(MiVeCCConfig(rows=1, cols=1), seed=0)
    with pytest.raises(ValueError, match="only under control='signalized'"):
        unsignalized.step(signal_phase=np.array([[0]]))


def test_signal_observation_and_reward_terms() -> None:
    cfg = _cfg()
    sim = Simulator(cfg, seed=0)
    place(sim, [(EAST, 130.0, 0.0), (EAST, 120.0, 0.2), (WEST, 100.0, 6.0),
                (NORTH, 160.0, 8.0)])
    sim.signal_phases.elapsed[:] = 42
    obs, terms = sc.signal_observation(sim.network, cfg, sim.view, sim.view.s,
                                       sim.v.ravel()[sim.view.vehicle], sim.signal_phases)
    assert obs.shape == (1, 1, 15)
    east, west, north = obs[0, 0, 0:3], obs[0, 0, 3:6], obs[0, 0, 6:9]
    assert east.tolist() == pytest.approx([2, 2, 0.1])
    assert west.tolist() == pytest.approx([1, 0, 6.0])
    assert north.tolist() == [0, 0, 0]  # past the centre: downstream, not approaching
    assert obs[0, 0, 12:].tolist() == pytest.approx([0, sc.STAGE_GREEN, 4.2])
    assert terms["reward_queue"].tolist() == [[-2.0]]
    assert terms["reward_pressure"].tolist() == [[-2.0]]  # 3 upstream - 1 downstream
