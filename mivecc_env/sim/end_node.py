"""End node: the on-board rules and the fusion of end, edge and cloud actions (Algorithm 3).

All functions are vectorised over vehicles. A missing coordinator action is ``NaN``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig

FloatArray = NDArray[np.float64]


def same_lane_threshold_m(config: MiVeCCConfig) -> float:
    """Gap below which the released code's same-lane rule reacts [m].

    ``(v_max - v_min)^2 / (4 a_max) + 2.2``: 6.28 m with the paper's constants.
    """
    dv = config.v_max_mps - config.v_min_mps
    return dv * dv / (4.0 * config.a_max_mps2) + 2.2


def end_accel(
    sv: FloatArray, d_front_m: FloatArray, d_back_m: FloatArray, config: MiVeCCConfig
) -> FloatArray:
    """On-board action ``a_end`` [m/s^2] from the safety value (before any clipping).

    ``sensible`` (default): nearest vehicle ahead (``d_f <= d_b``) -> ``SV / eta`` (brake when
    unsafe), nearest behind -> ``|SV / eta|`` (move away from the follower).
    ``literal``: the cases as printed in Algorithm 3 (``|SV / eta|`` when ``d_f <= d_b``).
    """
    ratio = sv / config.eta
    nearest_ahead = d_front_m <= d_back_m
    if config.end_rule == "sensible":
        return np.where(nearest_ahead, ratio, np.abs(ratio))
    return np.where(nearest_ahead, np.abs(ratio), ratio)


def entry_action(a_end: FloatArray, s_m: FloatArray, config: MiVeCCConfig) -> FloatArray:
    """The released code's first step: a vehicle still at the lane entry (``s = 0``: it entered
    at the end of the last step) acts on ``entry_accel_mps2`` instead of its SV (the released
    code starts every vehicle with SV 10, whose ``SV / eta`` is clipped to ``+a_max``).
    A no-op when ``entry_accel_mps2 = 0`` (default)."""
    if config.entry_accel_mps2 == 0.0:
        return a_end
    return np.where(s_m == 0.0, config.entry_accel_mps2, a_end)


def apply_same_lane_rule(
    a_end: FloatArray,
    leader_gap_m: FloatArray,
    follower_gap_m: FloatArray,
    to_conflict_m: FloatArray,
    d_front_m: FloatArray,
    config: MiVeCCConfig,
) -> FloatArray:
    """The released code's extra same-lane rule ("priori knowledge"), applied over ``a_end``.

    More than ``same_lane_rule_horizon_m`` before the next conflict point, a vehicle closer than
    :func:`same_lane_threshold_m` to its own-lane leader brakes at ``-a_max`` (``0`` if its
    follower is that close too); one whose follower is that close accelerates at ``+a_max``.
    A vehicle with nothing ahead on its virtual lane accelerates at ``+a_max`` (project form;
    the released form leaves that to ``header_rule``).
    """
    thr = same_lane_threshold_m(config)
    far = to_conflict_m > config.same_lane_rule_horizon_m
    close_lead = far & (leader_gap_m < thr)
    close_follow = far & (follower_gap_m < thr)
    out = np.where(close_follow, config.a_max_mps2, a_end)
    out = np.where(close_lead, np.where(close_follow, 0.0, -config.a_max_mps2), out)
    if config.same_lane_rule_form == "released":  # its first vehicle: the header rule instead
        return out
    return np.where(np.isinf(d_front_m), config.a_max_mps2, out)


def fuse(
    a_end: FloatArray,
    sv: FloatArray,
    a_edge: FloatArray | None,
    a_cloud: FloatArray | None,
    config: MiVeCCConfig,
    after_edge: Callable[[FloatArray], FloatArray] | None = None,
    raw_edge: NDArray[np.bool_] | None = None,
) -> FloatArray:
    """Executed acceleration [m/s^2] from end, edge and cloud actions (Algorithm 3).

    * Edge (where given and, if ``edge_sv_gate`` is set, where ``SV > edge_sv_gate``):
      ``max(a_edge, a_end)`` when ``a_edge * a_end > 0``, else ``a_end`` (the rule vetoes).
    * ``raw_edge`` (per vehicle; the released trainer's exploration on every other training
      step): where true and an edge action is given, ``a_edge`` replaces the rule's action
      unmodified (no SV gate, no veto, no max).
    * ``after_edge`` (the released code's same-lane rule) then rewrites the result.
    * Cloud (where given): ``(1 - omega) a + omega a_cloud``.
    * Finally clipped to ``[-a_max, a_max]`` (documented; the velocity bounds are applied by the
      motion model).
    """
    a = a_end
    if a_edge is not None:
        use = ~np.isnan(a_edge)
        if config.edge_sv_gate is not None:
            use &= sv > config.edge_sv_gate
        edge = np.where(use, a_edge, 0.0)
        agree = use & (edge * a > 0)
        a = np.where(agree, np.maximum(edge, a), a)
        if raw_edge is not None:
            a = np.where(raw_edge & ~np.isnan(a_edge), np.nan_to_num(a_edge), a)
    if after_edge is not None:
        a = after_edge(a)
    if a_cloud is not None:
        use = ~np.isnan(a_cloud)
        a = np.where(use, (1.0 - config.omega) * a + config.omega * np.where(use, a_cloud, 0.0), a)
    return np.clip(a, -config.a_max_mps2, config.a_max_mps2)


def bounded_motion(
    s_m: FloatArray, v_mps: FloatArray, a_mps2: FloatArray, v_lo: float, v_hi: float, dt_s: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Motion by eq. (1) with the acceleration clipped so that ``v`` stays in ``[v_lo, v_hi]``.

    Returns the new position [m], velocity [m/s] and the acceleration actually applied [m/s^2].
    """
    a = np.clip(a_mps2, (v_lo - v_mps) / dt_s, (v_hi - v_mps) / dt_s)
    s_new = s_m + v_mps * dt_s + 0.5 * a * dt_s * dt_s
    v_new = np.clip(v_mps + a * dt_s, v_lo, v_hi)
    return s_new, v_new, a
