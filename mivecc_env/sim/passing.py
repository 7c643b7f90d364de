"""Passing times to the released code's metric mark (the released-style velocity).

The authors' released code measures a vehicle's *passing time*: from its entry into the
network (no entry-queue wait) until it is :data:`MARK_PAST_LAST_CENTRE_M` = 5 m past the last
intersection centre of its lane, and reports ``path length / mean passing time``. On the 3x3
grid with 150 m segments the mark is ``3 * 150 + 5 = 455 m`` from every lane's entry (with the
released lane offset of 5 m it is the lane's last conflict point), on 1x1 ``155 m``. The exit
link after it, where every scheme cruises at v_max, is left out.

:class:`PassingTimes` accumulates, per environment, the number of vehicles that crossed the mark,
the sum of their passing times and the sum of their path lengths; the crossing time is
interpolated within the step like the exit time. The released-style velocity of an environment
is ``sum(path lengths) / sum(passing times)`` = ``mean length / mean time``, which is the
released ``455 m / mean(time)`` whenever every lane has the same mark (square grids); it is not
the mean of per-vehicle velocities.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mivecc_env.sim.network import GridNetwork

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: The mark is this far past the last intersection centre of a lane [m] (released code).
MARK_PAST_LAST_CENTRE_M = 5.0


def mark_s(network: GridNetwork) -> FloatArray:
    """(n_lanes,) distance of each lane's metric mark from its entry [m]."""
    centres = np.where(np.isfinite(network.lane_centres_s), network.lane_centres_s, -np.inf)
    return centres.max(axis=1) + MARK_PAST_LAST_CENTRE_M


class PassingTimes:
    """Per-environment passing-time accumulators (arrays of shape (B,)).

    Attributes:
        count: vehicles that crossed the mark.
        sum_time_s: sum of their passing times (mark crossing - network entry) [s].
        sum_length_m: sum of their path lengths (entry to mark) [m].
    """

    def __init__(self, network: GridNetwork, batch_size: int) -> None:
        self.mark_s = mark_s(network)
        self.batch_size = batch_size
        self.count = np.zeros(batch_size, dtype=np.int64)
        self.sum_time_s = np.zeros(batch_size)
        self.sum_length_m = np.zeros(batch_size)

    def reset_at(self, envs: NDArray[np.bool_] | IntArray | slice = slice(None)) -> None:
        """Zero the accumulators of some environments (a mask, indices or a slice)."""
        self.count[envs] = 0
        self.sum_time_s[envs] = 0.0
        self.sum_length_m[envs] = 0.0

    def record(
        self, env: IntArray, lane: IntArray, s_old: FloatArray, s_new: FloatArray,
        t_enter: FloatArray, t0_s: float | FloatArray, dt_s: float,
    ) -> None:
        """Record the vehicles that crossed their mark during one step.

        Args:
            env / lane: (n,) environment and lane of each moved vehicle.
            s_old / s_new: (n,) position before and after the step [m].
            t_enter: (n,) time each vehicle entered the network [s].
            t0_s: time at the start of the step [s], one value or one per environment
                (the same clock as ``t_enter``); dt_s: step length [s].
        """
        mark = self.mark_s[lane]
        idx = np.flatnonzero((s_old < mark) & (s_new >= mark))
        if idx.size == 0:
            return
        frac = (mark[idx] - s_old[idx]) / np.maximum(s_new[idx] - s_old[idx], 1e-12)
        b = self.batch_size
        e = env[idx]
        t0 = np.broadcast_to(np.asarray(t0_s, dtype=np.float64), (b,))[e]
        t_cross = t0 + np.clip(frac, 0.0, 1.0) * dt_s
        self.count += np.bincount(e, minlength=b)
        self.sum_time_s += np.bincount(e, t_cross - t_enter[idx], minlength=b)
        self.sum_length_m += np.bincount(e, mark[idx], minlength=b)

    def velocity_mps(self) -> FloatArray:
        """(B,) released-style velocity ``sum(length) / sum(time)`` [m/s].

        0 where no vehicle has passed its mark yet (``count == 0``), like the average travel
        velocity before the first exit.
        """
        return self.sum_length_m / np.where(self.count > 0, self.sum_time_s, np.inf)
