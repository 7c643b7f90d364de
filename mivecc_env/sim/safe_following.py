"""Safe following with bounded braking (a Gipps-style rule) and planned speed profiles.

Used by the reservation and optimisation control modes (``sim/reservation.py``,
``sim/optimisation.py``), where the velocity floor is 0 and braking is bounded by
``b = a_max``. A vehicle at ``s`` with velocity ``v`` can always stop at its *stopping point*
``D = s + v^2 / (2 b)``; ``D`` never decreases under any acceleration ``>= -b``. A follower
keeps the invariant

    I:  s_lead - s >= gap  and  D_lead - D >= gap

towards its obstacle (own-lane leader, or a stop line = a standing obstacle). If ``I`` holds now
and the leader brakes at most at ``b``, braking at ``b`` keeps it one step later, so
:func:`safe_accel` (the largest acceleration that keeps ``I`` against the leader's worst case,
maximum braking) is always at least ``-b`` and no two vehicles of a lane come closer than
``gap`` (up to the discrete stop overshoot ``b dt^2 / 8`` = 4 mm).

Speed profiles: a planned trajectory moves its velocity towards a target at ``b`` and then
holds it (:func:`speed_profile`); positions follow eq. (1) exactly (``s' = s + (v + v') dt / 2``
for a constant acceleration within a step).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def brake_step(s: FloatArray, v: FloatArray, b: float, dt: float) -> tuple[FloatArray, FloatArray]:
    """Position [m] and velocity [m/s] after one step of maximum braking ``b`` (floor 0)."""
    a = np.maximum(-b, -v / dt)
    return s + v * dt + 0.5 * a * dt * dt, np.maximum(v + a * dt, 0.0)


def stopping_point(s: FloatArray, v: FloatArray, b: float) -> FloatArray:
    """Where a vehicle stops when it brakes at ``b`` from now [m]."""
    return s + v * v / (2.0 * b)


def safe_accel(
    s: FloatArray, v: FloatArray, s_obs: FloatArray, v_obs: FloatArray, gap: float, b: float,
    dt: float,
) -> FloatArray:
    """Largest acceleration [m/s^2] that keeps invariant ``I`` one step ahead.

    The obstacle (``s_obs``, ``v_obs``; ``inf`` position for none) is assumed to brake at ``b``
    during the step (its worst case). The result can be below ``-b`` only if ``I`` did not hold.
    """
    s_o1, v_o1 = brake_step(s_obs, v_obs, b, dt)
    d_o1 = stopping_point(s_o1, v_o1, b)
    with np.errstate(invalid="ignore"):
        a_pos = 2.0 * (s_o1 - gap - s - v * dt) / (dt * dt)
        # new velocity u: s + (v + u) dt / 2 + u^2 / (2 b) <= d_o1 - gap
        c = s + 0.5 * v * dt - (d_o1 - gap)
        disc = 0.25 * dt * dt - 2.0 * c / b
        u = b * (-0.5 * dt + np.sqrt(np.maximum(disc, 0.0)))
        a_stop = np.where(disc >= 0.0, (u - v) / dt, -np.inf)
    out = np.minimum(a_pos, a_stop)
    return np.where(np.isfinite(s_obs), out, np.inf)


def speed_profile(v0: float, target: FloatArray, n_steps: int, b: float, dt: float) -> FloatArray:
    """(n, n_steps + 1) velocities [m/s] of plans moving from ``v0`` to each target at ``b``."""
    j = np.arange(n_steps + 1, dtype=np.float64)
    delta = np.asarray(target, dtype=np.float64) - v0
    return v0 + np.sign(delta)[:, None] * np.minimum(np.abs(delta)[:, None], b * dt * j)


def positions(s0: float, u: FloatArray, dt: float) -> FloatArray:
    """(n, H + 1) positions [m] of velocity profiles ``u`` (eq. 1, constant accel per step)."""
    steps = 0.5 * dt * (u[:, :-1] + u[:, 1:])
    return s0 + np.concatenate([np.zeros((u.shape[0], 1)), np.cumsum(steps, axis=1)], axis=1)


def braking_tail(s_m: float, v_m: float, n_steps: int, b: float, dt: float) -> tuple[
    FloatArray, FloatArray
]:
    """(n_steps + 1,) positions and velocities braking at ``b`` from (``s_m``, ``v_m``)."""
    u = np.maximum(v_m - b * dt * np.arange(n_steps + 1), 0.0)[None, :]
    return positions(s_m, u, dt)[0], u[0]


def worst_case_leader(
    s0: float, v0: float, v_target: float | None, release_s: float, n_steps: int, b: float,
    dt: float,
) -> tuple[FloatArray, FloatArray]:
    """Lower bound of a leader's future positions and velocities, (n_steps + 1,) each.

    A leader with a plan (``v_target``) follows it until it reaches ``release_s`` and may brake
    at ``b`` from then on; a leader without one may brake at ``b`` from now.
    """
    if v_target is None:
        return braking_tail(s0, v0, n_steps, b, dt)
    u = speed_profile(v0, np.array([v_target]), n_steps, b, dt)
    s = positions(s0, u, dt)[0]
    u = u[0]
    past = np.flatnonzero(s >= release_s)
    if past.size == 0:
        return s, u
    m = int(past[0])
    tail_s, tail_u = braking_tail(float(s[m]), float(u[m]), n_steps - m, b, dt)
    return np.concatenate([s[:m], tail_s]), np.concatenate([u[:m], tail_u])
