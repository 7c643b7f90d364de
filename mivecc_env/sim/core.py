"""The batched traffic simulator: vehicle arrays, one step of the whole network.

State is held as arrays with a leading batch axis of B independent environments and a slot
axis (``(B, capacity)``); a slot is free when ``active`` is False. One :meth:`Simulator.step`

1. takes the virtual-lane view of the current state (built at the end of the previous step),
2. computes every vehicle's safety value and on-board action, fuses the coordinators' actions
   (unsignalized) or applies car-following and signals (signalized),
3. moves every vehicle by eq. (1) within the velocity bounds,
4. removes the vehicles that left the network, recording their trips,
5. detects collisions (closer than the vehicle size, own lane or crossing lanes), counts them
   and removes the vehicles involved,
6. moves arrivals into the entry queues and lets queued vehicles enter where the lane is clear,
7. builds the new virtual-lane view.

Accounting invariant, per environment, after every step:
``arrived == queued + in_network + exited + collided``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig, field_range
from mivecc_env.sim import (
    checks,
    controllers,
    edge_selection,
    end_node,
    released_check,
    rule_shield,
    sections,
    signals,
    step_kernels,
)
from mivecc_env.sim.arrivals import ArrivalProcess
from mivecc_env.sim.near_miss import NearMissStats
from mivecc_env.sim.network import GridNetwork
from mivecc_env.sim.passing import PassingTimes
from mivecc_env.sim.safety import safety_value, time_to_collision
from mivecc_env.sim.signal_control import SignalPhases
from mivecc_env.sim.view_kernel import ViewWorkspace
from mivecc_env.sim.virtual_lane import VirtualLaneView, build_view

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass
class VehicleSafety:
    """Per-vehicle quantities of the current view (arrays of length n, view order)."""

    sv: FloatArray  # safety value
    d_front: FloatArray  # distance to the nearest point ahead on the virtual lane [m]
    d_back: FloatArray  # ... behind [m]
    ttc: FloatArray  # time to collision with the nearest point [s]


@dataclass
class StepEvents:
    """What happened in the last step, per environment (arrays of shape (B,))."""

    exited: IntArray
    collided_vehicles: IntArray
    collision_events: IntArray
    entered: IntArray
    #: (k,) environment and intersection (control area, -1 outside) of each collided vehicle.
    collided_env: IntArray
    collided_area: IntArray
    #: (k,) flat slot (``env * capacity + slot``) of each collided vehicle (same order).
    collided_slot: IntArray


class Simulator:
    """B independent copies of the MiVeCC road network, stepped together.

    Args:
        config: the model constants.
        batch_size: number of independent environments B.
        seed: one seed for all (environment ``b`` gets child ``b`` of
            ``SeedSequence(seed).spawn(B)``, so environment 0 of a batch replays a B = 1 run with
            the same seed) or one seed per environment (environment ``b`` replays a B = 1 run
            seeded with ``seed[b]``).
        capacity: initial vehicle slots per environment (grows on demand).
        densities: arrival rate per entry lane of each environment [veh/lane/h] ((B,) values
            in the config's ``density_vplh`` range); default: the config's ``density_vplh``.

    Every environment has its own clock: :meth:`reset_at` restarts some environments at time 0
    while the others go on (``env_steps`` / ``env_time_s``; ``step_count`` counts the steps
    since the last full :meth:`reset`).
    """

    def __init__(
        self,
        config: MiVeCCConfig,
        batch_size: int = 1,
        seed: int | Sequence[int] | None = None,
        capacity: int = 256,
        densities: Sequence[float] | np.ndarray | None = None,
    ) -> None:
        batch_size = checks.check_positive_int("batch_size", batch_size)
        self.config = config
        self.network = GridNetwork.from_config(config)
        self.batch_size = batch_size
        self._initial_capacity = max(8, int(capacity))
        self.densities = _checked_densities(config, batch_size, densities)
        # the released collision check's config (built once, not on every collision step)
        self._check_config = (config if config.section_entry_lag
                              else config.replace(section_entry_lag=True))
        self.arrivals = ArrivalProcess(
            batch_size, self.network.n_lanes, self.densities, config.min_headway_s
        )
        self.reset(seed)

    # ------------------------------------------------------------------------------------
    # state
    def reset(self, seed: int | Sequence[int] | None = None) -> None:
        """Empty network, fresh arrival streams, time 0."""
        seeds = self._seed_sequences(seed)
        self.arrivals.reset(seeds)
        self.selection_rngs = edge_selection.SelectionStreams(seeds)  # edge_selection="random"
        shape = (self.batch_size, self._initial_capacity)
        self.active = np.zeros(shape, dtype=bool)
        self.lane = np.zeros(shape, dtype=np.int64)
        self.s = np.zeros(shape)  # distance from the lane entry [m]
        self.v = np.zeros(shape)  # velocity [m/s]
        self.a = np.zeros(shape)  # acceleration applied in the last step [m/s^2]
        self.t_arrive = np.zeros(shape)  # arrival at the entry queue [s]
        self.t_enter = np.zeros(shape)  # entry into the network [s]
        self.vid = np.full(shape, -1, dtype=np.int64)  # unique id per environment
        b = self.batch_size
        self.step_count = 0
        self.start_step = np.zeros(b, dtype=np.int64)  # step_count at each env's last reset
        self.next_vid = np.zeros(b, dtype=np.int64)
        self._v_init_lanes: FloatArray | None = None  # entry speeds at v_init (read-only)
        self.exited = np.zeros(b, dtype=np.int64)
        self.collided = np.zeros(b, dtype=np.int64)  # vehicles removed by collision
        self.collision_events = np.zeros(b, dtype=np.int64)
        self.released_flagged = np.zeros(b, dtype=np.int64)  # sim/released_check.py
        # trip statistics of exited vehicles
        self.sum_travel_velocity = np.zeros(b)  # path / (exit - arrival) [m/s]
        self.sum_travel_velocity_no_wait = np.zeros(b)  # path / (exit - entry) [m/s]
        self.sum_trip_time = np.zeros(b)  # exit - arrival [s]
        self.sum_wait_time = np.zeros(b)  # entry - arrival [s]
        self.sum_speed_samples = np.zeros(b)  # sum over steps of the vehicles' speeds [m/s]
        self.vehicle_steps = np.zeros(b, dtype=np.int64)
        # released-style passing times and near-miss measures (their modules say what)
        self.passing = PassingTimes(self.network, b)
        self.near_miss = NearMissStats(self.network, b, self.config.vehicle_length_m)
        self.last_events = self._no_events()
        self.controller = controllers.make_controller(self.config, self.network, self.batch_size)
        self.signal_phases = (SignalPhases(self.config, self.network, self.batch_size)
                              if self.config.control == "signalized" else None)
        self._prev_s: tuple[IntArray, FloatArray] | None = None  # (slots, s) before the move
        self._seen: NDArray[np.bool_] | None = None  # on a section virtual lane (view order)
        # stale_action: SV and nearest vehicle's distance to the section centre [m] of the last
        # step on a virtual lane
        self._sv_last = np.zeros(shape)
        self._closer_last = np.zeros(shape)
        self._view_buffers = ViewWorkspace()  # reused arrays of self._view (two in turn)
        self._refresh_view()

    def reset_at(self, env_index: Sequence[int] | np.ndarray, seeds: Sequence[int]) -> None:
        """Restart environments ``env_index`` (empty, time 0) from one seed each.

        Environment ``env_index[i]`` then runs exactly like a B = 1 simulator reset with
        ``seeds[i]``; the other environments continue untouched.

        Raises:
            ValueError: ``env_index`` not distinct integers in ``[0, B)``, or not one seed per
                index.
        """
        envs = checks.check_env_indices(env_index, self.batch_size)
        if envs.size == 0:
            return
        if self.controller is not None:
            raise NotImplementedError(
                f"reset_at: not supported under control={self.config.control!r} (its plans "
                "run on one clock for the whole batch); use reset()"
            )
        if len(seeds) != envs.size:
            raise ValueError(f"seeds: need one seed per reset environment ({envs.size}), "
                             f"got {len(seeds)}")
        seqs = [np.random.SeedSequence(int(x)).spawn(1)[0] for x in seeds]
        self.arrivals.reset_at(envs, seqs)
        self.selection_rngs.reset_at(envs.tolist(), seqs)
        self.active[envs] = False
        self.vid[envs] = -1
        self._sv_last[envs] = 0.0  # released-model records (stale_action)
        self._closer_last[envs] = 0.0
        self.start_step[envs] = self.step_count
        for name in ("next_vid", "exited", "collided", "collision_events", "released_flagged",
                     "sum_travel_velocity",
                     "sum_travel_velocity_no_wait", "sum_trip_time", "sum_wait_time",
                     "sum_speed_samples", "vehicle_steps"):
            getattr(self, name)[envs] = 0
        self.passing.reset_at(envs)
        self.near_miss.reset_at(envs)
        if self.signal_phases is not None:  # back to the plan's state at time 0
            fresh = SignalPhases(self.config, self.network, self.batch_size)
            for name in ("phase", "stage", "elapsed", "gap_steps"):
                getattr(self.signal_phases, name)[envs] = getattr(fresh, name)[envs]
        self._refresh_view()

    def _seed_sequences(self, seed: int | Sequence[int] | None) -> list[np.random.SeedSequence]:
        seed = checks.check_seed(seed, self.batch_size)
        if seed is None or isinstance(seed, int):
            return np.random.SeedSequence(seed).spawn(self.batch_size)
        seeds = seed
        # Environment b of a seed list runs exactly like a B = 1 simulator seeded with seeds[b].
        return [np.random.SeedSequence(int(x)).spawn(1)[0] for x in seeds]

    def _no_events(self) -> StepEvents:
        zero = np.zeros(self.batch_size, dtype=np.int64)
        empty = np.zeros(0, dtype=np.int64)
        return StepEvents(zero, zero.copy(), zero.copy(), zero.copy(), empty, empty.copy(),
                          empty.copy())

    @property
    def time_s(self) -> float:
        """Simulated time since the last full :meth:`reset` [s]."""
        return self.step_count * self.config.dt_s

    @property
    def env_steps(self) -> IntArray:
        """(B,) steps of each environment since its own last reset."""
        return self.step_count - self.start_step

    @property
    def env_time_s(self) -> FloatArray:
        """(B,) simulated time of each environment since its own last reset [s]."""
        return self.env_steps * self.config.dt_s

    @property
    def capacity(self) -> int:
        return int(self.active.shape[1])

    @property
    def in_network(self) -> IntArray:
        """(B,) vehicles in the network."""
        return self.active.sum(axis=1)

    @property
    def queued(self) -> IntArray:
        """(B,) vehicles waiting at the entries."""
        return self.arrivals.queued.sum(axis=1)

    @property
    def arrived(self) -> IntArray:
        """(B,) vehicles that have arrived at an entry so far."""
        return self.arrivals.arrived.sum(axis=1)

    @property
    def view(self) -> VirtualLaneView:
        """Virtual-lane view of the current state. Its arrays live in reused buffers: they
        stay valid through the next ``step``/``reset_at`` and are overwritten by the one after
        (copy what must live longer)."""
        return self._view

    @property
    def prev_positions(self) -> tuple[IntArray, FloatArray] | None:
        """(flat slots, positions [m]) of the vehicles of the last move, before it; None
        before the first step."""
        return self._prev_s

    @property
    def safety(self) -> VehicleSafety:
        """Safety values of the current state (view order)."""
        return self._safety

    def _refresh_view(self) -> None:
        self._view = build_view(
            self.network, self.config.projection_window_m, self.config.projection_clear_m,
            self.active, self.lane, self.s, self._view_buffers,
        )
        self._safety = self._compute_safety(self._view)

    def _compute_safety(self, view: VirtualLaneView) -> VehicleSafety:
        c = self.config
        d_front, d_back = view.d_front, view.d_back
        neighbours = None
        if c.section_virtual_lanes:  # released code: section-limited virtual lanes
            neighbours = sections.section_neighbours(
                self.network, c, view, self.active, self.lane, self.s, self._prev_s
            )
            d_front, d_back = neighbours[2], neighbours[3]
            self._seen = neighbours[4]
            neighbours = neighbours[:4]
        fast = None
        if neighbours is None and c.ttc_closing_offset_mps == 0.0:
            fused = step_kernels.safety_fast(
                self.v.ravel(), self.a.ravel(), view.vehicle, view.point_vehicle,
                view.front_point, view.back_point, view.d_front, view.d_back, c,
            )
            if fused is not None:
                return VehicleSafety(sv=fused[0], d_front=d_front, d_back=d_back, ttc=fused[1])
            fast = step_kernels.safety_inputs(
                self.v.ravel(), self.a.ravel(), view.vehicle, view.point_vehicle,
                view.front_point, view.back_point, view.d_front, view.d_back,
                c.sv_acc_source == "ego",
            )
        d_nearest, ttc, acc = (
            fast if fast is not None else self._safety_inputs_reference(view, neighbours)
        )
        sv = safety_value(d_nearest, ttc, d_front, acc, c)
        return VehicleSafety(sv=sv, d_front=d_front, d_back=d_back, ttc=ttc)

    def _safety_inputs_reference(
        self, view: VirtualLaneView,
        neighbours: tuple[IntArray, IntArray, FloatArray, FloatArray] | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(nearest distance [m], time to collision [s], SV_acc acceleration [m/s^2]).

        ``neighbours``: (front, back, d_front, d_back) in view order to use instead of the
        view's own (the released code's section-limited virtual lanes).
        """
        c = self.config
        v = self.v.ravel()[view.vehicle]
        a = self.a.ravel()[view.vehicle]
        if neighbours is None:
            pv = view.point_vehicle
            d_front, d_back = view.d_front, view.d_back
            has_f, has_b = view.front_point >= 0, view.back_point >= 0
            fi = pv[np.maximum(view.front_point, 0)]
            bi = pv[np.maximum(view.back_point, 0)]
        else:
            front, back, d_front, d_back = neighbours
            has_f, has_b = front >= 0, back >= 0
            fi, bi = np.maximum(front, 0), np.maximum(back, 0)
        v_front = np.where(has_f, v[fi], 0.0)
        v_back = np.where(has_b, v[bi], 0.0)
        ahead = d_front <= d_back
        d_nearest = np.minimum(d_front, d_back)
        off = c.ttc_closing_offset_mps  # released code: 0.1 (subtracted when behind)
        closing = np.where(ahead, v - v_front + off, v_back - v - off)
        ttc = np.where(np.isfinite(d_nearest), time_to_collision(d_nearest, closing), np.inf)
        acc = a if c.sv_acc_source == "ego" else np.where(has_f, a[fi], 0.0)
        return d_nearest, ttc, acc

    # ------------------------------------------------------------------------------------
    # stepping
    def step(
        self,
        edge_accel: FloatArray | None = None,
        cloud_accel: FloatArray | None = None,
        signal_phase: IntArray | None = None,
        raw_edge: NDArray[np.bool_] | None = None,
    ) -> StepEvents:
        """Advance every environment by one time step.

        Args:
            edge_accel: (B, capacity) edge action per vehicle slot [m/s^2], NaN where none.
            cloud_accel: (B, capacity) cloud action per vehicle slot [m/s^2], NaN where none.
                Both are ignored under signalized control.
            signal_phase: (B, n_intersections) phase a signal agent wants green (0 east-west,
                1 north-south), -1 where the configured controller decides (signalized only;
                timing enforced by ``sim/signal_control.py``).
            raw_edge: (B,) bool array: in these environments the edge action replaces the
                rule's action unmodified (``end_node.fuse``; the released trainer's
                exploration).

        Raises:
            ValueError: an action array of another shape than ``(B, capacity)`` (capacity
                grows during ``step``: size the arrays from ``sim.capacity`` every step), not
                numeric, or holding +-inf; ``raw_edge`` not a (B,) bool array.
        """
        shape = self.active.shape
        edge_accel = checks.check_accel("edge_accel", edge_accel, shape)
        cloud_accel = checks.check_accel("cloud_accel", cloud_accel, shape)
        raw_edge = checks.check_env_flags("raw_edge", raw_edge, self.batch_size)
        if signal_phase is not None and self.signal_phases is None:
            raise ValueError("signal_phase: only under control='signalized', got control="
                             f"{self.config.control!r}")
        c, view = self.config, self._view
        flat = view.vehicle
        lane = view.lane
        t0 = self.env_time_s  # (B,) each environment's own clock
        t1 = t0 + c.dt_s
        # n_out: (B,) exits when the compiled move also recorded passing times and exits
        moved = self._move_compiled(view, edge_accel, cloud_accel, raw_edge, t0, t1)
        if moved is not None:
            s, v, s_new, out, n_out = moved
        else:
            s, v, s_new, out = self._move(view, edge_accel, cloud_accel, signal_phase, raw_edge)
            n_out = None
        self._prev_s = (flat.copy(), s)  # the view's buffers are reused two builds on

        events = self._no_events()
        p = self.passing
        if n_out is not None:
            events.exited = n_out
        elif not self.t_enter.flags.c_contiguous or not step_kernels.record_passing(
            view.env, lane, flat, s, s_new, self.t_enter.ravel(), p.mark_s, t0, c.dt_s,
            (p.count, p.sum_time_s, p.sum_length_m),
        ):
            p.record(view.env, lane, s, s_new, self.t_enter.ravel()[flat], t0, c.dt_s)
        self.near_miss.record_step(view, v, s_new, out, t0, c.dt_s)
        flat_ok = all(x.flags.c_contiguous for x in (self.active, self.t_arrive, self.t_enter))
        if n_out is None and out.any():
            n_out = None if not flat_ok else step_kernels.record_exits(
                out, view.env, flat, lane, s, s_new, self.network.lane_length, t0, t1,
                self.t_arrive.ravel(), self.t_enter.ravel(), self.active.ravel(),
                (self.sum_travel_velocity, self.sum_travel_velocity_no_wait,
                 self.sum_trip_time, self.sum_wait_time), self.exited,
            )
            if n_out is None:
                length = self.network.lane_length[lane]
                self._record_exits(view, out, s, s_new, length, t0, t1, events)
            else:
                events.exited = n_out
        self._remove_collisions(view, s_new, out, events)

        self.step_count += 1
        self._enter_vehicles(t1, events, s_new)
        self.last_events = events
        self._refresh_view()
        return events

    def _move_compiled(
        self, view: VirtualLaneView, edge_accel: FloatArray | None,
        cloud_accel: FloatArray | None, raw_edge: NDArray[np.bool_] | None,
        t0: FloatArray, t1: FloatArray,
    ) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.bool_], IntArray | None] | None:
        """:meth:`_move` by the compiled kernel where the model is the plain unsignalized one
        (no released-code rules, float64 actions); None elsewhere. In the same pass the
        passing times and the exits (``step_kernels.move``'s ``record``) when the arrays
        allow it; the last item is then the (B,) exits, else None."""
        c = self.config
        if (c.control != "unsignalized" or self.controller is not None or c.header_rule
                or c.sections or c.speed_reset or c.stale_action or c.same_lane_rule
                or c.accel_record == "commanded" or c.safety_shield):
            return None
        edge = None if edge_accel is None or c.scheme == "E" else edge_accel
        cloud = None if cloud_accel is None or c.scheme != "EEC" else cloud_accel
        if any(x is not None and x.dtype != np.float64 for x in (edge, cloud)):
            return None  # e.g. float32 actions: the reference's mixed-precision arithmetic
        if not all(x.flags.c_contiguous for x in (self.s, self.v, self.a)):
            return None  # the kernel writes through flat views
        raw = None if raw_edge is None or edge is None else np.asarray(raw_edge, dtype=bool)
        safety = self._safety
        record = None
        if all(x.flags.c_contiguous for x in (self.active, self.t_arrive, self.t_enter)):
            p = self.passing
            record = (t0, t1, p.mark_s, self.t_arrive.ravel(), self.t_enter.ravel(),
                      self.active.ravel(), (p.count, p.sum_time_s, p.sum_length_m),
                      (self.sum_travel_velocity, self.sum_travel_velocity_no_wait,
                       self.sum_trip_time, self.sum_wait_time), self.exited)
        return step_kernels.move(
            view.vehicle, view.env, view.lane, safety.sv, safety.d_front, safety.d_back,
            None if edge is None else edge.ravel(), None if cloud is None else cloud.ravel(),
            raw, (self.s.ravel(), self.v.ravel(), self.a.ravel()), self.network.lane_length,
            (self.sum_speed_samples, self.vehicle_steps), c, record,
        )

    def _move(
        self, view: VirtualLaneView, edge_accel: FloatArray | None,
        cloud_accel: FloatArray | None, signal_phase: IntArray | None,
        raw_edge: NDArray[np.bool_] | None,
    ) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.bool_]]:
        """Accelerations, motion and the state update of every view vehicle (numpy path).

        Returns (s before, v before, s after, exited) in view order.
        """
        c = self.config
        flat, lane = view.vehicle, view.lane
        s, v = self.s.ravel()[flat], self.v.ravel()[flat]
        if c.control == "signalized":
            accel = signals.signalized_accel(self, view, s, v)
            self.signal_phases.step(view, s, signal_phase)
        elif self.controller is not None:  # reservation / optimisation (sim/controllers.py)
            accel = self.controller.accel(self, view, s, v)
        else:
            raw = None if raw_edge is None else np.asarray(raw_edge, dtype=bool)[view.env]
            accel = self._unsignalized_accel(view, s, v, edge_accel, cloud_accel, raw)
            if c.safety_shield:
                accel = rule_shield.apply_shield(accel, view, v, self.vid.ravel()[flat], c)
        s_new, v_new, a_applied = end_node.bounded_motion(
            s, v, accel, c.velocity_floor_mps, c.v_max_mps, c.dt_s
        )
        if c.accel_record == "commanded":  # released code
            a_applied = np.where(v_new == v, 0.0, accel)
        if c.speed_reset and c.control != "signalized":
            v_new = sections.apply_speed_reset(self.network, c, lane, s_new, v_new)
        self.s.ravel()[flat] = s_new
        self.v.ravel()[flat] = v_new
        self.a.ravel()[flat] = a_applied
        self.sum_speed_samples += np.bincount(view.env, v_new, minlength=self.batch_size)
        self.vehicle_steps += np.bincount(view.env, minlength=self.batch_size)
        return s, v, s_new, s_new >= self.network.lane_length[lane]

    def _unsignalized_accel(
        self, view: VirtualLaneView, s: FloatArray, v: FloatArray,
        edge_accel: FloatArray | None, cloud_accel: FloatArray | None,
        raw_edge: NDArray[np.bool_] | None = None,
    ) -> FloatArray:
        c, safety = self.config, self._safety
        a_end = end_node.end_accel(safety.sv, safety.d_front, safety.d_back, c)
        a_end = end_node.entry_action(a_end, s, c)
        edge = None if edge_accel is None or c.scheme == "E" else edge_accel.ravel()[view.vehicle]
        cloud = (None if cloud_accel is None or c.scheme != "EEC"
                 else cloud_accel.ravel()[view.vehicle])
        overrides = c.header_rule or c.sections or c.speed_reset
        ctrl = sections.controlled(self.network, c, view.lane, s) if overrides else None
        seen = None
        if c.stale_action:  # released code: off the virtual lanes, the last a_end is kept
            seen = ctrl if ctrl is not None else np.ones(s.shape, dtype=bool)
            if c.section_virtual_lanes and self._seen is not None:
                seen = self._seen | (s == 0.0)
            a_end = sections.stale_action(
                self.network, c, view, s, seen, a_end, safety.sv, safety.d_front,
                safety.d_back, self._sv_last.ravel(), self._closer_last.ravel(),
                self._prev_s if c.stale_corner_reset else None,
            )
        rule = None
        if c.same_lane_rule:
            has_lead = view.leader >= 0
            follower_gap = np.where(view.follower >= 0, s - s[view.follower], np.inf)
            if c.same_lane_rule_form == "released":
                to_ref = sections.distance_to_section_centre(self.network, c, view.lane, s)
            else:
                cps = self.network.lane_cp_s[view.lane]
                to_ref = np.where(cps >= s[:, None], cps - s[:, None], np.inf).min(axis=1)

            def rule(a: FloatArray, lead_s: FloatArray) -> FloatArray:
                gap = np.where(has_lead, lead_s[view.leader] - s, np.inf)
                return end_node.apply_same_lane_rule(
                    a, gap, follower_gap, to_ref, safety.d_front, c
                )

        lead_s = s
        # The released code moves vehicles one by one in lane order, so its same-lane rule sees
        # the leader's position after the leader's own move: a few passes settle it.
        passes = 3 if c.same_lane_rule and c.same_lane_rule_form == "released" else 1
        for k in range(passes):
            if rule is not None and c.same_lane_rule_form == "released":
                after = functools.partial(rule, lead_s=lead_s)
                accel = end_node.fuse(a_end, safety.sv, edge, cloud, c, after_edge=after,
                                      raw_edge=raw_edge)
            else:
                a_rule = a_end if rule is None else rule(a_end, s)
                accel = end_node.fuse(a_rule, safety.sv, edge, cloud, c, raw_edge=raw_edge)
            if overrides:
                accel = sections.control_overrides(accel, ctrl, safety.d_front, c, seen)
            if k + 1 < passes:
                lead_s = end_node.bounded_motion(
                    s, v, accel, c.velocity_floor_mps, c.v_max_mps, c.dt_s
                )[0]
        return accel

    def _record_exits(
        self, view: VirtualLaneView, out: NDArray[np.bool_], s_old: FloatArray,
        s_new: FloatArray, length: FloatArray, t0: FloatArray, t1: FloatArray,
        events: StepEvents,
    ) -> None:
        idx = np.flatnonzero(out)
        flat = view.vehicle[idx]
        env = view.env[idx]
        # Exit time interpolated within the step.
        frac = (length[idx] - s_old[idx]) / np.maximum(s_new[idx] - s_old[idx], 1e-12)
        t_exit = t0[env] + np.clip(frac, 0.0, 1.0) * (t1[env] - t0[env])
        t_arr, t_ent = self.t_arrive.ravel()[flat], self.t_enter.ravel()[flat]
        trip, trip_no_wait = t_exit - t_arr, t_exit - t_ent
        b = self.batch_size
        self.sum_travel_velocity += np.bincount(env, length[idx] / trip, minlength=b)
        self.sum_travel_velocity_no_wait += np.bincount(
            env, length[idx] / trip_no_wait, minlength=b
        )
        self.sum_trip_time += np.bincount(env, trip, minlength=b)
        self.sum_wait_time += np.bincount(env, t_ent - t_arr, minlength=b)
        n_out = np.bincount(env, minlength=b)
        self.exited += n_out
        events.exited = n_out
        self.active.ravel()[flat] = False

    def _remove_collisions(
        self, view: VirtualLaneView, s_new: FloatArray, out: NDArray[np.bool_],
        events: StepEvents,
    ) -> None:
        pairs = collision_pairs(self.network, view, s_new, out, self.config.vehicle_length_m)
        if pairs.size == 0:
            return
        b = self.batch_size
        # Only environments with a strict event can have a flagged vehicle: check just those.
        hit_envs = np.unique(view.env[pairs[:, 0]])
        self.released_flagged[hit_envs] += released_check.flagged_count(
            self.network, self._check_config, self.active[hit_envs], self.lane[hit_envs],
            self.s[hit_envs], _rows_of_slots(self._prev_s, hit_envs, b, self.capacity))
        env_of_pair = view.env[pairs[:, 0]]
        events.collision_events = np.bincount(env_of_pair, minlength=b)
        self.collision_events += events.collision_events
        hit = np.unique(pairs.ravel())
        env = view.env[hit]
        events.collided_vehicles = np.bincount(env, minlength=b)
        self.collided += events.collided_vehicles
        events.collided_env = env
        events.collided_area = sections.control_area(
            self.network, self.config, view.lane[hit], s_new[hit]
        )
        events.collided_slot = view.vehicle[hit]
        self.active.ravel()[view.vehicle[hit]] = False

    def _entry_speeds(self, nearest: FloatArray) -> FloatArray:
        """(B, n_lanes) entry speed per lane [m/s]: ``v_init``, or under the comparators with
        ``comparator_entry="slowed"`` the speed from which the entering vehicle can stop behind
        the lane's nearest vehicle (at ``nearest`` [m]; :func:`signals.entry_speed`)."""
        c = self.config
        if c.control != "unsignalized" and c.comparator_entry == "slowed":
            return signals.entry_speed(c, nearest)
        if self._v_init_lanes is None or self._v_init_lanes.shape != nearest.shape:
            self._v_init_lanes = np.full(nearest.shape, c.v_init_mps)
        return self._v_init_lanes

    def _enter_vehicles(self, now_s: FloatArray, events: StepEvents, s_new: FloatArray) -> None:
        """Arrivals into the queues, queue heads into the network where the entry is clear.
        ``s_new``: the positions after the step's move in view order (the compiled plan reads
        the vehicles near the entries from the view)."""
        c = self.config
        self.arrivals.advance(now_s)
        queued = self.arrivals.queued
        # A lane is blocked while any of its vehicles is closer than the clearance to its entry.
        clearance = (signals.entry_clearance_m(c) if c.control != "unsignalized"
                     else c.entry_clearance_m)
        view = self._view  # the step's view; s_new: its positions after the move
        plan = None if not self.active.flags.c_contiguous else (
            step_kernels.entry_plan(self.active.ravel(), view.vehicle, view.env, view.lane,
                                    s_new, queued, clearance))
        if plan is not None:  # compiled: same slots, same order as below
            go, n_new, n_free, nearest = plan
            if (n_new > n_free).any():
                self._grow(int(n_new.max() + self.active.sum(axis=1).max()))
            step_kernels.place_entries(
                go, (self.arrivals.times, self.arrivals.entered), now_s,
                (self.active, self.lane, self.s, self.v, self.a, self.t_arrive, self.t_enter,
                 self.vid), self.next_vid, self._entry_speeds(nearest), c.entry_accel_mps2,
            )
            events.entered = n_new
            return
        want = queued > 0
        if not want.any():
            return
        nearest = np.full(want.shape, np.inf)  # the numpy path (no numba)
        bb, kk = np.nonzero(self.active)
        np.minimum.at(nearest, (bb, self.lane[bb, kk]), self.s[bb, kk])
        go = want & ~(nearest < clearance)
        env, lane = np.nonzero(go)
        if env.size == 0:
            return
        t_arr = self.arrivals.head_arrival_time()[env, lane]
        n_new = np.bincount(env, minlength=self.batch_size)
        free_count = self.capacity - self.active.sum(axis=1)
        if (n_new > free_count).any():
            self._grow(int(n_new.max() + self.active.sum(axis=1).max()))
        free_env, free_slot = np.nonzero(~self.active)
        first_free = np.searchsorted(free_env, np.arange(self.batch_size))
        ordinal = np.arange(env.size) - np.searchsorted(env, env)  # rank within its env
        slot = free_slot[first_free[env] + ordinal]
        self.active[env, slot] = True
        self.lane[env, slot] = lane
        self.s[env, slot] = 0.0
        self.v[env, slot] = self._entry_speeds(nearest)[env, lane]
        self.a[env, slot] = c.entry_accel_mps2
        self.t_arrive[env, slot] = t_arr
        self.t_enter[env, slot] = now_s[env]
        self.vid[env, slot] = self.next_vid[env] + ordinal
        self.next_vid += n_new
        self.arrivals.pop(go)
        events.entered = n_new

    def _grow(self, needed: int) -> None:
        old_cap = self.capacity
        new_cap = max(2 * old_cap, needed + 16)
        pad = new_cap - old_cap
        if self._prev_s is not None:  # flat slots of the last move, in the new layout
            slots, s_old = self._prev_s
            self._prev_s = ((slots // old_cap) * new_cap + slots % old_cap, s_old)
        for name, fill in (("active", False), ("lane", 0), ("s", 0.0), ("v", 0.0), ("a", 0.0),
                           ("t_arrive", 0.0), ("t_enter", 0.0), ("vid", -1),
                           ("_sv_last", 0.0), ("_closer_last", 0.0)):
            arr = getattr(self, name)
            setattr(self, name, np.pad(arr, ((0, 0), (0, pad)), constant_values=fill))

    # ------------------------------------------------------------------------------------
    def vehicle_table(self, env: int = 0) -> dict[str, np.ndarray]:
        """Arrays describing the vehicles of one environment (for rendering and tests)."""
        env = checks.check_env_index(env, self.batch_size)
        m = self.active[env]
        lane, s = self.lane[env, m], self.s[env, m]
        return {
            "vid": self.vid[env, m], "lane": lane, "s": s, "v": self.v[env, m],
            "a": self.a[env, m], "xy": self.network.xy(lane, s),
        }


def _rows_of_slots(
    prev_s: tuple[IntArray, FloatArray] | None, envs: IntArray, batch: int, capacity: int
) -> tuple[IntArray, FloatArray] | None:
    """``prev_s`` (flat slots of a (batch, capacity) layout, positions) restricted to the rows
    ``envs`` (sorted) and renumbered for the (len(envs), capacity) layout of those rows."""
    if prev_s is None:
        return None
    slots, s_old = prev_s
    row = np.full(batch, -1, dtype=np.int64)
    row[envs] = np.arange(envs.size)
    r = row[slots // capacity]
    keep = r >= 0
    return r[keep] * capacity + slots[keep] % capacity, s_old[keep]


def _checked_densities(
    config: MiVeCCConfig, batch: int, densities: Sequence[float] | np.ndarray | None
) -> FloatArray:
    """(B,) per-environment demand [veh/lane/h], validated against ``density_vplh``'s range."""
    if densities is None:
        return np.full(batch, float(config.density_vplh))
    try:
        d = np.asarray(densities, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"densities: expected {batch} numbers [veh/lane/h]") from err
    if d.shape != (batch,):
        raise ValueError(f"densities: expected shape ({batch},) (one per environment), "
                         f"got {d.shape}")
    rng = field_range("density_vplh")
    bad = [i for i, x in enumerate(d.tolist()) if not (math.isfinite(x) and rng.contains(x))]
    if bad:
        raise ValueError(f"densities: each must be {rng.describe()} veh/lane/h, "
                         f"got {d[bad].tolist()} at index {bad}")
    return d


def collision_pairs(
    network: GridNetwork,
    view: VirtualLaneView,
    s_new: FloatArray,
    exited: NDArray[np.bool_],
    vehicle_length_m: float,
) -> IntArray:
    """(k, 2) view indices of vehicle pairs closer than ``vehicle_length_m`` after a move.

    The compiled kernel :func:`mivecc_env.sim.step_kernels.collision_pairs` when numba is
    installed, else :func:`collision_pairs_reference` (identical results).
    """
    fast = step_kernels.collision_pairs(
        view.leader, s_new, exited, view.lane, view.env, network.lane_cp, network.lane_cp_s,
        network.n_cp, network.segment_length_m, network.lane_offset_m, vehicle_length_m,
    )
    if fast is not None:
        return fast
    return collision_pairs_reference(network, view, s_new, exited, vehicle_length_m)


def collision_pairs_reference(
    network: GridNetwork,
    view: VirtualLaneView,
    s_new: FloatArray,
    exited: NDArray[np.bool_],
    vehicle_length_m: float,
) -> IntArray:
    """(k, 2) view indices of vehicle pairs closer than ``vehicle_length_m`` (numpy reference).

    Two vehicles can only be that close on the same lane (checked between own-lane neighbours,
    whose order cannot change within one step) or on two crossing lanes near their shared
    conflict point, where their Euclidean distance is ``hypot(delta_1, delta_2)`` with
    ``delta`` the signed distance of each to the point. Exited vehicles are ignored.
    """
    pairs = []
    stay = ~exited
    lead = view.leader
    has = (lead >= 0) & stay
    has[has] &= stay[lead[has]]
    i = np.flatnonzero(has)
    close = s_new[lead[i]] - s_new[i] < vehicle_length_m
    if close.any():
        pairs.append(np.stack([i[close], lead[i[close]]], axis=1))

    # Only vehicles near an intersection centre can be near a conflict point.
    seg = network.segment_length_m
    to_centre = np.abs(s_new - np.round(s_new / seg) * seg)
    near = np.flatnonzero(stay & (to_centre < network.lane_offset_m + vehicle_length_m))
    delta = s_new[near, None] - network.lane_cp_s[view.lane[near]]
    vi, ci = np.nonzero(np.abs(delta) < vehicle_length_m)
    delta = delta[vi, ci]
    vi = near[vi]
    if vi.size > 1:
        cp = network.lane_cp[view.lane[vi], ci]
        key = view.env[vi] * network.n_cp + cp
        order = np.argsort(key, kind="stable")
        vi, key, d = vi[order], key[order], delta[order]
        lanes = view.lane[vi]
        for shift in range(1, 8):  # at most a few vehicles share a conflict point
            if shift >= vi.size:
                break
            a, b = slice(0, vi.size - shift), slice(shift, vi.size)
            hit = (key[a] == key[b]) & (lanes[a] != lanes[b])
            hit &= d[a] ** 2 + d[b] ** 2 < vehicle_length_m**2
            if hit.any():
                pairs.append(np.stack([vi[a][hit], vi[b][hit]], axis=1))
    if not pairs:
        return np.zeros((0, 2), dtype=np.int64)
    return np.unique(np.sort(np.concatenate(pairs), axis=1), axis=0)
