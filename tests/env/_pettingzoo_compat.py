"""PettingZoo test-suite calls that work from the lowest supported PettingZoo (1.24) up."""

from __future__ import annotations

import inspect
from collections.abc import Callable

from pettingzoo.test import parallel_seed_test


def run_parallel_seed_test(env_fn: Callable, num_cycles: int) -> None:
    """``parallel_seed_test`` (PettingZoo 1.24 has no ``num_cycles`` and runs its default)."""
    if "num_cycles" in inspect.signature(parallel_seed_test).parameters:
        parallel_seed_test(env_fn, num_cycles=num_cycles)
    else:
        parallel_seed_test(env_fn)
