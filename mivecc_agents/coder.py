"""Coder: cooperative deep RL signal control of a grid, the paper's multi-intersection comparator.

The paper's Table eff_imp_rate compares MiVeCC-EEC on 3x3 with Coder (Tan et al., "Cooperative
deep reinforcement learning for large-scale traffic grid signal control", IEEE T-CYB 2020):
regional agents each learn a Q-function over a small region with few actions, and a global
agent aggregates them into the Q-function of the whole grid. No implementation is public; this
module is this package's reading of that design, on the signal agents of
:mod:`mivecc_env.signal_agents` (``control="signalized"``):

* **regions**: every 2x2 block of neighbouring intersections (:func:`grid_regions`; four
  overlapping blocks on 3x3). A regional agent observes its four intersections' signal
  observations (4 x 15 features) and has 16 actions, the joint phase of its block.
* **global Q**: for a joint phase ``a`` of all ``n`` intersections,
  ``Q(s, a) = sum_r w_r(s) Q_region(s_r, a_r)``: each region's value of its part of ``a``,
  weighted by the aggregation network (``w_r >= 0`` from the region's observation and the grid's
  mean observation; all 1 before the aggregation stage). The decision is the best of the ``2^n``
  joint phases, searched exhaustively on grids of at most :data:`MAX_INTERSECTIONS`
  intersections (training: always); on larger grids a trained policy decides by
  :func:`coordinate_ascent` (a local optimum of the same Q).
* **decision** every ``decision_period_s`` (10 s), held in between, as PA-DQN
  (:class:`mivecc_agents.signal_dqn.HeldPhases`).
* **training**, two stages with TorchRL's double-DQN loss (:class:`~mivecc_agents.signal_dqn.
  DQNLearner`) on the PA-DQN training loop and settings (:class:`CoderSettings`):
  1. *regional*: one regional network shared by all regions learns from every region's
     transitions (its observation, its joint phase, the vehicles through its four centres in
     the period x ``reward_scale``); the grid acts on the sum of the regional values
     (``w_r = 1``), epsilon-greedy per intersection.
  2. *aggregation*: the regional network frozen, the aggregation network learns the global Q
     from the grid's reward (vehicles through all centres x ``reward_scale``), exploration from
     ``global_eps_start``, on training seeds apart from the first stage's.

  With ``keep_network="best"`` (the default) each stage ends with its best-validated network
  restored (:class:`mivecc_agents.signal_dqn.KeptNetwork`): the aggregation stage trains over
  the kept regional network.

A trained policy is :class:`CoderPolicy` (:meth:`CoderPolicy.without_aggregation`: its regional
network on the plain sum, as in stage 1); ``mivecc evaluate --scheme coder`` runs the shipped
one (trained on 3x3, :func:`shipped_policy_path`), ``mivecc train-coder`` trains one and warns
when the training ended with networks that move fewer vehicles than its regional stage did
(:func:`training_shortfall`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from mivecc_agents.checkpoints import corrupt_policy, read_policy_file, save_checkpoint
from mivecc_agents.coder_settings import MAX_INTERSECTIONS, CoderSettings, check_coder_grid
from mivecc_agents.signal_dqn import (
    FIRST_TRAIN_SEED,
    SHIPPED_DIR,
    DQNLearner,
    KeptNetwork,
    SignalQNetwork,
    explore,
    run_episodes,
    saved_settings,
    training_env,
)
from mivecc_env import signal_agents

__all__ = [
    "MAX_INTERSECTIONS",
    "CoderPolicy",
    "CoderSettings",
    "GlobalQ",
    "coordinate_ascent",
    "grid_regions",
    "joint_phases",
    "shipped_policy_path",
    "train_coder",
]

#: ``kind`` of a Coder checkpoint.
CODER_KIND = "coder"
#: Intersections of a region (a 2x2 block).
REGION_SIZE = 4
#: Joint phases of a region.
REGION_ACTIONS = signal_agents.N_PHASES ** REGION_SIZE
#: First training seed of the aggregation stage (apart from the regional stage's).
AGGREGATION_SEED_OFFSET = 500_000
#: ``mivecc train-coder`` warns when the aggregation stage's last episodes moved fewer vehicles
#: than this share of the regional stage's last ones (:func:`training_shortfall`) ...
SHORTFALL_SHARE = 0.9
#: ... over this many episodes at the end of each stage.
SHORTFALL_EPISODES = 5
#: Aggregation output before the softplus that gives a weight of 1 (log(e - 1)).
_UNIT_WEIGHT_LOGIT = math.log(math.e - 1.0)


def shipped_policy_path() -> Path:
    """The shipped Coder policy (``pretrained/coder_3x3.pt``, trained on 3x3)."""
    return SHIPPED_DIR / "coder_3x3.pt"


def grid_regions(rows: int, cols: int) -> np.ndarray:
    """``(n_regions, 4)`` intersection ids (row-major, ``r * cols + c``) of every 2x2 block of
    the grid, each block's ids in the order top-left, top-right, bottom-left, bottom-right
    (rows counted from the grid's first row). ConfigError for a grid without a 2x2 block."""
    check_coder_grid(rows, cols, exhaustive=False)
    return np.array([[r * cols + c, r * cols + c + 1, (r + 1) * cols + c, (r + 1) * cols + c + 1]
                     for r in range(rows - 1) for c in range(cols - 1)], dtype=np.int64)


def joint_phases(n_int: int) -> np.ndarray:
    """``(2^n_int, n_int)`` every joint phase of ``n_int`` intersections: row ``a`` holds bit
    ``i`` of ``a`` for intersection ``i``."""
    return (np.arange(2 ** n_int)[:, None] >> np.arange(n_int)[None, :]) & 1


def joint_index(phases: np.ndarray) -> np.ndarray:
    """The index (row of :func:`joint_phases`) of joint phases ``(..., n)``."""
    return (np.asarray(phases, dtype=np.int64) << np.arange(phases.shape[-1])).sum(-1)


class AggregationNetwork(nn.Module):
    """The weight ``w_r >= 0`` of each region from its observation ``(..., 60)`` and the grid's
    mean observation ``(..., 15)`` (one hidden ReLU layer, softplus); starts at ``w_r = 1``."""

    def __init__(self, high: torch.Tensor, hidden: int) -> None:
        super().__init__()
        region_high = high.repeat(REGION_SIZE + 1)
        self.register_buffer("scale", 1.0 / region_high.to(torch.float32).clamp(min=1.0))
        self.net = nn.Sequential(nn.Linear(region_high.numel(), hidden), nn.ReLU(),
                                 nn.Linear(hidden, 1))
        with torch.no_grad():
            self.net[-1].weight.mul_(0.01)
            self.net[-1].bias.fill_(_UNIT_WEIGHT_LOGIT)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return nn.functional.softplus(self.net(features * self.scale))


class GlobalQ(nn.Module):
    """Q-values ``(..., 2^n)`` of the joint phases of a grid from its signal observations
    flattened, ``(..., n * 15)`` (module docstring: ``sum_r w_r Q_region(s_r, a_r)``; ``w_r = 1``
    without an aggregation network). With ``exhaustive=False`` (grids too large to enumerate)
    it holds no joint-phase table: use :meth:`region_values` and :func:`coordinate_ascent`."""

    def __init__(self, regional: SignalQNetwork, aggregation: AggregationNetwork | None,
                 rows: int, cols: int, exhaustive: bool = True) -> None:
        super().__init__()
        self.regional = regional
        self.aggregation = aggregation
        self.n_int = rows * cols
        check_coder_grid(rows, cols, exhaustive)
        regions = grid_regions(rows, cols)
        self.regions = torch.from_numpy(regions)
        table = np.zeros((regions.shape[0], 0), np.int64)
        if exhaustive:  # each region's part of every joint phase
            table = joint_index(joint_phases(self.n_int)[:, regions]).T.copy()
        self.register_buffer("region_action", torch.from_numpy(table))

    def region_values(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Each region's Q-values ``(..., R, 16)`` and weight ``(..., R, 1)`` (1 without an
        aggregation network) for the grid's observations ``(..., n * 15)``."""
        per_int = obs.reshape(*obs.shape[:-1], self.n_int, signal_agents.OBS_DIM)
        region_obs = per_int[..., self.regions, :].flatten(-2)  # (..., R, 60)
        q_region = self.regional(region_obs)
        if self.aggregation is None:
            return q_region, torch.ones_like(q_region[..., :1])
        grid_mean = per_int.mean(-2, keepdim=True).expand(*region_obs.shape[:-1], -1)
        return q_region, self.aggregation(torch.cat([region_obs, grid_mean], dim=-1))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        q_region, weights = self.region_values(obs)
        index = self.region_action.expand(*q_region.shape[:-1], -1)
        return (weights * q_region.gather(-1, index)).sum(-2)  # (..., A)


def coordinate_ascent(q_region: np.ndarray, weights: np.ndarray, regions: np.ndarray,
                      n_int: int, max_sweeps: int = 50) -> np.ndarray:
    """A joint phase ``(n_int,)`` of high global Q ``sum_r weights[r] q_region[r, a_r]``
    without enumerating all 2^n (grids of more than :data:`MAX_INTERSECTIONS` intersections):
    start from each intersection's weighted vote of its regions' best joint phases (ties:
    phase 0), then sweep the intersections in order, flipping one whenever that raises the
    global Q, until a sweep changes nothing (a local optimum: no single flip improves) or after
    ``max_sweeps`` sweeps. Deterministic."""
    n_regions = regions.shape[0]
    rows = np.arange(n_regions)

    def value(phases: np.ndarray) -> float:
        return float((weights * q_region[rows, joint_index(phases[regions])]).sum())

    best = q_region.argmax(1)
    wants = ((best[:, None] >> np.arange(REGION_SIZE)) & 1) * 2 - 1  # (R, 4) in {-1, +1}
    votes = np.zeros(n_int)
    np.add.at(votes, regions.ravel(), (weights[:, None] * wants).ravel())
    phases = (votes > 0).astype(np.int64)
    current = value(phases)
    for _ in range(max_sweeps):
        changed = False
        for i in range(n_int):  # intersections, at decision steps only
            phases[i] ^= 1
            flipped = value(phases)
            if flipped > current:
                current, changed = flipped, True
            else:
                phases[i] ^= 1
        if not changed:
            break
    return phases


class CoderPolicy:
    """A trained Coder policy: ``policy(obs)`` -> the phases ``(n,)`` of the best joint phase
    for the grid's signal observations ``(n, 15)`` (ties: the lowest joint index); on grids of
    more than :data:`MAX_INTERSECTIONS` intersections the joint phase of
    :func:`coordinate_ascent`.

    Attributes:
        rows, cols: the grid it acts on (:meth:`for_grid` gives the policy on another grid).
        decision_period_s: time between two decisions [s] (the training's).
        settings: the training settings (a dict).
        checkpoint: the file it was loaded from ("" if trained in this process).
    """

    #: The evaluation scheme this policy is for.
    scheme = "coder"

    def __init__(self, regional: SignalQNetwork, aggregation: AggregationNetwork | None,
                 decision_period_s: float, settings: dict[str, Any], checkpoint: str = "",
                 rows: int | None = None, cols: int | None = None) -> None:
        self.regional = regional.eval()
        #: None: the plain sum of the regional values (:meth:`without_aggregation`).
        self.aggregation = None if aggregation is None else aggregation.eval()
        self.decision_period_s = float(decision_period_s)
        self.settings = settings
        self.checkpoint = checkpoint
        self.rows = int(settings["rows"] if rows is None else rows)
        self.cols = int(settings["cols"] if cols is None else cols)
        #: Whether decisions search all joint phases (else coordinate ascent: larger grids).
        self.exhaustive = self.rows * self.cols <= MAX_INTERSECTIONS
        self._q = GlobalQ(self.regional, self.aggregation, self.rows, self.cols,
                          self.exhaustive)
        self._phases = joint_phases(self.rows * self.cols) if self.exhaustive else None

    def for_grid(self, rows: int, cols: int) -> CoderPolicy:
        """The same networks on a ``rows`` x ``cols`` grid (ConfigError without a 2x2
        block)."""
        if (rows, cols) == (self.rows, self.cols):
            return self
        return CoderPolicy(self.regional, self.aggregation, self.decision_period_s,
                           self.settings, self.checkpoint, rows, cols)

    def without_aggregation(self) -> CoderPolicy:
        """The same regional network deciding on the plain sum of its regions' values (every
        weight 1, as in the regional training stage): tells a regional network's decisions
        from the aggregation's."""
        return CoderPolicy(self.regional, None, self.decision_period_s, self.settings,
                           self.checkpoint, self.rows, self.cols)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        arr = np.asarray(obs, dtype=np.float32)
        n_int = self.rows * self.cols
        if arr.shape != (n_int, signal_agents.OBS_DIM):
            raise ValueError(f"obs: expected shape ({n_int}, {signal_agents.OBS_DIM}) for the "
                             f"{self.rows}x{self.cols} grid, got {arr.shape}")
        with torch.no_grad():
            if not self.exhaustive:
                q_region, weights = self._q.region_values(torch.from_numpy(arr.reshape(-1)))
                return coordinate_ascent(q_region.numpy(), weights[:, 0].numpy(),
                                         self._q.regions.numpy(), n_int)
            best = int(self._q(torch.from_numpy(arr.reshape(-1))).argmax())
        return self._phases[best].astype(np.int64)

    def save(self, path: str | Path, extra: dict[str, Any] | None = None) -> Path:
        """Write the policy as a mivecc checkpoint (``kind="coder"``); not one without its
        aggregation network."""
        if self.aggregation is None:
            raise ValueError("a Coder policy without its aggregation network is not saved")
        return save_checkpoint(path, {
            "kind": CODER_KIND, "decision_period_s": self.decision_period_s,
            "hidden": self.regional.net[0].out_features,
            "global_hidden": self.aggregation.net[0].out_features, "settings": self.settings,
            "regional": self.regional.state_dict(),
            "aggregation": self.aggregation.state_dict(), "extra": extra or {},
        })

    @classmethod
    def load(cls, path: str | Path) -> CoderPolicy:
        """Read a policy written by :meth:`save`; :class:`CheckpointError` (naming the file)
        for a missing, corrupt or foreign file."""
        data = read_policy_file(path, CODER_KIND, ("decision_period_s", "hidden",
                                                   "global_hidden", "settings", "regional",
                                                   "aggregation"))
        with corrupt_policy(path, "Coder policy"):
            hidden, global_hidden = int(data["hidden"]), int(data["global_hidden"])
            period = float(data["decision_period_s"])
            if hidden < 1 or global_hidden < 1 or not period > 0:
                raise ValueError(f"hidden {hidden}, global_hidden {global_hidden}, decision "
                                 f"period {period}")
            ones = torch.ones(signal_agents.OBS_DIM)
            regional = SignalQNetwork(ones.repeat(REGION_SIZE), hidden, REGION_ACTIONS)
            regional.load_state_dict(data["regional"])
            aggregation = AggregationNetwork(ones, global_hidden)
            aggregation.load_state_dict(data["aggregation"])
            settings = saved_settings(data)
            check_coder_grid(int(settings["rows"]), int(settings["cols"]))
        return cls(regional, aggregation, period, settings, checkpoint=str(path))


def training_shortfall(log: Sequence[Mapping[str, float]]) -> str | None:
    """A one-line warning when a training ended with networks that move fewer vehicles than its
    regional stage did: the mean ``throughput`` (vehicles out per training environment) of the
    last :data:`SHORTFALL_EPISODES` episodes of each ``stage`` of a training log, the
    aggregation stage's (which acts with the frozen regional network the first stage returned:
    its last, or its best-validated with ``keep_network="best"``) below
    :data:`SHORTFALL_SHARE` of the regional stage's; None otherwise or without both stages.

    Both stages explore (their own epsilon), so this is a coarse check: it flags a training such
    as the one in docs/comparators.md, "Signal policies trained with the keep-clear rule, and
    on another CPU", whose final regional network does far worse than the regional stage's
    episodes did, not a small shortfall."""
    regional, aggregated = ([float(r["throughput"]) for r in log if int(r["stage"]) == stage]
                            [-SHORTFALL_EPISODES:] for stage in (1, 2))
    if not regional or not aggregated:
        return None
    before, after = float(np.mean(regional)), float(np.mean(aggregated))
    if after >= SHORTFALL_SHARE * before:
        return None
    return (f"warning: the aggregation stage's last {len(aggregated)} episodes moved "
            f"{after:.0f} vehicles per training environment, {100 * after / before:.0f} % of "
            f"the regional stage's {before:.0f}: the networks the training ended with do worse "
            "than its regional stage did; evaluate the policy before using it "
            "(docs/comparators.md, \"Signal policies trained with the keep-clear rule, and on "
            "another CPU\")")


def train_coder(settings: CoderSettings,
                on_episode: Callable[[dict[str, float]], None] | None = None,
                ) -> tuple[CoderPolicy, list[dict[str, float]]]:
    """Train a Coder policy (module docstring); returns it and one log row per episode.

    Deterministic for a given ``settings`` (torch's global random state is used inside
    :func:`torch.random.fork_rng` and left as it was). Log rows: those of
    :func:`mivecc_agents.signal_dqn.train_signal_dqn` and ``stage`` (1 regional, 2
    aggregation); ``episode`` and ``wall_s`` count on over both stages.
    """
    settings.check()
    cfg = settings.env_config()
    env = training_env(settings, cfg)
    high = torch.from_numpy(signal_agents.observation_bounds(cfg)[1])
    rows, cols = settings.rows, settings.cols
    regions = grid_regions(rows, cols)
    phases_of = joint_phases(rows * cols)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(settings.seed)
        regional = SignalQNetwork(high.repeat(REGION_SIZE), settings.hidden, REGION_ACTIONS)
        aggregation = AggregationNetwork(high, settings.global_hidden)
        rng = np.random.default_rng(settings.seed)
        log: list[dict[str, float]] = []

        def stage_rows(stage: int) -> Callable[[dict[str, float]], None]:
            wall_before = log[-1]["wall_s"] if log else 0.0

            def record(row: dict[str, float]) -> None:
                row = {**row, "episode": len(log) + 1, "stage": stage,
                       "wall_s": row["wall_s"] + wall_before}
                log.append(row)
                if on_episode is not None:
                    on_episode(row)
            return record

        def greedy_phases(q: GlobalQ, obs: np.ndarray) -> np.ndarray:
            with torch.no_grad():
                best = q(torch.from_numpy(obs.reshape(obs.shape[0], -1))).argmax(-1).numpy()
            return phases_of[best]

        # Stage 1: the regional network, the grid acting on the plain sum of regional values.
        regional_learner = DQNLearner(settings, regional)
        summed = GlobalQ(regional, None, rows, cols)

        def act_regional(obs: np.ndarray, eps: float) -> np.ndarray:
            return explore(rng, greedy_phases(summed, obs), eps)

        def learn_regional(obs: np.ndarray, phases: np.ndarray, reward: np.ndarray,
                           next_obs: np.ndarray) -> float | None:
            width = REGION_SIZE * signal_agents.OBS_DIM
            regional_learner.add(obs[:, regions].reshape(-1, width),
                                 joint_index(phases[:, regions]).reshape(-1),
                                 reward[:, regions].sum(-1).reshape(-1),
                                 next_obs[:, regions].reshape(-1, width))
            return regional_learner.update()

        run_episodes(settings, env, act_regional, learn_regional, stage_rows(1),
                     keep=KeptNetwork.for_settings(settings, cfg, regional,
                                                   lambda obs: greedy_phases(summed, obs)))

        # Stage 2: the aggregation network over the frozen regional network.
        regional.requires_grad_(False)
        weighted = GlobalQ(regional, aggregation, rows, cols)
        global_learner = DQNLearner(settings, weighted)

        def act_global(obs: np.ndarray, eps: float) -> np.ndarray:
            return explore(rng, greedy_phases(weighted, obs), eps)

        def learn_global(obs: np.ndarray, phases: np.ndarray, reward: np.ndarray,
                         next_obs: np.ndarray) -> float | None:
            b = obs.shape[0]
            global_learner.add(obs.reshape(b, -1), joint_index(phases), reward.sum(-1),
                               next_obs.reshape(b, -1))
            return global_learner.update()

        run_episodes(settings, env, act_global, learn_global, stage_rows(2),
                     episodes=settings.global_episodes, eps_start=settings.global_eps_start,
                     first_seed=FIRST_TRAIN_SEED + AGGREGATION_SEED_OFFSET,
                     keep=KeptNetwork.for_settings(settings, cfg, aggregation,
                                                   lambda obs: greedy_phases(weighted, obs)))
    regional.requires_grad_(True)
    return CoderPolicy(regional, aggregation, settings.decision_period_s,
                       settings.to_dict()), log
