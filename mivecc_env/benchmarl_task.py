"""BenchMARL task class of MiVeCC: ``MiVeCCTask.EDGES`` / ``MiVeCCTask.FULL``.

Needs ``benchmarl`` (which brings torchrl and torch); nothing else in :mod:`mivecc_env` imports
this module, so the environment itself never needs torchrl. One import gives the task:

    >>> from mivecc_env.benchmarl_task import MiVeCCTask
    >>> task = MiVeCCTask.EDGES.get_from_yaml()     # mivecc_env/conf/benchmarl/edges.yaml
    >>> # Experiment(task=task, algorithm_config=MappoConfig.get_from_yaml(), ...)

Tasks:
    ``EDGES``: :mod:`mivecc_env.mivecc_edges_v0` (one group ``edge``, homogeneous agents,
    ``scheme="EE"``); ``FULL``: :mod:`mivecc_env.mivecc_v0` (groups ``edge`` and ``cloud``,
    ``scheme="EEC"``). Both continuous actions only (MADDPG, IPPO, MAPPO, ISAC, ...).

Observations: each group's ``(K, K, 3)`` state graph is flattened to ``K * K * 3`` features
(BenchMARL's MLP model takes flat vectors); ``state`` (the cloud graph) likewise. The ``info``
entries (``mask`` and the reward terms) are passed through.

Config: the YAML's keys are :class:`mivecc_env.config.MiVeCCConfig` fields (``density`` for
``density_vplh``); an unknown key raises :class:`mivecc_env.config.ConfigError` when the task
is loaded.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml
from benchmarl.environments.common import Task, TaskClass
from torchrl.data import Composite
from torchrl.envs import EnvBase, FlattenObservation, PettingZooWrapper, Transform

from mivecc_env import mivecc_edges_v0, mivecc_v0
from mivecc_env.config import from_overrides

CONF_DIR = Path(__file__).parent / "conf" / "benchmarl"


class MiVeCCTaskClass(TaskClass):
    """How BenchMARL builds a MiVeCC task (see the module docstring)."""

    def _module(self) -> Any:
        return mivecc_edges_v0 if self.name == "EDGES" else mivecc_v0

    def get_env_fun(
        self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any
    ) -> Callable[[], EnvBase]:
        """A factory of the PettingZoo env wrapped by TorchRL (BenchMARL batches it serially)."""
        config = copy.deepcopy(self.config)
        module = self._module()
        return lambda: PettingZooWrapper(
            module.parallel_env(**config), return_state=True, seed=seed, device=device
        )

    def supports_continuous_actions(self) -> bool:
        return True

    def supports_discrete_actions(self) -> bool:
        return False

    def has_render(self, env: EnvBase) -> bool:
        return False

    def max_steps(self, env: EnvBase) -> int:
        return int(self.config["max_steps"])

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return env.group_map

    def get_env_transforms(self, env: EnvBase) -> list[Transform]:
        """Flatten every group's observation and the state to vectors."""
        keys = [(group, "observation") for group in self.group_map(env)] + ["state"]
        return [FlattenObservation(-3, -1, in_keys=keys)]

    def observation_spec(self, env: EnvBase) -> Composite:
        return self._group_keys(env, "observation")

    def info_spec(self, env: EnvBase) -> Composite | None:
        return self._group_keys(env, "info")

    def _group_keys(self, env: EnvBase, keep: str) -> Composite:
        spec = env.observation_spec.clone()
        for group in self.group_map(env):
            for key in list(spec[group].keys()):
                if key != keep:
                    del spec[group][key]
        if "state" in spec.keys():  # noqa: SIM118 (a Composite spec)
            del spec["state"]
        return spec

    def state_spec(self, env: EnvBase) -> Composite | None:
        return Composite({"state": env.observation_spec["state"].clone()})

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return None

    @staticmethod
    def env_name() -> str:
        return "mivecc"


class MiVeCCTask(Task):
    """The MiVeCC tasks; ``get_from_yaml()`` reads ``mivecc_env/conf/benchmarl/<task>.yaml``."""

    EDGES = None
    FULL = None

    @staticmethod
    def associated_class() -> type[MiVeCCTaskClass]:
        return MiVeCCTaskClass

    def get_from_yaml(self, path: str | None = None) -> TaskClass:
        """The task with its config from ``path`` (default: the YAML shipped with mivecc)."""
        path = path or str(CONF_DIR / f"{self.name.lower()}.yaml")
        with open(path, encoding="utf-8") as f:
            config = yaml.safe_load(f) or {}
        config.pop("defaults", None)
        from_overrides(None, **config)  # validates every key and value (ConfigError)
        return self.get_task(config=config)
