"""Native TorchRL env on :class:`mivecc_env.batched.BatchedMiVeCCEnv` (B envs, one simulator).

:class:`MiVeCCTorchEnv` is an ``EnvBase`` with ``batch_size=[B]`` and the groups and keys that
``PettingZooWrapper(mivecc_v0.parallel_env(...))`` gives (``docs/training.md``), without the
per-agent dicts, the ``SerialEnv`` copies and one ``torch.tensor`` per info key per agent:

=============================  ===========================================  ================
key                            shape                                        dtype
=============================  ===========================================  ================
``(g, "observation")``         ``(B, n_g, K, K, 3)``                        float32
``(g, "mask")``                ``(B, n_g, K)`` (1: a real decision vehicle)  float32
``(g, "action")``              ``(B, n_g, K)`` in ``[-a_max, a_max]`` m/s^2  float32
``(g, "reward")``              ``(B, n_g, 1)``                              float32
``(g, "done" | "terminated" |  ``(B, n_g, 1)``                              bool
"truncated")``
``(g, "info", "mask")``        ``(B, n_g, K)``                              float32
``(g, "info", term)``          ``(B, n_g)``, ``term`` in ``REWARD_TERMS``   float32
``(s, "info", summary key)``   ``(B, n_g)`` (``summary_keys``)               float32
``("cloud", "info",            ``(B, 1)``, only with ``cloud_period > 1``:    bool
"decides")``                   the cloud action is used on the next step
``"done" | "terminated" |      ``(B, 1)``                                   bool
"truncated"``
=============================  ===========================================  ================

Signal agents (``control="signalized"``, ``groups`` with ``"signal"``: the batched env's
``signal_agents``): ``("signal", "observation")`` ``(B, n_int, 15)`` float32
(:data:`mivecc_env.signal_agents.OBS_FEATURES`), ``("signal", "action")`` ``(B, n_int)``
int64 in {0, 1} (the phase each intersection wants green), ``("signal", "reward")``
``(B, n_int, 1)`` (``signal_reward``: queue, pressure or throughput), ``("signal", "info",
term)`` for every reward term, and the done keys.

with ``g`` in ``groups`` (``edge``: ``n_g`` = number of intersections, K = ``k_edge``;
``cloud``: ``n_g`` = 1, K = ``k_cloud``; with ``cloud_graphs="per_lane"`` ``n_g`` = the
number of through lanes, one agent ``cloud_<lane>`` per lane graph, each with the network's
cloud reward: there the ParallelEnv has one ``cloud_0`` with all the graphs). ``(g, "mask")``
is the same tensor as ``(g, "info", "mask")`` (the pipeline of ``training.make_env`` copies it
there). The episode summary (whole network) is in group ``s`` = ``cloud``, as the ParallelEnv
puts it in ``cloud_0``'s info; when only ``edge`` is exposed, it is under ``edge`` (broadcast to the
``n_edge`` agents without a copy), when only ``signal``, under ``signal``.

Partial resets: TorchRL passes ``"_reset"`` (B, 1); only those environments restart
(:meth:`BatchedMiVeCCEnv.reset_at`, each with the next seed of its own sequence) while the
others keep their state. Seeds: ``set_seed(s)`` seeds environment ``b`` with ``s + b`` exactly
as ``PettingZooWrapper.set_seed(s + b)`` seeds a B = 1 env (the seeded reset, then the next
reset draws the next seed), so environment ``b`` gives the same observations as that wrapper.

Observations and masks are wrapped with ``torch.from_numpy`` (no copy); rewards and summaries
are converted to float32 (one small copy per key and step). Only graphs of the groups asked
for are built: a stage-I run with ``groups=("edge",)`` builds no cloud graph.

Needs the ``train`` extra (torch, torchrl); :mod:`mivecc_env` itself never imports torch.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from mivecc_env import signal_agents as signal_agents_mod
from mivecc_env.batched import REWARD_TERMS, BatchedMiVeCCEnv, BatchStep
from mivecc_env.metrics import SUMMARY_KEYS

__all__ = ["ALL_GROUPS", "GROUPS", "MiVeCCTorchEnv"]

GROUPS: tuple[str, ...] = ("edge", "cloud")
#: Every group the env can expose: the coordinators and the signal agents.
ALL_GROUPS: tuple[str, ...] = (*GROUPS, signal_agents_mod.SIGNAL_GROUP)


class MiVeCCTorchEnv(EnvBase):
    """B MiVeCC environments as one TorchRL env (see the module docstring).

    Args:
        batch_size: number of environments B (default: ``len(densities)``, else 1).
        densities: demand of each environment [veh/lane/h], B values (one batch may mix
            densities); default: the config's density for all.
        groups: agent groups to expose, a subset of ``("edge", "cloud", "signal")``
            (default ``("edge", "cloud")``); ``"signal"`` needs ``control="signalized"``.
        signal_reward: the signal agents' reward, ``"queue"``, ``"pressure"`` or
            ``"throughput"``.
        summary_keys: episode-summary keys to put under ``(g, "info")`` (default all of
            :data:`mivecc_env.metrics.SUMMARY_KEYS`; ``()`` for none).
        seed: if given, :meth:`set_seed` is called with it.
        continuous: one continuing simulation per environment, episodes are chunks of
            ``max_steps`` steps (the released trainer): an environment whose chunk ended is
            not reset by ``"_reset"``, it starts its next chunk in place
            (:meth:`BatchedMiVeCCEnv.start_chunk`: truncation without reset). A reset without
            ``"_reset"`` (the collector's first) restarts every environment.
        raw_edge_period: ``n > 0``: on every ``n``-th step (steps ``n-1, 2n-1, ...`` of this
            env, counted over its whole life) the edge actions are executed unmodified (no
            veto, no max; the released trainer uses ``n = 2``); ``0`` (default): never.
        config: a :class:`~mivecc_env.config.MiVeCCConfig`; ``**overrides`` replace fields
            (``scheme``, ``rows``, ``max_steps``...).
        device: torch device of the tensors; the simulation stays on the CPU (tested on the
            CPU and on CUDA: ``tests/agents/test_device.py``).

    Raises:
        ConfigError: a bad config value, batch size or density (from the batched env);
            ``"signal"`` without ``control="signalized"``, or a bad ``signal_reward``.
        ValueError: an unknown group or summary key.
    """

    def __init__(
        self,
        batch_size: int | None = None,
        *,
        densities: Sequence[float] | None = None,
        groups: Sequence[str] = GROUPS,
        signal_reward: str = "queue",
        summary_keys: Sequence[str] = SUMMARY_KEYS,
        seed: int | None = None,
        continuous: bool = False,
        raw_edge_period: int = 0,
        config: Any = None,
        device: Any = "cpu",
        **overrides: Any,
    ) -> None:
        groups = tuple(groups)
        if not groups or not set(groups) <= set(ALL_GROUPS) or len(set(groups)) < len(groups):
            raise ValueError(f"groups: must be a non-empty subset of {ALL_GROUPS}, "
                             f"got {groups!r}")
        bad = sorted(set(summary_keys) - set(SUMMARY_KEYS))
        if bad:
            raise ValueError(f"summary_keys: unknown {bad}; known: {list(SUMMARY_KEYS)}")
        if densities is not None and len(densities) == 0:
            raise ValueError("densities: need at least one [veh/lane/h], got none")
        if batch_size is None:
            batch_size = len(densities) if densities is not None else 1
        if isinstance(raw_edge_period, bool) or int(raw_edge_period) != raw_edge_period or (
            raw_edge_period < 0
        ):
            raise ValueError(f"raw_edge_period: must be an integer >= 0, got {raw_edge_period!r}")
        self.raw_edge_period = int(raw_edge_period)
        self._steps_taken = 0
        signal = signal_agents_mod.SIGNAL_GROUP
        self._batched = BatchedMiVeCCEnv(
            config, int(batch_size), densities=densities, observe=set(groups) - {signal},
            continuous=continuous, signal_agents=signal in groups, signal_reward=signal_reward,
            **overrides,
        )
        b = self._batched.batch_size
        super().__init__(device=device, batch_size=torch.Size([b]))
        self.groups = groups
        self.summary_keys = tuple(summary_keys)
        c = self._batched.config
        self.config = c
        self._n = {"edge": c.n_intersections, "cloud": c.n_cloud_graphs,
                   signal: c.n_intersections}
        self._k = {"edge": c.k_edge, "cloud": c.k_cloud}
        self.group_map = {
            g: [f"{g}_{i}" for i in range(self._n[g])] for g in groups
        }
        #: The group whose infos hold the episode summary.
        self.summary_group = next(g for g in ("cloud", "edge", signal) if g in groups)
        #: cloud_period > 1: ``("cloud", "info", "decides")`` says whether the cloud action
        #: is used on the next step (mivecc_env.cloud_hold).
        self._holds_cloud = c.cloud_period > 1 and c.scheme == "EEC"
        self._make_specs()
        if seed is not None:
            self.set_seed(seed)

    # ------------------------------------------------------------------------------------
    @property
    def batched_env(self) -> BatchedMiVeCCEnv:
        """The numpy batched env underneath."""
        return self._batched

    def _make_specs(self) -> None:
        b = self.batch_size[0]
        c = self.config
        obs, act, rew, done = {}, {}, {}, {}
        for g in self.groups:
            if g == signal_agents_mod.SIGNAL_GROUP:
                obs[g], act[g], rew[g], done[g] = self._signal_specs(b)
                continue
            n, k = self._n[g], self._k[g]
            info = {"mask": Unbounded((b, n, k), dtype=torch.float32)}
            if g == "cloud" and self._holds_cloud:
                info["decides"] = Categorical(2, (b, n), dtype=torch.bool)
            summary = self.summary_keys if g == self.summary_group else ()
            for key in (*REWARD_TERMS, *summary):
                info[key] = Unbounded((b, n), dtype=torch.float32)
            obs[g] = Composite(
                observation=Bounded(-1.0, 1.0, (b, n, k, k, 3), dtype=torch.float32),
                mask=Bounded(0.0, 1.0, (b, n, k), dtype=torch.float32),
                info=Composite(info, shape=(b, n)),
                shape=(b, n),
            )
            act[g] = Composite(
                action=Bounded(-c.a_max_mps2, c.a_max_mps2, (b, n, k), dtype=torch.float32),
                shape=(b, n),
            )
            rew[g] = Composite(reward=Unbounded((b, n, 1), dtype=torch.float32), shape=(b, n))
            done[g] = _done_spec(b, n)
        for key in ("done", "terminated", "truncated"):
            done[key] = Categorical(2, (b, 1), dtype=torch.bool)
        self.observation_spec = Composite(obs, shape=(b,))
        self.action_spec = Composite(act, shape=(b,))
        self.reward_spec = Composite(rew, shape=(b,))
        self.done_spec = Composite(done, shape=(b,))

    def _signal_specs(self, b: int) -> tuple[Composite, Composite, Composite, Composite]:
        """Observation, action, reward and done specs of the signal group."""
        n = self._n[signal_agents_mod.SIGNAL_GROUP]
        low, high = signal_agents_mod.observation_bounds(self.config)
        shape = (b, n, signal_agents_mod.OBS_DIM)
        summary = (self.summary_keys if self.summary_group == signal_agents_mod.SIGNAL_GROUP
                   else ())
        info = {key: Unbounded((b, n), dtype=torch.float32)
                for key in (*signal_agents_mod.SIGNAL_REWARD_TERMS, *summary)}
        obs = Composite(
            observation=Bounded(torch.from_numpy(np.broadcast_to(low, shape).copy()),
                                torch.from_numpy(np.broadcast_to(high, shape).copy()), shape,
                                dtype=torch.float32),
            info=Composite(info, shape=(b, n)),
            shape=(b, n),
        )
        act = Composite(action=Categorical(signal_agents_mod.N_PHASES, (b, n),
                                           dtype=torch.int64), shape=(b, n))
        rew = Composite(reward=Unbounded((b, n, 1), dtype=torch.float32), shape=(b, n))
        return obs, act, rew, _done_spec(b, n)

    # ------------------------------------------------------------------------------------
    def _set_seed(self, seed: int | None) -> None:
        # As PettingZooWrapper does: a seeded reset now; the next reset draws the next seed.
        self._batched.reset(seed=None if seed is None else int(seed))

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        mask = _reset_mask(tensordict, self.groups, self.batch_size[0])
        env = self._batched
        if env.continuous and mask is not None and env.started and kwargs.get("seed") is None:
            step = env.start_chunk(mask)  # the next chunk of one continuing simulation
        elif mask is None or mask.all():
            step = env.reset(seed=kwargs.get("seed"))
        else:
            step = env.reset_at(mask)
        return self._pack(step, with_reward=False)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        edge = cloud = None
        if "edge" in self.groups:
            edge = self._action(tensordict, "edge")
        if "cloud" in self.groups:
            cloud = self._action(tensordict, "cloud").reshape(
                self.batch_size[0], *self.config.cloud_action_shape)
        n = self.raw_edge_period
        raw = None
        if n and edge is not None:
            raw = np.full(self.batch_size[0], self._steps_taken % n == n - 1)
        self._steps_taken += 1
        signal = None
        if signal_agents_mod.SIGNAL_GROUP in self.groups:
            signal = self._action(tensordict, signal_agents_mod.SIGNAL_GROUP)
        step = self._batched.step(
            None if edge is None else edge.astype(np.float64, copy=False),
            None if cloud is None else cloud.astype(np.float64, copy=False),
            signal_action=signal, raw_edge=raw,
        )
        return self._pack(step, with_reward=True)

    def _action(self, tensordict: TensorDictBase, group: str) -> np.ndarray:
        """``(group, "action")`` of ``tensordict`` as a numpy array (checked by the batched
        env's action rule); a ``KeyError`` naming the key if it is missing."""
        action = tensordict.get((group, "action"), None)
        if action is None:
            raise KeyError(f"({group!r}, 'action'): missing; the env's groups "
                           f"{list(self.groups)} each need an action at every step")
        return action.detach().cpu().numpy()

    # ------------------------------------------------------------------------------------
    def _pack(self, step: BatchStep, with_reward: bool) -> TensorDictBase:
        b = self.batch_size[0]
        summary = self._batched.summary() if self.summary_keys else {}
        trunc = torch.from_numpy(step.truncated).unsqueeze(-1)  # (B, 1)
        term = torch.from_numpy(step.terminated).unsqueeze(-1)
        done = trunc | term
        out: dict[str, Any] = {"done": done, "terminated": term, "truncated": trunc}
        for g in self.groups:
            n = self._n[g]
            if g == signal_agents_mod.SIGNAL_GROUP:
                out[g] = self._pack_signal(step, with_reward, summary, done, term, trunc)
                continue
            if g == "edge":
                o, m, r, terms = step.edge_obs, step.edge_mask, step.edge_reward, step.edge_terms
            else:  # one agent per cloud graph, each with the network's reward
                k = self._k[g]
                o = step.cloud_obs.reshape(b, n, k, k, 3)
                m = step.cloud_mask.reshape(b, n, k)
                r = np.broadcast_to(step.cloud_reward[:, None], (b, n))
                terms = {key: np.broadcast_to(v[:, None], (b, n))
                         for key, v in step.cloud_terms.items()}
            mask = torch.from_numpy(m)
            info = {k: _f32(terms[k]) for k in REWARD_TERMS}
            if g == self.summary_group:
                for key in self.summary_keys:
                    info[key] = _f32(summary[key])[:, None].expand(b, n)
            info["mask"] = mask
            if g == "cloud" and self._holds_cloud:
                info["decides"] = torch.from_numpy(self._batched.cloud_decides)[:, None].expand(
                    b, n)
            td = {
                "observation": torch.from_numpy(o),
                "mask": mask,
                "info": TensorDict(info, batch_size=(b, n)),
                "done": done[:, None].expand(b, n, 1),
                "terminated": term[:, None].expand(b, n, 1),
                "truncated": trunc[:, None].expand(b, n, 1),
            }
            if with_reward:
                td["reward"] = _f32(r).unsqueeze(-1)
            out[g] = TensorDict(td, batch_size=(b, n))
        return TensorDict(out, batch_size=(b,), device=self.device)

    def _pack_signal(self, step: BatchStep, with_reward: bool, summary: dict[str, np.ndarray],
                     done: torch.Tensor, term: torch.Tensor, trunc: torch.Tensor
                     ) -> TensorDict:
        """The signal group's entries of one step."""
        b, n = self.batch_size[0], self._n[signal_agents_mod.SIGNAL_GROUP]
        info = {k: _f32(step.signal_terms[k]) for k in signal_agents_mod.SIGNAL_REWARD_TERMS}
        if self.summary_group == signal_agents_mod.SIGNAL_GROUP:
            for key in self.summary_keys:
                info[key] = _f32(summary[key])[:, None].expand(b, n)
        td = {
            "observation": torch.from_numpy(step.signal_obs),
            "info": TensorDict(info, batch_size=(b, n)),
            "done": done[:, None].expand(b, n, 1),
            "terminated": term[:, None].expand(b, n, 1),
            "truncated": trunc[:, None].expand(b, n, 1),
        }
        if with_reward:
            td["reward"] = _f32(step.signal_reward).unsqueeze(-1)
        return TensorDict(td, batch_size=(b, n))

    def close(self, *, raise_if_closed: bool = True) -> None:
        """Nothing to release (numpy arrays only)."""
        self.is_closed = True


def _done_spec(b: int, n: int) -> Composite:
    """The done, terminated and truncated flags of a group of ``n`` agents."""
    return Composite({key: Categorical(2, (b, n, 1), dtype=torch.bool)
                      for key in ("done", "terminated", "truncated")}, shape=(b, n))


def _f32(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.asarray(a, dtype=np.float32))


def _reset_mask(
    tensordict: TensorDictBase | None, groups: Sequence[str], batch: int
) -> np.ndarray | None:
    """(B,) bool of the environments to reset from the ``"_reset"`` entries (None: all)."""
    if tensordict is None:
        return None
    found = None
    for key in ("_reset", *((g, "_reset") for g in groups)):
        val = tensordict.get(key, None)
        if val is None:
            continue
        val = val.reshape(batch, -1).any(-1)
        found = val if found is None else found | val
    return None if found is None else found.cpu().numpy()
