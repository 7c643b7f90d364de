"""A cloud that decides every n steps: its commands held by the vehicles it picked.

With ``config.cloud_period = n > 1`` the cloud decides on steps ``0, n, 2n, ...`` of each
environment (counted since the environment's reset; a continuous run keeps counting across
chunks). On a decision step the cloud's per-column action is mapped to the vehicles of its
columns, as with ``n = 1``, and remembered per vehicle (slot and unique id). On the ``n - 1``
steps that follow, the action given for the cloud is ignored and each of those vehicles keeps
its commanded acceleration while it is still in the cloud's population
(``cloud_pick_population``); vehicles that left the network or the population, and vehicles
that entered since, get no cloud command. The fusion itself (``end_node.fuse``:
``(1 - omega) a + omega a_cloud``) is unchanged.

``n = 1`` (the paper's cloud) never stores anything: every step is a decision step.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def decision_steps(env_steps: NDArray[np.int64], period: int) -> BoolArray:
    """(B,) bool: whether the cloud decides on the step each environment takes next."""
    return env_steps % period == 0


class HeldCloudCommands:
    """Per-vehicle cloud commands between two decisions (see the module docstring).

    Args:
        shape: ``(B, capacity)`` of the simulator's vehicle slots (it follows the simulator
            when that adds slots).
    """

    def __init__(self, shape: tuple[int, int]) -> None:
        self._accel = np.full(shape, np.nan)  # [m/s^2], NaN: no command
        self._vid = np.full(shape, -1, dtype=np.int64)  # the vehicle each command is for

    def commands(
        self,
        fresh: FloatArray | None,
        decides: BoolArray,
        vid: NDArray[np.int64],
        population_slots: NDArray[np.int64],
    ) -> FloatArray:
        """The (B, capacity) cloud command of this step, NaN where none.

        Args:
            fresh: (B, capacity) command mapped from this step's cloud action (NaN where none),
                or ``None`` (no cloud action given: a deciding environment commands nothing).
            decides: (B,) bool, the environments whose cloud decides on this step; they store
                ``fresh``, the others execute what they stored.
            vid: (B, capacity) the simulator's vehicle ids per slot (-1: empty slot).
            population_slots: flat slot indices of the vehicles in the cloud's population.
        """
        grow = vid.shape[1] - self._vid.shape[1]
        if grow > 0:  # the simulator added slots at the end of its arrays
            self._accel = np.pad(self._accel, ((0, 0), (0, grow)), constant_values=np.nan)
            self._vid = np.pad(self._vid, ((0, 0), (0, grow)), constant_values=-1)
        if decides.any():
            self._accel[decides] = np.nan if fresh is None else fresh[decides]
            self._vid[decides] = vid[decides]
        in_population = np.zeros(vid.size, dtype=bool)
        in_population[population_slots] = True
        keep = in_population.reshape(vid.shape) & (vid == self._vid) & (vid >= 0)
        return np.where(keep, self._accel, np.nan)
