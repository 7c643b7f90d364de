"""RLlib PPO (new API stack) on MiVeCC through RLlib's own PettingZoo wrapper.

Path: ``mivecc_v0.parallel_env`` -> ``ray.rllib.env.wrappers.pettingzoo_env.ParallelPettingZooEnv``
-> PPO with one policy shared by the edge agents and, with ``--view full``, a second one for
``cloud_0``.

RLlib has default CNNs only for 10x10, 42x42, 64x64, 84x84 and 96x96 images, so the 15 x 15 x 3
(edge) and 60 x 60 x 3 (cloud) state graphs need one of two recipes:

* ``--obs graph`` (default): give each module its own ``conv_filters`` in its
  ``DefaultModelConfig`` (:data:`CONV_FILTERS` below: 15 -> 8 -> 4 -> 2 for the edge,
  60 -> 30 -> 15 -> 8 -> 4 for the cloud; RLlib pads "same" and flattens the last map);
* ``--obs flat``: RLlib's ``FlattenObservations`` env-to-module connector, then its default MLP.

Install: ``pip install ".[rllib]" torch==2.13.0`` (``ray[rllib]`` brings the gymnasium it needs).

Run:
    python examples/rllib_ppo.py --iters 2
    python examples/rllib_ppo.py --iters 2 --view full --obs flat
"""

from __future__ import annotations

import argparse
import time

import ray
from ray.rllib.algorithms.ppo import PPOConfig
from ray.rllib.connectors.env_to_module import FlattenObservations
from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
from ray.rllib.core.rl_module.rl_module import RLModuleSpec
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv
from ray.tune.registry import register_env

from mivecc_env import CLOUD_AGENT, mivecc_edges_v0, mivecc_v0

# [out_channels, [kernel, kernel], stride] per layer.
CONV_FILTERS = {
    "edge": [[16, [3, 3], 2], [32, [3, 3], 2], [64, [3, 3], 2]],
    "cloud": [[16, [4, 4], 2], [32, [4, 4], 2], [64, [4, 4], 2], [64, [4, 4], 2]],
}
ENV_KW = {"rows": 1, "cols": 2, "density": 1500, "max_steps": 100}


def policy_of(agent_id: str, *args: object, **kwargs: object) -> str:
    """Edge agents share the ``edge`` policy; ``cloud_0`` has its own."""
    return "cloud" if agent_id == CLOUD_AGENT else "edge"


def make_config(view: str, obs: str, seed: int) -> PPOConfig:
    module = mivecc_v0 if view == "full" else mivecc_edges_v0
    scheme = "EEC" if view == "full" else "EE"
    register_env("mivecc", lambda cfg: ParallelPettingZooEnv(
        module.parallel_env(scheme=scheme, **ENV_KW)))
    policies = {"edge", "cloud"} if view == "full" else {"edge"}
    if obs == "graph":
        specs = {p: RLModuleSpec(model_config=DefaultModelConfig(conv_filters=CONV_FILTERS[p]))
                 for p in policies}
        connector = None
    else:
        specs = {p: RLModuleSpec() for p in policies}
        connector = lambda env, spaces=None, device=None: FlattenObservations(  # noqa: E731
            multi_agent=True)
    return (
        PPOConfig()
        .environment("mivecc")
        .env_runners(num_env_runners=0, rollout_fragment_length=50,
                     env_to_module_connector=connector)
        .multi_agent(policies=policies, policy_mapping_fn=policy_of)
        .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs=specs))
        .training(train_batch_size_per_learner=100, minibatch_size=50, num_epochs=1)
        .debugging(seed=seed)
    )


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iters", type=int, default=2)
    parser.add_argument("--view", choices=("edges", "full"), default="edges")
    parser.add_argument("--obs", choices=("graph", "flat"), default="graph")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    ray.init(num_cpus=2, include_dashboard=False, ignore_reinit_error=True)
    try:
        algo = make_config(args.view, args.obs, args.seed).build_algo()
        start = time.perf_counter()
        results = [algo.train() for _ in range(args.iters)]
        steps = results[-1]["env_runners"]["num_env_steps_sampled_lifetime"]
        print(f"rllib ppo ({args.view}, {args.obs}): {args.iters} iterations, {steps} env steps "
              f"in {time.perf_counter() - start:.1f} s")
        algo.stop()
    finally:
        ray.shutdown()
    return results


if __name__ == "__main__":
    main()
