"""``mivecc_env.processes.map_jobs``: the results of every job, in job order, with or without
worker processes."""

from __future__ import annotations

import pytest

from mivecc_env.processes import map_jobs


@pytest.mark.parametrize("workers", [1, 2, 8])
def test_results_come_back_in_job_order(workers: int) -> None:
    jobs = [-5, 3, -1, 0, -7]
    assert map_jobs(abs, jobs, workers, "jobs", show=False) == [5, 3, 1, 0, 7]


@pytest.mark.parametrize("jobs", [[], [-2]])
def test_no_pool_for_fewer_than_two_jobs(jobs: list[int]) -> None:
    assert map_jobs(abs, jobs, 4, "jobs", show=False) == [abs(j) for j in jobs]
