"""Reservation-based intersection management (AIM, first come first served; Dresner & Stone).

``control="reservation"``. Velocity in ``[0, v_max]`` (a refused vehicle must be able to wait),
acceleration in ``[-a_max, a_max]``.

* Every intersection manager keeps, per conflict point, the slots it has granted: intervals of
  state indices (0.1 s steps) during which one vehicle occupies the point (within
  ``r_occ = vehicle_length + reservation_margin_m`` of it).
* A vehicle that is within ``control_radius_m`` of its next intersection, holds no slot there
  and whose own-lane leader before the same intersection already holds one (first come, first
  served along a lane) requests. The manager tries the trajectories "move to cruise velocity
  ``v_c`` at ``a_max``, hold it" for ``v_c`` from ``v_max`` down to
  ``reservation_v_cross_min_mps`` in 0.5 m/s steps (earliest arrival first) and grants the
  first one whose occupancy of both conflict points is free of every slot of a crossing lane
  (plus ``reservation_buffer_s`` on each side) and which keeps the same-lane invariant against
  the leader's worst case (``sim/safe_following.py``). The vehicle then follows it exactly.
* A refused vehicle slows towards ``reservation_refused_speed_mps`` (braking at ``a_max / 2``),
  never passes the point ``r_occ`` before the first conflict point, and requests again after
  ``reservation_retry_s``.

Zero collisions by construction: granted slots of crossing lanes never overlap (tested), a
vehicle without a slot stays out of the conflict zone, a vehicle with one follows its
trajectory exactly (its leader's worst case was checked; ``deviations`` counts any departure,
tested to be 0), and same-lane gaps are kept by the safe-following bound.

Python loops run per request (a few per intersection and second), never per vehicle per step.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import intersection_plan as ip
from mivecc_env.sim.network import GridNetwork

if TYPE_CHECKING:
    from mivecc_env.sim.core import Simulator
    from mivecc_env.sim.virtual_lane import VirtualLaneView

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class ReservationBook:
    """Granted slots per (environment, conflict point): state-index intervals and their lane.

    Args:
        batch_size: environments B.
        n_cp: conflict points per environment.
        buffer_steps: slots of crossing lanes must be at least this many steps apart.
        record: keep every grant in :attr:`log` (for tests).
    """

    def __init__(self, batch_size: int, n_cp: int, buffer_steps: int, record: bool = False):
        self.buffer = int(buffer_steps)
        self.slots: list[list[list[tuple[int, int, int]]]] = [
            [[] for _ in range(n_cp)] for _ in range(batch_size)
        ]
        self.record = record
        #: (env, cp, lane, first, last) of every grant when ``record`` is set.
        self.log: list[tuple[int, int, int, int, int]] = []

    def conflicts(self, env: int, cp: int, lane: int, first: IntArray, last: IntArray,
                  now: int) -> NDArray[np.bool_]:
        """(n,) whether each candidate interval ``[first, last]`` hits a crossing lane's slot."""
        kept = [x for x in self.slots[env][cp] if x[1] + self.buffer >= now]
        self.slots[env][cp] = kept
        other = [x for x in kept if x[2] != lane]
        if not other:
            return np.zeros(first.shape, dtype=bool)
        arr = np.asarray(other, dtype=np.int64)
        lo, hi = arr[:, 0] - self.buffer, arr[:, 1] + self.buffer
        return ((first[:, None] <= hi[None, :]) & (last[:, None] >= lo[None, :])).any(axis=1)

    def grant(self, env: int, cp: int, lane: int, first: int, last: int) -> None:
        self.slots[env][cp].append((int(first), int(last), int(lane)))
        if self.record:
            self.log.append((env, cp, lane, int(first), int(last)))


class ReservationControl:
    """The reservation (AIM FCFS) control mode of a :class:`Simulator` (see module docstring)."""

    def __init__(self, config: MiVeCCConfig, network: GridNetwork, batch_size: int,
                 record: bool = False) -> None:
        self.config = config
        self.network = network
        self.batch_size = batch_size
        self.record = record
        self.cruise = ip.cruise_grid(config)
        self.reset()

    def reset(self) -> None:
        c = self.config
        self.plans = ip.PlanState(self.batch_size)
        self.book = ReservationBook(self.batch_size, self.network.n_cp,
                                    round(c.reservation_buffer_s / c.dt_s), self.record)
        self.requests = 0  # requests handled
        self.refusals = 0
        self.deviations = 0  # vehicle-steps where a planned vehicle could not follow its plan
        self.infeasible = 0  # vehicle-steps where the safe bound was below -a_max

    # ------------------------------------------------------------------------------------
    def accel(self, sim: Simulator, view: VirtualLaneView, s: FloatArray,
              v: FloatArray) -> FloatArray:
        """Acceleration of every vehicle of the view [m/s^2]; handles this step's requests."""
        c = self.config
        self.plans.sync(sim.vid)
        flat = view.vehicle
        crossing = ip.next_crossing(self.network, c, view.lane, s)
        plan_k = self.plans.plan_k.ravel()[flat]
        planned = crossing.has & (plan_k == crossing.k)
        now = sim.step_count
        self._serve_requests(view, s, v, crossing, planned, now)
        plan_k = self.plans.plan_k.ravel()[flat]
        planned = crossing.has & (plan_k == crossing.k)
        refused = self.plans.refused.ravel()[flat]
        approach_v = np.where(refused, c.reservation_refused_speed_mps, c.v_max_mps)
        approach_brake = np.where(refused, 0.5 * c.a_max_mps2, c.a_max_mps2)
        a, want = ip.execute(c, s, v, view.leader, crossing, planned,
                             self.plans.plan_v.ravel()[flat], approach_v, approach_brake)
        self.deviations += int(np.sum(planned & (a < want - 1e-6)))
        self.infeasible += int(np.sum(a < -c.a_max_mps2 - 1e-6))
        return np.maximum(a, -c.a_max_mps2)

    def _serve_requests(self, view: VirtualLaneView, s: FloatArray, v: FloatArray,
                        crossing: ip.Crossing, planned: NDArray[np.bool_], now: int) -> None:
        c = self.config
        flat = view.vehicle
        leader = view.leader
        li = np.maximum(leader, 0)
        same = (leader >= 0) & (crossing.k[li] == crossing.k)
        lead_ok = ~same | planned[li]
        due = self.plans.next_request.ravel()[flat] <= now
        near = crossing.centre_s - s <= c.control_radius_m
        ask = np.flatnonzero(crossing.has & ~planned & near & due & lead_ok)
        if ask.size == 0:
            return
        ask = ask[np.argsort(crossing.cp1_s[ask] - s[ask], kind="stable")]
        plan_v = self.plans.plan_v.ravel()
        for i in ask:
            lead = None
            if leader[i] >= 0:
                j = leader[i]
                v_plan = float(plan_v[flat[j]]) if same[i] else None
                lead = (float(s[j]), float(v[j]), v_plan, float(crossing.clear_s[j]))
            self._request(int(i), int(flat[i]), int(view.env[i]), int(view.lane[i]),
                          float(s[i]), float(v[i]), crossing, lead, now)

    def _request(self, i: int, slot: int, env: int, lane: int, s0: float, v0: float,
                 crossing: ip.Crossing, leader: tuple | None, now: int) -> None:
        c = self.config
        self.requests += 1
        cps = self._conflict_points(lane, float(crossing.centre_s[i]))
        cand = ip.plan_candidates(
            c, s0, v0, (float(crossing.cp1_s[i]), float(crossing.cp2_s[i])),
            float(crossing.clear_s[i]), leader, self.cruise,
        )
        ok = cand.ok.copy()
        for m, cp in enumerate(cps):
            ok &= ~self.book.conflicts(env, cp, lane, now + cand.first[:, m],
                                       now + cand.last[:, m], now)
        pv = self.plans
        if not ok.any():
            self.refusals += 1
            pv.refused.ravel()[slot] = True
            pv.next_request.ravel()[slot] = now + max(1, round(c.reservation_retry_s / c.dt_s))
            return
        best = int(np.argmax(ok))
        for m, cp in enumerate(cps):
            self.book.grant(env, cp, lane, now + int(cand.first[best, m]),
                            now + int(cand.last[best, m]))
        pv.plan_k.ravel()[slot] = int(crossing.k[i])
        pv.plan_v.ravel()[slot] = float(cand.v_cruise[best])
        pv.refused.ravel()[slot] = False

    def _conflict_points(self, lane: int, centre_s: float) -> list[int]:
        """The lane's two conflict points at the intersection centred at ``centre_s``."""
        net = self.network
        near = np.abs(net.lane_cp_s[lane] - centre_s) <= net.lane_offset_m + 1e-6
        return [int(x) for x in net.lane_cp[lane][near]]
