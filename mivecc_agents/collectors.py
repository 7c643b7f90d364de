"""The collector that training runs: TorchRL's local ``Collector``, a ``MultiSyncCollector``
of several worker processes, or a ``RayCollector``."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch
from tensordict import TensorDictBase

from mivecc_agents.stages import TrainingError

__all__ = ["make_collector"]


def _flatten_ray_batch(data: TensorDictBase) -> TensorDictBase:
    """RayCollector stacks its workers' ``(n_densities, T)`` batches into ``(workers, n_dens,
    T)``: join the workers along time -> ``(n_densities, workers*T)``, the local layout."""
    return torch.cat(data.unbind(0), dim=1) if data.shape[0] > 1 else data[0]


def make_collector(
    env_fn: Callable | Sequence[Callable],
    policy,
    frames_per_batch,
    total_frames,
    workers,
    ray_address,
):
    """Collector over ``env_fn`` (or one factory per worker): local, multi-process or Ray.

    The local collector yields its own rollout buffer (``return_same_td=True``), overwritten
    by the next batch: the training loop copies what it keeps (into the replay buffer) before
    asking for the next one. Without it TorchRL clones every batch, a fresh copy of all its
    observations (about 650 MB per stage-II batch of 48 x 100 frames).

    ``frames_per_batch`` is what all workers together collect per iteration; the training loop
    makes it whole steps of every worker's environments, so each worker's share is exact and
    ``total_frames`` is rounded up to whole batches (what TorchRL would collect anyway).
    """
    from torchrl.collectors import Collector, MultiSyncCollector

    # Every collector keeps the env as given: TorchRL would otherwise warn (and, from 0.15,
    # add an InitTracker transform) for the policy, in the driver or in each worker.
    keep_env = {"auto_register_policy_transforms": False}
    if total_frames > 0:  # whole batches, as collected anyway (TorchRL warns otherwise)
        total_frames = -(-total_frames // frames_per_batch) * frames_per_batch
    n = max(1, workers)
    fns = list(env_fn) if isinstance(env_fn, Sequence) else [env_fn] * n
    if len(fns) != n:
        raise TrainingError(f"{len(fns)} env factories for {n} workers")
    if ray_address is not None:
        try:
            import ray  # noqa: F401
        except ImportError as exc:
            raise TrainingError(
                "ray_address needs ray: install it with `pip install mivecc[ray]`"
            ) from exc
        from torchrl.collectors.distributed import RayCollector

        from mivecc_agents.ray_worker import RayWorkerCollector

        if frames_per_batch % n:
            raise TrainingError(
                f"ray: {frames_per_batch} frames per batch cannot be split over {n} workers"
            )
        # "local": start a fresh single-node Ray instance with enough CPUs for the workers
        # (each remote collector asks for 1 CPU); "auto" / "host:port" / "ray://..." go to
        # ray.init(address=...). If ray is already initialised, RayCollector uses that runtime.
        init: dict[str, Any] = {"address": ray_address}
        if ray_address == "local":
            import os

            init.update(num_cpus=max(n, os.cpu_count() or 1), include_dashboard=False)
        try:
            collector = RayCollector(
                fns,
                policy,
                frames_per_batch=frames_per_batch,
                total_frames=total_frames,
                ray_init_config=init,
                sync=True,
                postproc=_flatten_ray_batch,
                collector_class=RayWorkerCollector,
                collector_kwargs=dict(keep_env),
            )
        except ConnectionError as exc:
            raise TrainingError(f"cannot connect to Ray at {ray_address!r}: {exc}") from exc
        collector.update_policy_weights_()  # connect the weight sync before the first batch
        return collector
    if n > 1:
        return MultiSyncCollector(
            fns,
            policy,
            frames_per_batch=frames_per_batch,
            total_frames=total_frames,
            **keep_env,
        )
    return Collector(
        fns[0],
        policy,
        frames_per_batch=frames_per_batch,
        total_frames=total_frames,
        return_same_td=True,
        **keep_env,
    )
