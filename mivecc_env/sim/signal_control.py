"""Signal phases as a state machine, and the classical controllers that drive it.

Every intersection of every environment has two phases (0: east-west green, 1: north-south
green) and is, at any time, in one stage of its current phase: GREEN, YELLOW or ALL_RED. A
controller (or a signal agent) only says *whether the current phase should end*; the state
machine enforces the timing: a green lasts at least ``signal_min_green_s`` (the fixed-time
plan: exactly ``signal_green_s``), then ``signal_yellow_s`` of yellow and ``signal_all_red_s``
of all-red follow before the other phase turns green. Times are counted in whole steps.

Controllers (``signal_controller``), all vectorised over environments and intersections:

* ``fixed-time``: end the green after ``signal_green_s`` (the plan of ``signals.phase_states``,
  offsets included).
* ``actuated`` (gap-out / max-out): after the minimum green, end the green when the other
  phase has a call (a vehicle within ``control_radius_m`` before its stop line) and either no
  vehicle has been in the green phase's detection zones (``actuated_detector_m`` before the
  stop line) for ``actuated_gap_s`` (gap-out) or the green has lasted ``signal_max_green_s``
  (max-out).
* ``max-pressure`` (Varaiya 2013): after the minimum green, switch when the other phase's
  pressure is higher. The pressure of a phase is the sum over its two approach lanes of the
  vehicles upstream of the intersection (within ``control_radius_m`` before the centre) minus
  those downstream (within ``control_radius_m`` after it): with one through movement per lane
  and equal saturation flows, Varaiya's weights reduce to these counts.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.network import GridNetwork

if TYPE_CHECKING:
    from mivecc_env.sim.virtual_lane import VirtualLaneView

IntArray = NDArray[np.int64]
FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Stages of the current phase (the head colours are signals.GREEN / YELLOW / RED).
STAGE_GREEN, STAGE_YELLOW, STAGE_ALL_RED = 0, 1, 2
N_PHASES = 2


def _steps(seconds: float, dt: float) -> int:
    return round(seconds / dt)


class SignalPhases:
    """Phase state of ``batch_size`` environments x ``n_intersections`` (see module docstring).

    Attributes:
        phase: (B, n_int) current phase (0 east-west, 1 north-south).
        stage: (B, n_int) STAGE_GREEN / STAGE_YELLOW / STAGE_ALL_RED.
        elapsed: (B, n_int) steps spent in the current stage.
        gap_steps: (B, n_int, 2) steps since a vehicle was last in each phase's detection zones.
    """

    def __init__(self, config: MiVeCCConfig, network: GridNetwork, batch_size: int) -> None:
        self.config = config
        self.network = network
        self.batch_size = batch_size
        dt = config.dt_s
        self.green_steps = _steps(config.signal_green_s, dt)
        self.yellow_steps = _steps(config.signal_yellow_s, dt)
        self.all_red_steps = _steps(config.signal_all_red_s, dt)
        self.min_green_steps = _steps(config.signal_min_green_s, dt)
        self.max_green_steps = _steps(config.signal_max_green_s, dt)
        self.gap_limit_steps = _steps(config.actuated_gap_s, dt)
        self.reset()

    def reset(self) -> None:
        """Start every intersection where the fixed-time plan (with offsets) is at time 0."""
        c, n = self.config, self.network.n_intersections
        rows, cols = np.divmod(np.arange(n), c.cols)
        half = self.green_steps + self.yellow_steps + self.all_red_steps
        offset = np.array([_steps(c.signal_offset_s * (r + k), c.dt_s) for r, k in
                           zip(rows, cols, strict=True)], dtype=np.int64)
        local = (-offset) % (2 * half)
        phase = local // half
        rest = local - phase * half
        stage = np.where(rest < self.green_steps, STAGE_GREEN,
                         np.where(rest < self.green_steps + self.yellow_steps, STAGE_YELLOW,
                                  STAGE_ALL_RED))
        start = np.where(stage == STAGE_GREEN, 0,
                         np.where(stage == STAGE_YELLOW, self.green_steps,
                                  self.green_steps + self.yellow_steps))
        b = self.batch_size
        self.phase = np.tile(phase, (b, 1)).astype(np.int64)
        self.stage = np.tile(stage, (b, 1)).astype(np.int64)
        self.elapsed = np.tile(rest - start, (b, 1)).astype(np.int64)
        self.gap_steps = np.zeros((b, n, N_PHASES), dtype=np.int64)

    def heads(self) -> IntArray:
        """(B, n_int, 2) head colour (signals.GREEN / YELLOW / RED) of each phase's approaches."""
        from mivecc_env.sim.signals import GREEN, RED, YELLOW

        out = np.full((*self.phase.shape, N_PHASES), RED, dtype=np.int64)
        colour = np.where(self.stage == STAGE_GREEN, GREEN,
                          np.where(self.stage == STAGE_YELLOW, YELLOW, RED))
        np.put_along_axis(out, self.phase[..., None], colour[..., None], axis=2)
        return out

    def green_elapsed_s(self) -> FloatArray:
        """(B, n_int) seconds the current phase has been green (0 outside green)."""
        return np.where(self.stage == STAGE_GREEN, self.elapsed, 0) * self.config.dt_s

    # ------------------------------------------------------------------------------------
    def advance(self, end_green: BoolArray) -> None:
        """One step: ``end_green`` (B, n_int) asks to end the current green; timing enforced."""
        self.elapsed += 1
        green = self.stage == STAGE_GREEN
        to_yellow = green & end_green & (self.elapsed >= self.min_green_steps)
        to_red = (self.stage == STAGE_YELLOW) & (self.elapsed >= self.yellow_steps)
        to_green = (self.stage == STAGE_ALL_RED) & (self.elapsed >= self.all_red_steps)
        self.stage = np.where(to_yellow, STAGE_YELLOW, self.stage)
        self.stage = np.where(to_red, STAGE_ALL_RED, self.stage)
        self.stage = np.where(to_green, STAGE_GREEN, self.stage)
        self.phase = np.where(to_green, 1 - self.phase, self.phase)
        self.elapsed = np.where(to_yellow | to_red | to_green, 0, self.elapsed)
        # a zero-length yellow or all-red passes at once
        for _ in range(2):
            skip_y = (self.stage == STAGE_YELLOW) & (self.elapsed >= self.yellow_steps)
            self.stage = np.where(skip_y, STAGE_ALL_RED, self.stage)
            skip_r = (self.stage == STAGE_ALL_RED) & (self.elapsed >= self.all_red_steps)
            self.stage = np.where(skip_r, STAGE_GREEN, self.stage)
            self.phase = np.where(skip_r, 1 - self.phase, self.phase)

    def step(self, view: VirtualLaneView, s: FloatArray,
             agent_phase: IntArray | None = None) -> None:
        """Decide (controller, or agents where ``agent_phase >= 0``) and advance one step.

        Args:
            view: the virtual-lane view of the state the decision is made on.
            s: (n,) positions of the view's vehicles [m].
            agent_phase: (B, n_int) phase a signal agent wants green, -1 where none acts.
        """
        agent_phase = check_phase_action(agent_phase, self.phase.shape)
        counts = approach_counts(self.network, self.config, view, s, self.batch_size)
        in_zone = counts["detected"] > 0
        self.gap_steps = np.where(in_zone, 0, self.gap_steps + 1)
        end = self.controller_decision(counts)
        if agent_phase is not None:
            acts = agent_phase >= 0
            end = np.where(acts, agent_phase != self.phase, end)
        self.advance(end)

    def controller_decision(self, counts: dict[str, IntArray]) -> BoolArray:
        """(B, n_int) whether the configured controller wants the current green to end."""
        kind = self.config.signal_controller
        cur = self.phase[..., None]
        after = self.elapsed + 1  # the decision is about the state after this step
        if kind == "fixed-time":
            return after >= self.green_steps
        other = 1 - cur
        if kind == "actuated":
            call = np.take_along_axis(counts["calls"], other, axis=2)[..., 0] > 0
            gap = np.take_along_axis(self.gap_steps, cur, axis=2)[..., 0]
            gap_out = gap >= self.gap_limit_steps
            max_out = after >= self.max_green_steps
            return call & (gap_out | max_out)
        pressure = counts["upstream"] - counts["downstream"]
        p_cur = np.take_along_axis(pressure, cur, axis=2)[..., 0]
        p_other = np.take_along_axis(pressure, other, axis=2)[..., 0]
        return p_other > p_cur


def check_phase_action(action: object, shape: tuple[int, int]) -> IntArray | None:
    """Validate a signal action: integers in {-1, 0, 1} of shape ``(B, n_intersections)``."""
    if action is None:
        return None
    arr = np.asarray(action)
    if arr.shape != shape:
        raise ValueError(f"signal_phase: expected shape {shape} (B, n_intersections), "
                         f"got {arr.shape}")
    if arr.dtype.kind not in "iub" and not (
        arr.dtype.kind == "f" and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr))
    ):
        raise ValueError(f"signal_phase: must hold integers, got dtype {arr.dtype}")
    arr = arr.astype(np.int64)
    if arr.size and (arr.min() < -1 or arr.max() > 1):
        raise ValueError("signal_phase: values must be -1 (controller decides), 0 (east-west) "
                         f"or 1 (north-south), got range [{arr.min()}, {arr.max()}]")
    return arr


def approach_counts(network: GridNetwork, config: MiVeCCConfig, view: VirtualLaneView,
                    s: FloatArray, batch_size: int) -> dict[str, IntArray]:
    """Per (env, intersection, phase) vehicle counts, each (B, n_int, 2).

    ``upstream`` / ``downstream``: vehicles within ``control_radius_m`` before / after the
    centre on the phase's lanes; ``calls``: vehicles within ``control_radius_m`` before the stop
    line; ``detected``: vehicles in the detection zone (``actuated_detector_m`` before the stop
    line, up to the line).
    """
    from mivecc_env.sim.signals import stop_line_offset_m

    n_int = network.n_intersections
    shape = (batch_size, n_int, N_PHASES)
    out = {k: np.zeros(shape, dtype=np.int64) for k in
           ("upstream", "downstream", "calls", "detected")}
    if s.size == 0:
        return out
    lane = view.lane
    phase = np.where(network.lane_horizontal[lane], 0, 1)
    r = config.control_radius_m
    seg = network.segment_length_m
    n_on = network.lane_centres_s.shape[1]
    k = np.clip(np.floor((s + r) / seg).astype(np.int64) - 1, 0, n_on - 1)
    centre = network.lane_centres_s[lane, k]
    inter = network.lane_intersections[lane, k]
    inside = (s >= centre - r) & (s < centre + r) & (inter >= 0)
    before = inside & (s < centre)
    line = centre - stop_line_offset_m(config)
    flat = (view.env * n_int + np.maximum(inter, 0)) * N_PHASES + phase
    size = batch_size * n_int * N_PHASES

    def count(mask: BoolArray) -> IntArray:
        return np.bincount(flat[mask], minlength=size).reshape(shape)

    out["upstream"] = count(before)
    out["downstream"] = count(inside & ~before)
    out["calls"] = count(before & (s <= line))
    out["detected"] = count(before & (s <= line) & (s >= line - config.actuated_detector_m))
    return out


#: Features per approach in :func:`signal_observation` and the phase features after them.
APPROACH_FEATURES = ("approaching", "queue", "mean_speed_mps")
PHASE_FEATURES = ("phase", "stage", "elapsed_s")
#: Velocity below which an approaching vehicle counts as queued [m/s].
QUEUE_SPEED_MPS = 0.5


def centre_crossings(network: GridNetwork, view: VirtualLaneView,
                     prev_s: tuple[IntArray, FloatArray] | None, batch_size: int) -> IntArray:
    """(B, n_int) vehicles that passed each intersection's centre in the last move.

    A vehicle of the view passed the centre ``c`` of its lane if its position before the move
    was below ``c`` and is now at or past it. Vehicles removed in the step (exits, collisions)
    are not in the view and are not counted; a vehicle entering a slot freed in the same step
    starts near its lane's entry, before any centre, so it never counts.

    Args:
        prev_s: (flat slots in increasing order, positions [m]) before the last move
            (:attr:`Simulator.prev_positions`); ``None`` before the first step (zeros).
    """
    n_int = network.n_intersections
    out = np.zeros((batch_size, n_int), dtype=np.int64)
    if prev_s is None or prev_s[0].size == 0 or view.n_vehicles == 0:
        return out
    slots, s_old = prev_s
    at = np.minimum(np.searchsorted(slots, view.vehicle), slots.size - 1)
    known = slots[at] == view.vehicle
    before = np.where(known, s_old[at], np.inf)
    centres = network.lane_centres_s[view.lane]  # (n, n_on): inf past the lane's last
    inter = network.lane_intersections[view.lane]
    passed = (before[:, None] < centres) & (view.s[:, None] >= centres) & (inter >= 0)
    vehicle, k = np.nonzero(passed)
    flat = view.env[vehicle] * n_int + inter[vehicle, k]
    return np.bincount(flat, minlength=batch_size * n_int).reshape(batch_size, n_int)


def signal_observation(network: GridNetwork, config: MiVeCCConfig, view: VirtualLaneView,
                       s: FloatArray, v: FloatArray, phases: SignalPhases,
                       prev_s: tuple[IntArray, FloatArray] | None = None,
                       ) -> tuple[FloatArray, dict[str, FloatArray]]:
    """What a signal controller sees, per intersection, and its reward terms.

    Returns:
        obs: (B, n_int, 4 * 3 + 3): for each approach (lane heading east, west, north, south,
            :data:`network.HEADINGS`) the vehicles within ``control_radius_m`` before the centre
            (``approaching``), those of them slower than :data:`QUEUE_SPEED_MPS` (``queue``) and
            their mean velocity [m/s] (0 without vehicles); then the current phase (0 / 1), its
            stage (0 green, 1 yellow, 2 all-red) and the seconds spent in that stage.
        terms: (B, n_int) reward terms, ``reward_queue`` = -(queued vehicles),
            ``reward_pressure`` = -|upstream - downstream vehicles over all approaches| and
            ``reward_throughput`` = the vehicles that passed the centre in the last move
            (:func:`centre_crossings`; ``prev_s`` as there).
    """
    b, n_int = phases.batch_size, network.n_intersections
    approaching = np.zeros((b, n_int, 4))
    queue = np.zeros((b, n_int, 4))
    speed_sum = np.zeros((b, n_int, 4))
    counts = approach_counts(network, config, view, s, b)
    if s.size:
        lane = view.lane
        r, seg = config.control_radius_m, network.segment_length_m
        n_on = network.lane_centres_s.shape[1]
        k = np.clip(np.floor((s + r) / seg).astype(np.int64) - 1, 0, n_on - 1)
        centre = network.lane_centres_s[lane, k]
        inter = network.lane_intersections[lane, k]
        before = (s >= centre - r) & (s < centre) & (inter >= 0)
        flat = ((view.env * n_int + np.maximum(inter, 0)) * 4 + network.lane_heading[lane])
        size = b * n_int * 4
        shape = (b, n_int, 4)
        approaching = np.bincount(flat[before], minlength=size).reshape(shape).astype(float)
        queue = np.bincount(flat[before & (v < QUEUE_SPEED_MPS)],
                            minlength=size).reshape(shape).astype(float)
        speed_sum = np.bincount(flat[before], v[before], minlength=size).reshape(shape)
    mean_speed = np.where(approaching > 0, speed_sum / np.maximum(approaching, 1), 0.0)
    per_approach = np.stack([approaching, queue, mean_speed], axis=-1).reshape(b, n_int, 12)
    phase_part = np.stack([phases.phase, phases.stage, phases.elapsed * config.dt_s],
                          axis=-1).astype(float)
    obs = np.concatenate([per_approach, phase_part], axis=-1)
    pressure = (counts["upstream"] - counts["downstream"]).sum(axis=-1)
    crossed = centre_crossings(network, view, prev_s, b).astype(float)
    terms = {"reward_queue": -queue.sum(axis=-1), "reward_pressure": -np.abs(pressure),
             "reward_throughput": crossed}
    return obs, terms
