"""Helpers for hand-built simulator scenarios (vehicles placed directly in the arrays)."""

from __future__ import annotations

from collections.abc import Sequence

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.core import Simulator

# Lane ids of the 1x1 grid (lane order: eastbound rows, westbound rows, northbound columns,
# southbound columns).
EAST, WEST, NORTH, SOUTH = 0, 1, 2, 3


def hand_sim(config: MiVeCCConfig | None = None, seed: int = 0) -> Simulator:
    """A 1x1 simulator (or the given config) with an empty network at time 0."""
    return Simulator(config or MiVeCCConfig(rows=1, cols=1), seed=seed)


def place(
    sim: Simulator,
    vehicles: Sequence[tuple[int, float, float]],
    accel: Sequence[float] | None = None,
    env: int = 0,
) -> None:
    """Replace the vehicles of ``env`` by ``(lane, s, v)`` in slots 0, 1, ... and rebuild the view.

    Slot ``k`` holds ``vehicles[k]``; with a single environment, view index ``k`` is slot ``k``.
    """
    sim.active[env] = False
    for k, (lane, s, v) in enumerate(vehicles):
        sim.active[env, k] = True
        sim.lane[env, k] = lane
        sim.s[env, k] = s
        sim.v[env, k] = v
        sim.a[env, k] = 0.0 if accel is None else accel[k]
        sim.vid[env, k] = k
        sim.t_arrive[env, k] = sim.t_enter[env, k] = sim.time_s
    sim._refresh_view()
