"""End node: a_end from SV, the same-lane rule and the fusion of edge and cloud actions."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.end_node import (
    apply_same_lane_rule,
    end_accel,
    fuse,
    same_lane_threshold_m,
)
from tests.sim._scenario import EAST, SOUTH, hand_sim, place

CFG = MiVeCCConfig()
LITERAL = CFG.replace(end_rule="literal")
INF = np.inf
NAN = np.nan


def arr(*x: float) -> np.ndarray:
    return np.array(x, dtype=np.float64)


def test_end_accel_sensible() -> None:
    sv = arr(-6.0, -6.0, 6.0, 6.0, -6.0, 20.0)
    d_front = arr(5.0, 10.0, 5.0, 10.0, 7.0, INF)
    d_back = arr(10.0, 5.0, 10.0, 5.0, 7.0, INF)
    # nearest ahead -> SV / 3; nearest behind -> |SV / 3|; a tie counts as ahead;
    # nobody around (inf <= inf) -> ahead, +20 / 3
    np.testing.assert_allclose(
        end_accel(sv, d_front, d_back, CFG), [-2.0, 2.0, 2.0, 2.0, -2.0, 20.0 / 3.0]
    )


def test_end_accel_literal() -> None:
    sv = arr(-6.0, -6.0, 6.0, 6.0)
    d_front = arr(5.0, 10.0, 5.0, 10.0)
    d_back = arr(10.0, 5.0, 10.0, 5.0)
    # as printed: |SV / 3| when d_f <= d_b, SV / 3 otherwise
    np.testing.assert_allclose(end_accel(sv, d_front, d_back, LITERAL), [2.0, -2.0, 2.0, 2.0])


def test_end_accel_uses_eta() -> None:
    cfg = CFG.replace(eta=4.0)
    np.testing.assert_allclose(end_accel(arr(-6.0), arr(1.0), arr(2.0), cfg), [-1.5])


def test_fuse_edge() -> None:
    a_end = arr(1.0, 1.0, -1.0, -1.0, 1.0, -1.0, 0.0, 1.0)
    a_edge = arr(2.0, 0.5, -2.0, -0.5, -2.0, 2.0, 2.0, NAN)
    sv = np.zeros(8)
    out = fuse(a_end, sv, a_edge, None, CFG)
    # agree -> max(a_edge, a_end); disagree (or a_end = 0) -> a_end; NaN -> a_end
    np.testing.assert_allclose(out, [2.0, 1.0, -1.0, -0.5, 1.0, -1.0, 0.0, 1.0])


def test_fuse_without_coordinators_only_clips() -> None:
    np.testing.assert_allclose(
        fuse(arr(20.0 / 3.0, -20.0 / 3.0, 1.0), np.zeros(3), None, None, CFG), [3.0, -3.0, 1.0]
    )


def test_fuse_edge_sv_gate() -> None:
    cfg = CFG.replace(edge_sv_gate=-2.0)
    a_end, a_edge = arr(1.0, 1.0, 1.0), arr(2.5, 2.5, 2.5)
    sv = arr(-3.0, -2.0, -1.0)
    # fused only where SV > -2 (strictly)
    np.testing.assert_allclose(fuse(a_end, sv, a_edge, None, cfg), [1.0, 1.0, 2.5])
    np.testing.assert_allclose(fuse(a_end, sv, a_edge, None, CFG), [2.5, 2.5, 2.5])


def test_fuse_cloud() -> None:
    a_end = arr(1.0, 1.0, 20.0 / 3.0, 1.0, 0.0)
    a_cloud = arr(-2.0, NAN, 3.0, 3.0, 1.0)
    # (1 - 0.2) a + 0.2 a_cloud: 0.8 - 0.4 = 0.4; NaN keeps a; 5.333 + 0.6 -> clipped to 3;
    # 0.8 + 0.6 = 1.4; 0 + 0.2 = 0.2 (a cloud action is fused even when a_end is 0)
    np.testing.assert_allclose(fuse(a_end, np.zeros(5), None, a_cloud, CFG),
                               [0.4, 1.0, 3.0, 1.4, 0.2])


def test_fuse_edge_then_cloud() -> None:
    # edge 2.5 agrees with a_end 1 -> 2.5; cloud -3: 0.8 * 2.5 - 0.6 = 1.4
    out = fuse(arr(1.0), arr(0.0), arr(2.5), arr(-3.0), CFG.replace(omega=0.2))
    np.testing.assert_allclose(out, [1.4])
    np.testing.assert_allclose(fuse(arr(1.0), arr(0.0), arr(2.5), arr(-3.0),
                                    CFG.replace(omega=1.0)), [-3.0])


def test_same_lane_threshold() -> None:
    # (13 - 6)^2 / (4 * 3) + 2.2 = 4.0833 + 2.2
    assert same_lane_threshold_m(CFG) == pytest.approx(6.283333333333333)


def test_same_lane_rule_cases() -> None:
    a_end = arr(1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    leader_gap = arr(5.0, 5.0, 20.0, 5.0, 20.0, 6.3, 5.0)
    follower_gap = arr(20.0, 5.0, 5.0, 5.0, 20.0, 20.0, INF)
    to_conflict = arr(60.0, 60.0, 60.0, 40.0, 60.0, 60.0, 60.0)
    d_front = arr(5.0, 5.0, 20.0, 5.0, 20.0, 6.3, INF)
    out = apply_same_lane_rule(a_end, leader_gap, follower_gap, to_conflict, d_front, CFG)
    # close leader -> -3; both close -> 0; close follower -> +3; within 50 m of the conflict
    # point -> a_end; nothing close -> a_end; 6.3 m is beyond the 6.283 m threshold;
    # nothing ahead on the virtual lane -> +3
    np.testing.assert_array_equal(out, [-3.0, 0.0, 3.0, 1.0, 1.0, 1.0, 3.0])


def test_same_lane_rule_horizon_boundary() -> None:
    # "more than 50 m before the conflict point": 50 m exactly does not apply
    out = apply_same_lane_rule(arr(1.0, 1.0), arr(5.0, 5.0), arr(INF, INF), arr(50.0, 50.01),
                               arr(5.0, 5.0), CFG)
    np.testing.assert_array_equal(out, [1.0, -3.0])


# --- the same, wired through the simulator ------------------------------------------------
# An eastbound ego at s = 130 with a southbound vehicle at 135, projected 5 m behind it
# (145 + 135 - 155 = 125) and nothing ahead: SV = 10 ln(5 / 10) + 2 = -4.9315 (no TTC risk at
# equal speeds, no front vehicle), nearest behind -> a_end = |SV / 3| = 1.6438.
A_END = 1.6438239351998176


def _ego_scene(**overrides: object) -> tuple:
    sim = hand_sim(MiVeCCConfig(rows=1, cols=1, **overrides))  # type: ignore[arg-type]
    place(sim, [(EAST, 130.0, 10.0), (SOUTH, 135.0, 10.0)])
    return sim, np.full((1, sim.capacity), np.nan)


def test_simulator_safety_value_of_ego() -> None:
    sim, _ = _ego_scene()
    assert sim.safety.sv[0] == pytest.approx(-4.931471805599453, abs=1e-9)
    assert sim.safety.ttc[0] == INF


def test_simulator_ttc_of_ego() -> None:
    # the projected vehicle behind closes in at 13 - 6 = 7 m/s: TTC = 5 / 7 s,
    # SV = SV_d + SV_t = 10 ln(5 / 10) - (1.5 / tanh(5 / 7))^2 = -6.9315 - 5.9807 (SV_t
    # replaces the +2 of the safe case)
    sim = hand_sim()
    place(sim, [(EAST, 130.0, 6.0), (SOUTH, 135.0, 13.0)])
    assert sim.safety.ttc[0] == pytest.approx(5.0 / 7.0)
    assert sim.safety.sv[0] == pytest.approx(-12.912219716198749, abs=1e-9)


@pytest.mark.parametrize(
    ("scheme", "edge", "cloud", "expected"),
    [
        ("E", 2.5, -3.0, A_END),  # scheme E ignores both coordinators
        ("EE", 2.5, -3.0, 2.5),  # agree -> max; the cloud is ignored
        ("EE", -1.0, NAN, A_END),  # disagree -> a_end
        ("EEC", NAN, -3.0, 0.8 * A_END - 0.6),  # 0.7151
        ("EEC", 2.5, -3.0, 0.8 * 2.5 - 0.6),  # 1.4
    ],
)
def test_simulator_applies_scheme(scheme: str, edge: float, cloud: float, expected: float) -> None:
    sim, blank = _ego_scene(scheme=scheme)
    edge_accel, cloud_accel = blank.copy(), blank.copy()
    edge_accel[0, 0], cloud_accel[0, 0] = edge, cloud
    sim.step(edge_accel, cloud_accel)
    assert sim.a[0, 0] == pytest.approx(expected, abs=1e-9)
    # eq. (1) with the fused acceleration
    assert sim.s[0, 0] == pytest.approx(130.0 + 1.0 + 0.005 * expected, abs=1e-9)
