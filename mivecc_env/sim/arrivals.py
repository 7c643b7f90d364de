"""Poisson arrivals per entry lane, with a headway floor, and the entry queues.

Each (environment, lane) pair owns its own ``numpy.random.Generator`` (spawned from the
environment's seed), so the arrival stream of a lane depends only on the seed, never on the
batch size or on what the vehicles do: two schemes run with the same seed see the same demand.

Arrival times are drawn ahead in chunks into a ring buffer. The entry queue of a lane is the
stretch of that buffer between the vehicles that have entered and those that have arrived, so
no queued vehicle is ever dropped (the buffer grows if a queue outgrows it).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

CHUNK = 32


class ArrivalProcess:
    """Arrival times and entry queues of ``batch`` environments x ``n_lanes`` entry lanes.

    Args:
        batch: number of environments B.
        n_lanes: number of entry lanes (one per through lane).
        rate_vph: arrival rate per lane [vehicles/hour].
        min_headway_s: floor of the gap between consecutive arrivals [s].
    """

    def __init__(self, batch: int, n_lanes: int, rate_vph: float, min_headway_s: float) -> None:
        self.batch, self.n_lanes = batch, n_lanes
        self.mean_gap_s = 3600.0 / rate_vph
        self.min_headway_s = min_headway_s
        self._rngs: list[list[np.random.Generator]] = []
        self.reset([0] * batch)

    def reset(self, seeds: Sequence[int | np.random.SeedSequence]) -> None:
        """Restart every lane's stream from per-environment seeds."""
        if len(seeds) != self.batch:
            raise ValueError(f"seeds: need {self.batch} seeds, got {len(seeds)}")
        self._rngs = []
        for seed in seeds:
            seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
            self._rngs.append([np.random.default_rng(c) for c in seq.spawn(self.n_lanes)])
        shape = (self.batch, self.n_lanes)
        self.times = np.zeros((*shape, 4 * CHUNK))  # ring buffer of arrival times [s]
        self.generated = np.zeros(shape, dtype=np.int64)  # arrivals drawn so far
        self.arrived = np.zeros(shape, dtype=np.int64)  # arrivals with time <= now
        self.entered = np.zeros(shape, dtype=np.int64)  # vehicles that left the queue
        self._last = np.zeros(shape)  # time of the last drawn arrival [s]
        for b in range(self.batch):
            for lane in range(self.n_lanes):
                self._draw(b, lane)

    @property
    def queued(self) -> NDArray[np.int64]:
        """(B, n_lanes) vehicles waiting at each entry."""
        return self.arrived - self.entered

    def _draw(self, b: int, lane: int) -> None:
        """Append one chunk of arrival times to lane ``lane`` of environment ``b``."""
        cap = self.times.shape[2]
        if self.generated[b, lane] + CHUNK - self.entered[b, lane] > cap:
            self._grow()
            cap = self.times.shape[2]
        draws = self._rngs[b][lane].exponential(self.mean_gap_s, CHUNK)
        gaps = np.maximum(draws, self.min_headway_s)
        times = self._last[b, lane] + np.cumsum(gaps)
        idx = (self.generated[b, lane] + np.arange(CHUNK)) % cap
        self.times[b, lane, idx] = times
        self.generated[b, lane] += CHUNK
        self._last[b, lane] = times[-1]

    def _grow(self) -> None:
        old = self.times
        cap = old.shape[2]
        new = np.zeros((*old.shape[:2], 2 * cap))
        k = np.arange(cap)
        for b in range(self.batch):
            for lane in range(self.n_lanes):
                first = self.entered[b, lane]
                absolute = first + k
                keep = absolute < self.generated[b, lane]
                new[b, lane, absolute[keep] % (2 * cap)] = old[b, lane, absolute[keep] % cap]
        self.times = new

    def advance(self, now_s: float) -> None:
        """Move every arrival with time <= ``now_s`` into its entry queue."""
        while True:
            cap = self.times.shape[2]
            nxt = np.take_along_axis(
                self.times, (self.arrived % cap)[..., None], axis=2
            )[..., 0]
            due = nxt <= now_s
            if not due.any():
                return
            self.arrived += due
            for b, lane in zip(*np.nonzero(self.generated - self.arrived < 2), strict=True):
                self._draw(int(b), int(lane))

    def head_arrival_time(self) -> NDArray[np.float64]:
        """(B, n_lanes) arrival time of the first queued vehicle (meaningless if none) [s]."""
        cap = self.times.shape[2]
        return np.take_along_axis(self.times, (self.entered % cap)[..., None], axis=2)[..., 0]

    def pop(self, mask: NDArray[np.bool_]) -> None:
        """Let the head vehicle of every (env, lane) in ``mask`` enter the network."""
        self.entered += mask
