"""Which vehicles an edge node decides for: the lowest safety values, or a random draw.

``edge_selection="lowest_sv"`` (default, the paper): the ``k_edge`` vehicles of an area with the
lowest SV. ``edge_selection="random"`` (the released code at test time): a uniformly random
``k_edge`` of the area, drawn from one generator per environment owned by the simulator
(seeded from the environment's seed, independent of the arrival streams), so a run is the same
whatever the batch size.

Both are expressed as a *priority key* per vehicle in ``[sv_min, sv_max]``: the selection
(``state_graph.select_edge_decisions``) takes the lowest keys.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig

#: Extra spawn-key word that derives the selection stream from an environment's seed.
_SALT = 0xED6E


def make_generators(seeds: Sequence[np.random.SeedSequence]) -> list[np.random.Generator]:
    """One selection generator per environment, derived from its seed without consuming it."""
    return [
        np.random.default_rng(
            np.random.SeedSequence(entropy=s.entropy, spawn_key=(*s.spawn_key, _SALT))
        )
        for s in seeds
    ]


def edge_priority(
    sv: NDArray[np.float64],
    env: NDArray[np.int64],
    generators: Sequence[np.random.Generator],
    config: MiVeCCConfig,
) -> NDArray[np.float64]:
    """(n,) selection key of each view vehicle: its SV, or a uniform draw in
    ``[sv_min, sv_max)`` (one draw per vehicle of each environment, in view order)."""
    if config.edge_selection == "lowest_sv":
        return sv
    key = np.empty(sv.shape)
    counts = np.bincount(env, minlength=len(generators))
    start = 0
    for b, count in enumerate(counts):  # a loop over environments, not vehicles
        key[start:start + count] = generators[b].random(count)
        start += count
    return config.sv_min + key * (config.sv_max - config.sv_min)
