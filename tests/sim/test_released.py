"""The released code's behaviours (``model="released"``), each on a hand-computed case."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mivecc_env.config import ConfigError, MiVeCCConfig, from_overrides
from mivecc_env.model_presets import PAPER, RELEASED
from mivecc_env.sim import edge_selection, sections
from mivecc_env.sim.core import Simulator
from mivecc_env.sim.end_node import same_lane_threshold_m
from mivecc_env.sim.network import GridNetwork
from mivecc_env.sim.safety import safety_value
from mivecc_env.sim.virtual_lane import build_view
from tests.sim._scenario import EAST, NORTH, WEST, place

# 1x1 grid: lanes are 300 m long, the centre is at s = 150, conflict points at 145 and 155.
REL_1X1 = MiVeCCConfig(rows=1, cols=1, density_vplh=1.0, model="released", scheme="E")


def released_sim(**overrides: object) -> Simulator:
    return Simulator(REL_1X1.replace(**overrides), seed=0)


# --- the preset -----------------------------------------------------------------------------
def test_preset_sets_every_named_field() -> None:
    cfg = MiVeCCConfig(model="released")
    for name, value in RELEASED.items():
        assert getattr(cfg, name) == value, name
    assert cfg.v_min_mps == 5.0 and cfg.speed_reset and cfg.header_rule
    paper = MiVeCCConfig()
    for name, value in PAPER.items():
        assert getattr(paper, name) == value, name


def test_explicit_fields_win_over_the_preset() -> None:
    cfg = MiVeCCConfig(model="released", v_min_mps=6.0, speed_reset=False)
    assert cfg.v_min_mps == 6.0 and not cfg.speed_reset and cfg.header_rule
    base = MiVeCCConfig(omega=0.3, v_min_mps=6.5)
    cfg = from_overrides(base, model="released", edge_sv_gate=-1.0)
    # base < preset < explicit overrides
    assert cfg.omega == 0.3 and cfg.v_min_mps == 5.0 and cfg.edge_sv_gate == -1.0
    # a replace without ``model`` keeps every field, a switch back restores the paper's
    assert cfg.replace(omega=0.1).v_min_mps == 5.0
    back = cfg.replace(model="paper")
    assert back.v_min_mps == 6.0 and not back.sections and back.omega == 0.3


def test_parallel_env_accepts_model() -> None:
    from mivecc_env.mivecc_v0 import parallel_env

    env = parallel_env(rows=1, cols=1, model="released", max_steps=5)
    assert env.config.section_virtual_lanes and env.config.entry_clearance_m == 0.0
    env.reset(seed=0)
    for _ in range(5):
        env.step({})
    with pytest.raises(ConfigError, match="model"):
        parallel_env(model="authors")


# --- 2: sections ----------------------------------------------------------------------------
def test_section_boundaries_on_3x3() -> None:
    cfg = MiVeCCConfig(model="released")  # lanes 600 m, centres at 150, 300, 450
    sim = Simulator(cfg.replace(density_vplh=1.0), seed=0)
    s = np.array([0.0, 154.99, 155.0, 159.99, 160.0, 304.99, 305.0, 454.99, 455.0, 599.0])
    lane = np.zeros(s.size, dtype=np.int64)
    k, offset = sections.section_of(sim.network, cfg, lane, s)
    assert k.tolist() == [0, 0, 0, 0, 1, 1, 1, 2, 2, 2]
    np.testing.assert_allclose(offset[[0, 4, 6]], [-150.0, -140.0, 5.0])
    ctrl = sections.controlled(sim.network, cfg, lane, s)
    assert ctrl.tolist() == [True, True, False, False, True, True, False, True, False, False]
    area = sections.control_area(sim.network, cfg, lane, s)
    ids = sim.network.lane_intersections[0]
    assert area.tolist() == [ids[0], ids[0], -1, -1, ids[1], ids[1], -1, ids[2], -1, -1]


# --- 1: speed reset -------------------------------------------------------------------------
def test_speed_reset_jumps_to_v_max_past_the_controlled_part() -> None:
    sim = released_sim()
    # 0: lone, ends the step at 155.55 (past centre + 5): reset to 13 m/s.
    # 1 (other lane): ends at 154.2, still controlled: bounded by a_max (header: +3).
    place(sim, [(EAST, 154.5, 10.0), (WEST, 153.2, 10.0)])
    sim.step()
    assert sim.s[0, 0] == pytest.approx(154.5 + 1.0 + 0.5 * 3.0 * 0.01)
    assert sim.v[0, 0] == 13.0
    assert sim.v[0, 1] == pytest.approx(10.3)
    sim.step()  # uncontrolled: drives on at 13 m/s, no rule acts
    assert sim.v[0, 0] == 13.0 and sim.a[0, 0] == 0.0


def test_without_speed_reset_uncontrolled_vehicles_accelerate_within_bounds() -> None:
    sim = released_sim(speed_reset=False)
    place(sim, [(EAST, 156.0, 10.0)])
    sim.step()
    assert sim.v[0, 0] == pytest.approx(10.3) and sim.a[0, 0] == pytest.approx(3.0)


# --- 3: section-limited virtual lanes -------------------------------------------------------
def test_section_virtual_lane_sees_crossing_but_not_opposite_or_uncontrolled() -> None:
    # ego east at 100; a northbound vehicle at 100 conflicts at (east 155, north 145), so it is
    # projected at 155 + (100 - 145) = 110 on the ego's lane; a westbound (opposite) vehicle is
    # never projected; a northbound vehicle past its controlled part (156 > 155) is not seen.
    sim = released_sim()
    place(sim, [(EAST, 100.0, 10.0), (NORTH, 100.0, 10.0), (WEST, 140.0, 10.0)])
    assert sim.safety.d_front[0] == pytest.approx(10.0)
    place(sim, [(EAST, 100.0, 10.0), (NORTH, 156.0, 10.0), (WEST, 140.0, 10.0)])
    assert math.isinf(sim.safety.d_front[0]) and math.isinf(sim.safety.d_back[0])
    # the paper's view projects the first northbound vehicle too (window 75 m)
    paper = released_sim(section_virtual_lanes=False)
    place(paper, [(EAST, 100.0, 10.0), (NORTH, 100.0, 10.0)])
    assert paper.safety.d_front[0] == pytest.approx(10.0)


def test_section_virtual_lane_hides_the_leader_in_the_next_section() -> None:
    cfg = MiVeCCConfig(model="released", density_vplh=1.0)
    sim = Simulator(cfg, seed=0)
    place(sim, [(0, 150.0, 10.0), (0, 165.0, 10.0)])  # 165 is in section 1 (starts at 160)
    assert math.isinf(sim.safety.d_front[0])
    full = Simulator(cfg.replace(section_virtual_lanes=False), seed=0)
    place(full, [(0, 150.0, 10.0), (0, 165.0, 10.0)])
    assert full.safety.d_front[0] == pytest.approx(15.0)


# --- 4: header rule -------------------------------------------------------------------------
def test_header_rule_overrides_rule_and_edge() -> None:
    args = (np.array([-3.0, -3.0, -3.0]), np.array([True, True, False]),
            np.array([np.inf, 5.0, np.inf]))
    # uncontrolled under speed_reset: a = 0, or its last action with stale_action
    assert sections.control_overrides(*args, REL_1X1.replace(stale_action=False)).tolist() == [
        3.0, -3.0, 0.0]
    assert sections.control_overrides(*args, REL_1X1).tolist() == [3.0, -3.0, -3.0]
    # a vehicle off the virtual lanes this step is never a header
    seen = np.array([False, True, False])
    assert sections.control_overrides(*args, REL_1X1, seen).tolist() == [-3.0, -3.0, -3.0]
    # in the simulator, an edge command of -3 for the lone first vehicle is overridden
    sim = released_sim(scheme="EE", edge_sv_gate=None)
    place(sim, [(EAST, 50.0, 10.0)])
    edge = np.full(sim.active.shape, np.nan)
    edge[0, 0] = -3.0
    sim.step(edge_accel=edge)
    assert sim.a[0, 0] == pytest.approx(3.0)
    off = released_sim(scheme="EE", edge_sv_gate=None, header_rule=False)
    place(off, [(EAST, 50.0, 10.0), (EAST, 40.0, 10.0)])  # safe follower far behind
    edge = np.full(off.active.shape, np.nan)
    edge[0, 0] = 3.0
    off.step(edge_accel=edge)
    assert off.a[0, 0] == pytest.approx(3.0)


# --- 5: SV floor ----------------------------------------------------------------------------
def test_sv_floor_at_two_metres() -> None:
    cfg = REL_1X1
    # ln((2/10)^10 + 1e-4) = ln(1.024e-7 + 1e-4) = -9.209316; SV_t = 2; SV_acc = 0 (a = 0)
    sv = safety_value(np.array([2.0]), np.array([np.inf]), np.array([2.0]), np.array([0.0]), cfg)
    assert sv[0] == pytest.approx(math.log(0.2**10 + 1e-4) + 2.0)
    assert sv[0] == pytest.approx(-7.209316, abs=1e-6)
    paper = MiVeCCConfig()
    sv_p = safety_value(np.array([2.0]), np.array([np.inf]), np.array([2.0]), np.array([0.0]),
                        paper)
    assert sv_p[0] == pytest.approx(10 * math.log(0.2) + 2.0)  # -14.09: no floor
    # nothing ahead counts as 100 m: SV_acc = 0.2 * 3 * ln(1.5^12 + 1e-7) = 2.9194
    sv_a = safety_value(np.array([50.0]), np.array([np.inf]), np.array([np.inf]),
                        np.array([3.0]), cfg.replace(sv_max=100.0))
    expected = math.log(5.0**10 + 1e-4) + 2.0 + 0.2 * 3.0 * math.log(1.5**12 + 1e-7)
    assert sv_a[0] == pytest.approx(expected)


def test_ttc_closing_offset() -> None:
    # leader 5 m ahead, same speed: closing 0 + 0.1 -> TTC 50 s (not sensitive, SV_t = 2)
    sim = released_sim()
    place(sim, [(EAST, 100.0, 10.0), (EAST, 105.0, 10.0)])
    assert sim.safety.ttc[0] == pytest.approx(50.0)
    paper = Simulator(MiVeCCConfig(rows=1, cols=1, density_vplh=1.0), seed=0)
    place(paper, [(EAST, 100.0, 10.0), (EAST, 105.0, 10.0)])
    assert math.isinf(paper.safety.ttc[0])


# --- 6: same-lane rule ----------------------------------------------------------------------
def test_same_lane_threshold_is_7_53_m_with_v_min_5() -> None:
    assert same_lane_threshold_m(REL_1X1) == pytest.approx(64.0 / 12.0 + 2.2)
    assert same_lane_threshold_m(REL_1X1) == pytest.approx(7.5333, abs=1e-4)


def test_same_lane_rule_released_form() -> None:
    # follower 6 m behind its leader brakes at -3 only more than 50 m before the reference:
    # s = 97 is 53 m before the centre (150) but 48 m before the first conflict point (145);
    # s = 102 is within 50 m of both.
    def accel(s_f: float, gap: float, form: str) -> float:
        sim = released_sim(header_rule=False, same_lane_rule_form=form)
        place(sim, [(EAST, s_f, 10.0), (EAST, s_f + gap, 10.0)])
        sim.step()
        return float(sim.a[0, 0])

    assert accel(97.0, 6.0, "released") == pytest.approx(-3.0)
    assert accel(97.0, 6.0, "project") != pytest.approx(-3.0)
    assert accel(102.0, 6.0, "released") != pytest.approx(-3.0)
    assert accel(90.0, 6.0, "project") == pytest.approx(-3.0)
    # released form: the leader moves first (nothing ahead: +3, 1.015 m), so a 7 m gap reads
    # 8.015 m > 7.53 m and the follower does not brake; the project form reads 7 m and brakes.
    assert accel(90.0, 7.0, "released") != pytest.approx(-3.0)
    assert accel(90.0, 7.0, "project") == pytest.approx(-3.0)


def test_same_lane_rule_released_form_is_not_softened_by_the_edge() -> None:
    # the rule brakes at -3; an edge action of -1 agrees in sign, so the fusion max(-1, -3)
    # softens it to -1 when the rule acts before the fusion (project form), not after it.
    for form, expected in (("released", -3.0), ("project", -1.0)):
        sim = released_sim(scheme="EE", edge_sv_gate=None, same_lane_rule_form=form)
        place(sim, [(EAST, 80.0, 10.0), (EAST, 86.0, 10.0)])
        edge = np.full(sim.active.shape, np.nan)
        edge[0, 0] = -1.0
        sim.step(edge_accel=edge)
        assert sim.a[0, 0] == pytest.approx(expected)


# --- 7: entry -------------------------------------------------------------------------------
def test_entry_without_clearance_and_with_a_max() -> None:
    cfg = MiVeCCConfig(rows=1, cols=1, density_vplh=3600.0, min_headway_s=1.0,
                       model="released")
    sim = Simulator(cfg, seed=0)
    entered_a = []
    for _ in range(300):
        sim.step()
        new = sim.active[0] & (sim.s[0] == 0.0)
        entered_a += sim.a[0, new].tolist()
        arrived, queued = sim.arrived[0], sim.queued[0]
        assert arrived == queued + sim.in_network[0] + sim.exited[0] + sim.collided[0]
    assert entered_a and all(a == 3.0 for a in entered_a)
    assert sim.queued[0] == 0  # never held back: no clearance check
    with pytest.raises(ConfigError, match="entry_accel_mps2"):
        MiVeCCConfig(entry_accel_mps2=4.0)


# --- 8: edge selection ----------------------------------------------------------------------
def test_random_edge_selection_is_seeded_and_batch_independent() -> None:
    seeds = [np.random.SeedSequence(5).spawn(1)[0], np.random.SeedSequence(6).spawn(1)[0]]
    cfg = REL_1X1
    env = np.array([0, 0, 0, 1, 1])
    streams = edge_selection.SelectionStreams(seeds)
    k1 = edge_selection.edge_priority(np.zeros(5), env, streams, cfg, 0)
    k2 = edge_selection.edge_priority(np.zeros(3), env[:3],
                                      edge_selection.SelectionStreams(seeds[:1]), cfg, 0)
    np.testing.assert_array_equal(k1[:3], k2)
    assert ((k1 >= cfg.sv_min) & (k1 < cfg.sv_max)).all() and np.unique(k1).size == 5
    # the same step observed again draws nothing new; the next step draws new keys
    np.testing.assert_array_equal(edge_selection.edge_priority(np.zeros(5), env, streams, cfg, 0),
                                  k1)
    k3 = edge_selection.edge_priority(np.zeros(5), env, streams, cfg, 1)
    assert not np.isin(k3, k1).any()
    # a restarted environment draws its fresh generator's first numbers again
    streams.reset_at([1], seeds[1:])
    k4 = edge_selection.edge_priority(np.zeros(5), env, streams, cfg, 1)
    np.testing.assert_array_equal(k4[:3], k3[:3])
    np.testing.assert_array_equal(k4[3:], k1[3:])
    low = cfg.replace(edge_selection="lowest_sv")
    sv = np.arange(5.0)
    assert edge_selection.edge_priority(sv, env, streams, low, 0) is sv


def test_released_batch_with_growth_and_partial_resets_matches_single_runs() -> None:
    """Environment b of a released-model batch under partial resets and slot-array growth is
    bit-identical to a B = 1 simulator with the same seeds (the per-slot records of the stale
    action and the section-entry lag's positions before the move included)."""
    cfg = MiVeCCConfig(rows=1, cols=2, density_vplh=2400.0, model="released", scheme="E")
    seeds = [7, 8, 9]
    batch = Simulator(cfg, batch_size=3, seed=seeds, capacity=8)
    singles = [Simulator(cfg, seed=[s], capacity=8) for s in seeds]
    resets = {60: ([1], [21]), 130: ([0, 2], [22, 23]), 170: ([1], [24])}
    grown = {batch.capacity}
    for t in range(260):
        batch.step()
        for single in singles:
            single.step()
        grown.add(batch.capacity)
        if t in resets:
            envs, new = resets[t]
            batch.reset_at(envs, new)
            for b, s in zip(envs, new, strict=True):
                singles[b].reset([s])
        for b, single in enumerate(singles):
            got, ref = batch.vehicle_table(b), single.vehicle_table(0)
            for k in got:
                assert got[k].tobytes() == ref[k].tobytes(), f"step {t} env {b}: {k}"
            for k in ("exited", "collided", "collision_events", "sum_travel_velocity"):
                assert getattr(batch, k)[b] == getattr(single, k)[0], f"step {t} env {b}: {k}"
            sv_b = batch.safety.sv[batch.view.env == b]
            assert sv_b.tobytes() == single.safety.sv.tobytes(), f"step {t} env {b}: sv"
    assert len(grown) > 1  # the slot arrays grew during the run


def test_released_run_keeps_the_accounting() -> None:
    cfg = MiVeCCConfig(rows=2, cols=2, density_vplh=2100.0, model="released")
    sim = Simulator(cfg, batch_size=2, seed=[0, 1])
    for _ in range(400):
        sim.step()
        np.testing.assert_array_equal(
            sim.arrived, sim.queued + sim.in_network + sim.exited + sim.collided
        )
    assert (sim.exited > 0).all()


def test_section_entry_lag_hides_a_vehicle_that_just_entered() -> None:
    # a northbound vehicle at its entry (s = 0) projects at 155 + (0 - 145) = 10 on the
    # eastbound lane, 90 m behind the eastbound vehicle at 100
    for lag, expected in ((True, math.inf), (False, 90.0)):
        sim = released_sim(section_entry_lag=lag)
        place(sim, [(EAST, 100.0, 10.0), (NORTH, 0.0, 10.0)])
        assert sim.safety.d_back[0] == pytest.approx(expected)


def test_accel_record_commanded() -> None:
    # a lone vehicle (header: +3) at 12.9 m/s reaches v_max within the step: the project records
    # the applied 1.0 m/s^2, the released code the commanded 3; at v_max it records 0.
    for record, expected in (("applied", 1.0), ("commanded", 3.0)):
        sim = released_sim(accel_record=record)
        place(sim, [(EAST, 50.0, 12.9), (WEST, 50.0, 13.0)])
        sim.step()
        assert sim.a[0, 0] == pytest.approx(expected)
        assert sim.a[0, 1] == 0.0


def test_stale_action_in_the_speed_reset_band() -> None:
    # eastbound, centre at 150: the vehicle is last seen at s = 154.0 with a northbound vehicle
    # at 147 projected 3 m ahead (155 + 2; SV < 0, nearest ahead: a_end = SV / 3 < 0). Past
    # 155 it is off the virtual lanes: with
    # stale_action it keeps braking with that a_end during its move (then v is reset to 13);
    # without, it drives at 13 m/s with a = 0.
    for stale in (True, False):
        sim = released_sim(stale_action=stale)
        place(sim, [(EAST, 154.0, 13.0), (NORTH, 147.0, 13.0)])
        sv0 = float(sim.safety.sv[0])
        assert sv0 < 0
        sim.step()  # seen: a_end = sv0 / 3, now at 155.3 (uncontrolled)
        s1 = float(sim.s[0, 0])
        sim.step()  # unseen
        a = sv0 / 3.0
        if stale:
            assert sim.a[0, 0] == pytest.approx(a)
            assert sim.s[0, 0] == pytest.approx(s1 + 1.3 + 0.5 * a * 0.01)
        else:
            assert sim.a[0, 0] == 0.0 and sim.s[0, 0] == pytest.approx(s1 + 1.3)
        assert sim.v[0, 0] == 13.0


def test_released_same_lane_rule_leaves_the_first_vehicle_to_the_header_rule() -> None:
    # a vehicle with nothing ahead and the header rule off: the project form still gives +a_max
    for form, expected in (("project", 10.0), ("released", 20.0 / 3.0)):
        sim = released_sim(header_rule=False, same_lane_rule_form=form, a_max_mps2=10.0,
                           entry_accel_mps2=0.0)
        place(sim, [(EAST, 50.0, 10.0)])
        sim.step()
        assert sim.a[0, 0] == pytest.approx(expected)


def test_slot_growth_keeps_the_positions_before_the_move() -> None:
    """The section-entry lag compares each vehicle's section before and after the last move;
    growing the slot arrays in between (as a crowded entry does) must not change what it sees.
    Environment 1 of the batch has its flat slot numbers shifted by the growth."""
    cfg = MiVeCCConfig(rows=1, cols=2, density_vplh=2400.0, model="released", scheme="E")
    a = Simulator(cfg, batch_size=2, seed=[3, 4], capacity=64)
    b = Simulator(cfg, batch_size=2, seed=[3, 4], capacity=64)
    for _ in range(400):
        a.step()
        b.step()
        slots, s_old = a._prev_s
        lane = a.lane.ravel()[slots]
        k_old = sections.section_of(a.network, cfg, lane, s_old)[0]
        k_new = sections.section_of(a.network, cfg, lane, a.s.ravel()[slots])[0]
        if ((slots // a.capacity == 1) & (k_old != k_new) & a.active.ravel()[slots]).any():
            break  # a vehicle of env 1 changed section in this move
    else:
        pytest.fail("no section change in env 1")
    b._grow(2 * b.capacity)
    b._refresh_view()
    a._refresh_view()
    np.testing.assert_array_equal(a._seen, b._seen)
    assert a.safety.sv.tobytes() == b.safety.sv.tobytes()


def test_stale_record_reset_entering_the_corner_section() -> None:
    """``stale_corner_reset``: a vehicle that entered the south-east corner intersection's
    section in the last move (unseen there for a step) forgets where its nearest vehicle was
    and acts on |SV/3|; entering another section it keeps its record."""
    cfg = MiVeCCConfig(rows=3, cols=3, model="released", scheme="E")
    net = GridNetwork.from_config(cfg)
    corner = sections.corner_intersection(net)
    assert corner == 2 and net.intersection_xy[corner].tolist() == [450.0, 150.0]
    # lane 0 runs east at y = 145 through centres at s = 150, 300, 450 (the corner); sections
    # start 140 m before a centre: 310 m for the corner's, 160 m for the middle one's
    s_old = np.array([309.5, 159.5, 200.0])  # -> 310.5 (corner), 160.5 (middle), 201 (no change)
    s = s_old + 1.0
    view = build_view(net, cfg.projection_window_m, cfg.projection_clear_m,
                      np.ones((1, 3), dtype=bool), np.zeros((1, 3), dtype=np.int64), s[None])
    prev = (view.vehicle.copy(), s_old[np.argsort(view.vehicle)])
    entered = sections.corner_entries(net, cfg, view, view.s, prev)
    assert entered.tolist() == [bool(x == 310.5) for x in view.s]
    n = view.n_vehicles
    for reset, expected in ((False, -2.0), (True, 2.0)):
        sv_last = np.full(3, -6.0)  # last seen braking: SV -6, a_end = -2 when judged ahead
        closer_last = np.full(3, 50.0)  # its nearest was 50 m before its centre: ahead of it
        a = sections.stale_action(
            net, cfg, view, view.s, np.zeros(n, dtype=bool), np.zeros(n), np.zeros(n),
            np.full(n, np.inf), np.full(n, np.inf), sv_last, closer_last,
            prev if reset else None,
        )
        got = dict(zip(view.s.tolist(), a.tolist(), strict=True))
        assert got[310.5] == expected  # the corner entry: |SV/3| after the reset
        assert got[160.5] == -2.0 and got[201.0] == -2.0  # other sections: record kept
    assert RELEASED["stale_corner_reset"] is True and PAPER["stale_corner_reset"] is False
