"""Stable-Baselines3 PPO on the edge-only view through SuperSuit, with no other glue.

Path: ``mivecc_edges_v0.parallel_env`` (homogeneous edge agents) ->
``supersuit.pettingzoo_env_to_vec_env_v1`` (one vector slot per agent) ->
``supersuit.concat_vec_envs_v1(..., base_class="stable_baselines3")`` -> ``PPO("MlpPolicy")``
(one policy shared by all edge agents; SB3 flattens the 15 x 15 x 3 graphs).

Seeding: SuperSuit 3.11's SB3 wrapper has no ``seed()``, so ``PPO(seed=...)`` raises
``AttributeError``; seed torch with ``set_random_seed`` and the envs with one seeded reset of the
concatenated vector env (copy ``i`` gets ``seed + i``; later resets continue each copy's
sequence).

Install: ``pip install ".[sb3]" torch==2.13.0`` (stable-baselines3, supersuit).

Run:
    python examples/sb3_ppo_supersuit.py --steps 1024
"""

from __future__ import annotations

import argparse
import time

import supersuit as ss
from stable_baselines3 import PPO
from stable_baselines3.common.utils import set_random_seed

from mivecc_env import mivecc_edges_v0


def main(argv: list[str] | None = None) -> PPO:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1024, help="total agent-steps to learn")
    parser.add_argument("--copies", type=int, default=2, help="concatenated env copies")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    env = mivecc_edges_v0.parallel_env(rows=2, cols=2, density=1500, max_steps=200)
    vec = ss.pettingzoo_env_to_vec_env_v1(env)
    vec = ss.concat_vec_envs_v1(vec, args.copies, num_cpus=0, base_class="stable_baselines3")
    vec.venv.reset(seed=args.seed)
    set_random_seed(args.seed)
    n_steps = 64
    model = PPO("MlpPolicy", vec, n_steps=n_steps, batch_size=n_steps * vec.num_envs // 2,
                n_epochs=2, verbose=0)
    start = time.perf_counter()
    model.learn(total_timesteps=args.steps)
    print(f"sb3 ppo (supersuit, {vec.num_envs} agent slots): {model.num_timesteps} agent-steps "
          f"in {time.perf_counter() - start:.1f} s")
    vec.close()
    return model


if __name__ == "__main__":
    main()
