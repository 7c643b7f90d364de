"""PA-DQN: learned traffic-signal control by DQN, the paper's learned signal comparator.

The paper compares MiVeCC on the single intersection with PA-DQN, "an application of DQN in the
single intersection traffic light control" (its reference: Tan et al. 2020); no implementation
is public. This module is this package's reading of it, on the signal agents of
:mod:`mivecc_env.signal_agents` (``control="signalized"``):

* **decision**: every ``decision_period_s`` (10 s) each intersection's agent picks the phase it
  wants green (0 east-west, 1 north-south) from its 15 observation features (vehicles, queued
  vehicles and mean velocity per approach; phase, stage, time in stage); the choice is held until
  the next decision. The phase machine enforces the minimum green, the yellow and the all-red.
* **reward** of a decision: the vehicles that passed the intersection's centre during the period
  (``signal_reward="throughput"``) times ``reward_scale``. A queue reward saturates once a queue
  outgrows the observed 75 m, and a DQN trained on it starved an approach
  (``examples/torchrl_signal_dqn.py``, ``docs/comparators.md``).
* **network**: an MLP (two hidden layers, ReLU) over the observation divided by its bounds, one
  network shared by all intersections (independent agents with shared parameters).
* **training**: double DQN with TorchRL's ``DQNLoss`` and a soft target update, epsilon-greedy
  exploration decaying linearly, a replay buffer; ``batch`` environments on the single
  intersection with the densities of ``densities`` cycled over them, episodes of
  ``episode_steps`` steps from an empty network, each on fresh training seeds (never the
  evaluation seeds 0-2). With ``keep_network="best"`` (the default) the network returned is
  the one whose greedy run on validation environments moved the most vehicles out
  (:class:`KeptNetwork`, :func:`greedy_throughput`; validated once the exploration has
  decayed), not the last one.

A trained policy is :class:`SignalDQNPolicy`; :class:`HeldPhases` holds its choices between
decisions; ``mivecc evaluate --scheme pa-dqn`` runs the shipped one of
the grid (:func:`shipped_policy_path`: trained on 1x1 for the single intersection, on 3x3 for
larger grids), ``mivecc train-signal`` trains one.
"""

from __future__ import annotations

import copy
import csv
import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from mivecc_agents.checkpoints import corrupt_policy, read_policy_file, save_checkpoint
from mivecc_agents.signal_dqn_settings import SignalDQNSettings, decision_steps
from mivecc_env import signal_agents
from mivecc_env.config import MiVeCCConfig

__all__ = [
    "HeldPhases",
    "SignalDQNPolicy",
    "SignalDQNSettings",
    "SignalQNetwork",
    "shipped_policy_path",
    "train_signal_dqn",
]

#: ``kind`` of a signal-policy checkpoint.
SIGNAL_KIND = "signal_dqn"
#: The shipped policies (in the package): trained on the single intersection, and on 3x3.
SHIPPED_DIR = Path(__file__).parent / "pretrained"
#: The first training seed (training never uses the evaluation seeds 0, 1, 2).
FIRST_TRAIN_SEED = 10_000
#: Seed of the first validation environment of ``keep_network="best"`` (environment ``b``:
#: this + ``b``), apart from the evaluation seeds (0-7 in the docs) and the training seeds.
VALIDATION_SEED = 1_000


def shipped_policy_path(rows: int = 1, cols: int = 1) -> Path:
    """The shipped PA-DQN policy for a grid: the one trained on the single intersection
    (``pretrained/signal_dqn_1x1.pt``) for 1x1, the one trained on 3x3
    (``pretrained/signal_dqn_3x3.pt``, where an intersection's neighbours feed and drain it)
    for every larger grid."""
    name = "signal_dqn_1x1.pt" if rows * cols == 1 else "signal_dqn_3x3.pt"
    return SHIPPED_DIR / name


class SignalQNetwork(nn.Module):
    """Q-values ``(..., n_actions)`` of observations ``(..., n_in)``: one per phase of a signal
    observation ``(..., 15)`` for PA-DQN, one per joint phase of a region for Coder.

    The observation is divided by its bounds ``high`` (``(n_in,)``, each taken as at least 1;
    :func:`mivecc_env.signal_agents.observation_bounds`) before two hidden ReLU layers.
    """

    def __init__(self, high: torch.Tensor, hidden: int,
                 n_actions: int = signal_agents.N_PHASES) -> None:
        super().__init__()
        self.register_buffer("scale", 1.0 / high.to(torch.float32).clamp(min=1.0))
        n_in = high.numel()
        self.net = nn.Sequential(nn.Linear(n_in, hidden), nn.ReLU(), nn.Linear(hidden, hidden),
                                 nn.ReLU(), nn.Linear(hidden, n_actions))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net(obs * self.scale)


class SignalDQNPolicy:
    """A trained PA-DQN policy: ``policy(obs)`` -> the greedy phase of every row.

    Attributes:
        scheme: the evaluation scheme it is for (``"pa-dqn"``).
        net: the Q-network.
        decision_period_s: time between two decisions [s] (the training's).
        settings: the training settings (a dict).
        checkpoint: the file it was loaded from ("" if trained in this process).
    """

    scheme = "pa-dqn"

    def __init__(self, net: SignalQNetwork, decision_period_s: float,
                 settings: dict[str, Any], checkpoint: str = "") -> None:
        self.net = net.eval()
        self.decision_period_s = float(decision_period_s)
        self.settings = settings
        self.checkpoint = checkpoint

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """(n,) int64 phases of observations ``(n, 15)`` (ties: phase 0)."""
        arr = np.asarray(obs, dtype=np.float32)
        if arr.ndim != 2 or arr.shape[1] != signal_agents.OBS_DIM:
            raise ValueError(f"obs: expected shape (n, {signal_agents.OBS_DIM}), got "
                             f"{arr.shape}")
        with torch.no_grad():
            q = self.net(torch.from_numpy(arr))
        return q.argmax(dim=-1).numpy().astype(np.int64)

    def save(self, path: str | Path, extra: dict[str, Any] | None = None) -> Path:
        """Write the policy as a mivecc checkpoint (``kind="signal_dqn"``)."""
        return save_checkpoint(path, {
            "kind": SIGNAL_KIND, "decision_period_s": self.decision_period_s,
            "hidden": self.net.net[0].out_features, "settings": self.settings,
            "network": self.net.state_dict(), "extra": extra or {},
        })

    @classmethod
    def load(cls, path: str | Path) -> SignalDQNPolicy:
        """Read a policy written by :meth:`save`; :class:`CheckpointError` (naming the file)
        for a missing, corrupt or foreign file."""
        data = read_policy_file(path, SIGNAL_KIND,
                                ("decision_period_s", "hidden", "network", "settings"))
        with corrupt_policy(path, "signal policy"):
            hidden = int(data["hidden"])
            period = float(data["decision_period_s"])
            if hidden < 1 or not period > 0:
                raise ValueError(f"hidden {hidden}, decision period {period}")
            net = SignalQNetwork(torch.ones(signal_agents.OBS_DIM), hidden)
            net.load_state_dict(data["network"])
        return cls(net, period, saved_settings(data), checkpoint=str(path))


def saved_settings(checkpoint: dict[str, Any]) -> dict[str, Any]:
    """A signal checkpoint's training settings; one written before ``keep_network`` existed
    (session 46) kept the last network."""
    return {"keep_network": "last", **dict(checkpoint["settings"])}


class HeldPhases:
    """The phases a policy chose at its last decision, held between decisions.

    With ``t`` the env steps taken since the reset, :meth:`due` says whether ``t`` is a
    decision step (``t = 0, p, 2p, ...`` for ``period_steps`` = p); on those the caller passes
    the ``(B, n_int, 15)`` observations to :meth:`decide`, which calls the policy once per
    environment on its ``(n_int, 15)`` rows (so no environment's choice depends on the batch).
    :attr:`phases` holds the last choice, ``(B, n_int)`` int64, for the steps in between.
    """

    def __init__(self, policy: Callable[[np.ndarray], np.ndarray], period_steps: int) -> None:
        self.policy = policy
        self.period_steps = int(period_steps)
        self.phases: np.ndarray | None = None

    def due(self, t: int) -> bool:
        """Whether step ``t`` is a decision step (the first call always is)."""
        return self.phases is None or t % self.period_steps == 0

    def decide(self, obs: np.ndarray) -> np.ndarray:
        """The policy's phases for ``obs`` (B, n_int, 15), held from now on."""
        self.phases = np.stack([np.asarray(self.policy(env_obs), dtype=np.int64)
                                for env_obs in obs])
        return self.phases


def _high(cfg: MiVeCCConfig) -> torch.Tensor:
    return torch.from_numpy(signal_agents.observation_bounds(cfg)[1])


def train_signal_dqn(settings: SignalDQNSettings,
                     on_episode: Callable[[dict[str, float]], None] | None = None,
                     on_validated: Callable[[dict[str, float], SignalDQNPolicy], None]
                     | None = None,
                     ) -> tuple[SignalDQNPolicy, list[dict[str, float]]]:
    """Train a PA-DQN policy (module docstring); returns it and one log row per episode.

    The run is deterministic for a given ``settings`` (torch's global random state is used
    inside :func:`torch.random.fork_rng` and left as it was). ``on_episode(row)`` is called
    after each episode (progress). Log row keys: ``episode``, ``epsilon`` (at the episode's
    end), ``reward_per_decision`` (mean over agents and decisions), ``throughput``,
    ``backlog`` and ``avg_travel_velocity_mps`` (means over the episode's environments),
    ``loss`` (mean TD loss of the episode's updates; NaN before the first), ``wall_s``; with
    ``keep_network="best"`` also ``validation_throughput`` (:func:`run_episodes`), and
    ``on_validated(row, policy)`` gets each validated network (a copy) with its log row.
    """
    settings.check()
    cfg = settings.env_config()
    env = training_env(settings, cfg)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(settings.seed)
        learner = DQNLearner(settings, SignalQNetwork(_high(cfg), settings.hidden))
        rng = np.random.default_rng(settings.seed)

        def act(obs: np.ndarray, eps: float) -> np.ndarray:
            return explore(rng, learner.greedy(obs.reshape(-1, obs.shape[-1])), eps
                           ).reshape(obs.shape[:2])

        def learn(obs: np.ndarray, phases: np.ndarray, reward: np.ndarray,
                  next_obs: np.ndarray) -> float | None:
            n_in = obs.shape[-1]
            learner.add(obs.reshape(-1, n_in), phases.reshape(-1), reward.reshape(-1),
                        next_obs.reshape(-1, n_in))
            return learner.update()

        def greedy(obs: np.ndarray) -> np.ndarray:
            return learner.greedy(obs.reshape(-1, obs.shape[-1])).reshape(obs.shape[:2])

        def episode_done(row: dict[str, float]) -> None:
            if on_validated is not None and not math.isnan(
                    row.get("validation_throughput", math.nan)):
                on_validated(row, SignalDQNPolicy(copy.deepcopy(learner.qnet),
                                                  settings.decision_period_s,
                                                  settings.to_dict()))
            if on_episode is not None:
                on_episode(row)

        keep = KeptNetwork.for_settings(settings, cfg, learner.qnet, greedy)
        log = run_episodes(settings, env, act, learn, episode_done, keep=keep)
    policy = SignalDQNPolicy(learner.qnet, settings.decision_period_s, settings.to_dict())
    return policy, log


def training_env(settings: SignalDQNSettings, cfg: MiVeCCConfig,
                 batch: int | None = None) -> Any:
    """``batch`` (default ``settings.batch``) signalized environments with signal agents and
    the throughput reward, the densities of ``settings.densities`` cycled over them."""
    from mivecc_env.batched import BatchedMiVeCCEnv

    batch = settings.batch if batch is None else batch
    densities = [settings.densities[i % len(settings.densities)] for i in range(batch)]
    return BatchedMiVeCCEnv(cfg, batch_size=batch, densities=densities, observe=(),
                            signal_agents=True, signal_reward="throughput")


def greedy_throughput(settings: SignalDQNSettings, env: Any,
                      greedy: Callable[[np.ndarray], np.ndarray]) -> float:
    """Vehicles out per environment (mean over ``env``'s environments) of a run of
    ``settings.episode_steps`` steps from an empty network on the seeds from
    :data:`VALIDATION_SEED`, ``greedy(obs)`` choosing the phases ``(b, n_int)`` every
    ``settings.decision_period_s`` (no exploration, no learning). ``greedy`` is called once per
    environment (``b = 1``), as in an evaluation (:class:`HeldPhases`), so that an
    environment's run does not depend on the others."""
    period = decision_steps(settings.decision_period_s, env.config.dt_s)
    obs = env.reset(seed=VALIDATION_SEED).signal_obs
    for _ in range(settings.episode_steps // period):
        phases = np.concatenate([greedy(obs[b:b + 1]) for b in range(obs.shape[0])])
        obs, _ = hold_phases(env, phases, period)
    return float(env.summary()["throughput"].mean())


def hold_phases(env: Any, phases: np.ndarray, period: int) -> tuple[np.ndarray, np.ndarray]:
    """Step ``env`` ``period`` times with the signal ``phases`` ``(B, n_int)`` held; returns
    the signal observations after the last step and each intersection's reward summed over
    the period ``(B, n_int)`` (vehicles through its centre)."""
    reward = np.zeros(phases.shape)
    for _ in range(period):
        out = env.step(signal_action=phases)
        reward += out.signal_reward
    return out.signal_obs, reward


class KeptNetwork:
    """Keeps the best of a module's states: :meth:`consider` scores the current state with
    ``score()`` and remembers it if ``key(score)`` beats every earlier one's (ties: the earlier);
    :meth:`restore` loads the best. ``keep_network="best"`` of the signal trainers
    (:meth:`for_settings`: vehicles out of a :func:`greedy_throughput` run on the validation
    environments, one per entry of ``settings.densities``) and of CoMADDPG. Validation neither
    explores nor learns, so the training itself is the same as with ``keep_network="last"``."""

    def __init__(self, module: nn.Module, score: Callable[[], Any],
                 key: Callable[[Any], Any] = lambda score: score) -> None:
        self.module = module
        self.score = score
        self.key = key
        self.best_key: Any = None
        self.best_state: dict[str, torch.Tensor] | None = None

    @classmethod
    def for_settings(cls, settings: SignalDQNSettings, cfg: MiVeCCConfig, module: nn.Module,
                     greedy: Callable[[np.ndarray], np.ndarray]) -> KeptNetwork | None:
        """The keeper of ``module`` for ``settings`` (None with ``keep_network="last"``)."""
        if settings.keep_network != "best":
            return None
        env = training_env(settings, cfg, batch=len(settings.densities))
        return cls(module, lambda: greedy_throughput(settings, env, greedy))

    def consider(self) -> Any:
        """Score the current state; keep it if it beats every earlier one. Returns the score."""
        score = self.score()
        key = self.key(score)
        if self.best_key is None or key > self.best_key:
            self.best_key = key
            self.best_state = {k: v.detach().clone() for k, v in self.module.state_dict().items()}
        return score

    def restore(self) -> None:
        """Load the best state considered (nothing if none was)."""
        if self.best_state is not None:
            self.module.load_state_dict(self.best_state)


def explore(rng: np.random.Generator, phases: np.ndarray, eps: float) -> np.ndarray:
    """``phases`` with each entry replaced by a uniformly random phase with probability
    ``eps`` (epsilon-greedy exploration, per intersection)."""
    chosen = rng.random(phases.shape) < eps
    return np.where(chosen, rng.integers(0, signal_agents.N_PHASES, phases.shape), phases)


class DQNLearner:
    """A Q-network, TorchRL's double-DQN loss, its soft target update, Adam and a replay
    buffer; :meth:`add` stores transitions, :meth:`update` trains, :meth:`greedy` acts.

    Parameters of ``qnet`` with ``requires_grad`` off stay as they are (Coder's aggregation
    stage trains its weighting network over frozen regional networks).
    """

    def __init__(self, settings: SignalDQNSettings, qnet: nn.Module) -> None:
        from tensordict.nn import TensorDictModule, TensorDictSequential
        from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
        from torchrl.modules import QValueModule
        from torchrl.objectives import DQNLoss, SoftUpdate

        self.qnet = qnet
        module = TensorDictModule(self.qnet, in_keys=["observation"], out_keys=["action_value"])
        policy = TensorDictSequential(module, QValueModule(action_space="categorical"))
        self.loss = DQNLoss(policy, action_space="categorical", delay_value=True,
                            double_dqn=True)
        self.loss.make_value_estimator(gamma=settings.gamma)
        self.target = SoftUpdate(self.loss, tau=settings.tau)
        self.optim = torch.optim.Adam(self.loss.parameters(), lr=settings.lr)
        self.buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(settings.buffer),
                                             batch_size=settings.minibatch)
        self.settings = settings

    def add(self, obs: np.ndarray, action: np.ndarray, reward: np.ndarray,
            next_obs: np.ndarray) -> None:
        """Store transitions (rows; no terminal states: the flow continues)."""
        from tensordict import TensorDict

        n = obs.shape[0]
        done = torch.zeros((n, 1), dtype=torch.bool)
        self.buffer.extend(TensorDict({
            "observation": torch.from_numpy(obs), "action": torch.from_numpy(action),
            "next": TensorDict({"observation": torch.from_numpy(next_obs),
                                "reward": torch.from_numpy(reward.astype(np.float32))[:, None],
                                "done": done, "terminated": done.clone()}, [n]),
        }, [n]))

    def update(self) -> float | None:
        """``updates_per_decision`` gradient steps (after the warm-up); the mean loss."""
        if len(self.buffer) < self.settings.warmup or self.settings.updates_per_decision == 0:
            return None
        total = 0.0
        for _ in range(self.settings.updates_per_decision):
            loss = self.loss(self.buffer.sample())["loss"]
            self.optim.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(self.loss.parameters(), 10.0)
            self.optim.step()
            self.target.step()
            total += float(loss.detach())
        return total / self.settings.updates_per_decision

    def greedy(self, obs: np.ndarray) -> np.ndarray:
        """The action of highest Q-value of every row of ``obs``."""
        with torch.no_grad():
            return self.qnet(torch.from_numpy(obs)).argmax(-1).numpy().astype(np.int64)


def run_episodes(settings: SignalDQNSettings, env: Any,
                 act: Callable[[np.ndarray, float], np.ndarray],
                 learn: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], float | None],
                 on_episode: Callable[[dict[str, float]], None] | None, *,
                 episodes: int | None = None, eps_start: float | None = None,
                 first_seed: int = FIRST_TRAIN_SEED,
                 keep: KeptNetwork | None = None) -> list[dict[str, float]]:
    """The training loop of the signal learners: ``episodes`` (default ``settings.episodes``)
    episodes of ``settings.episode_steps`` steps, each from an empty network on fresh seeds
    (``first_seed`` + ``settings.seed`` x 1e6 + episode x batch); a decision every
    ``settings.decision_period_s``.

    At a decision ``act(obs, eps)`` returns the phases ``(B, n_int)`` for the signal
    observations ``(B, n_int, 15)`` and the exploration probability ``eps`` (linear from
    ``eps_start``, default ``settings.eps_start``, to ``settings.eps_end`` over
    ``settings.eps_decay_fraction`` of the decisions); they are held for the period, then
    ``learn(obs, phases, reward, next_obs)`` gets the reward per intersection (vehicles through
    its centre in the period x ``settings.reward_scale``, ``(B, n_int)``) and returns the mean
    loss of its updates (None before the first). One log row per episode
    (:func:`train_signal_dqn`).

    With ``keep`` (``keep_network="best"``) each row also has ``validation_throughput``:
    ``keep.consider()`` after every episode that ended with the exploration decayed to
    ``settings.eps_end`` and after the last one, NaN after the others; the best network is
    restored at the end.
    """
    episodes = settings.episodes if episodes is None else episodes
    eps_start = settings.eps_start if eps_start is None else eps_start
    period = decision_steps(settings.decision_period_s, env.config.dt_s)
    decisions_per_episode = settings.episode_steps // period
    decay = max(1.0, settings.eps_decay_fraction * episodes * decisions_per_episode)
    log, done_decisions, t0 = [], 0, time.perf_counter()
    for episode in range(episodes):
        out = env.reset(seed=first_seed + settings.seed * 1_000_000 + episode * settings.batch)
        obs = out.signal_obs
        rewards, losses, eps = [], [], eps_start
        for _ in range(decisions_per_episode):
            frac = min(1.0, done_decisions / decay)
            eps = eps_start + frac * (settings.eps_end - eps_start)
            phases = act(obs, eps)
            next_obs, reward = hold_phases(env, phases, period)
            reward *= settings.reward_scale
            loss = learn(obs, phases, reward, next_obs)
            if loss is not None:
                losses.append(loss)
            rewards.append(float(reward.mean()))
            obs = next_obs
            done_decisions += 1
        summary = env.summary()
        row = {"episode": episode + 1, "epsilon": eps,
               "reward_per_decision": float(np.mean(rewards)) if rewards else math.nan,
               "throughput": float(summary["throughput"].mean()),
               "backlog": float(summary["backlog"].mean()),
               "avg_travel_velocity_mps": float(np.nanmean(summary["avg_travel_velocity_mps"])),
               "loss": float(np.mean(losses)) if losses else math.nan}
        if keep is not None:
            # the episode's last decision explored at eps_end (or there is no decay)
            decayed = frac >= 1.0 or eps_start == settings.eps_end
            validate = decayed or episode == episodes - 1
            row["validation_throughput"] = keep.consider() if validate else math.nan
        row["wall_s"] = time.perf_counter() - t0
        log.append(row)
        if on_episode is not None:
            on_episode(row)
    if keep is not None:
        keep.restore()
    return log


def progress_line(row: dict[str, float], total: int) -> str:
    """One episode's progress line of ``mivecc train-signal`` / ``train-coder``."""
    stage = f" (stage {row['stage']:.0f})" if "stage" in row else ""
    return (f"episode {row['episode']:.0f}/{total}{stage}: reward/decision "
            f"{row['reward_per_decision']:.3f}, throughput {row['throughput']:.1f} veh, "
            f"backlog {row['backlog']:.1f} veh, epsilon {row['epsilon']:.2f}, loss "
            f"{row['loss']:.4f}{_validation(row)}, {row['wall_s']:.0f} s")


def kept_episodes(log: Sequence[Mapping[str, float]]) -> list[tuple[int, int, float, float]]:
    """Per stage of a ``keep_network="best"`` training log (one stage for PA-DQN; Coder's
    ``stage`` 1 and 2): ``(stage, episode kept, its validation throughput, the last validated
    episode's)``, the kept one the first of the highest; empty for a log without validation."""
    out = []
    for stage in sorted({int(r.get("stage", 1)) for r in log}):
        rows = [r for r in log if int(r.get("stage", 1)) == stage
                and not math.isnan(float(r.get("validation_throughput", math.nan)))]
        if rows:
            best = max(rows, key=lambda r: float(r["validation_throughput"]))
            out.append((stage, int(best["episode"]), float(best["validation_throughput"]),
                        float(rows[-1]["validation_throughput"])))
    return out


def kept_note(log: Sequence[Mapping[str, float]]) -> str | None:
    """One line naming the network(s) a ``keep_network="best"`` training returned (None for
    ``keep_network="last"``)."""
    kept = kept_episodes(log)
    if not kept:
        return None
    staged = len(kept) > 1 or "stage" in log[0]
    parts = [f"after episode {episode}{f' (stage {stage})' if staged else ''}: {value:.1f} "
             f"vehicles out per validation environment, the last validated network {last:.1f}"
             for stage, episode, value, last in kept]
    return "kept the network of the best greedy validation run " + "; ".join(parts)


def _validation(row: dict[str, float]) -> str:
    value = row.get("validation_throughput", math.nan)
    return "" if math.isnan(value) else f", validation {value:.1f} veh"


def write_log(rows: Sequence[dict[str, float]], path: str | Path) -> Path:
    """The training log as CSV (one row per episode)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return path


def plot_learning_curve(rows: Sequence[dict[str, float]], path: str | Path) -> Path:
    """A PNG of a training log: reward per decision and throughput per episode (Coder's
    logs, with a ``stage`` column, get a line where the aggregation stage begins)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    episodes = [r["episode"] for r in rows]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9.5, 6), sharex=True)
    top.plot(episodes, [r["reward_per_decision"] for r in rows], marker="o", ms=3)
    top.set_ylabel("reward per decision\n(vehicles through x scale)")
    bottom.plot(episodes, [r["throughput"] for r in rows], marker="o", ms=3, label="throughput")
    bottom.plot(episodes, [r["backlog"] for r in rows], marker="s", ms=3, label="entry backlog")
    if "validation_throughput" in rows[0]:
        bottom.plot(episodes, [r["validation_throughput"] for r in rows], "D", ms=4,
                    label="throughput, greedy validation run")
        kept = kept_episodes(rows)
        bottom.plot([k[1] for k in kept], [k[2] for k in kept], "*", ms=14, color="black",
                    label="network kept (keep_network=best)")
    bottom.set_ylabel("vehicles per environment")
    bottom.set_xlabel("episode")
    second_stage = [r["episode"] for r in rows if r.get("stage") == 2]
    if second_stage:
        top.set_title("Coder training (exploration included): regional stage, then "
                      "aggregation")
        top.axvline(second_stage[0] - 0.5, color="grey", ls="--", lw=1)
        bottom.axvline(second_stage[0] - 0.5, color="grey", ls="--", lw=1,
                       label="aggregation stage begins")
    else:
        top.set_title("PA-DQN training (exploration included)")
    bottom.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    return save_figure(fig, path)


def save_figure(fig: Any, path: str | Path) -> Path:
    """Lay out ``fig``, write it as a PNG at ``path`` (its folder made if needed), close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
