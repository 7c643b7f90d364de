"""Compiled episode summaries: every key of every environment in one call (bit-identical).

:func:`mivecc_env.metrics.batch_summary` builds the summary of a batch from about forty small
numpy calls, which cost more than the rest of a B = 1 environment's infos together (the
ParallelEnv puts the summary in ``infos["cloud_0"]`` every step, the native TorchRL env in its
``info`` entries). :func:`fill` computes the same values with the same IEEE operations in one
compiled loop over the environments; the numpy code in :mod:`mivecc_env.metrics` stays the
reference (used without numba and compared key by key, bit for bit, in
``tests/sim/test_metrics.py``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mivecc_env.sim._numba import HAVE_NUMBA, njit

__all__ = ["HAVE_NUMBA", "N_KEYS", "fill"]

#: Rows :func:`fill` writes (``len(metrics.SUMMARY_KEYS)``; a key added there without a row
#: here makes ``metrics.batch_summary`` raise instead of returning an unwritten row).
N_KEYS = 23

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@njit
def _fill(out, exited, collision_events, collided, flagged, sum_v, sum_v_no_wait, sum_trip,
          sum_wait, sum_speed, vehicle_steps, env_steps, dt, upper, active, arrived, entered,
          passed, pass_time, pass_length, min_ttc, hist, min_pet, pet_samples, pet_under, min_dist,
          q, bin_s):  # pragma: no cover - compiled; compared with the numpy reference
    n_bins = hist.shape[1]
    for e in range(out.shape[1]):
        ex = exited[e]
        n = max(float(ex), 1.0)
        has = ex > 0
        sim_time = env_steps[e] * dt
        out[0, e] = sum_v[e] / n if has else 0.0
        out[1, e] = sum_v_no_wait[e] / n if has else 0.0
        out[2, e] = upper
        out[3, e] = sum_speed[e] / max(vehicle_steps[e], 1)
        out[4, e] = float(ex)
        out[5, e] = float(ex) * 3600.0 / sim_time if sim_time > 0 else 0.0
        out[6, e] = float(collision_events[e])
        out[7, e] = float(collided[e])
        queued = 0
        came = 0
        for j in range(arrived.shape[1]):
            queued += arrived[e, j] - entered[e, j]
            came += arrived[e, j]
        inside = 0
        for j in range(active.shape[1]):
            if active[e, j]:
                inside += 1
        out[8, e] = float(flagged[e])
        out[9, e] = float(queued)
        out[10, e] = float(inside)
        out[11, e] = float(came)
        out[12, e] = sum_trip[e] / n if has else 0.0
        out[13, e] = sum_wait[e] / n if has else 0.0
        out[14, e] = sim_time
        out[15, e] = pass_length[e] / (pass_time[e] if passed[e] > 0 else np.inf)
        out[16, e] = float(passed[e])
        out[17, e] = min_ttc[e]
        total = 0
        for j in range(n_bins):
            total += hist[e, j]
        p1 = np.inf
        if total > 0:
            need = max(np.ceil(total * (q / 100.0)), 1.0)
            cum = 0
            first = 0
            for j in range(n_bins):
                cum += hist[e, j]
                if cum >= need:
                    first = j
                    break
            if first < n_bins - 1:
                p1 = (first + 1) * bin_s
        out[18, e] = p1
        out[19, e] = min_pet[e]
        out[20, e] = float(pet_under[e])
        out[21, e] = float(pet_samples[e])
        out[22, e] = min_dist[e]


def fill(
    out: FloatArray, counters: dict[str, NDArray], dt_s: float, upper_bound_mps: float,
    active: NDArray[np.bool_], arrived: IntArray, entered: IntArray,
    passed: IntArray, pass_time_s: FloatArray, pass_length_m: FloatArray,
    min_ttc_s: FloatArray, ttc_hist: IntArray, min_pet_s: FloatArray, pet_samples: IntArray,
    pet_under: IntArray, min_distance_m: FloatArray, q: float, bin_s: float,
) -> FloatArray:
    """Write the summary of every environment into ``out``, (23, B), rows in
    ``metrics.SUMMARY_KEYS`` order, and return it.

    Args:
        counters: ``metrics.COUNTERS`` -> (B,) (already minus a chunk's start, if any).
        dt_s: step length [s]; ``upper_bound_mps``: the config's bound [m/s].
        active: (B, capacity) vehicle slots in use; ``arrived`` / ``entered``: (B, n_lanes).
        passed / pass_time_s / pass_length_m: (B,) passing-time accumulators.
        min_ttc_s ... min_distance_m: the near-miss accumulators (``ttc_hist``: (B, bins + 1)).
        q: TTC percentile [%]; ``bin_s``: TTC bin width [s].
    """
    c = counters
    _fill(out, c["exited"], c["collision_events"], c["collided"], c["released_flagged"],
          c["sum_travel_velocity"],
          c["sum_travel_velocity_no_wait"], c["sum_trip_time"], c["sum_wait_time"],
          c["sum_speed_samples"], c["vehicle_steps"], c["env_steps"], float(dt_s),
          float(upper_bound_mps), active, arrived, entered, passed, pass_time_s, pass_length_m,
          min_ttc_s, ttc_hist, min_pet_s, pet_samples, pet_under, min_distance_m, float(q),
          float(bin_s))
    return out
