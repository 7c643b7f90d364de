"""One frozen, validated configuration for the MiVeCC simulator and environment.

Every constant of the model (``shared/MODEL.md``) lives here with the paper's value as the
default. Where the paper is ambiguous, the reading used by this project is the default and the
alternative reading is one field away (``end_rule``, ``same_lane_rule``, ``edge_sv_gate``,
``sv_acc_source``). ``docs/model.md`` explains every choice.

Example:
    >>> cfg = MiVeCCConfig(rows=1, cols=1, density_vplh=2100)
    >>> cfg.replace(scheme="EE").scheme
    'EE'
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from mivecc_env.model_presets import MODEL_PRESETS

Scheme = Literal["E", "EE", "EEC"]
Control = Literal["unsignalized", "signalized", "reservation", "optimisation"]
SignalController = Literal["fixed-time", "actuated", "max-pressure"]
ComparatorEntry = Literal["stop_clearance", "slowed"]
EndRule = Literal["sensible", "literal"]
AccSource = Literal["front", "ego"]
CloudPopulation = Literal["conflict_ahead", "before_last_centre", "network"]
CloudView = Literal["window", "released"]
CloudRewardPopulation = Literal["picks", "released"]
CloudGraphs = Literal["network", "per_lane"]
EdgeRewardScope = Literal["area", "decisions"]
Model = Literal["paper", "released"]
AccelRecord = Literal["applied", "commanded"]
SameLaneForm = Literal["project", "released"]
EdgeSelection = Literal["lowest_sv", "random"]


class ConfigError(ValueError):
    """A configuration value is unknown or outside its allowed range."""


@dataclass(frozen=True)
class Range:
    """Allowed numeric range of a field (inclusive unless stated; ``hi = inf``: no upper
    bound)."""

    lo: float
    hi: float
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False

    def describe(self) -> str:
        kind = "an integer" if self.integer else "a number"
        if self.hi == math.inf:  # open-ended: no upper bound to state
            return f"{kind} {'>' if self.lo_open else '>='} {self.lo}"
        left = "(" if self.lo_open else "["
        right = ")" if self.hi_open else "]"
        return f"{kind} in {left}{self.lo}, {self.hi}{right}"

    def contains(self, value: float) -> bool:
        if self.lo_open and not value > self.lo:
            return False
        if not self.lo_open and not value >= self.lo:
            return False
        if self.hi_open and not value < self.hi:
            return False
        return self.hi_open or value <= self.hi


def _num(default: float, lo: float, hi: float, doc: str, **kw: Any) -> Any:
    return field(default=default, metadata={"range": Range(lo, hi, **kw), "doc": doc})


def _int(default: int, lo: int, hi: int, doc: str) -> Any:
    return field(default=default, metadata={"range": Range(lo, hi, integer=True), "doc": doc})


def _choice(default: Any, choices: tuple[Any, ...], doc: str) -> Any:
    return field(default=default, metadata={"choices": choices, "doc": doc})


@dataclass(frozen=True)
class MiVeCCConfig:
    """All constants of the MiVeCC model, with the paper's values as defaults.

    Units are in the field names: ``_m`` metres, ``_s`` seconds, ``_mps`` m/s, ``_mps2`` m/s^2,
    ``_vplh`` vehicles per lane per hour. A value out of range raises :class:`ConfigError` naming
    the field and its allowed range; integral floats for integer fields are converted. An
    unknown keyword raises ``TypeError`` here (as for any Python call); :func:`from_overrides`,
    :meth:`replace` and the environments raise :class:`ConfigError` with a suggestion instead.
    """

    # --- road network -------------------------------------------------------------------
    rows: int = _int(3, 1, 16, "rows of intersections in the grid")
    cols: int = _int(3, 1, 16, "columns of intersections in the grid")
    segment_length_m: float = _num(
        150.0, 40.0, 2000.0, "length of every segment: approach, between intersections, exit"
    )
    lane_offset_m: float = _num(
        5.0, 1.0, 10.0, "distance of a lane's centreline from its road's centreline "
        "(released code: 5 m); conflict points sit this far from the centre on each axis"
    )

    # --- vehicles -----------------------------------------------------------------------
    vehicle_length_m: float = _num(
        2.0, 0.5, 10.0, "vehicle size; two vehicles closer than this collide"
    )
    v_min_mps: float = _num(6.0, 0.0, 30.0, "minimum velocity (unsignalized control)")
    v_max_mps: float = _num(13.0, 1.0, 40.0, "maximum velocity")
    v_init_mps: float = _num(10.0, 0.0, 40.0, "velocity at network entry")
    a_max_mps2: float = _num(3.0, 0.1, 10.0, "acceleration bound: a in [-a_max, a_max]")
    dt_s: float = _num(0.1, 0.01, 1.0, "simulation time step T")

    # --- demand -------------------------------------------------------------------------
    density_vplh: float = _num(
        900.0, 1.0, 3600.0, "Poisson arrival rate per entry lane (before the headway floor)"
    )
    min_headway_s: float = _num(
        1.0, 0.0, 10.0, "floor on the gap between consecutive arrivals of one entry lane"
    )
    entry_clearance_m: float = _num(
        10.0, 0.0, 100.0, "a queued vehicle enters only when the last vehicle of its lane is "
        "at least this far from the lane start; 0: no check (released code: a vehicle may be "
        "placed on top of another, which is then a counted collision)"
    )
    entry_accel_mps2: float = _num(
        0.0, -100.0, 100.0, "acceleration a new vehicle carries at entry (released code: +a_max; "
        "it enters SV_acc of its first step); within [-a_max, a_max]"
    )

    # --- safety value (eqs. safe_value) -------------------------------------------------
    sv_alpha_d: float = _num(10.0, 0.0, 1000.0, "alpha_d [m]", lo_open=True)
    sv_beta_d: float = _num(10.0, 0.0, 100.0, "beta_d", lo_open=True)
    sv_alpha_t: float = _num(1.5, 0.0, 100.0, "alpha_t", lo_open=True)
    sv_beta_t: float = _num(2.0, 0.0, 10.0, "beta_t", lo_open=True)
    sv_alpha_acc: float = _num(1.5, 0.0, 100.0, "alpha_acc", lo_open=True)
    sv_beta_acc: float = _num(12.0, 0.0, 100.0, "beta_acc", lo_open=True)
    sv_lambda_acc: float = _num(0.2, 0.0, 10.0, "lambda_acc")
    sv_d_threshold_m: float = _num(
        10.0, 0.0, 1000.0, "d_threshold of SV_acc (not in the paper; released code: 10 m)",
        lo_open=True,
    )
    sv_min: float = _num(-20.0, -1000.0, 0.0, "lower clip of the safety value", hi_open=True)
    sv_max: float = _num(20.0, 0.0, 1000.0, "upper clip of the safety value", lo_open=True)
    sv_acc_source: AccSource = _choice(
        "ego", ("ego", "front"),
        "whose acceleration SV_acc uses: the ego's (released code, default: far fewer "
        "collisions, see docs/model.md) or the front vehicle's (paper text)",
    )

    # --- virtual lanes, selection, density indicator ------------------------------------
    projection_window_m: float = _num(
        75.0, 0.0, 1000.0, "a crossing vehicle is projected onto a lane from this far before "
        "the shared conflict point", lo_open=True,
    )
    projection_clear_m: float = _num(
        10.0, 0.0, 1000.0, "... until this far past it (default 2 * lane_offset_m: until it "
        "has cleared the intersection box, as in the released code)",
    )
    control_radius_m: float = _num(
        75.0, 0.0, 1000.0, "edge control area: vehicles within this distance (along their "
        "lane) of an intersection centre", lo_open=True,
    )
    k_edge: int = _int(15, 2, 256, "state-graph size K of an edge node")
    k_cloud: int = _int(60, 2, 512, "state-graph size K of the cloud node")
    di_n: int = _int(5, 1, 100, "n of the density indicator (n-th vehicle ahead / behind)")
    cloud_pick_population: CloudPopulation = _choice(
        "conflict_ahead", ("conflict_ahead", "before_last_centre", "network"),
        "vehicles the cloud may pick, and its velocity reward's scope: those with a conflict "
        "point of their lane still ahead (default), those before the last intersection centre "
        "of their lane (released code), or all (earlier behaviour: most picks on exit links)",
    )
    cloud_graphs: CloudGraphs = _choice(
        "network", ("network", "per_lane"),
        "the cloud's state graphs: one K x K graph of the network's k_cloud highest-DI "
        "vehicles (released code; default), or one per through lane of that lane's k_cloud "
        "highest-DI vehicles, every graph acted on by the same policy (the paper's "
        "Algorithm 1): the cloud then commands up to n_lanes * k_cloud vehicles "
        "(docs/model.md, Coordinators)",
    )
    cloud_view: CloudView = _choice(
        "window", ("window", "released"),
        "the cloud's virtual lanes: the edges' windowed view (projection_window_m / "
        "projection_clear_m; default) or the released code's: own vehicles before the lane's "
        "last centre, each crossing lane's whole upstream part projected until lane_offset_m "
        "past its conflict point and only onto the part before that last centre "
        "(sim/cloud_view.py)",
    )
    cloud_reward_population: CloudRewardPopulation = _choice(
        "picks", ("picks", "released"),
        "the cloud velocity reward's vehicles: the pick population (cloud_pick_population; "
        "default) or the released code's controlled vehicles: every vehicle from its first "
        "move until the step after it passed section_control_end_m beyond its lane's last "
        "centre (sim/cloud_view.py)",
    )

    # --- end node (Algorithm 3) ---------------------------------------------------------
    eta: float = _num(3.0, 0.0, 100.0, "conversion factor: a_end = SV / eta", lo_open=True)
    omega: float = _num(0.2, 0.0, 1.0, "fusion weight of the cloud action")
    cloud_period: int = _int(
        1, 1, 1000, "the cloud decides every this many steps (steps 0, n, 2n... of each "
        "environment); its action is held by the vehicles it picked until the next decision "
        "(while they stay in the cloud's population); 1 (paper): every step",
    )
    end_rule: EndRule = _choice(
        "sensible", ("sensible", "literal"),
        "sensible: nearest ahead -> SV/eta, nearest behind -> |SV/eta|; literal: as printed",
    )
    same_lane_rule: bool = _choice(
        False, (False, True), "the released code's extra same-lane rule ('priori knowledge')"
    )
    same_lane_rule_horizon_m: float = _num(
        50.0, 0.0, 1000.0, "the same-lane rule applies this far or more before the next "
        "conflict point (released code: 50 m)"
    )
    edge_sv_gate: float | None = field(
        default=None,
        metadata={
            "range": Range(-1000.0, 1000.0),
            "optional": True,
            "doc": "fuse the edge action only when the vehicle's SV exceeds this (released "
            "code: -2); None fuses always (paper)",
        },
    )

    safety_shield: bool = _choice(
        False, (False, True), "cap every vehicle's fused acceleration by safe following on its "
        "virtual lane (own-lane leader and projected crossing vehicles, braking at a_max to "
        "v_min); in neither the paper nor the released code (sim/rule_shield.py)"
    )
    shield_gap_m: float = _num(
        3.0, 0.0, 100.0, "with safety_shield: the gap kept on the virtual lane; at least "
        "sqrt(2) * vehicle_length_m (a crossing pair this far apart on the virtual lane is "
        "that far apart / sqrt(2) in the plane)", lo_open=True,
    )

    # --- the released code's behaviours (docs/model.md, divergence table) ----------------
    model: Model = _choice(
        "paper", ("paper", "released"),
        "preset: 'paper' (this project's reading of the paper) or 'released' (the authors' "
        "released code, mivecc_env/model_presets.py); fields given explicitly win over it",
    )
    sections: bool = _choice(
        False, (False, True), "control (rules, edge) only inside a section (see section_*) and "
        "less than section_control_end_m past its centre; elsewhere a vehicle speeds up at "
        "a_max (or jumps to v_max with speed_reset); the edge area is the section's controlled "
        "part (released code)"
    )
    section_after_m: float = _num(
        10.0, 0.0, 1000.0, "a section ends this far past its intersection centre and the next "
        "one starts there (so it starts segment_length_m minus this before its centre: 140 m; "
        "the first reaches back to the lane entry)"
    )
    section_control_end_m: float = _num(
        5.0, 0.0, 1000.0, "a vehicle is controlled while less than this far past its section's "
        "centre [m] (released code: 5 m, the lane offset)"
    )
    section_virtual_lanes: bool = _choice(
        False, (False, True), "virtual lanes limited to a section's controlled part: own-lane "
        "vehicles of that part only, crossing vehicles while in the controlled part of the same "
        "section (released code)"
    )
    section_entry_lag: bool = _choice(
        False, (False, True), "with section_virtual_lanes: a vehicle is left out of the virtual "
        "lanes on the step it enters the network or a new section (released code: it files a "
        "vehicle under its section one step late and adds new vehicles after the SV pass)"
    )
    stale_action: bool = _choice(
        False, (False, True), "a vehicle left out of the virtual lanes this step (uncontrolled, "
        "or unseen after entering a section) acts on its last computed a_end, without the header "
        "rule; under speed_reset it moves with it before v is set back to v_max (released code: "
        "it keeps its last SV, so it can enter the next section slightly below v_max)"
    )
    stale_corner_reset: bool = _choice(
        False, (False, True), "with stale_action: a vehicle entering the section of the "
        "south-east corner intersection forgets where its nearest vehicle was (recorded as "
        "behind it), so its stale action there is |SV/eta| (released code: a debug branch "
        "resets that record when a vehicle enters its section 8)"
    )
    speed_reset: bool = _choice(
        False, (False, True), "every vehicle past a section's controlled part (until the next "
        "section) and on exit links drives at v_max, set instantly, no rule acting (released "
        "code; breaks the acceleration bound)"
    )
    header_rule: bool = _choice(
        False, (False, True), "the first vehicle of its virtual lane (nothing ahead) gets "
        "+a_max, overriding rule, edge and cloud (released code)"
    )
    sv_d_epsilon: float = _num(
        0.0, 0.0, 1.0, "SV_d = ln((d / alpha_d)^beta_d + this) (released code: 1e-4, floors "
        "SV_d at -9.21); 0: the paper's log"
    )
    sv_acc_epsilon: float = _num(
        0.0, 0.0, 1.0, "SV_acc uses ln(min(d_f / d_threshold, alpha_acc)^beta_acc + this) "
        "(released code: 1e-7); 0: the paper's log"
    )
    sv_no_front_distance_m: float | None = field(
        default=None,
        metadata={
            "range": Range(0.0, 1e6, lo_open=True),
            "optional": True,
            "doc": "d_front used by SV_acc when nothing is ahead on the virtual lane [m] "
            "(released code: 100); None: SV_acc is 0 then",
        },
    )
    accel_record: AccelRecord = _choice(
        "applied", ("applied", "commanded"),
        "the acceleration a vehicle records (SV_acc, state graphs): the one applied within the "
        "velocity bounds, or the commanded one when a bound cut the step, 0 when the velocity "
        "did not change (released code)",
    )
    ttc_closing_offset_mps: float = _num(
        0.0, 0.0, 10.0, "TTC = gap / (closing speed + this) [m/s] (released code: 0.1; "
        "subtracted when the nearest vehicle is behind, as there)"
    )
    same_lane_rule_form: SameLaneForm = _choice(
        "project", ("project", "released"),
        "project: the same-lane rule acts more than same_lane_rule_horizon_m before the next "
        "conflict point, on a_end before the fusion, with positions at the step start; released "
        "(released code): more than that before its section's centre (never on exit links), "
        "after the edge fusion (an edge action cannot soften it), with the leader's position "
        "after the leader's own move (the released code moves vehicles one by one)",
    )
    edge_selection: EdgeSelection = _choice(
        "lowest_sv", ("lowest_sv", "random"),
        "edge decision vehicles: the k_edge lowest SV of the area, or a random k_edge of it "
        "(released code at test time; simulator-owned seeded generator)",
    )

    # --- scheme and control -------------------------------------------------------------
    scheme: Scheme = _choice(
        "E", ("E", "EE", "EEC"),
        "E: end rules only; EE: rules + edge actions; EEC: rules + edge + cloud actions",
    )
    control: Control = _choice(
        "unsignalized", ("unsignalized", "signalized", "reservation", "optimisation"),
        "signalized: signal heads (signal_controller) and IDM car-following, v in [0, v_max]; "
        "reservation: AIM first-come-first-served slots at the conflict points; optimisation: "
        "DOOC-style arrival-time MILP per intersection (both v in [0, v_max], "
        "docs/comparators.md)",
    )
    signal_keep_clear: bool = _choice(
        True, (True, False),
        "signalized: a vehicle stops at a green or yellow stop line (if it can, at "
        "idm_comfort_decel) while the queue past the box on its lane (the first vehicle "
        "slower than 1 m/s past its stop line among the 12 ahead) leaves no room for it and "
        "the vehicles before it, each vehicle_length + idm_min_gap, so no vehicle waits "
        "inside the box (docs/comparators.md); false: vehicles may drive into a blocked box "
        "and collide there (the signal runs published before this default)",
    )
    comparator_entry: ComparatorEntry = _choice(
        "stop_clearance", ("stop_clearance", "slowed"),
        "how a queued vehicle enters under the comparators (control other than unsignalized): "
        "stop_clearance: at v_init, once the lane's last vehicle is far enough ahead to stop "
        "behind it standing (v_init^2 / (2 idm_comfort_decel) + idm_min_gap + vehicle_length); "
        "slowed: once it is entry_clearance_m ahead (MiVeCC's rule; at least idm_min_gap + "
        "vehicle_length), at the speed from which it can stop behind it at "
        "idm_comfort_decel, at most v_init (docs/comparators.md)",
    )
    signal_controller: SignalController = _choice(
        "fixed-time", ("fixed-time", "actuated", "max-pressure"),
        "signal controller when no signal agent acts: fixed-time plan, actuated (gap-out / "
        "max-out) or max-pressure (Varaiya)",
    )
    signal_min_green_s: float = _num(
        10.0, 0.0, 600.0, "minimum green of a phase (actuated, max-pressure, signal agents)"
    )
    signal_max_green_s: float = _num(
        40.0, 1.0, 600.0, "actuated: maximum green of a phase (max-out)"
    )
    actuated_gap_s: float = _num(
        3.0, 0.1, 60.0, "actuated: passage time; the phase gaps out after this long without a "
        "vehicle in its detection zones"
    )
    actuated_detector_m: float = _num(
        30.0, 1.0, 1000.0, "actuated: length of the detection zone before each stop line"
    )
    reservation_margin_m: float = _num(
        0.5, 0.0, 50.0, "reservation / optimisation: margin added to the vehicle size, both "
        "for a conflict point's occupancy radius and for the same-lane gap"
    )
    reservation_buffer_s: float = _num(
        0.2, 0.0, 10.0, "reservation: time buffer on each side of a granted slot"
    )
    reservation_v_cross_min_mps: float = _num(
        3.0, 0.5, 40.0, "reservation / optimisation: slowest cruise velocity of a planned "
        "trajectory through an intersection"
    )
    reservation_retry_s: float = _num(
        0.5, 0.0, 60.0, "reservation: a refused vehicle requests again after this long"
    )
    reservation_refused_speed_mps: float = _num(
        6.0, 0.0, 40.0, "reservation: a refused vehicle slows towards this velocity"
    )
    optimisation_period_s: float = _num(
        1.0, 0.0, 60.0, "optimisation: the arrival-time schedule is re-solved this often",
        lo_open=True,
    )
    optimisation_headway_s: float = _num(
        1.5, 0.0, 60.0, "optimisation: minimum time between two vehicles of crossing lanes "
        "at a conflict point (and between same-lane vehicles)"
    )
    optimisation_max_vehicles: int = _int(
        6, 1, 64, "optimisation: vehicles per intersection in one MILP (nearest first)"
    )
    signal_green_s: float = _num(30.0, 1.0, 600.0, "green time of each phase (signalized)")
    signal_yellow_s: float = _num(3.0, 0.0, 60.0, "yellow time of each phase (signalized)")
    signal_all_red_s: float = _num(2.0, 0.0, 60.0, "all-red clearance time (signalized)")
    signal_offset_s: float = _num(
        0.0, 0.0, 600.0, "start offset added per intersection column and row (green wave)"
    )
    idm_time_headway_s: float = _num(1.0, 0.1, 10.0, "IDM desired time headway")
    idm_min_gap_m: float = _num(2.0, 0.0, 50.0, "IDM jam distance (bumper to bumper)")
    idm_comfort_decel_mps2: float = _num(2.0, 0.1, 10.0, "IDM comfortable deceleration b")
    idm_delta: float = _num(4.0, 1.0, 10.0, "IDM acceleration exponent")
    idm_max_decel_mps2: float = _num(
        9.0, 0.1, 20.0, "emergency braking limit under signals (a red light may need more than "
        "the unsignalized bound a_max)"
    )

    # --- episode and reward -------------------------------------------------------------
    max_steps: int = _int(3000, 1, 10_000_000, "truncation: steps per episode")
    reward_v_ref_mps: float = _num(
        12.0, 0.0, 40.0, "velocity reference of the reward: term mean(v - v_ref)"
    )
    reward_sv_weight: float = _num(
        0.05, 0.0, 100.0, "weight of the edge reward's mean-SV term"
    )
    collision_penalty: float = _num(
        10.0, 0.0, 1e6, "reward penalty per vehicle removed by collision in a node's scope"
    )
    edge_reward_scope: EdgeRewardScope = _choice(
        "area", ("area", "decisions"),
        "the edge reward's velocity term mean(v - v_ref) over every vehicle of the node's "
        "control area (default) or over its decision vehicles only (released trainer)",
    )

    # ------------------------------------------------------------------------------------
    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            raw = getattr(self, f.name)
            value = _plain_scalar(raw)  # numpy scalars are accepted as their Python value
            if value is not raw:
                object.__setattr__(self, f.name, value)
            _check_field(f, value)
            rng = f.metadata.get("range")
            if rng is not None and rng.integer and isinstance(value, float):
                object.__setattr__(self, f.name, int(value))
        self._check_relations()

    def _check_relations(self) -> None:
        def need(ok: bool, name: str, message: str) -> None:
            if not ok:
                raise ConfigError(f"{name}: {message}")

        need(self.v_min_mps < self.v_max_mps, "v_min_mps",
             f"must be below v_max_mps={self.v_max_mps}, got {self.v_min_mps}")
        lo = 0.0 if self.control != "unsignalized" else self.v_min_mps
        need(lo <= self.v_init_mps <= self.v_max_mps, "v_init_mps",
             f"must be in [{lo}, {self.v_max_mps}], got {self.v_init_mps}")
        need(self.sv_min < self.sv_max, "sv_min", "must be below sv_max")
        half = self.segment_length_m / 2
        need(self.control_radius_m <= half, "control_radius_m",
             f"must be in (0, {half}] (half a segment) so control areas do not overlap, "
             f"got {self.control_radius_m}")
        lim = self.segment_length_m - self.lane_offset_m
        need(self.projection_window_m < lim, "projection_window_m",
             f"must be in (0, {lim}) (segment_length_m - lane_offset_m), "
             f"got {self.projection_window_m}")
        need(2 * self.lane_offset_m < half, "lane_offset_m",
             f"must be below segment_length_m / 4 = {half / 2}, got {self.lane_offset_m}")
        need(not self.safety_shield
             or self.shield_gap_m >= math.sqrt(2.0) * self.vehicle_length_m, "shield_gap_m",
             f"must be at least sqrt(2) * vehicle_length_m = "
             f"{math.sqrt(2.0) * self.vehicle_length_m:.4g}, got {self.shield_gap_m}")
        need(not self.safety_shield or self.control == "unsignalized", "safety_shield",
             f"acts on the MiVeCC rules only (control='unsignalized'), got "
             f"control={self.control!r}")
        # Opposite-direction lanes run 2 * lane_offset_m apart; only same-lane and
        # conflict-point pairs are checked for collisions, so longer vehicles would overlap unseen.
        need(self.vehicle_length_m <= 2 * self.lane_offset_m, "vehicle_length_m",
             f"must be at most 2 * lane_offset_m = {2 * self.lane_offset_m} (vehicles on "
             f"opposite-direction lanes would overlap unseen), got {self.vehicle_length_m}")
        # The collision check samples positions once per step: a vehicle that moves 2 vehicle
        # lengths in one step can cross another's collision zone between two checks.
        step_m = self.v_max_mps * self.dt_s
        need(step_m < 2 * self.vehicle_length_m, "dt_s",
             f"v_max_mps * dt_s = {step_m:g} m per step must be below 2 * vehicle_length_m = "
             f"{2 * self.vehicle_length_m:g} m (else a vehicle can pass another within one step "
             f"unseen by the collision check): lower dt_s or v_max_mps, got dt_s={self.dt_s}")
        need(abs(self.entry_accel_mps2) <= self.a_max_mps2, "entry_accel_mps2",
             f"must be in [{-self.a_max_mps2}, {self.a_max_mps2}] (a_max_mps2), "
             f"got {self.entry_accel_mps2}")
        need(self.section_after_m < self.segment_length_m, "section_after_m",
             f"must be in [0, {self.segment_length_m}) (segment_length_m), "
             f"got {self.section_after_m}")
        need(self.section_control_end_m <= self.section_after_m, "section_control_end_m",
             f"must be in [0, {self.section_after_m}] (section_after_m), "
             f"got {self.section_control_end_m}")

    # ------------------------------------------------------------------------------------
    @property
    def a_min_mps2(self) -> float:
        """Lower acceleration bound [m/s^2] (the paper's range is symmetric)."""
        return -self.a_max_mps2

    @property
    def velocity_floor_mps(self) -> float:
        """Velocity floor actually applied [m/s]: ``v_min_mps`` unsignalized, else 0."""
        return 0.0 if self.control != "unsignalized" else self.v_min_mps

    @property
    def n_intersections(self) -> int:
        return self.rows * self.cols

    @property
    def n_cloud_graphs(self) -> int:
        """Number of cloud state graphs: 1, or one per through lane (2R + 2C) with
        ``cloud_graphs="per_lane"``."""
        return 2 * (self.rows + self.cols) if self.cloud_graphs == "per_lane" else 1

    @property
    def cloud_graph_shape(self) -> tuple[int, ...]:
        """Shape of the cloud's observation: ``(K, K, 3)``, or ``(n_lanes, K, K, 3)`` with
        ``cloud_graphs="per_lane"`` (K = ``k_cloud``)."""
        k = self.k_cloud
        return (k, k, 3) if self.n_cloud_graphs == 1 else (self.n_cloud_graphs, k, k, 3)

    @property
    def cloud_action_shape(self) -> tuple[int, ...]:
        """Shape of the cloud's action [m/s^2] and mask: ``cloud_graph_shape`` without its
        last two axes, one acceleration per graph column."""
        return self.cloud_graph_shape[:-2]

    def replace(self, **overrides: Any) -> MiVeCCConfig:
        """A copy with some fields changed (validated like the constructor)."""
        return from_overrides(self, **overrides)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _plain_scalar(value: Any) -> Any:
    """A numpy scalar (or 0-d array) as the plain Python bool/int/float/str it holds."""
    if isinstance(value, np.generic) or (isinstance(value, np.ndarray) and value.ndim == 0):
        return value.item()
    return value


_dataclass_init = MiVeCCConfig.__init__


def _init_with_preset(self: MiVeCCConfig, *args: Any, **kwargs: Any) -> None:
    """The dataclass ``__init__``, with the ``model`` preset under the explicit keywords."""
    model = kwargs.get("model", "paper")
    if model in MODEL_PRESETS and not args:
        kwargs = {**MODEL_PRESETS[model], **kwargs}
    _dataclass_init(self, *args, **kwargs)


_init_with_preset.__doc__ = _dataclass_init.__doc__
_init_with_preset.__signature__ = inspect.signature(_dataclass_init)  # type: ignore[attr-defined]
MiVeCCConfig.__init__ = _init_with_preset  # type: ignore[method-assign]


def _check_field(f: dataclasses.Field, value: Any) -> None:
    meta = f.metadata
    if "choices" in meta:
        if value not in meta["choices"] or type(value) is not type(meta["choices"][0]):
            raise ConfigError(f"{f.name}: must be one of {list(meta['choices'])}, got {value!r}")
        return
    check_range(f.name, value, meta["range"], optional=bool(meta.get("optional")))


def check_range(name: str, value: Any, rng: Range, optional: bool = False) -> None:
    """:class:`ConfigError` naming ``name`` and ``rng`` unless ``value`` is a finite number in
    it (an integer where ``rng.integer``; ``None`` too where ``optional``). One check for the
    config's fields and the training presets'."""
    if value is None and optional:
        return
    ok = not isinstance(value, bool) and isinstance(value, int | float)
    if ok and rng.integer and not isinstance(value, int):
        ok = isinstance(value, float) and value.is_integer()
    if not (ok and math.isfinite(value) and rng.contains(value)):
        allowed = rng.describe() + (" or None" if optional else "")
        raise ConfigError(f"{name}: must be {allowed}, got {value!r}")


FIELD_NAMES: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(MiVeCCConfig))
_FIELDS_BY_NAME: dict[str, Any] = {f.name: f for f in dataclasses.fields(MiVeCCConfig)}


def field_range(name: str) -> Range:
    """The allowed range of the numeric config field ``name`` (``KeyError``: no such field,
    or not a numeric one)."""
    rng = _FIELDS_BY_NAME[name].metadata.get("range")
    if rng is None:
        raise KeyError(f"{name}: not a numeric configuration field")
    return rng


#: Short keyword aliases accepted by :func:`from_overrides` (``density`` is in veh/lane/h;
#: ``max_cycles`` is PettingZoo's keyword for the episode length).
ALIASES: dict[str, str] = {"density": "density_vplh", "max_cycles": "max_steps"}


def from_overrides(base: MiVeCCConfig | None = None, **overrides: Any) -> MiVeCCConfig:
    """Build a config from keyword overrides, rejecting unknown keys with a suggestion."""
    base = base or MiVeCCConfig()
    for alias, name in ALIASES.items():
        if alias in overrides and name in overrides:
            raise ConfigError(
                f"{alias}: given together with {name} ({alias!r} is another name for {name!r}); "
                "give only one"
            )
    fixed: dict[str, Any] = {}
    model = overrides.get("model")
    if isinstance(model, str) and model in MODEL_PRESETS:
        # Precedence: the base config < the new model's preset < the other explicit overrides.
        fixed.update(MODEL_PRESETS[model])
    for key, value in overrides.items():
        value = _plain_scalar(value)
        name = ALIASES.get(key, key)
        if name not in FIELD_NAMES:
            close = difflib.get_close_matches(key, [*FIELD_NAMES, *ALIASES], n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ConfigError(f"{key}: unknown configuration field{hint}")
        rng = _FIELDS_BY_NAME[name].metadata.get("range")
        if rng is not None and rng.integer:
            if isinstance(value, float) and value.is_integer():
                value = int(value)
        fixed[name] = value
    return dataclasses.replace(base, **fixed)


def describe_fields() -> list[tuple[str, Any, str]]:
    """(name, default, description) of every field, for documentation and the CLI."""
    fields = dataclasses.fields(MiVeCCConfig)
    return [(f.name, f.default, f.metadata.get("doc", "")) for f in fields]
