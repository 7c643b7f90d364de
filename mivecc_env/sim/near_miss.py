"""Near-miss (surrogate safety) measures of an episode, accumulated per environment.

Collisions are rare; these measures say how close the traffic came to one. All are per
environment, accumulated by :meth:`NearMissStats.record_step` once per simulator step and reset
with the episode (:meth:`NearMissStats.reset_at` for some environments). Definitions:

* **Time to collision (TTC)** on the virtual lanes. At the start of every step, for every
  vehicle whose nearest point ahead on its virtual lane (own-lane leader or a projected
  crossing vehicle, in the simulator's view) is closing in (``v_ego > v_front``):
  ``TTC = d_front / (v_ego - v_front)`` [s] with ``d_front`` the centre distance on the virtual
  lane: the model's own TTC (the one SV_t reacts to below 1 s,
  :func:`mivecc_env.sim.safety.time_to_collision`), the time until the two points meet at
  constant speeds (for a projected vehicle: until both are equally far from their conflict
  point). An own-lane pair touches (2 m) ``2 m / closing`` earlier. Vehicle-steps without a
  closing vehicle ahead are not samples. A point level with the ego (the view orders points
  closer than its 0.1 mm resolution by input, so the "point ahead" can sit up to 0.1 mm behind)
  counts at distance 0: every TTC is ``>= 0``. Under ``control="signalized"`` the vehicles
  waiting at a red light are projected too (at 0 m/s): a vehicle driving on green past the
  projection of a waiting crossing vehicle gives TTC samples down to 0 although the two never
  meet, so there ``min_ttc_s`` / ``ttc_p1_s`` measure projected spacing, not danger; compare
  signalized and unsignalized safety with ``min_pet_s`` and ``min_distance_m``.
  ``min_ttc_s`` is the episode minimum; ``ttc_p1_s`` the 1st percentile of all samples, read
  from a histogram with fixed bins of :data:`TTC_BIN_S` = 0.01 s on ``[0, TTC_HIST_MAX_S =
  20 s)`` plus one overflow bin: the upper edge of the first bin at which the cumulative count
  reaches 1 % of the samples (exact to 0.01 s, rounded up), ``inf`` when that is the overflow
  bin.
* **Post-encroachment time (PET)** at the conflict points. A vehicle *reaches* a conflict point
  when its centre is ``vehicle_length / 2`` before it (its front at the point) and *leaves* it
  when its centre is ``vehicle_length / 2`` past it (its rear clear); both times are
  interpolated within the step. When a vehicle reaches a point and the vehicle that last left
  that point came from the crossing lane, ``PET = t_reach - t_leave`` is one sample (a crossing
  encounter; a vehicle following one of its own lane is not a sample). ``min_pet_s`` is the
  minimum, ``pet_under_1s`` the number of samples below :data:`PET_THRESHOLD_S` = 1 s and
  ``pet_samples`` their number. A vehicle that reaches the point while the crossing one is still
  on it overlaps it (both centres within 1 m of the point: a collision under the 2 m check); it
  is not a PET sample and shows in the collisions and ``min_distance_m`` instead.
* **Minimum distance** ``min_distance_m``: the smallest centre distance between any two
  vehicles of the environment after any step's motion (before collided vehicles are removed,
  so a collision shows as a distance below 2 m). Computed exactly: own-lane neighbours
  (``|delta s|``) and crossing-lane pairs near their conflict point
  (``hypot(delta_1, delta_2)``) cover every pair closer than ``2 * lane_offset_m``; while an
  environment's minimum is not below that, the opposite lanes of each road are compared too
  (``hypot(2 lane_offset, delta)``, exact below ``segment - 2 lane_offset``, the distance of
  parallel roads), and while it is not below that either (a nearly empty network), every pair.

:meth:`NearMissStats.record_step` runs a compiled kernel (``near_miss_kernel``) when numba is
installed; the numpy code here is its reference (bit-identical, compared in the tests).

A minimum without samples is ``inf`` (the minimum of nothing; so is ``ttc_p1_s``), never NaN:
the summaries travel in the environments' infos, whose equality checks NaN would break.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from mivecc_env.sim import near_miss_kernel
from mivecc_env.sim._numba import HAVE_NUMBA
from mivecc_env.sim.network import GridNetwork
from mivecc_env.sim.virtual_lane import VirtualLaneView

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Width of a TTC histogram bin [s] (the resolution of ``ttc_p1_s``).
TTC_BIN_S = 0.01
#: TTCs at or above this go to the overflow bin [s].
TTC_HIST_MAX_S = 20.0
#: ``pet_under_1s`` counts PET samples below this [s].
PET_THRESHOLD_S = 1.0
#: Percentile of the TTC samples reported as ``ttc_p1_s`` [%].
TTC_PERCENTILE = 1.0

_N_TTC_BINS = round(TTC_HIST_MAX_S / TTC_BIN_S)


def ttc_percentile(hist: NDArray[np.int64], q: float = TTC_PERCENTILE) -> FloatArray:
    """(B,) ``q``-th percentile [s] of TTC histograms ``(B, n_bins + 1)`` (see module docs).

    The upper edge of the first bin whose cumulative count reaches ``q`` % of the samples;
    ``inf`` if that is the overflow bin or there are no samples.
    """
    total = hist.sum(axis=1)
    need = np.maximum(np.ceil(total * (q / 100.0)), 1)
    first = (np.cumsum(hist, axis=1) >= need[:, None]).argmax(axis=1)
    edge = np.where(first >= hist.shape[1] - 1, np.inf, (first + 1) * TTC_BIN_S)
    return np.where(total > 0, edge, np.inf)


#: :func:`ttc_percentile_of` accumulates this many bins first (all of them if too few).
_PREFIX_BINS = 256


def ttc_percentile_of(hist: NDArray[np.int64], q: float = TTC_PERCENTILE) -> float:
    """:func:`ttc_percentile` of one histogram ``(n_bins + 1,)``, as a float (bit-identical).

    For the per-step summary of one environment: the same rule with scalar arithmetic, and the
    cumulative count of a prefix of the bins first (the percentile bin is usually near the
    start; all bins when the prefix is short of the count needed).
    """
    total = int(hist.sum())
    if total == 0:
        return np.inf
    need = max(math.ceil(total * (q / 100.0)), 1)
    cum = np.cumsum(hist[:_PREFIX_BINS])
    if cum[-1] < need:
        cum = np.cumsum(hist)
    first = int(cum.searchsorted(need))  # the first bin whose cumulative count reaches need
    return np.inf if first >= hist.shape[0] - 1 else (first + 1) * TTC_BIN_S


class NearMissStats:
    """Per-environment near-miss accumulators (see the module docstring).

    Attributes (leading axis B):
        min_ttc_s: minimum TTC [s], ``inf`` before any sample.
        ttc_hist: (B, n_bins + 1) TTC sample counts per bin (last: overflow).
        min_pet_s: minimum PET [s], ``inf`` before any sample.
        pet_samples / pet_under: number of PET samples / of those below 1 s.
        min_distance_m: minimum centre distance [m], ``inf`` before two vehicles coexist.
        last_leave_s / last_leave_side: (B * n_cp,) time [s] (environment clock; -inf if none)
            and side (0 horizontal, 1 vertical lane; -1 if none) of the last vehicle that left
            each conflict point.
    """

    def __init__(self, network: GridNetwork, batch_size: int, vehicle_length_m: float) -> None:
        self.network = network
        self.batch_size = batch_size
        self.length_m = float(vehicle_length_m)
        b = batch_size
        self.min_ttc_s = np.full(b, np.inf)
        self.ttc_hist = np.zeros((b, _N_TTC_BINS + 1), dtype=np.int64)
        self.min_pet_s = np.full(b, np.inf)
        self.pet_samples = np.zeros(b, dtype=np.int64)
        self.pet_under = np.zeros(b, dtype=np.int64)
        self.min_distance_m = np.full(b, np.inf)
        self.last_leave_s = np.full(b * network.n_cp, -np.inf)
        self.last_leave_side = np.full(b * network.n_cp, -1, dtype=np.int64)
        # Side (0 horizontal, 1 vertical) of each lane at its conflict points.
        self._lane_side = (~network.lane_horizontal).astype(np.int64)
        self._build_marks()
        #: Use the compiled kernel (bit-identical to the numpy reference) when numba is there.
        self.use_kernel = HAVE_NUMBA

    def _build_marks(self) -> None:
        """Conflict points and reach / leave marks of each (lane, intersection on it)."""
        net, half = self.network, 0.5 * self.length_m
        n_on = net.lane_centres_s.shape[1]
        cp_s = net.lane_cp_s[:, : 2 * n_on].reshape(net.n_lanes, n_on, 2)
        cp = net.lane_cp[:, : 2 * n_on].reshape(net.n_lanes, n_on, 2)
        side = self._lane_side[:, None, None]
        #: (n_lanes, n_on, 2) key ``cp * 2 + side`` of the two points of each intersection
        self._cp_s = cp_s
        self._cp_side_key = cp * 2 + side
        # (n_lanes, n_on, 4): reach and leave of the first point, then of the second
        self._mark_pos = np.stack([cp_s[..., 0] - half, cp_s[..., 0] + half,
                                   cp_s[..., 1] - half, cp_s[..., 1] + half], axis=2)
        self._mark_cp = np.repeat(cp, 2, axis=2)
        self._mark_leave = np.array([False, True, False, True])
        seg = net.segment_length_m
        # A vehicle is near (the marks and points of) only its nearest centre while it moves
        # less than this in a step [m] and the points are closer to it than a segment allows.
        self._local_step_m = 0.5 * seg - net.lane_offset_m - half
        self._local = 3.0 * net.lane_offset_m < 0.5 * seg
        # (n_lanes * n_on, ...) views for one-index lookups by lane * n_on + centre
        self._mark_pos_flat = self._mark_pos.reshape(-1, 4)
        self._mark_cp_flat = self._mark_cp.reshape(-1, 4)
        self._cp_s_flat = cp_s.reshape(-1, 2)
        self._cp_side_key_flat = self._cp_side_key.reshape(-1, 2)
        # the kernel's float parameters, and its reusable work arrays
        self._geom = np.array([seg, net.lane_offset_m, half, self._local_step_m,
                               1.0 / TTC_BIN_S, PET_THRESHOLD_S])
        self._scratch = near_miss_kernel.NearMissScratch(self.batch_size, net.n_cp)

    def reset_at(self, envs: NDArray[np.bool_] | IntArray | slice = slice(None)) -> None:
        """Clear the accumulators of some environments (a mask, indices or a slice)."""
        self.min_ttc_s[envs] = np.inf
        self.ttc_hist[envs] = 0
        self.min_pet_s[envs] = np.inf
        self.pet_samples[envs] = 0
        self.pet_under[envs] = 0
        self.min_distance_m[envs] = np.inf
        leave = self.last_leave_s.reshape(self.batch_size, -1)
        leave[envs] = -np.inf
        self.last_leave_side.reshape(self.batch_size, -1)[envs] = -1

    # ------------------------------------------------------------------------------------
    def record_step(
        self, view: VirtualLaneView, v_old: FloatArray, s_new: FloatArray,
        gone: NDArray[np.bool_], t0_s: float | FloatArray, dt_s: float,
    ) -> None:
        """Update every measure with one step.

        Args:
            view: the virtual-lane view at the start of the step.
            v_old: (n,) velocities at the start of the step [m/s] (view order).
            s_new: (n,) positions after the step's motion [m].
            gone: (n,) True for vehicles that left the network in this step.
            t0_s: time at the start of the step [s], one value or one per environment.
            dt_s: step length [s].
        """
        if view.n_vehicles == 0:
            return
        net = self.network
        if self.use_kernel:
            t0 = t0_s  # the core's (B,) clocks as they are; else broadcast and copied
            if not (isinstance(t0, np.ndarray) and t0.dtype == np.float64
                    and t0.shape == (self.batch_size,) and t0.flags.c_contiguous):
                t0 = np.ascontiguousarray(np.broadcast_to(
                    np.asarray(t0_s, dtype=np.float64), (self.batch_size,)))
            n, n_on, w = view.n_vehicles, net.lane_centres_s.shape[1], self._scratch
            w.ensure(n, n_on)
            near_miss_kernel.record(
                view.env, view.lane, view.s, s_new, v_old, view.front_point, view.point_vehicle,
                view.d_front, view.leader, gone, t0, float(dt_s),
                self._mark_pos_flat, self._mark_cp_flat, self._cp_s_flat,
                self._cp_side_key_flat, self._lane_side, self._geom, n_on, net.n_cp,
                self._local, _N_TTC_BINS, self.min_ttc_s, self.ttc_hist, self.min_pet_s,
                self.pet_samples, self.pet_under, self.last_leave_s, self.last_leave_side,
                self.min_distance_m, w.ints, w.floats,
            )
            self._far_pairs(view, s_new, gone)
            return
        self._record_ttc(view, v_old)
        s_old = view.s
        moved = s_new - s_old
        max_move = float(moved.max())
        off, half, seg = net.lane_offset_m, 0.5 * self.length_m, net.segment_length_m
        # Vehicles near an intersection centre (centres sit at multiples of a segment): only
        # they can cross a reach / leave mark or be within 2 * offset of a conflict point.
        k = np.rint(s_new * (1.0 / seg))
        local = self._local and max_move <= self._local_step_m
        if local:
            radius = off + max(half + max_move, 2.0 * off)
            near = (np.abs(s_new - k * seg) < radius).nonzero()[0]
        else:  # long steps or wide lane offsets: check every conflict point of every lane
            near = np.arange(s_new.size)
        step_min = self._own_lane_gaps(view, s_new, gone)
        if near.size:
            lane, env, sn = view.lane[near], view.env[near], s_new[near]
            so = s_old[near]
            if local:
                n_on = net.lane_centres_s.shape[1]
                j = np.minimum(np.maximum(k[near].astype(np.int64) - 1, 0), n_on - 1)
                j += lane * n_on  # row of (lane, centre) in the flattened tables
                mark_pos, mark_cp = self._mark_pos_flat[j], self._mark_cp_flat[j]
                cp_s, cp_key = self._cp_s_flat[j], self._cp_side_key_flat[j]
            else:
                m = near.size
                mark_pos = self._mark_pos[lane].reshape(m, -1)
                mark_cp = self._mark_cp[lane].reshape(m, -1)
                cp_s = self._cp_s[lane].reshape(m, -1)
                cp_key = self._cp_side_key[lane].reshape(m, -1)
            self._record_pet(lane, env, so, sn, mark_pos, mark_cp, t0_s, dt_s)
            self._crossing_pairs(env, sn, cp_s, cp_key, step_min)
        np.minimum(self.min_distance_m, step_min, out=self.min_distance_m)
        self._far_pairs(view, s_new, gone)

    def _far_pairs(
        self, view: VirtualLaneView, s_new: FloatArray, gone: NDArray[np.bool_]
    ) -> None:
        """The pairs the fast path leaves out, while an environment's minimum allows them."""
        net = self.network
        off, seg = net.lane_offset_m, net.segment_length_m
        # Every other pair is at least 2 * offset apart. While an environment has seen no
        # closer pair: opposite lanes of one road (exact below segment - 2 * offset, the
        # distance of parallel roads), and while none closer than that either, every pair.
        far = self.min_distance_m >= 2.0 * off
        if far.any():
            stay = ~gone
            self._opposite_pairs(view, s_new, stay & far[view.env])
            far_all = np.flatnonzero(self.min_distance_m >= seg - 2.0 * off)
            if far_all.size:
                self._all_pairs(view, s_new, stay, far_all)

    def _record_ttc(self, view: VirtualLaneView, v: FloatArray) -> None:
        f = view.front_point
        closing = v - v[view.point_vehicle[f]]  # f = -1 (none) is masked below
        i = ((closing > 0.0) & (f >= 0)).nonzero()[0]
        if i.size == 0:
            return
        # time_to_collision(d_front, closing) without its guards: closing > 0 here. A point
        # level with the ego (the view orders points within 0.1 mm by input, so it can be up to
        # 0.1 mm behind) is at distance 0: TTC is never negative.
        d = view.d_front[i]
        ttc = np.where(d > 0.0, d, 0.0) / closing[i]
        env = view.env[i]
        np.minimum.at(self.min_ttc_s, env, ttc)
        bins = np.fmin(ttc * (1.0 / TTC_BIN_S), _N_TTC_BINS).astype(np.int64)  # inf: overflow
        np.add.at(self.ttc_hist.reshape(-1), env * (_N_TTC_BINS + 1) + bins, 1)

    def _record_pet(
        self, lane: IntArray, env: IntArray, s_old: FloatArray, s_new: FloatArray,
        mark_pos: FloatArray, mark_cp: IntArray, t0_s: float | FloatArray, dt_s: float,
    ) -> None:
        """PET samples of the marks crossed in this step (arrays of the near vehicles)."""
        r, c = ((s_old[:, None] < mark_pos) & (s_new[:, None] >= mark_pos)).nonzero()
        if r.size == 0:
            return
        # s_old < mark <= s_new: the fraction of the step is in (0, 1]
        t_rel = (mark_pos[r, c] - s_old[r]) / (s_new[r] - s_old[r]) * dt_s
        env = env[r]
        point = env * self.network.n_cp + mark_cp[r, c]
        leave = (c & 1).astype(bool)  # marks alternate reach, leave
        side = self._lane_side[lane[r]]
        if isinstance(t0_s, float | int):
            t_abs = t_rel + t0_s
        else:
            t_abs = t_rel + np.asarray(t0_s, dtype=np.float64)[env]
        n = point.size
        if n == 1 or np.bincount(point).max() == 1:
            # one event per point (the usual case): compare with the stored leave
            prev_t, prev_side = self.last_leave_s[point], self.last_leave_side[point]
            last = leave.nonzero()[0]
        else:  # events in time order per point; the latest leave before each event
            order = np.argsort(point * (2.0 * dt_s) + t_rel, kind="stable")
            point, env, side, leave, t_abs = (
                point[order], env[order], side[order], leave[order], t_abs[order])
            start = np.ones(n, dtype=bool)
            start[1:] = point[1:] != point[:-1]
            idx = np.arange(n)
            group_start = np.maximum.accumulate(np.where(start, idx, 0))
            latest = np.maximum.accumulate(np.where(leave, idx, -1))
            prev = np.empty(n, dtype=np.int64)
            prev[0] = -1
            prev[1:] = latest[:-1]
            here = prev >= group_start  # this step's leave, else the stored one
            prev_c = np.maximum(prev, 0)
            prev_t = np.where(here, t_abs[prev_c], self.last_leave_s[point])
            prev_side = np.where(here, side[prev_c], self.last_leave_side[point])
            end = np.ones(n, dtype=bool)
            end[:-1] = start[1:]
            last = latest[end]
            last = last[last >= group_start[end]]
        # a reach after a leave of the crossing lane (stored side -1: no leave yet)
        sample = (prev_side + side == 1) & ~leave
        if sample.any():
            pet = (t_abs - prev_t)[sample]
            es = env[sample]
            b = self.batch_size
            np.minimum.at(self.min_pet_s, es, pet)
            self.pet_samples += np.bincount(es, minlength=b)
            self.pet_under += np.bincount(es[pet < PET_THRESHOLD_S], minlength=b)
        # Store each point's last leave of the step.
        self.last_leave_s[point[last]] = t_abs[last]
        self.last_leave_side[point[last]] = side[last]

    def _own_lane_gaps(
        self, view: VirtualLaneView, s_new: FloatArray, gone: NDArray[np.bool_]
    ) -> FloatArray:
        """(B,) smallest own-lane gap after the move (order cannot change within a step)."""
        step_min = np.full(self.batch_size, np.inf)
        i = (view.leader >= 0).nonzero()[0]
        lead = view.leader[i]
        gap = s_new[lead] - s_new[i]
        if gone.any():  # a follower that left the network has a leader that left too
            gap[gone[lead]] = np.inf
        np.minimum.at(step_min, view.env[i], gap)
        return step_min

    def _crossing_pairs(
        self, env: IntArray, s_new: FloatArray, cp_s: FloatArray, cp_key: IntArray,
        step_min: FloatArray,
    ) -> None:
        """Lower ``step_min`` by crossing-lane pairs: ``hypot`` of their distances to the point.

        Per conflict point the closest pair is the closest vehicle of each lane; only pairs
        within ``2 * lane_offset`` can matter here (the rest is checked in ``record_step``).
        """
        net, b = self.network, self.batch_size
        delta = s_new[:, None] - cp_s
        r, c = (np.abs(delta) < 2.0 * net.lane_offset_m).nonzero()
        if r.size < 2:
            return
        d = delta[r, c]
        sq = np.full(b * net.n_cp * 2, np.inf)
        np.minimum.at(sq, env[r] * (2 * net.n_cp) + cp_key[r, c], d * d)
        pair = np.sqrt(sq.reshape(b, -1, 2).sum(axis=2)).min(axis=1)
        np.minimum(step_min, pair, out=step_min)

    def _opposite_pairs(
        self, view: VirtualLaneView, s_new: FloatArray, use: NDArray[np.bool_]
    ) -> None:
        """Closest opposite-direction pairs of each road: ``hypot(2 offset, delta)``."""
        net = self.network
        idx = np.flatnonzero(use)
        if idx.size < 2:
            return
        lane = view.lane[idx]
        xy = net.xy(lane, s_new[idx])
        horizontal = net.lane_horizontal[lane]
        coord = np.where(horizontal, xy[:, 0], xy[:, 1])  # along the road [m]
        n_roads = net.rows + net.cols
        road = np.where(horizontal, lane % net.rows, net.rows + (lane - 2 * net.rows) % net.cols)
        key = view.env[idx] * n_roads + road
        order = np.lexsort((coord, key))
        key, coord, lane, env = key[order], coord[order], lane[order], view.env[idx][order]
        # The closest pair of two sorted sets is adjacent in their merged order.
        pair = (key[1:] == key[:-1]) & (lane[1:] != lane[:-1])
        if pair.any():
            d = np.hypot(2.0 * net.lane_offset_m, (coord[1:] - coord[:-1])[pair])
            np.minimum.at(self.min_distance_m, env[1:][pair], d)

    def _all_pairs(
        self, view: VirtualLaneView, s_new: FloatArray, stay: NDArray[np.bool_], envs: IntArray
    ) -> None:
        """Exact minimum over every pair (only for environments with far-apart vehicles)."""
        for e in envs.tolist():  # only while no pair is closer than a segment - 2 * offset
            idx = np.flatnonzero(stay & (view.env == e))
            if idx.size < 2:
                continue
            xy = self.network.xy(view.lane[idx], s_new[idx])
            d2 = ((xy[:, None, :] - xy[None, :, :]) ** 2).sum(axis=2)
            np.fill_diagonal(d2, np.inf)
            self.min_distance_m[e] = min(self.min_distance_m[e], float(np.sqrt(d2.min())))

    # ------------------------------------------------------------------------------------
    def batch_summary(self) -> dict[str, FloatArray]:
        """The near-miss keys, (B,) float64 arrays (``inf`` minima without samples)."""
        return {
            "min_ttc_s": self.min_ttc_s.copy(),
            "ttc_p1_s": ttc_percentile(self.ttc_hist),
            "min_pet_s": self.min_pet_s.copy(),
            "pet_under_1s": self.pet_under.astype(np.float64),
            "pet_samples": self.pet_samples.astype(np.float64),
            "min_distance_m": self.min_distance_m.copy(),
        }

    def summary(self, env: int) -> dict[str, float]:
        """The near-miss keys of one environment (``inf`` minima without samples)."""
        return {
            "min_ttc_s": float(self.min_ttc_s[env]),
            "ttc_p1_s": ttc_percentile_of(self.ttc_hist[env]),
            "min_pet_s": float(self.min_pet_s[env]),
            "pet_under_1s": float(self.pet_under[env]),
            "pet_samples": float(self.pet_samples[env]),
            "min_distance_m": float(self.min_distance_m[env]),
        }
