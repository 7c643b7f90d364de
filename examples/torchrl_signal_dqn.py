"""Independent DQN signal agents (in the spirit of PA-DQN) on the native batched TorchRL env.

Path: ``MiVeCCTorchEnv(groups=("signal",), control="signalized")`` (B environments in one
batched simulator, one agent per intersection) -> one Q-network shared by the agents (an MLP
over the 15 observation features, each divided by its bound) -> ``QValueModule`` +
``EGreedyModule`` -> ``Collector`` -> replay buffer -> ``DQNLoss`` (categorical actions,
double DQN) + ``SoftUpdate``. An agent asks every step (0.1 s) for the phase it wants green;
the env's phase state machine enforces the minimum green, the yellow and the all-red. Reward:
minus the queued vehicles of the intersection (``signal_reward="queue"``).

After training, the greedy policy runs on evaluation seeds beside the fixed-time and
max-pressure controllers (the same seeds and demand) and the script prints each one's average
travel velocity, queue and throughput. This is a plain baseline, not a tuned one: the default
run is a short demonstration, not a result.

Install: ``pip install -c constraints.txt ".[train]"`` (torch, torchrl >= 0.14, tensordict).

Run:
    python examples/torchrl_signal_dqn.py --frames 20000
    python examples/torchrl_signal_dqn.py --frames 2000 --eval-steps 300   # a quick check
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.modules import EGreedyModule, QValueModule
from torchrl.objectives import DQNLoss, SoftUpdate

from mivecc_agents.torchrl_env import MiVeCCTorchEnv
from mivecc_env.batched import BatchedMiVeCCEnv

GROUP = "signal"
DENSITIES = (600.0, 900.0, 1200.0, 1500.0)
GRID = {"rows": 1, "cols": 1, "control": "signalized"}


def make_env(args: argparse.Namespace, seed: int) -> MiVeCCTorchEnv:
    """The signal agents of ``len(DENSITIES)`` environments, one per demand."""
    return MiVeCCTorchEnv(densities=list(DENSITIES), groups=(GROUP,), seed=seed,
                          max_steps=args.episode_steps, summary_keys=(), **GRID)


class ScaledMLP(nn.Module):
    """Q-values ``(..., 2)`` of observations ``(..., 15)`` divided by their bounds."""

    def __init__(self, high: torch.Tensor, cells: int) -> None:
        super().__init__()
        self.register_buffer("scale", 1.0 / high.clamp(min=1.0))
        self.net = nn.Sequential(nn.Linear(high.numel(), cells), nn.ReLU(),
                                 nn.Linear(cells, cells), nn.ReLU(), nn.Linear(cells, 2))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net(obs * self.scale)


def make_policy(env: MiVeCCTorchEnv, cells: int) -> TensorDictSequential:
    """Greedy Q policy: Q-network, then the arg-max phase under ``(signal, action)``."""
    high = env.observation_spec[GROUP, "observation"].space.high[0, 0]
    qnet = TensorDictModule(ScaledMLP(high, cells), in_keys=[(GROUP, "observation")],
                            out_keys=[(GROUP, "action_value")])
    qvalue = QValueModule(action_space="categorical", action_value_key=(GROUP, "action_value"),
                          out_keys=[(GROUP, "action"), (GROUP, "action_value"),
                                    (GROUP, "chosen_action_value")])
    return TensorDictSequential(qnet, qvalue)


def train(args: argparse.Namespace) -> TensorDictSequential:
    """DQN on the signal group; prints the mean queue reward per collected batch."""
    env = make_env(args, args.seed)
    policy = make_policy(env, args.cells)
    explore = TensorDictSequential(policy, EGreedyModule(
        env.full_action_spec[GROUP, "action"], eps_init=1.0, eps_end=0.05,
        annealing_num_steps=args.frames // 2, action_key=(GROUP, "action")))
    loss = DQNLoss(policy, action_space="categorical", delay_value=True, double_dqn=True)
    loss.set_keys(action_value=(GROUP, "action_value"), action=(GROUP, "action"),
                  value=(GROUP, "chosen_action_value"), reward=(GROUP, "reward"),
                  done=(GROUP, "done"), terminated=(GROUP, "terminated"))
    loss.make_value_estimator(gamma=args.gamma)
    target = SoftUpdate(loss, tau=0.01)
    optim = torch.optim.Adam(loss.parameters(), lr=args.lr)
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(args.buffer), batch_size=256)
    frames_per_batch = len(DENSITIES) * args.steps_per_batch
    collector = Collector(lambda: make_env(args, args.seed), explore,
                          frames_per_batch=frames_per_batch, total_frames=args.frames,
                          auto_register_policy_transforms=False)  # the env as it is
    t0 = time.perf_counter()
    frames = 0
    for i, batch in enumerate(collector):
        frames += batch.numel()
        buffer.extend(batch.reshape(-1))
        explore[-1].step(batch.numel())
        if len(buffer) >= args.warmup:
            for _ in range(args.updates_per_batch):
                sample = buffer.sample()
                loss_td = loss(sample)
                optim.zero_grad()
                loss_td["loss"].backward()
                nn.utils.clip_grad_norm_(loss.parameters(), 10.0)
                optim.step()
                target.step()
        reward = batch["next", GROUP, "reward"].mean().item()
        print(f"batch {i + 1}: {frames} frames, mean reward (minus queued vehicles "
              f"per intersection) {reward:.3f}, {time.perf_counter() - t0:.0f} s", flush=True)
    collector.shutdown()
    return policy


def evaluate(policy: TensorDictSequential | None, controller: str, args: argparse.Namespace
             ) -> dict[str, float]:
    """Mean over the evaluation seeds and demands of the summary, with the DQN (``policy``)
    or a signal controller deciding."""
    seeds = list(args.eval_seeds)
    pairs = [(d, s) for d in DENSITIES for s in seeds]
    env = BatchedMiVeCCEnv(batch_size=len(pairs), densities=[d for d, _ in pairs],
                           signal_agents=policy is not None, signal_controller=controller,
                           max_steps=args.eval_steps, **GRID)
    out = env.reset(seed=[s for _, s in pairs])
    for _ in range(args.eval_steps):
        phases = None
        if policy is not None:
            with torch.no_grad():
                values = policy[0].module(torch.from_numpy(out.signal_obs))
            phases = values.argmax(-1).numpy()
        out = env.step(signal_action=phases)
    summary = env.summary()
    return {k: float(np.mean(summary[k])) for k in ("avg_travel_velocity_mps", "throughput",
                                                     "backlog", "collisions")}


def main(argv: list[str] | None = None) -> dict[str, dict[str, float]]:
    """Train, evaluate, print; returns the evaluation rows (scheme -> mean summary)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=20000,
                   help="environment steps collected (over the 4 demands; default 20000)")
    p.add_argument("--episode-steps", type=int, default=1500)
    p.add_argument("--steps-per-batch", type=int, default=100)
    p.add_argument("--updates-per-batch", type=int, default=50)
    p.add_argument("--cells", type=int, default=64)
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--buffer", type=int, default=100_000)
    p.add_argument("--warmup", type=int, default=1000,
                   help="frames in the replay buffer before the first update (default 1000)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eval-seeds", type=int, nargs="+", default=[100, 101])
    p.add_argument("--eval-steps", type=int, default=1500)
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    policy = train(args)
    print(f"evaluation: 1x1, {', '.join(f'{d:.0f}' for d in DENSITIES)} veh/lane/h, seeds "
          f"{args.eval_seeds}, {args.eval_steps} steps")
    rows = {"DQN": evaluate(policy, "fixed-time", args)}
    for name in ("fixed-time", "max-pressure"):
        rows[name] = evaluate(None, name, args)
    for name, r in rows.items():
        print(f"  {name:>12}: avg travel velocity {r['avg_travel_velocity_mps']:.3f} m/s, "
              f"throughput {r['throughput']:.1f}, backlog {r['backlog']:.1f}, "
              f"collisions {r['collisions']:.1f}")
    return rows


if __name__ == "__main__":
    main()
