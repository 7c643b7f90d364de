"""TorchRL MAPPO or MADDPG on the edge-only view, the way TorchRL's multi-agent tutorials do it.

Path: ``mivecc_edges_v0.parallel_env`` -> ``torchrl.envs.PettingZooWrapper`` (one group
``edge``, parameter sharing) -> ``MultiAgentMLP`` actor and critic (centralised critic) ->
``ClipPPOLoss`` + ``GAE`` (MAPPO) or ``DDPGLoss`` + ``SoftUpdate`` (MADDPG). The observations are
flattened (``FlattenObservation``) for the MLPs; the columns' ``mask`` is not used (a plain
baseline; the project's own agents in ``mivecc_agents`` mask padded columns).

Install: ``pip install -c constraints.txt ".[train]"`` (torch, torchrl >= 0.14, tensordict).

Run:
    python examples/torchrl_marl.py --algo mappo --iters 2
    python examples/torchrl_marl.py --algo maddpg --iters 2
    python examples/torchrl_marl.py --algo mappo --device cuda   # networks and tensors on a GPU
"""

from __future__ import annotations

import argparse
import time

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.envs import FlattenObservation, PettingZooWrapper, RewardSum, TransformedEnv
from torchrl.modules import (
    AdditiveGaussianModule,
    MultiAgentMLP,
    ProbabilisticActor,
    TanhDelta,
    TanhNormal,
)
from torchrl.objectives import ClipPPOLoss, DDPGLoss, SoftUpdate, ValueEstimators

from mivecc_env import mivecc_edges_v0

GROUP = "edge"


def make_env(seed: int, max_steps: int, device: str = "cpu") -> TransformedEnv:
    """The edge-only view (2 x 2 grid) wrapped for TorchRL, observations flattened; the
    simulation runs on the CPU, its tensors are on ``device``."""
    base = PettingZooWrapper(
        mivecc_edges_v0.parallel_env(rows=2, cols=2, density=1500, max_steps=max_steps),
        seed=seed,
        device=device,
    )
    return TransformedEnv(
        base,
        FlattenObservation(-3, -1, in_keys=[(GROUP, "observation")]),
        RewardSum(in_keys=[base.reward_key], out_keys=[(GROUP, "episode_reward")]),
    )


def mlp(env: TransformedEnv, n_out: int, centralised: bool, n_in: int | None = None):
    n_agents = env.full_action_spec[GROUP, "action"].shape[0]
    return MultiAgentMLP(
        n_agent_inputs=n_in or env.observation_spec[GROUP, "observation"].shape[-1],
        n_agent_outputs=n_out,
        n_agents=n_agents,
        centralised=centralised,
        share_params=True,
        depth=2,
        num_cells=64,
        activation_class=nn.Tanh,
        device=env.device,
    )


def mappo(env: TransformedEnv, args: argparse.Namespace) -> list[float]:
    act_spec = env.full_action_spec[GROUP, "action"]
    k = act_spec.shape[-1]
    actor_net = nn.Sequential(mlp(env, 2 * k, centralised=False), NormalParamExtractor())
    policy = ProbabilisticActor(
        TensorDictModule(actor_net, in_keys=[(GROUP, "observation")],
                         out_keys=[(GROUP, "loc"), (GROUP, "scale")]),
        spec=act_spec,
        in_keys=[(GROUP, "loc"), (GROUP, "scale")],
        out_keys=[(GROUP, "action")],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": act_spec.space.low, "high": act_spec.space.high},
        return_log_prob=True,
    )
    critic = TensorDictModule(mlp(env, 1, centralised=True), in_keys=[(GROUP, "observation")],
                              out_keys=[(GROUP, "state_value")])
    loss = ClipPPOLoss(actor_network=policy, critic_network=critic, entropy_coeff=1e-3)
    loss.set_keys(reward=env.reward_key, action=(GROUP, "action"),
                  value=(GROUP, "state_value"), done=(GROUP, "done"),
                  terminated=(GROUP, "terminated"))
    loss.make_value_estimator(ValueEstimators.GAE, gamma=0.99, lmbda=0.9)
    optim = torch.optim.Adam(loss.parameters(), 3e-4)
    collector = Collector(env, policy, frames_per_batch=args.frames,
                          total_frames=args.frames * args.iters,
                          auto_register_policy_transforms=False)
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(args.frames, device=env.device),
                                    sampler=SamplerWithoutReplacement(), batch_size=args.batch)
    returns = []
    for data in collector:
        with torch.no_grad():
            loss.value_estimator(data, params=loss.critic_network_params,
                                 target_params=loss.target_critic_network_params)
        buffer.extend(data.reshape(-1))
        for _ in range(args.epochs):
            for _ in range(args.frames // args.batch):
                out = loss(buffer.sample())
                total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
                optim.zero_grad()
                total.backward()
                nn.utils.clip_grad_norm_(loss.parameters(), 1.0)
                optim.step()
        collector.update_policy_weights_()
        returns.append(float(data.get(("next", env.reward_key)).mean()))
    collector.shutdown()
    return returns


def maddpg(env: TransformedEnv, args: argparse.Namespace) -> list[float]:
    act_spec = env.full_action_spec[GROUP, "action"]
    k = act_spec.shape[-1]
    actor = TensorDictModule(mlp(env, k, centralised=False), in_keys=[(GROUP, "observation")],
                             out_keys=[(GROUP, "param")])
    policy = ProbabilisticActor(actor, spec=act_spec, in_keys=[(GROUP, "param")],
                                out_keys=[(GROUP, "action")], distribution_class=TanhDelta,
                                distribution_kwargs={"low": act_spec.space.low,
                                                     "high": act_spec.space.high},
                                return_log_prob=False)
    explore = TensorDictSequential(
        policy, AdditiveGaussianModule(spec=act_spec, annealing_num_steps=args.frames * args.iters,
                                       action_key=(GROUP, "action"), sigma_init=0.5)
    )
    n_obs = env.observation_spec[GROUP, "observation"].shape[-1]
    cat = TensorDictModule(lambda o, a: torch.cat([o, a], dim=-1),
                           in_keys=[(GROUP, "observation"), (GROUP, "action")],
                           out_keys=[(GROUP, "obs_action")])
    q = TensorDictModule(mlp(env, 1, centralised=True, n_in=n_obs + k),
                         in_keys=[(GROUP, "obs_action")],
                         out_keys=[(GROUP, "state_action_value")])
    loss = DDPGLoss(actor_network=policy, value_network=TensorDictSequential(cat, q),
                    delay_value=True, loss_function="l2")
    loss.set_keys(state_action_value=(GROUP, "state_action_value"), reward=env.reward_key,
                  done=(GROUP, "done"), terminated=(GROUP, "terminated"))
    loss.make_value_estimator(ValueEstimators.TD0, gamma=0.95)
    target = SoftUpdate(loss, tau=0.01)
    optim = {"actor": torch.optim.Adam(loss.actor_network_params.flatten_keys().values(), 1e-4),
             "value": torch.optim.Adam(loss.value_network_params.flatten_keys().values(), 1e-3)}
    collector = Collector(env, explore, frames_per_batch=args.frames,
                          total_frames=args.frames * args.iters,
                          auto_register_policy_transforms=False)
    buffer = TensorDictReplayBuffer(
        storage=LazyTensorStorage(10 * args.frames, device=env.device), batch_size=args.batch)
    returns = []
    for data in collector:
        buffer.extend(data.reshape(-1))
        for _ in range(args.epochs):
            out = loss(buffer.sample())
            for name, opt in optim.items():
                opt.zero_grad()
                out[f"loss_{name}"].backward()
                opt.step()
            target.step()
        explore[-1].step(data.numel())
        collector.update_policy_weights_()
        returns.append(float(data.get(("next", env.reward_key)).mean()))
    collector.shutdown()
    return returns


def main(argv: list[str] | None = None) -> list[float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", choices=("mappo", "maddpg"), default="mappo")
    parser.add_argument("--iters", type=int, default=2, help="collection + update rounds")
    parser.add_argument("--frames", type=int, default=64, help="env steps per round")
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--epochs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu",
                        help="torch device of the networks and tensors (e.g. cuda)")
    args = parser.parse_args(argv)
    torch.manual_seed(args.seed)
    env = make_env(args.seed, max_steps=args.frames * 2, device=args.device)
    start = time.perf_counter()
    returns = (mappo if args.algo == "mappo" else maddpg)(env, args)
    print(f"{args.algo}: {args.iters} iterations x {args.frames} steps in "
          f"{time.perf_counter() - start:.1f} s; mean edge reward per round {returns}")
    return returns


if __name__ == "__main__":
    main()
