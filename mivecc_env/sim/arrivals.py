"""Poisson arrivals per entry lane, with a headway floor, and the entry queues.

Each (environment, lane) pair owns its own ``numpy.random.Generator`` (spawned from the
environment's seed), so the arrival stream of a lane depends only on the seed and on the
environment's rate, never on the batch size, on the other environments or on what the vehicles
do: two schemes run with the same seed see the same demand. A generator yields the same numbers
whatever the chunk size it is asked for, so the ring buffer below is invisible in the stream.

Each environment has its own rate (one batch can mix demands) and its own clock: ``advance``
takes one time per environment, and :meth:`ArrivalProcess.reset_at` restarts the streams of
some environments (time 0 for them) while the others continue untouched.

Arrival times are drawn ahead in chunks into a ring buffer. The entry queue of a lane is the
stretch of that buffer between the vehicles that have entered and those that have arrived, so
no queued vehicle is ever dropped (the buffer grows if a queue outgrows it).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mivecc_env.sim import step_kernels

#: Arrival times are accumulated in blocks of BLOCK gaps: a block's times are the previous
#: block's last time + the cumulative sum of its gaps (this rounding is part of the stream).
BLOCK = 32
#: Arrivals drawn per call (a draw costs ~10 us, mostly per call): several blocks at once.
CHUNK = 4 * BLOCK


class ArrivalProcess:
    """Arrival times and entry queues of ``batch`` environments x ``n_lanes`` entry lanes.

    Args:
        batch: number of environments B.
        n_lanes: number of entry lanes (one per through lane).
        rate_vph: arrival rate per lane [vehicles/hour], one value or one per environment.
        min_headway_s: floor of the gap between consecutive arrivals [s].
    """

    def __init__(
        self, batch: int, n_lanes: int, rate_vph: float | ArrayLike, min_headway_s: float
    ) -> None:
        self.batch, self.n_lanes = batch, n_lanes
        self.min_headway_s = min_headway_s
        self.set_rates(rate_vph)
        shape = (batch, n_lanes)
        self._rngs: list[list[np.random.Generator]] = [[] for _ in range(batch)]
        self.times = np.zeros((*shape, 2 * CHUNK))  # ring buffer of arrival times [s]
        self.generated = np.zeros(shape, dtype=np.int64)  # arrivals drawn so far
        self.arrived = np.zeros(shape, dtype=np.int64)  # arrivals with time <= now
        self.entered = np.zeros(shape, dtype=np.int64)  # vehicles that left the queue
        self._last = np.zeros(shape)  # time of the last drawn arrival [s]
        # time of arrival number ``arrived`` (the next one) of each lane [s]: a compact copy of
        # the ring buffer's heads, so that advance reads the buffer only where one arrives
        self._next = np.zeros(shape)
        # (B, 1) and (1, n_lanes) indices: times[b, lane, i] of one i per (b, lane)
        self._env_idx = np.arange(batch)[:, None]
        self._lane_idx = np.arange(n_lanes)[None, :]
        self.reset([0] * batch)

    def set_rates(self, rate_vph: float | ArrayLike) -> None:
        """Set the arrival rate [veh/lane/h] of every environment (applies to later draws)."""
        rate = np.broadcast_to(np.asarray(rate_vph, dtype=np.float64), (self.batch,))
        if not (np.isfinite(rate).all() and (rate > 0).all()):
            raise ValueError(f"rate_vph: must be finite and > 0 veh/lane/h, got {rate!r}")
        self.mean_gap_s = 3600.0 / rate  # (B,) [s]

    def reset(self, seeds: Sequence[int | np.random.SeedSequence]) -> None:
        """Restart every lane's stream from per-environment seeds."""
        if len(seeds) != self.batch:
            raise ValueError(f"seeds: need {self.batch} seeds, got {len(seeds)}")
        self.times = np.zeros((self.batch, self.n_lanes, 2 * CHUNK))
        self.reset_at(np.arange(self.batch), seeds)

    def reset_at(
        self, envs: ArrayLike, seeds: Sequence[int | np.random.SeedSequence]
    ) -> None:
        """Restart the streams of environments ``envs`` (time 0 for them) from ``seeds``.

        Environment ``envs[i]`` then draws exactly what a fresh process seeded with
        ``seeds[i]`` draws; the other environments are untouched.
        """
        envs = np.asarray(envs, dtype=np.int64).reshape(-1)
        if len(seeds) != envs.size:
            raise ValueError(f"seeds: need {envs.size} seeds, got {len(seeds)}")
        for b, seed in zip(envs.tolist(), seeds, strict=True):
            seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
            self._rngs[b] = [np.random.default_rng(c) for c in seq.spawn(self.n_lanes)]
        for arr in (self.generated, self.arrived, self.entered, self._last):
            arr[envs] = 0
        self.times[envs] = 0.0
        for b in envs.tolist():
            for lane in range(self.n_lanes):
                self._draw(b, lane)
        self._next[envs] = self._buffered(self.arrived)[envs]

    @property
    def queued(self) -> NDArray[np.int64]:
        """(B, n_lanes) vehicles waiting at each entry."""
        return self.arrived - self.entered

    def _draw(self, b: int, lane: int) -> None:
        """Append one chunk of arrival times to lane ``lane`` of environment ``b``."""
        cap = self.times.shape[2]
        generated = int(self.generated[b, lane])
        if generated + CHUNK - self.entered[b, lane] > cap:
            self._grow()
            cap = self.times.shape[2]
        gaps = self._rngs[b][lane].exponential(self.mean_gap_s[b], CHUNK)
        np.maximum(gaps, self.min_headway_s, out=gaps)
        times = np.cumsum(gaps.reshape(-1, BLOCK), axis=1)
        last = self._last[b, lane]
        for block in times:  # last + cumulative gap (addition commutes exactly)
            block += last
            last = block[-1]
        times = times.reshape(-1)
        start = generated % cap
        if start + CHUNK <= cap:  # always: the buffer is a multiple of CHUNK
            self.times[b, lane, start:start + CHUNK] = times
        else:
            self.times[b, lane, (generated + np.arange(CHUNK)) % cap] = times
        self.generated[b, lane] = generated + CHUNK
        self._last[b, lane] = times[-1]

    def _grow(self) -> None:
        """Double the ring buffer, keeping every drawn, not yet entered arrival."""
        old = self.times
        cap = old.shape[2]
        absolute = self.entered[..., None] + np.arange(cap)  # (B, n_lanes, cap)
        keep = absolute < self.generated[..., None]
        src = np.take_along_axis(old, absolute % cap, axis=2)
        new = np.zeros((*old.shape[:2], 2 * cap))
        np.put_along_axis(new, absolute % (2 * cap), np.where(keep, src, 0.0), axis=2)
        self.times = new

    def advance(self, now_s: float | ArrayLike) -> None:
        """Move every arrival with time <= ``now_s`` into its entry queue.

        Args:
            now_s: the time [s], one value or one per environment (each has its own clock).
        """
        now = np.asarray(now_s, dtype=np.float64)
        if step_kernels.HAVE_NUMBA:  # compiled: the same counts and the same draws per lane
            now_b = (now if now.shape == (self.batch,) and now.flags.c_contiguous
                     else np.ascontiguousarray(np.broadcast_to(now, (self.batch,))))
            need = np.empty((self.batch, self.n_lanes), dtype=bool)
            while step_kernels.advance_arrivals(
                self.times, self.generated, self.arrived, self._next, now_b, need
            ):
                for b, lane in zip(*np.nonzero(need), strict=True):
                    self._draw(int(b), int(lane))
            return
        now = now[:, None] if now.ndim == 1 else now
        while True:
            due = self._buffered(self.arrived) <= now
            if not due.any():
                self._next = self._buffered(self.arrived)
                return
            self.arrived += due
            for b, lane in zip(*np.nonzero(self.generated - self.arrived < 2), strict=True):
                self._draw(int(b), int(lane))

    def head_arrival_time(self) -> NDArray[np.float64]:
        """(B, n_lanes) arrival time of the first queued vehicle (meaningless if none) [s]."""
        return self._buffered(self.entered)

    def _buffered(self, count: NDArray[np.int64]) -> NDArray[np.float64]:
        """(B, n_lanes) arrival time number ``count`` of each lane (from the ring buffer) [s]."""
        return self.times[self._env_idx, self._lane_idx, count % self.times.shape[2]]

    def pop(self, mask: NDArray[np.bool_]) -> None:
        """Let the head vehicle of every (env, lane) in ``mask`` enter the network."""
        self.entered += mask
