"""CoMADDPG: vehicles as MADDPG agents on their virtual lanes, the paper's learned comparator.

The paper compares MiVeCC on the single intersection with CoMADDPG (Wu, Jiang and Zhang,
Mathematical Problems in Engineering 2020), "a distributed RL scheme" that "attempts to obtain
better policy than the proposed scheme, but collisions occur when the density exceeds 1500
vehicles/lane/hour". No implementation is public; its abstract gives the design this module
follows (the rest is this package's reading, ``docs/comparators.md``):

* **agents**: every vehicle inside an intersection's control area (a dynamic number); outside
  them vehicles follow the end-node rules (:mod:`mivecc_env.vehicle_agents`).
* **observation** ("each vehicle selects reference vehicles to construct a partial stationary
  environment ... projects the reference vehicles on a virtual lane"): the vehicle and its
  ``k - 1`` nearest reference vehicles on its virtual lane, position, velocity and acceleration
  (one column of an edge state graph, ``(k, 3)``).
* **action**: the vehicle's acceleration in ``[-a_max, a_max]``, executed unmodified (no rule, no
  veto: ``BatchedMiVeCCEnv.step_vehicles``).
* **learning** (MADDPG "redefined to adapt to the dynamic quantity of agents"): one actor shared
  by all vehicles; a centralised critic per vehicle that sees its observation, its action and
  the actions of its reference vehicles (the agents of its partial environment; with
  ``critic_view="observations"`` their observations too, as MADDPG's critic), with MADDPG's
  actor update (the other agents' actions from the replay buffer). TorchRL's ``DDPGLoss`` with
  the reference vehicles' actions as extra critic inputs: at the next state they are the target
  actor's actions for the next state's references, computed when the transition is stored.
* **reward** per vehicle and step: ``(v' - v_max) / (v_max - v_floor)`` (travel-time cost, 0
  at full speed) ``+ safety_weight * min(SV', 0) / 20`` (SV' the vehicle's safety value after the
  step) ``- collision_penalty`` if it collided; a vehicle's transitions end (terminal) when it
  leaves the control area, exits or collides.
* **training**: ``batch`` environments with the densities cycled over them, episodes from an
  empty network on fresh seeds (never the evaluation seeds 0-2), Gaussian exploration noise on
  each vehicle's acceleration, held for ``noise_hold_steps`` steps (a braking or a push long
  enough to change whether two vehicles meet at a conflict point: with noise drawn anew every
  0.1 s, a DDPG actor settled at +3 m/s^2 everywhere in a pilot) and decaying linearly, one
  update per step of the batch after the warm-up. With ``keep_network="best"`` (the default)
  the actor returned is the one whose greedy run on validation environments had the fewest
  strict collision events, ties by the highest average travel velocity
  (:func:`greedy_validation`, :func:`validation_key`; validated once the noise has decayed),
  not the last one.

A trained policy is :class:`CoMADDPGPolicy`; ``mivecc evaluate --scheme comaddpg`` runs the
shipped one (:data:`SHIPPED_PATH`, trained on 3x3, for every grid), ``mivecc
train-comaddpg`` trains one.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from mivecc_agents.checkpoints import corrupt_policy, read_policy_file, save_checkpoint
from mivecc_agents.comaddpg_settings import CoMADDPGSettings
from mivecc_agents.signal_dqn import (
    FIRST_TRAIN_SEED,
    SHIPPED_DIR,
    VALIDATION_SEED,
    KeptNetwork,
    save_figure,
    saved_settings,
    write_log,
)
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.core import StepEvents
from mivecc_env.vehicle_agents import (
    VehicleAgents,
    follow,
    observe_vehicles,
    vehicle_accelerations,
    vehicle_commands,
    vehicle_rewards,
)

__all__ = ["SHIPPED_PATH", "CoMADDPGPolicy", "CoMADDPGSettings", "VehicleActor",
           "VehicleCritic", "progress_line", "train_comaddpg", "write_log"]

#: The log columns of a validation run (:func:`greedy_validation`).
VALIDATION_COLUMNS = ("validation_collisions", "validation_reward", "validation_velocity")
#: ``kind`` of a CoMADDPG checkpoint.
VEHICLE_KIND = "comaddpg"
#: The shipped policy (in the package), trained on 3x3 and used on every grid: a vehicle's view
#: is one control area's virtual lane on any grid, and 3x3 gives nine intersections' vehicles
#: per step (it beat a policy trained on the single intersection there too, docs/comparators.md).
SHIPPED_PATH = SHIPPED_DIR / "comaddpg_3x3.pt"


def vehicle_features(observation: torch.Tensor) -> torch.Tensor:
    """``(..., 3 k)`` network input of observations ``(..., k, 3)``: the position channel as
    ``sign(x) sqrt(|x|)`` (positions are scaled by the 150 m of a control area, so a 10 m gap
    is 0.07; the root spreads the short distances that decide a conflict: 0.26), the
    velocity and acceleration channels as they are."""
    pos = observation[..., :1]
    return torch.cat([torch.sign(pos) * torch.sqrt(pos.abs()), observation[..., 1:]],
                     dim=-1).flatten(-2)


class VehicleActor(nn.Module):
    """Acceleration ``(..., 1)`` [m/s^2] of observations ``(..., k, 3)``: an MLP with two hidden
    ReLU layers over :func:`vehicle_features` and a tanh scaled to ``a_max``."""

    def __init__(self, k: int, hidden: int, a_max: float) -> None:
        super().__init__()
        self.k, self.a_max = int(k), float(a_max)
        self.net = nn.Sequential(nn.Linear(3 * k, hidden), nn.ReLU(),
                                 nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 1),
                                 nn.Tanh())

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return self.net(vehicle_features(observation)) * self.a_max


class VehicleCritic(nn.Module):
    """Q-value ``(..., 1)`` of a vehicle's observation ``(..., k, 3)``, its action ``(..., 1)``
    and its references' actions and mask ``(..., k - 1)`` (padding rows: action 0, mask 0);
    with ``observations`` also the references' own observations ``(..., k - 1, k, 3)``
    (padding rows: zeros)."""

    def __init__(self, k: int, hidden: int, a_max: float, observations: bool = False) -> None:
        super().__init__()
        self.a_scale = 1.0 / float(a_max)
        self.observations = bool(observations)
        width = 3 * k + 1 + 2 * (k - 1) + (3 * k * (k - 1) if observations else 0)
        self.net = nn.Sequential(nn.Linear(width, hidden), nn.ReLU(),
                                 nn.Linear(hidden, hidden // 2), nn.ReLU(),
                                 nn.Linear(hidden // 2, 1))

    def forward(self, observation: torch.Tensor, action: torch.Tensor,
                neighbour_action: torch.Tensor, neighbour_mask: torch.Tensor,
                neighbour_observation: torch.Tensor | None = None) -> torch.Tensor:
        parts = [vehicle_features(observation), action * self.a_scale,
                 neighbour_action * self.a_scale, neighbour_mask]
        if self.observations:
            parts.append(vehicle_features(neighbour_observation).flatten(-2))
        return self.net(torch.cat(parts, dim=-1))


class CoMADDPGPolicy:
    """A trained CoMADDPG actor: ``policy(obs)`` -> each vehicle's acceleration.

    Attributes:
        scheme: the evaluation scheme it is for (``"comaddpg"``).
        actor: the actor network.
        k: rows of an observation (the vehicle and its ``k - 1`` references).
        settings: the training settings (a dict).
        checkpoint: the file it was loaded from ("" if trained in this process).
    """

    scheme = "comaddpg"

    def __init__(self, actor: VehicleActor, settings: dict[str, Any],
                 checkpoint: str = "") -> None:
        self.actor = actor.eval()
        self.k = actor.k
        self.settings = settings
        self.checkpoint = checkpoint

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """(n,) float64 accelerations [m/s^2] of observations ``(n, k, 3)``."""
        arr = np.asarray(obs, dtype=np.float32)
        if arr.ndim != 3 or arr.shape[1:] != (self.k, 3):
            raise ValueError(f"obs: expected shape (n, {self.k}, 3), got {arr.shape}")
        return greedy_accelerations(self.actor, arr)

    def save(self, path: str | Path, extra: dict[str, Any] | None = None) -> Path:
        """Write the policy as a mivecc checkpoint (``kind="comaddpg"``)."""
        hidden = self.actor.net[0].out_features
        return save_checkpoint(path, {
            "kind": VEHICLE_KIND, "k": self.k, "hidden": hidden, "a_max": self.actor.a_max,
            "settings": self.settings, "network": self.actor.state_dict(),
            "extra": extra or {},
        })

    @classmethod
    def load(cls, path: str | Path) -> CoMADDPGPolicy:
        """Read a policy written by :meth:`save`; :class:`CheckpointError` (naming the file)
        for a missing, corrupt or foreign file."""
        data = read_policy_file(path, VEHICLE_KIND, ("k", "hidden", "a_max", "network",
                                                      "settings"))
        with corrupt_policy(path, "CoMADDPG policy"):
            k, hidden, a_max = int(data["k"]), int(data["hidden"]), float(data["a_max"])
            if k < 2 or hidden < 1 or not a_max > 0:
                raise ValueError(f"k {k}, hidden {hidden}, a_max {a_max}")
            actor = VehicleActor(k, hidden, a_max)
            actor.load_state_dict(data["network"])
        return cls(actor, saved_vehicle_settings(data), checkpoint=str(path))


def saved_vehicle_settings(checkpoint: dict[str, Any]) -> dict[str, Any]:
    """A CoMADDPG checkpoint's training settings; one written before ``keep_network``
    existed kept the last actor, one written before ``validation_steps`` existed (session 47)
    validated for ``episode_steps``, one written before ``validation_envs`` existed (session
    48) on one environment per density."""
    settings = saved_settings(checkpoint)
    return {"validation_steps": settings["episode_steps"],
            "validation_envs": len(settings["densities"]), **settings}


def greedy_accelerations(actor: VehicleActor, obs: np.ndarray) -> np.ndarray:
    """(n,) float64 accelerations [m/s^2] the actor gives observations ``(n, k, 3)``."""
    if obs.shape[0] == 0:
        return np.zeros(0)
    with torch.no_grad():
        x = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32))
        return actor(x)[:, 0].numpy().astype(np.float64)


@dataclass(frozen=True)
class _Batch:
    """Transitions of one step, as the replay buffer stores them."""

    obs: np.ndarray
    action: np.ndarray
    neighbour_action: np.ndarray
    neighbour_mask: np.ndarray
    reward: np.ndarray
    next_obs: np.ndarray
    next_neighbour_action: np.ndarray
    next_neighbour_mask: np.ndarray
    terminated: np.ndarray
    neighbour_obs: np.ndarray | None = None  # with critic_view "observations"
    next_neighbour_obs: np.ndarray | None = None


def neighbour_actions(agents: VehicleAgents, action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, k-1) actions of each agent's reference rows (0 for padding) and their mask."""
    mask = agents.ref_agent >= 0
    padded = np.append(action, 0.0)  # index -1 reads the 0
    return padded[agents.ref_agent].astype(np.float32), mask.astype(np.float32)


def neighbour_observations(agents: VehicleAgents) -> np.ndarray:
    """(n, k-1, k, 3) observations of each agent's reference rows (zeros for padding)."""
    padded = np.concatenate([agents.obs, np.zeros((1, *agents.obs.shape[1:]), np.float32)])
    return padded[agents.ref_agent]  # index -1 reads the zeros


def transitions(agents: VehicleAgents, action: np.ndarray, nxt: VehicleAgents,
                next_target_action: np.ndarray, events: StepEvents, cfg: MiVeCCConfig,
                settings: CoMADDPGSettings) -> _Batch:
    """The transitions of the step from ``agents`` (actions ``action``) to ``nxt``.

    An agent goes on where the same vehicle (environment, id) is an agent again; else its
    transition is terminal (it left the control area, exited or collided). Reward: module
    docstring.
    """
    n, k = len(agents), agents.obs.shape[1]
    found, j = follow(agents, nxt)
    reward = vehicle_rewards(agents, action, nxt, events, cfg, settings.collision_penalty,
                             settings.safety_weight)
    nb_action, nb_mask = neighbour_actions(agents, action)
    next_obs = np.zeros((n, k, 3), np.float32)
    next_nb = np.zeros((n, k - 1), np.float32)
    next_mask = np.zeros((n, k - 1), np.float32)
    if len(nxt):
        nb_all, mask_all = neighbour_actions(nxt, next_target_action)
        next_obs[found], next_nb[found], next_mask[found] = (
            nxt.obs[j[found]], nb_all[j[found]], mask_all[j[found]])
    nb_obs = next_nb_obs = None
    if settings.critic_view == "observations":
        nb_obs = neighbour_observations(agents)
        next_nb_obs = np.zeros_like(nb_obs)
        if len(nxt):
            next_nb_obs[found] = neighbour_observations(nxt)[j[found]]
    return _Batch(
        obs=agents.obs, action=action.astype(np.float32)[:, None],
        neighbour_action=nb_action, neighbour_mask=nb_mask,
        reward=reward.astype(np.float32)[:, None], next_obs=next_obs,
        next_neighbour_action=next_nb, next_neighbour_mask=next_mask, terminated=~found,
        neighbour_obs=nb_obs, next_neighbour_obs=next_nb_obs,
    )


class VehicleLearner:
    """The shared actor, the centralised critic, TorchRL's ``DDPGLoss`` with its soft target
    update, Adam (one learning rate each) and a replay buffer."""

    def __init__(self, settings: CoMADDPGSettings, a_max: float) -> None:
        from tensordict.nn import TensorDictModule
        from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
        from torchrl.objectives import DDPGLoss, SoftUpdate, ValueEstimators

        k = settings.k
        self.actor = VehicleActor(k, settings.hidden, a_max)
        with_obs = settings.critic_view == "observations"
        self.critic = VehicleCritic(k, settings.critic_hidden, a_max, observations=with_obs)
        actor = TensorDictModule(self.actor, in_keys=["observation"], out_keys=["action"])
        critic = TensorDictModule(
            self.critic, in_keys=["observation", "action", "neighbour_action", "neighbour_mask",
                                  *(["neighbour_observation"] if with_obs else [])],
            out_keys=["state_action_value"])
        self.loss = DDPGLoss(actor, critic, delay_actor=True, delay_value=True)
        self.loss.make_value_estimator(ValueEstimators.TD0, gamma=settings.gamma)
        self.target = SoftUpdate(self.loss, tau=settings.tau)
        self.optim = torch.optim.Adam([
            {"params": list(self.actor.parameters()), "lr": settings.lr_actor},
            {"params": list(self.critic.parameters()), "lr": settings.lr_critic},
        ])
        self.buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(settings.buffer),
                                             batch_size=settings.minibatch)
        self.settings = settings

    def act(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n,) actions of the actor and of its target copy for observations ``(n, k, 3)``."""
        if obs.shape[0] == 0:
            return np.zeros(0), np.zeros(0)
        x = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32))
        with torch.no_grad():
            mu = self.actor(x)[:, 0]
            target_params = self.loss.target_actor_network_params
            with target_params.to_module(self.loss.actor_network):
                mu_target = self.loss.actor_network.module(x)[:, 0]
        return mu.numpy().astype(np.float64), mu_target.numpy().astype(np.float64)

    def add(self, batch: _Batch) -> None:
        """Store one step's transitions."""
        from tensordict import TensorDict

        n = batch.obs.shape[0]
        if n == 0:
            return
        t = torch.from_numpy
        term = t(batch.terminated)[:, None]
        now = {"observation": t(batch.obs), "action": t(batch.action),
               "neighbour_action": t(batch.neighbour_action),
               "neighbour_mask": t(batch.neighbour_mask)}
        nxt = {"observation": t(batch.next_obs),
               "neighbour_action": t(batch.next_neighbour_action),
               "neighbour_mask": t(batch.next_neighbour_mask),
               "reward": t(batch.reward), "done": term, "terminated": term.clone()}
        if batch.neighbour_obs is not None:
            now["neighbour_observation"] = t(batch.neighbour_obs)
            nxt["neighbour_observation"] = t(batch.next_neighbour_obs)
        self.buffer.extend(TensorDict({**now, "next": TensorDict(nxt, [n])}, [n]))

    def update(self) -> tuple[float, float] | None:
        """``updates_per_step`` gradient steps (after the warm-up): mean critic and actor loss."""
        s = self.settings
        if len(self.buffer) < s.warmup or s.updates_per_step == 0:
            return None
        critic_total = actor_total = 0.0
        for _ in range(s.updates_per_step):
            out = self.loss(self.buffer.sample())
            total = out["loss_value"] + out["loss_actor"]
            self.optim.zero_grad()
            total.backward()
            nn.utils.clip_grad_norm_(self.critic.parameters(), 10.0)
            nn.utils.clip_grad_norm_(self.actor.parameters(), 10.0)
            self.optim.step()
            self.target.step()
            critic_total += float(out["loss_value"].detach())
            actor_total += float(out["loss_actor"].detach())
        return critic_total / s.updates_per_step, actor_total / s.updates_per_step


def training_env(settings: CoMADDPGSettings, cfg: MiVeCCConfig,
                 batch: int | None = None) -> Any:
    """``batch`` (default ``settings.batch``) environments with the densities of
    ``settings.densities`` cycled over them (no graphs observed: the vehicles observe
    themselves)."""
    from mivecc_env.batched import BatchedMiVeCCEnv

    batch = settings.batch if batch is None else batch
    densities = [settings.densities[i % len(settings.densities)] for i in range(batch)]
    return BatchedMiVeCCEnv(cfg, batch_size=batch, densities=densities, observe=())


@dataclass(frozen=True)
class ValidationRuns:
    """Per-environment results ``(B,)`` of a greedy validation run (:func:`validation_runs`)."""

    collisions: np.ndarray  #: strict collision events
    reward_sum: np.ndarray  #: summed reward of the vehicle agents' transitions
    transitions: np.ndarray  #: vehicle agents' transitions
    velocity: np.ndarray  #: average travel velocity [m/s] (NaN where no vehicle exited)
    throughput: np.ndarray  #: vehicles exited

    def measures(self, envs: int | None = None) -> dict[str, float]:
        """The validation measures of the first ``envs`` environments (default all):
        ``validation_collisions`` (strict collision events, summed), ``validation_reward``
        (mean reward per vehicle-step, the training reward) and ``validation_velocity``
        (average travel velocity [m/s], mean over the environments from which a vehicle
        exited; NaN if none did)."""
        part = slice(0, envs)
        transitions = int(self.transitions[part].sum())
        exited = self.throughput[part] > 0
        return {"validation_collisions": int(self.collisions[part].sum()),
                "validation_reward": float(self.reward_sum[part].sum()) / transitions
                if transitions else math.nan,
                "validation_velocity": float(self.velocity[part][exited].mean())
                if exited.any() else math.nan}


def validation_runs(settings: CoMADDPGSettings, env: Any, actor: VehicleActor) -> ValidationRuns:
    """Run ``env`` for ``settings.validation_steps`` steps from an empty network on the seeds
    from :data:`VALIDATION_SEED`, every agent executing the actor's acceleration (no
    exploration, no learning), the actor called once per environment as in an evaluation
    (``vehicle_accelerations``), so that an environment's run does not depend on the others."""
    cfg, b = env.config, env.batch_size

    def policy(obs: np.ndarray) -> np.ndarray:
        return greedy_accelerations(actor, obs)

    env.reset(seed=VALIDATION_SEED)
    agents = observe_vehicles(env.sim, settings.k)
    collisions = np.zeros(b, dtype=np.int64)
    reward_sum, transitions_n = np.zeros(b), np.zeros(b, dtype=np.int64)
    for _ in range(settings.validation_steps):
        action = vehicle_accelerations(policy, agents, b, cfg.a_max_mps2)
        env.step_vehicles(vehicle_commands(agents, action, b))
        events = env.sim.last_events
        collisions += events.collision_events
        nxt = observe_vehicles(env.sim, settings.k)
        reward = vehicle_rewards(agents, action, nxt, events, cfg, settings.collision_penalty,
                                 settings.safety_weight)
        reward_sum += np.bincount(agents.env, weights=reward, minlength=b)
        transitions_n += np.bincount(agents.env, minlength=b)
        agents = nxt
    summary = env.summary()
    return ValidationRuns(collisions, reward_sum, transitions_n,
                          np.asarray(summary["avg_travel_velocity_mps"], dtype=np.float64),
                          np.asarray(summary["throughput"], dtype=np.float64))


def validation_env(settings: CoMADDPGSettings, cfg: MiVeCCConfig,
                   envs: int | None = None) -> Any:
    """The validation environments of ``settings`` (``envs``, default
    ``settings.validation_envs``, with the training densities cycled over them) on the
    training environments' config ``cfg``, for runs of ``settings.validation_steps``."""
    envs = settings.validation_envs if envs is None else envs
    return training_env(settings, cfg.replace(max_steps=settings.validation_steps), batch=envs)


def greedy_validation(settings: CoMADDPGSettings, env: Any,
                      actor: VehicleActor) -> dict[str, float]:
    """The validation measures (:meth:`ValidationRuns.measures`) of a greedy run of all of
    ``env``'s environments (:func:`validation_runs`)."""
    return validation_runs(settings, env, actor).measures()


def validation_key(measures: Mapping[str, float]) -> tuple[float, float]:
    """The order of validation runs (:func:`greedy_validation`), the comparison's two
    measures: fewer strict collision events first, then a higher average travel velocity
    (NaN, no vehicle finished, ranks last). Not the reward per vehicle-step: its safety term
    pays for distance and ranks slower actors first (docs/comparators.md, "Keeping the
    best-validated actor")."""
    velocity = measures["validation_velocity"]
    return -measures["validation_collisions"], -math.inf if math.isnan(velocity) else velocity


def keeper(settings: CoMADDPGSettings, cfg: MiVeCCConfig,
           actor: VehicleActor) -> KeptNetwork | None:
    """The keeper of ``actor`` for ``settings`` (None with ``keep_network="last"``): on
    :func:`validation_env`."""
    if settings.keep_network != "best":
        return None
    env = validation_env(settings, cfg)
    return KeptNetwork(actor, lambda: greedy_validation(settings, env, actor), validation_key)


def train_comaddpg(settings: CoMADDPGSettings,
                   on_episode: Callable[[dict[str, float]], None] | None = None,
                   on_validated: Callable[[dict[str, float], CoMADDPGPolicy], None] | None = None,
                   ) -> tuple[CoMADDPGPolicy, list[dict[str, float]]]:
    """Train a CoMADDPG policy (module docstring); returns it and one log row per episode.

    Deterministic for a given ``settings`` (torch's global random state is used inside
    :func:`torch.random.fork_rng` and left as it was). ``on_episode(row)`` is called after each
    episode (progress). Log row keys: ``episode``, ``noise_sd`` (at the episode's end [m/s^2]),
    ``reward_per_transition``, ``collisions`` (strict collision events of the episode, all
    environments), ``avg_travel_velocity_mps`` and ``throughput`` (means over the
    environments), ``critic_loss`` and ``actor_loss`` (NaN before the first update),
    ``wall_s``; with ``keep_network="best"`` also :func:`greedy_validation`'s measures after
    every episode that ended with the noise decayed to ``noise_end`` and after the last one
    (NaN after the others); the best actor (:func:`validation_key`) is restored at the end,
    and ``on_validated(row, policy)`` gets each validated actor (a copy) with its log row.
    """
    settings.check()
    cfg = settings.env_config()
    env = training_env(settings, cfg)
    b, k, a_max = settings.batch, settings.k, cfg.a_max_mps2
    total_steps = settings.episodes * settings.episode_steps
    decay = max(1.0, settings.noise_decay_fraction * total_steps)
    log: list[dict[str, float]] = []
    t0, done_steps = time.perf_counter(), 0
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(settings.seed)
        learner = VehicleLearner(settings, a_max)
        keep = keeper(settings, cfg, learner.actor)
        rng = np.random.default_rng(settings.seed)
        for episode in range(settings.episodes):
            first = FIRST_TRAIN_SEED + settings.seed * 1_000_000 + episode * b
            env.reset(seed=[first + i for i in range(b)])
            agents = observe_vehicles(env.sim, k)
            mu, _ = learner.act(agents.obs)
            rewards, critic_losses, actor_losses, collisions = [], [], [], 0
            sigma = settings.noise_start
            noise = np.zeros(0)
            for t in range(settings.episode_steps):
                frac = min(1.0, done_steps / decay)
                sigma = settings.noise_start + frac * (settings.noise_end - settings.noise_start)
                if t % settings.noise_hold_steps == 0 or noise.size != b * agents.capacity:
                    noise = rng.standard_normal(b * agents.capacity)  # per vehicle slot, held
                action = np.clip(mu + sigma * noise[agents.slot], -a_max, a_max)
                env.step_vehicles(vehicle_commands(agents, action, b))
                events = env.sim.last_events
                collisions += int(events.collision_events.sum())
                nxt = observe_vehicles(env.sim, k)
                next_mu, next_target = learner.act(nxt.obs)
                batch = transitions(agents, action, nxt, next_target, events, cfg, settings)
                learner.add(batch)
                if batch.reward.size:
                    rewards.append(float(batch.reward.mean()))
                losses = learner.update()
                if losses is not None:
                    critic_losses.append(losses[0])
                    actor_losses.append(losses[1])
                agents, mu = nxt, next_mu
                done_steps += 1
            summary = env.summary()
            row = {"episode": episode + 1, "noise_sd": sigma,
                   "reward_per_transition": float(np.mean(rewards)) if rewards else math.nan,
                   "collisions": collisions,
                   "avg_travel_velocity_mps": float(np.nanmean(
                       summary["avg_travel_velocity_mps"])),
                   "throughput": float(summary["throughput"].mean()),
                   "critic_loss": float(np.mean(critic_losses)) if critic_losses else math.nan,
                   "actor_loss": float(np.mean(actor_losses)) if actor_losses else math.nan}
            if keep is not None:
                # the episode ended with the noise decayed to noise_end (or there is no decay)
                decayed = frac >= 1.0 or settings.noise_start == settings.noise_end
                if decayed or episode == settings.episodes - 1:
                    row.update(keep.consider())
                    if on_validated is not None:
                        on_validated(row, CoMADDPGPolicy(copy.deepcopy(learner.actor),
                                                         settings.to_dict()))
                else:
                    row.update(dict.fromkeys(VALIDATION_COLUMNS, math.nan))
            row["wall_s"] = time.perf_counter() - t0
            log.append(row)
            if on_episode is not None:
                on_episode(row)
        if keep is not None:
            keep.restore()
    return CoMADDPGPolicy(learner.actor, settings.to_dict()), log


def progress_line(row: dict[str, float], total: int) -> str:
    """One episode's progress line of ``mivecc train-comaddpg``."""
    validation = ""
    if not math.isnan(row.get("validation_reward", math.nan)):
        validation = (f", validation {row['validation_collisions']:.0f} collisions, "
                      f"{row['validation_reward']:.3f} reward/vehicle-step")
    return (f"episode {row['episode']:.0f}/{total}: reward/vehicle-step "
            f"{row['reward_per_transition']:.3f}, velocity {row['avg_travel_velocity_mps']:.2f} "
            f"m/s, collisions {row['collisions']:.0f}, noise {row['noise_sd']:.2f} m/s^2, "
            f"critic loss {row['critic_loss']:.4f}{validation}, {row['wall_s']:.0f} s")


def validated_rows(log: Sequence[Mapping[str, float]]) -> list[Mapping[str, float]]:
    """The rows of a ``keep_network="best"`` training log with a validation run."""
    return [r for r in log if not math.isnan(float(r.get("validation_collisions", math.nan)))]


def kept_row(log: Sequence[Mapping[str, float]]) -> Mapping[str, float] | None:
    """The row of the actor a ``keep_network="best"`` training returned (the first of the
    best by :func:`validation_key`); None for a log without validation."""
    rows = validated_rows(log)
    if not rows:
        return None
    return max(rows, key=lambda r: validation_key({c: float(r[c]) for c in VALIDATION_COLUMNS}))


def kept_note(log: Sequence[Mapping[str, float]]) -> str | None:
    """One line naming the actor a ``keep_network="best"`` training returned (None for
    ``keep_network="last"``)."""
    kept = kept_row(log)
    if kept is None:
        return None
    last = validated_rows(log)[-1]
    return (f"kept the actor of the best greedy validation run, after episode "
            f"{kept['episode']:.0f}: {_validation_text(kept)}; the last validated actor "
            f"{_validation_text(last)}")


def _validation_text(row: Mapping[str, float]) -> str:
    return (f"{row['validation_collisions']:.0f} collision events, "
            f"{row['validation_reward']:.4f} reward per vehicle-step, "
            f"{row['validation_velocity']:.3f} m/s")


def plot_learning_curve(rows: Sequence[dict[str, float]], path: str | Path) -> Path:
    """A PNG of a training log: reward per transition, average travel velocity and collisions
    per episode; with ``keep_network="best"`` also the greedy validation runs and a star at the
    kept actor."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    episodes = [r["episode"] for r in rows]
    kept = kept_row(rows)
    fig, axes = plt.subplots(3, 1, figsize=(9.5, 7.5), sharex=True)
    series = (("reward_per_transition", "validation_reward", "reward per vehicle-step"),
              ("avg_travel_velocity_mps", "validation_velocity",
               "average travel\nvelocity [m/s]"),
              ("collisions", "validation_collisions", "collision events\n(all environments)"))
    for ax, (key, validation, label) in zip(axes, series, strict=True):
        ax.plot(episodes, [r[key] for r in rows], marker="o", ms=3, label="training episode")
        if kept is not None:
            ax.plot(episodes, [r[validation] for r in rows], "D", ms=4,
                    label="greedy validation run")
            ax.plot([kept["episode"]], [kept[validation]], "*", ms=14, color="black",
                    label="actor kept (keep_network=best)")
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_title("CoMADDPG training (exploration included; densities mixed)")
    axes[-1].set_xlabel("episode")
    return save_figure(fig, path)
