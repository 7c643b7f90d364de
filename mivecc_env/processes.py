"""Run independent jobs in worker processes, results in job order.

One helper for every command with ``--workers`` that hands whole jobs (a batch of runs) to
other processes: ``mivecc evaluate``, ``benchmarks/paper_table.py``,
``benchmarks/ceiling_resolution.py``. The processes are *spawned* (fresh interpreters), never
forked: a fork would copy torch's and numba's thread pools in whatever state they are in.
Each job must be picklable and ``fn`` importable by name (a module-level function).
"""

from __future__ import annotations

import multiprocessing as mp
import sys
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

__all__ = ["map_jobs"]

J = TypeVar("J")
R = TypeVar("R")


def map_jobs(fn: Callable[[J], R], jobs: Sequence[J], workers: int, desc: str,
             show: bool = True, **bar: Any) -> list[R]:
    """``[fn(job) for job in jobs]``, in this process when ``workers <= 1`` or there is at most
    one job, else in a pool of ``min(workers, len(jobs))`` spawned processes; a progress bar
    over the jobs on stderr.

    Args:
        fn: A module-level function (workers import it by name).
        jobs: Its arguments, one per call.
        workers: Processes at most; 1 (or less): no pool.
        desc: Label of the progress bar.
        show: False: no progress bar.
        **bar: Further ``tqdm`` keywords (e.g. ``unit``, ``leave``).

    Returns:
        The results in the order of ``jobs``.
    """
    from tqdm.auto import tqdm

    options = {"total": len(jobs), "desc": desc, "file": sys.stderr, "disable": not show, **bar}
    if workers <= 1 or len(jobs) <= 1:
        return [fn(job) for job in tqdm(jobs, **options)]
    with mp.get_context("spawn").Pool(min(workers, len(jobs))) as pool:
        results = list(tqdm(pool.imap(fn, jobs), **options))
        # let the workers exit on their own (leaving the block terminates them), so that
        # what they hold is released: e.g. TorchRL's replay buffers hold semaphores, which a
        # terminated worker leaks (a resource_tracker warning at the end)
        pool.close()
        pool.join()
    return results
