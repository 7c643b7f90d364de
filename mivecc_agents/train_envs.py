"""The TorchRL envs that training collects from: the native batched env (default) or the
PettingZoo wrapper in a ``SerialEnv``, one factory per collector worker."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import numpy as np

from mivecc_agents.presets import TrainPreset
from mivecc_agents.stages import GROUPS, TrainingError
from mivecc_env.config import field_range

__all__ = ["density_list", "env_factory", "env_groups", "make_env", "make_native_env",
           "worker_env_fns"]


def make_env(config_overrides: dict[str, Any] | None = None, scheme: str | None = None):
    """Build the TorchRL env: PettingZoo wrapper + ``(g, "mask")`` at root and under ``next``.

    Args:
        config_overrides: MiVeCC config fields (``rows``, ``cols``, ``density``, ...).
        scheme: ``"E"``, ``"EE"`` or ``"EEC"`` (overrides the config's).

    Returns:
        A ``TransformedEnv`` with groups ``edge`` and ``cloud``.
    """
    from torchrl.envs import Compose, PettingZooWrapper, RenameTransform, TransformedEnv

    from mivecc_env import mivecc_v0

    overrides = dict(config_overrides or {})
    if scheme is not None:
        overrides["scheme"] = scheme
    base = PettingZooWrapper(
        mivecc_v0.parallel_env(**overrides),
        use_mask=False,
        categorical_actions=False,
        return_state=False,
    )
    groups = [g for g in GROUPS if g in base.group_map]
    return TransformedEnv(
        base,
        Compose(
            RenameTransform(
                in_keys=[(g, "info", "mask") for g in groups],
                out_keys=[(g, "mask") for g in groups],
                create_copy=True,
            ),
            _episode_reward_sum(base),
        ),
    )


def _episode_reward_sum(base: Any) -> Any:
    """``RewardSum`` of each agent group's reward into ``(g, "episode_reward")``."""
    from torchrl.envs import RewardSum

    groups = [g for g in GROUPS if g in base.group_map]
    return RewardSum(
        in_keys=[(g, "reward") for g in groups],
        out_keys=[(g, "episode_reward") for g in groups],
    )


def _make_batched_env(densities: Sequence[float], overrides: dict[str, Any], scheme: str):
    """One env per density in a SerialEnv (batch dim 0 indexes the density)."""
    from torchrl.envs import SerialEnv

    fns = [partial(make_env, {**overrides, "density": float(d)}, scheme) for d in densities]
    return SerialEnv(len(fns), fns)


def density_list(densities: float | Sequence[float]) -> list[float]:
    """The training densities [veh/lane/h] as a list of floats.

    Raises:
        TrainingError: none given, or one that is not a number in the range of the config's
            ``density_vplh`` (the message names ``densities`` and that range).
    """
    scalar = isinstance(densities, int | float | np.number | str)
    items = [densities] if scalar else list(densities)
    if not items:
        raise TrainingError("at least one density is needed")
    rng = field_range("density_vplh")
    for d in items:
        number = isinstance(d, int | float | np.number) and not isinstance(d, bool)
        if not (number and math.isfinite(d) and rng.contains(d)):
            raise TrainingError(f"densities: each must be {rng.describe()} veh/lane/h, "
                                f"got {d!r}")
    return [float(d) for d in items]


def env_factory(
    backend: str,
    densities: Sequence[float],
    overrides: dict[str, Any],
    scheme: str,
    envs_per_density: int = 1,
    seed: int | None = None,
    env_options: dict[str, Any] | None = None,
) -> tuple[Callable[[], Any], list[int]]:
    """The collector's env factory and the density index of each of its environments.

    Args:
        backend: ``"native"`` (:class:`~mivecc_agents.torchrl_env.MiVeCCTorchEnv`, one
            simulator for ``envs_per_density x len(densities)`` environments) or
            ``"pettingzoo"`` (``PettingZooWrapper`` envs in a ``SerialEnv``, one per density).
        densities: Training densities [veh/lane/h].
        overrides: Env config fields (grid, episode length...).
        scheme: ``"EE"`` or ``"EEC"``.
        envs_per_density: Environments per density (native backend).
        seed: Native backend: seed of the env (environment ``b`` gets ``seed + b``).
        env_options: Native backend: ``continuous`` / ``raw_edge_period`` of
            :class:`~mivecc_agents.torchrl_env.MiVeCCTorchEnv` (the pettingzoo backend has
            neither: asking for them there is a ``TrainingError``).

    Returns:
        ``(factory, env_density)`` with ``env_density[b]`` the index into ``densities`` of
        environment ``b`` (batch dim 0 of the collected data).
    """
    options = {k: v for k, v in (env_options or {}).items() if v}
    if backend == "pettingzoo":
        if options:
            raise TrainingError(
                f"backend 'pettingzoo' has no {sorted(options)}: use the native backend"
            )
        return partial(_make_batched_env, list(densities), overrides, scheme), list(
            range(len(densities))
        )
    if backend != "native":
        raise TrainingError(f"backend: must be 'native' or 'pettingzoo', got {backend!r}")
    if envs_per_density < 1:
        raise TrainingError(f"envs_per_density: must be >= 1, got {envs_per_density}")
    env_density = [i for i in range(len(densities)) for _ in range(envs_per_density)]
    per_env = [float(densities[i]) for i in env_density]
    return partial(make_native_env, per_env, overrides, scheme, seed, **options), env_density


#: Groups the native env exposes in each stage (stage I needs no cloud graph).
_STAGE_GROUPS = {"EE": ("edge",), "EEC": ("edge", "cloud")}
#: Episode-summary keys the training log reads.
_LOG_KEYS = ("avg_travel_velocity_mps", "collisions", "throughput")


def make_native_env(
    densities: Sequence[float],
    overrides: dict[str, Any],
    scheme: str,
    seed: int | None = None,
    **options: Any,
):
    """Native batched TorchRL env (one environment per entry of ``densities``) + RewardSum.

    It has the keys of :func:`make_env` that training reads: ``(g, "mask")`` at the root and
    under ``next``, and the ``(g, "info")`` summary keys of the log. Scheme ``EE`` exposes only
    the ``edge`` group (stage I acts on no cloud graph, so none is built). ``options``:
    ``continuous``, ``raw_edge_period`` of the env.
    """
    from torchrl.envs import TransformedEnv

    from mivecc_agents.torchrl_env import MiVeCCTorchEnv

    base = MiVeCCTorchEnv(
        densities=list(densities),
        scheme=scheme,
        groups=_STAGE_GROUPS.get(scheme, GROUPS),
        summary_keys=_LOG_KEYS,
        seed=seed,
        **options,
        **overrides,
    )
    return TransformedEnv(base, _episode_reward_sum(base))


def env_groups(env: Any) -> list[str]:
    """The agent groups (``edge``, ``cloud``) that an env (or a batch of envs) has."""
    acts = env.full_action_spec.keys()
    return [g for g in GROUPS if g in acts]


def worker_env_fns(
    backend: str,
    dens: list[float],
    overrides: dict[str, Any],
    scheme: str,
    p: TrainPreset,
    seed: int,
    state: dict[str, int],
    workers: int,
    env_options: dict[str, Any] | None = None,
) -> list[Callable]:
    """One env factory per collector worker; native envs get distinct seeds per worker (and
    per resumed run: the frame count is added)."""
    n = max(1, workers)
    n_envs = p.envs_per_density * len(dens)
    base = seed + state["frames"]
    return [
        env_factory(backend, dens, overrides, scheme, p.envs_per_density, base + w * n_envs,
                    env_options)[0]
        for w in range(n)
    ]
