"""The released code's own collision count: per vehicle its lenient check flags.

The released simulator checks, after every move, each *controlled* vehicle (in a section and
less than ``section_control_end_m`` past its centre, filed under that section since the last
step) against one vehicle only: its nearest vehicle on its section-limited virtual lane
(:func:`sections.section_view`; the vehicle behind when none is ahead, the one ahead when
none is behind, otherwise the closer, the one behind on a tie). It flags the vehicle when the
two are closer than ``vehicle_length_m`` (Euclidean distance of their centres; the virtual
lane projects at the conflict point, so for a crossing neighbour this is the hypotenuse of
the two distances to it) and counts one collision **per flagged vehicle**: two vehicles that
flag each other count 2, a pair only one of them looks at counts 1, a pair on the exit links,
in the 5 m after a centre or seen by neither counts 0.

This project's strict check (every pair closer than ``vehicle_length_m``, anywhere) counts
events (``collisions``) and removes the vehicles (``collided_vehicles``). Every vehicle the
released check flags is in a strict pair, so :func:`flagged_count` runs only on steps with a
strict event, on the positions after the move and before the strict check removes anyone,
under both models (the section geometry comes from ``section_after_m`` /
``section_control_end_m``, which only the released model uses for control). The count is the
simulator's ``released_flagged`` (summary key ``released_check_collisions``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import sections
from mivecc_env.sim.network import GridNetwork

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def flagged_count(
    network: GridNetwork, config: MiVeCCConfig, active: NDArray[np.bool_], lane: IntArray,
    s: FloatArray, prev_s: tuple[IntArray, FloatArray] | None,
) -> IntArray:
    """(B,) vehicles the released code's check flags in the given state.

    Args:
        active / lane / s: (B, capacity) slot arrays after the move (``s`` [m]), exited
            vehicles inactive, collided ones still active.
        prev_s: (flat slots, positions [m]) before the move: a vehicle whose section changed
            in it is not filed under its new section yet (the released code's one-step lag).
    """
    cfg = config if config.section_entry_lag else config.replace(section_entry_lag=True)
    sec = sections.section_view(network, cfg, active, lane, s, prev_s)
    batch = active.shape[0]
    if sec.n_vehicles == 0:
        return np.zeros(batch, dtype=np.int64)
    front, back = sec.front_point, sec.back_point
    take_front = (front >= 0) & ((back < 0) | (sec.d_front < sec.d_back))
    near = np.where(take_front, front, back)
    has = near >= 0
    me = sec.vehicle[has]
    other = sec.vehicle[sec.point_vehicle[near[has]]]
    cap = active.shape[1]
    xy_me = network.xy(lane.ravel()[me], s.ravel()[me])
    xy_other = network.xy(lane.ravel()[other], s.ravel()[other])
    close = np.hypot(*(xy_me - xy_other).T) < config.vehicle_length_m
    return np.bincount(me[close] // cap, minlength=batch).astype(np.int64)
