"""Stable-Baselines3 SAC on the single-agent Gymnasium view (one edge node).

Path: ``gymnasium.make("mivecc/MiVeCCEdge-v0")`` (registered on ``import mivecc_env``) ->
``SAC("MlpPolicy")``. The other edge nodes and the cloud node send no action.

Install: ``pip install ".[sb3]" torch==2.13.0``.

Run:
    python examples/sb3_sac_gymnasium.py --steps 300
"""

from __future__ import annotations

import argparse
import time

import gymnasium
from stable_baselines3 import SAC

import mivecc_env  # noqa: F401  (registers mivecc/MiVeCCEdge-v0)


def main(argv: list[str] | None = None) -> SAC:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    env = gymnasium.make("mivecc/MiVeCCEdge-v0", rows=1, cols=1, density=1500, max_steps=200)
    model = SAC("MlpPolicy", env, learning_starts=100, batch_size=64, buffer_size=10_000,
                train_freq=4, seed=args.seed, verbose=0)
    start = time.perf_counter()
    model.learn(total_timesteps=args.steps)
    print(f"sb3 sac (gymnasium view): {model.num_timesteps} steps "
          f"in {time.perf_counter() - start:.1f} s")
    env.close()
    return model


if __name__ == "__main__":
    main()
