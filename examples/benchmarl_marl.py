"""BenchMARL MAPPO / IPPO / MADDPG on MiVeCC with one import (the task class ships in mivecc).

Path: ``mivecc_env.benchmarl_task.MiVeCCTask`` (``EDGES``: homogeneous edge agents; ``FULL``:
edge and cloud groups) -> BenchMARL's ``Experiment`` with its own algorithm and MLP configs.

Install (no ``train`` extra: BenchMARL 1.5.x needs torchrl < 0.12, mivecc's env needs no torchrl):
    pip install ".[benchmarl]" torch==2.13.0

Run:
    python examples/benchmarl_marl.py --algo mappo --iters 2
    python examples/benchmarl_marl.py --algo maddpg --task full --iters 2
    python examples/benchmarl_marl.py --algo mappo --device cuda   # sampling and training on a GPU
"""

from __future__ import annotations

import argparse
import tempfile
import time

from benchmarl.algorithms import IppoConfig, MaddpgConfig, MappoConfig
from benchmarl.experiment import Experiment, ExperimentConfig
from benchmarl.models.mlp import MlpConfig

from mivecc_env.benchmarl_task import MiVeCCTask

ALGORITHMS = {"mappo": MappoConfig, "ippo": IppoConfig, "maddpg": MaddpgConfig}


def small_experiment(iters: int, frames: int, folder: str, device: str = "cpu") -> ExperimentConfig:
    """BenchMARL's default experiment config cut down to a few short iterations; the env's
    tensors, the networks and the replay buffer on ``device`` (the simulation stays on the CPU)."""
    cfg = ExperimentConfig.get_from_yaml()
    cfg.sampling_device = cfg.train_device = cfg.buffer_device = device
    cfg.max_n_iters = iters
    cfg.max_n_frames = None
    cfg.on_policy_collected_frames_per_batch = frames
    cfg.on_policy_n_envs_per_worker = 1
    cfg.on_policy_n_minibatch_iters = 1
    cfg.on_policy_minibatch_size = frames // 2
    cfg.off_policy_collected_frames_per_batch = frames
    cfg.off_policy_n_envs_per_worker = 1
    cfg.off_policy_n_optimizer_steps = 2
    cfg.off_policy_train_batch_size = frames // 2
    cfg.off_policy_memory_size = 10 * frames
    cfg.evaluation = False
    cfg.render = False
    cfg.loggers = ["csv"]
    cfg.create_json = False
    cfg.save_folder = folder
    cfg.checkpoint_at_end = False
    return cfg


def main(argv: list[str] | None = None) -> Experiment:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", choices=sorted(ALGORITHMS), default="mappo")
    parser.add_argument("--task", choices=("edges", "full"), default="edges")
    parser.add_argument("--iters", type=int, default=2)
    parser.add_argument("--frames", type=int, default=100, help="env steps per iteration")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu",
                        help="torch device of sampling, training and the buffer (e.g. cuda)")
    args = parser.parse_args(argv)
    task = MiVeCCTask[args.task.upper()].get_from_yaml()
    task.config.update(rows=1, cols=2, max_steps=args.frames)
    with tempfile.TemporaryDirectory() as folder:
        experiment = Experiment(
            task=task,
            algorithm_config=ALGORITHMS[args.algo].get_from_yaml(),
            model_config=MlpConfig.get_from_yaml(),
            critic_model_config=MlpConfig.get_from_yaml(),
            seed=args.seed,
            config=small_experiment(args.iters, args.frames, folder, args.device),
        )
        start = time.perf_counter()
        experiment.run()
        print(f"benchmarl {args.algo} on mivecc/{args.task}: {experiment.n_iters_performed} "
              f"iterations, {experiment.total_frames} frames in "
              f"{time.perf_counter() - start:.1f} s")
    return experiment


if __name__ == "__main__":
    main()
