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


class SelectionStreams:
    """The selection generators of a batch, drawing at most once per environment and step.

    Observing the same state twice (``reset_at`` rebuilds the observations of the environments
    that go on) returns the keys already drawn for that step instead of consuming new numbers,
    so environment ``b`` draws exactly what a B = 1 run draws, whatever the partial resets of
    the others. :meth:`reset_at` gives restarted environments fresh generators.
    """

    def __init__(self, seeds: Sequence[np.random.SeedSequence]) -> None:
        self.generators = make_generators(seeds)
        self._drawn: list[tuple[int, NDArray[np.float64]] | None] = [None] * len(seeds)

    def __len__(self) -> int:
        return len(self.generators)

    def reset_at(self, envs: Sequence[int], seeds: Sequence[np.random.SeedSequence]) -> None:
        """Fresh generators for environments ``envs`` (one seed each), nothing drawn yet."""
        for b, gen in zip(envs, make_generators(seeds), strict=True):
            self.generators[b] = gen
            self._drawn[b] = None

    def draw(self, b: int, count: int, step: int) -> NDArray[np.float64]:
        """``count`` uniform numbers in [0, 1) of environment ``b`` at simulator step
        ``step``: the ones drawn before at that step and count, else new ones."""
        last = self._drawn[b]
        if last is not None and last[0] == step and last[1].size == count:
            return last[1]
        keys = self.generators[b].random(count)
        self._drawn[b] = (step, keys)
        return keys


def edge_priority(
    sv: NDArray[np.float64],
    env: NDArray[np.int64],
    streams: SelectionStreams,
    config: MiVeCCConfig,
    step: int,
) -> NDArray[np.float64]:
    """(n,) selection key of each view vehicle: its SV, or a uniform draw in
    ``[sv_min, sv_max)`` (one draw per vehicle of each environment, in view order, at most
    once per environment and simulator ``step``: :class:`SelectionStreams`)."""
    if config.edge_selection == "lowest_sv":
        return sv
    key = np.empty(sv.shape)
    counts = np.bincount(env, minlength=len(streams))
    start = 0
    for b, count in enumerate(counts.tolist()):  # a loop over environments, not vehicles
        key[start:start + count] = streams.draw(b, count, step)
        start += count
    return config.sv_min + key * (config.sv_max - config.sv_min)
