"""Evaluate a control scheme on the MiVeCC ParallelEnv and summarise the episode.

:func:`evaluate_scheme` runs one episode of ``mivecc_v0.parallel_env`` for a fixed number of
steps and returns the traffic metrics of :func:`mivecc_env.metrics.episode_summary` together
with the run's settings and its speed (env steps per wall-clock second).

Schemes: ``E`` (end-node rules only), ``EE`` (rules + edge coordinators), ``EEC`` (rules + edge
+ cloud coordinators) and the comparators of :data:`COMPARATORS` (``fixed-time``, ``actuated``,
``max-pressure`` signals with IDM car-following, ``reservation`` (AIM FCFS), ``optimisation``
(DOOC-style), ``pa-dqn`` and ``coder`` (signal agents with a learned policy,
``policies["signal"]``), ``comaddpg`` (the vehicles in the control areas act with a learned
policy, ``policies["vehicle"]``, executed without the rules); ``signalized`` is the earlier
name of ``fixed-time``). The
coordinators' actions come from ``policies``: a mapping ``"edge"`` / ``"cloud"`` -> callable
``policy(obs_batch, mask) -> actions`` with ``obs_batch`` of shape ``(n_agents, K, K, 3)``,
``mask`` ``(n_agents, K)`` and ``actions`` ``(n_agents, K)`` in ``[-a_max, a_max]`` m/s^2
(clipped to the box), a pure function of its inputs (``n_agents`` may be any number of rows:
:func:`evaluate_batch` with ``stack_policies=True`` stacks environments where a check finds
that exact). A coordinator the scheme uses but for which no policy is given acts with zeros;
the result then says ``"coordinator_actions": "zero"`` and a warning is printed.

:func:`evaluate_batch` runs several seeds and densities of one configuration as one batch
(:class:`mivecc_env.batched.BatchedMiVeCCEnv`): the result of each (density, seed) is what
:func:`evaluate_scheme` gives for it (bit for bit, unless ``stack_policies=True``, below), in
a fraction of the time. By default every policy is called once per environment and step, with
the B = 1 shapes, so each environment's trajectory is the same whatever the batch it runs in.
``stack_policies=True`` is faster: a policy is then called once on all environments' graphs
stacked where a check on random graphs finds that this gives the bits of one call per
environment (:func:`stacking_is_exact`, checked before the run). That check is a sample, not a
proof (a network's float rounding can depend on the batch size): on real graphs a stacked call
rounded one action one unit in the last place differently in rare steps, with two torch threads
(the shipped released shield edge on 3x3) and with one (the same edge on 1x1), and the run then
left the environment's run alone (``benchmarks/stacking_audit.py``).

Example:
    >>> r = evaluate_scheme("E", 1, 1, 900, steps=50, seed=0, progress=False)
    >>> r["scheme"], r["steps"]
    ('E', 50)
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from mivecc_agents.comaddpg_settings import vehicle_agent_fields
from mivecc_env import mivecc_v0
from mivecc_env.config import ConfigError, MiVeCCConfig
from mivecc_env.no_data import mark_no_data
from mivecc_env.parallel_env import CLOUD_AGENT
from mivecc_env.sim.checks import check_positive_int
from mivecc_env.vehicle_agents import observe_vehicles, vehicle_accelerations, vehicle_commands

#: A coordinator policy: (obs_batch (n, K, K, 3), mask (n, K)) -> actions (n, K).
Policy = Callable[[np.ndarray, np.ndarray], np.ndarray]

#: Config overrides of every non-MiVeCC scheme (``signalized`` = ``fixed-time``, kept as the
#: baseline's earlier name); ``docs/comparators.md`` describes them.
COMPARATORS: dict[str, dict[str, str]] = {
    "fixed-time": {"control": "signalized", "signal_controller": "fixed-time"},
    "actuated": {"control": "signalized", "signal_controller": "actuated"},
    "max-pressure": {"control": "signalized", "signal_controller": "max-pressure"},
    "reservation": {"control": "reservation"},
    "optimisation": {"control": "optimisation"},
    "pa-dqn": {"control": "signalized"},
    "coder": {"control": "signalized"},
    "comaddpg": vehicle_agent_fields(),
    "signalized": {"control": "signalized", "signal_controller": "fixed-time"},
}
#: Comparators whose signal agents act with a learned policy (``policies["signal"]``:
#: :mod:`mivecc_agents.signal_dqn` for PA-DQN, :mod:`mivecc_agents.coder` for Coder), its choice
#: held between decisions.
LEARNED_SIGNAL_SCHEMES: tuple[str, ...] = ("pa-dqn", "coder")
#: Comparators whose vehicles are agents acting with a learned policy (``policies["vehicle"]``:
#: :mod:`mivecc_agents.comaddpg`), executed unmodified inside the control areas.
VEHICLE_AGENT_SCHEMES: tuple[str, ...] = ("comaddpg",)

#: Scheme names accepted by :func:`evaluate_scheme`: MiVeCC's and the comparators'.
SCHEMES: tuple[str, ...] = ("E", "EE", "EEC", *COMPARATORS)

#: Keys every result of :func:`evaluate_scheme` has (besides the episode summary's).
RESULT_KEYS: tuple[str, ...] = (
    "avg_travel_velocity_mps", "avg_travel_velocity_no_wait_mps", "upper_bound_mps",
    "mean_speed_mps", "throughput", "throughput_vph", "collisions", "collided_vehicles",
    "released_check_collisions", "backlog", "mean_trip_time_s", "steps", "steps_per_s",
    "scheme", "rows", "cols", "density", "seed", "end_rule", "same_lane_rule",
    "released_velocity_mps", "min_ttc_s", "ttc_p1_s", "min_pet_s", "pet_under_1s", "min_distance_m",
)

#: Config fields reported with every result (the readings of ambiguous parts of the paper).
CONFIG_READINGS: tuple[str, ...] = (
    "model", "control", "signal_controller", "comparator_entry", "signal_keep_clear",
    "end_rule", "same_lane_rule",
    "edge_sv_gate", "sv_acc_source", "omega", "cloud_pick_population", "cloud_graphs",
    "cloud_period", "safety_shield",
)

ZERO_ACTION_WARNING = (
    "warning: scheme {scheme} runs with zero coordinator actions for {missing} because no "
    "trained policy was given"
)


def scheme_overrides(scheme: str, config_overrides: dict[str, Any]) -> dict[str, Any]:
    """Config overrides that select ``scheme``: a MiVeCC scheme, or a comparator's control mode.

    Comparators (``fixed-time``, ``reservation``, ...) run with the rules-only scheme ``E`` and
    their control fields from :data:`COMPARATORS` (CoMADDPG's vehicles send their command as
    the edge action: scheme ``EE``).
    """
    overrides = dict(config_overrides)
    if scheme in COMPARATORS:
        overrides.update({"scheme": "E", **COMPARATORS[scheme]})
    else:
        overrides["scheme"] = scheme
    return overrides


def shipped_comparator_policies(scheme: str, rows: int, cols: int) -> dict[str, Any]:
    """The shipped learned policy a comparator runs with: ``{"signal": ...}`` for ``pa-dqn``
    and ``coder`` (the grid's, :mod:`mivecc_agents.signal_policy_files`), ``{"vehicle": ...}``
    for ``comaddpg``, ``{}`` for every other scheme."""
    if scheme in LEARNED_SIGNAL_SCHEMES:
        from mivecc_agents.signal_policy_files import load_signal_policy, shipped_signal_policy_path

        return {"signal": load_signal_policy(shipped_signal_policy_path(scheme, rows, cols))}
    if scheme in VEHICLE_AGENT_SCHEMES:
        from mivecc_agents.comaddpg import SHIPPED_PATH, CoMADDPGPolicy

        return {"vehicle": CoMADDPGPolicy.load(SHIPPED_PATH)}
    return {}


def _needed_policies(scheme: str) -> tuple[str, ...]:
    """Coordinator kinds whose actions a scheme uses."""
    return {"EE": ("edge",), "EEC": ("edge", "cloud")}.get(scheme, ())


def adopt_cloud_period(
    policies: Mapping[str, Policy], overrides: dict[str, Any], scheme: str
) -> bool:
    """Run a learned cloud at the ``cloud_period`` it was trained with (recorded in its
    checkpoint's config, ``policy.config``) unless ``overrides`` name one: adds it to
    ``overrides`` and returns True if it is not the default 1. Only scheme EEC uses the
    cloud. Used by :func:`evaluate_scheme`, :func:`evaluate_batch` and ``mivecc evaluate``."""
    cloud = policies.get("cloud")
    if scheme != "EEC" or cloud is None or "cloud_period" in overrides:
        return False
    period = int((getattr(cloud, "config", None) or {}).get("cloud_period", 1))
    if period == 1:
        return False
    overrides["cloud_period"] = period
    return True


def _check_args(
    scheme: str, steps: Any, seed: Any, policies: Mapping[str, Policy] | None,
    overrides: Mapping[str, Any],
) -> None:
    """Raise :class:`ConfigError` naming the first bad argument."""
    if scheme not in SCHEMES:
        raise ConfigError(f"scheme: must be one of {list(SCHEMES)}, got {scheme!r}")
    if isinstance(steps, bool) or not isinstance(steps, int | np.integer) or steps < 1:
        raise ConfigError(f"steps: must be an integer >= 1, got {steps!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ConfigError(f"seed: must be an integer >= 0, got {seed!r}")
    for name, instead in (("density_vplh", "density"), ("max_steps", "steps"),
                          ("scheme", "scheme"), ("rows", "rows"), ("cols", "cols")):
        if name in overrides:
            raise ConfigError(f"{name}: give it as the {instead!r} argument, not as an override")
    for name, value in COMPARATORS.get(scheme, {}).items():
        if overrides.get(name, value) != value:
            raise ConfigError(f"{name}: scheme {scheme!r} needs {name}={value!r}, "
                              f"got {overrides[name]!r}")
    if scheme in ("E", "EE", "EEC") and overrides.get("control", "unsignalized") != "unsignalized":
        raise ConfigError(f"control: scheme {scheme!r} needs control='unsignalized', "
                          f"got {overrides['control']!r}")
    if scheme in LEARNED_SIGNAL_SCHEMES and (policies or {}).get("signal") is None:
        raise ConfigError(f"policies: scheme {scheme!r} needs policies['signal'], e.g. "
                          "mivecc_agents.signal_policy_files.load_signal_policy("
                          f"shipped_signal_policy_path({scheme!r}, rows, cols))")
    if scheme in VEHICLE_AGENT_SCHEMES and (policies or {}).get("vehicle") is None:
        raise ConfigError(f"policies: scheme {scheme!r} needs policies['vehicle'], e.g. "
                          "mivecc_agents.comaddpg.CoMADDPGPolicy.load("
                          "mivecc_agents.comaddpg.SHIPPED_PATH)")
    if policies is not None:
        unknown = set(policies) - {"edge", "cloud", "signal", "vehicle"}
        if unknown:
            raise ConfigError(f"policies: keys must be 'edge', 'cloud', 'signal' and/or "
                              f"'vehicle', got {sorted(unknown)}")
        for kind, users in (("signal", LEARNED_SIGNAL_SCHEMES),
                            ("vehicle", VEHICLE_AGENT_SCHEMES)):
            if kind in policies and scheme not in users:
                raise ConfigError(f"policies: {kind!r} is used by scheme(s) {list(users)} "
                                  f"only, not {scheme!r}")
        for kind, policy in policies.items():
            if policy is not None and not callable(policy):
                raise ConfigError(f"policies: {kind!r} must be a callable (obs, mask) -> "
                                  f"actions or None, got {type(policy).__name__}")
        signal = policies.get("signal")
        if signal is not None and not getattr(signal, "decision_period_s", 0) > 0:
            raise ConfigError("policies: 'signal' must have a decision_period_s > 0 [s] "
                              "(a SignalDQNPolicy or a CoderPolicy)")
        for kind in ("signal", "vehicle"):
            policy = policies.get(kind)
            if getattr(policy, "scheme", scheme) != scheme:
                raise ConfigError(f"policies: {kind!r} is a policy of scheme "
                                  f"{policy.scheme!r}, not of {scheme!r}")
        vehicle = policies.get("vehicle")
        if vehicle is not None and not (isinstance(getattr(vehicle, "k", None), int)
                                        and vehicle.k >= 2):
            raise ConfigError("policies: 'vehicle' must have an integer k >= 2 (the rows of "
                              "its observations; a CoMADDPGPolicy)")


def _coordinator_actions(
    scheme: str, needed: Sequence[str], policies: Mapping[str, Policy], warn: bool,
) -> str:
    """``"unused"`` (the scheme has no coordinator), ``"zero"`` (one it uses has no policy:
    it acts with zeros, said on stderr if ``warn``) or ``"policy"``."""
    missing = [kind for kind in needed if kind not in policies]
    if missing and warn:
        print(ZERO_ACTION_WARNING.format(scheme=scheme, missing=" and ".join(missing)),
              file=sys.stderr)
    return "unused" if not needed else ("zero" if missing else "policy")


def _held_phases(scheme: str, policies: Mapping[str, Any], cfg: MiVeCCConfig) -> Any:
    """The learned signal policy of ``scheme`` with its choices held between decisions
    (:class:`mivecc_agents.signal_dqn.HeldPhases`), or None for every other scheme. A policy
    with a ``for_grid(rows, cols)`` method (Coder's) is set to the grid of ``cfg`` first."""
    if scheme not in LEARNED_SIGNAL_SCHEMES:
        return None
    from mivecc_agents.signal_dqn import HeldPhases, decision_steps

    policy = policies["signal"]
    if hasattr(policy, "for_grid"):
        policy = policy.for_grid(cfg.rows, cfg.cols)
    return HeldPhases(policy, decision_steps(policy.decision_period_s, cfg.dt_s))


def _progress_bar(progress: bool, steps: int, desc: str) -> Any:
    """A tqdm bar of ``steps`` env steps on stderr, or None without ``progress``."""
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=int(steps), desc=desc, unit="step", file=sys.stderr, mininterval=0.5,
                leave=False)


def _close_bar(bar: Any, steps: int) -> None:
    """Complete the bar (it is updated in chunks of steps) and close it."""
    if bar is not None:
        bar.update(int(steps) - bar.n)
        bar.close()


def _result(
    summary: Mapping[str, float], cfg: Any, scheme: str, steps: int, wall: float,
    env_steps: int, density: float, seed: int, coordinator_actions: str, **extra: Any,
) -> dict[str, Any]:
    """One run's result: its episode summary (NaN where nothing was measured yet), the run's
    settings and speed (``env_steps`` per wall-clock second), and the config readings."""
    result = mark_no_data(summary, cfg)  # a copy, NaN where nothing was measured yet
    result.update(
        steps=int(steps),
        steps_per_s=float(env_steps / wall) if wall > 0 else math.inf,
        wall_s=float(wall),
        **extra,
        scheme=scheme,
        rows=int(cfg.rows),
        cols=int(cfg.cols),
        density=density,
        seed=seed,
        coordinator_actions=coordinator_actions,
    )
    for name in CONFIG_READINGS:
        result[name] = getattr(cfg, name)
    return result


def batch_actions(
    policy: Policy | None, obs: np.ndarray, mask: np.ndarray, a_max: float, stacked: bool,
    envs: Sequence[int] | None = None,
) -> np.ndarray:
    """(B, n, K) float64 actions [m/s^2] of the environments ``envs`` (default: all; zeros
    for the others, and for all without a ``policy``), clipped to ``a_max``: one call on all
    of them stacked if ``stacked`` and ``envs`` is the whole batch, else one call per
    environment (B = 1 shapes).

    Args:
        obs: (B, n, K, K, 3) graphs; mask: (B, n, K) real columns.
    """
    b = mask.shape[0]
    envs = range(b) if envs is None else envs
    out = np.zeros(mask.shape, np.float32)
    if policy is not None:
        if stacked and len(envs) == b:
            rows = mask.reshape(-1, mask.shape[-1])
            a = np.asarray(policy(obs.reshape(-1, *obs.shape[2:]), rows), dtype=np.float32)
            if a.shape != rows.shape:
                raise ValueError(f"policy returned shape {a.shape}, expected {rows.shape}")
            out[:] = a.reshape(out.shape)
        else:
            for i in envs:
                a = np.asarray(policy(obs[i], mask[i]), dtype=np.float32)
                if a.shape != mask[i].shape:
                    raise ValueError(
                        f"policy returned shape {a.shape}, expected {mask[i].shape}")
                out[i] = a
        np.clip(out, -a_max, a_max, out=out)
    return out.astype(np.float64)


def evaluate_scheme(
    scheme: str,
    rows: int,
    cols: int,
    density: float,
    steps: int,
    seed: int,
    *,
    policies: Mapping[str, Policy] | None = None,
    progress: bool = True,
    warn: bool = True,
    step_hook: Callable[[Any, int], None] | None = None,
    **config_overrides: Any,
) -> dict[str, Any]:
    """Run one episode of ``steps`` env steps and return its metrics and settings.

    Args:
        scheme: one of :data:`SCHEMES`: ``"E"``, ``"EE"``, ``"EEC"``, ``"fixed-time"``,
            ``"actuated"``, ``"max-pressure"``, ``"reservation"``, ``"optimisation"``,
            ``"pa-dqn"``, ``"coder"``, ``"comaddpg"`` (``"signalized"`` = ``"fixed-time"``).
            All run on the same seeded demand.
        rows: intersection rows of the grid.
        cols: intersection columns of the grid.
        density: arrival rate per entry lane [veh/lane/h].
        steps: env steps to run (the episode's ``max_steps``).
        seed: seed of ``env.reset``.
        policies: ``"edge"`` / ``"cloud"`` -> policy callable (see the module docstring);
            a coordinator that the scheme uses and that has no policy acts with zeros.
            ``"signal"``: the learned signal policy of ``pa-dqn`` or ``coder`` (required
            there; a :class:`mivecc_agents.signal_dqn.SignalDQNPolicy`, a
            :class:`mivecc_agents.coder.CoderPolicy` or any callable ``(n, 15)
            observations -> (n,)`` phases with a ``decision_period_s``). ``"vehicle"``: the
            vehicles' policy of ``comaddpg`` (required there; a
            :class:`mivecc_agents.comaddpg.CoMADDPGPolicy` or any callable ``(n, k, 3)
            observations -> (n,)`` accelerations with an integer ``k``); run through
            :func:`evaluate_batch` (``step_hook`` is not available there).
        progress: show a tqdm progress bar on stderr.
        warn: print the zero-coordinator-action warning to stderr when it applies.
        step_hook: called as ``step_hook(env, t)`` after the reset (``t = 0``) and after every
            env step (``t`` = steps taken), to read the env's state (tracing); None: no calls.
        **config_overrides: further :class:`~mivecc_env.config.MiVeCCConfig` fields.

    Returns:
        The episode summary (:data:`mivecc_env.metrics.SUMMARY_KEYS`) plus ``steps``,
        ``steps_per_s`` (env steps per wall-clock second of the stepping loop), ``wall_s``,
        ``scheme``, ``rows``, ``cols``, ``density``, ``seed``, ``coordinator_actions``
        (``"policy"``, ``"zero"`` or ``"unused"``) and the config readings
        (:data:`CONFIG_READINGS`).

    Raises:
        ConfigError: a bad scheme, step count, seed or config value (the message names it).
    """
    _check_args(scheme, steps, seed, policies, config_overrides)
    if scheme in VEHICLE_AGENT_SCHEMES:  # the batched env steps vehicle agents
        if step_hook is not None:
            raise ConfigError(f"step_hook: not available for scheme {scheme!r}; use "
                              "evaluate_batch(on_step=...)")
        result = evaluate_batch(scheme, rows, cols, density, steps, [seed], policies=policies,
                                progress=progress, warn=warn, **config_overrides)[0]
        del result["batch_size"]
        return result
    policies = dict(policies or {})
    overrides = scheme_overrides(scheme, config_overrides)
    adopt_cloud_period(policies, overrides, overrides["scheme"])
    learned_signals = scheme in LEARNED_SIGNAL_SCHEMES
    env = mivecc_v0.parallel_env(
        rows=rows, cols=cols, density=density, max_steps=int(steps),
        signal_agents=learned_signals, **overrides
    )
    cfg = env.config

    needed = _needed_policies(cfg.scheme)
    coordinator_actions = _coordinator_actions(scheme, needed, policies, warn)
    if learned_signals:
        coordinator_actions = "policy"
    edge_policy = policies.get("edge") if "edge" in needed else None
    cloud_policy = policies.get("cloud") if "cloud" in needed else None
    held = _held_phases(scheme, policies, cfg)
    signal_agents = list(env.signal_agents)

    # Built once: the zero actions of every coordinator (policy outputs overwrite entries per
    # step; the signal agents' phases are set on every step when they act).
    actions = {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.possible_agents
               if a not in signal_agents}
    edge_agents = list(env.edge_agents)
    a_max = cfg.a_max_mps2

    def act(policy: Policy, agents: list[str], obs: dict, infos: dict) -> None:
        # one (K, K, 3) graph per row (the per-lane cloud has several per agent)
        mask = np.stack([infos[a]["mask"] for a in agents])
        k = mask.shape[-1]
        rows = mask.reshape(-1, k)
        obs_batch = np.stack([obs[a] for a in agents]).reshape(-1, k, k, 3)
        out = np.asarray(policy(obs_batch, rows), dtype=np.float32)
        if out.shape != rows.shape:
            raise ValueError(f"policy returned shape {out.shape}, expected {rows.shape}")
        np.clip(out, -a_max, a_max, out=out)
        out = out.reshape(mask.shape)
        for i, a in enumerate(agents):
            actions[a] = out[i]

    obs, infos = env.reset(seed=int(seed))
    if step_hook is not None:
        step_hook(env, 0)
    bar = _progress_bar(progress, steps, f"{scheme} {rows}x{cols} @{density:g}")
    step, update = env.step, (bar.update if bar is not None else None)
    uses_policy = edge_policy is not None or cloud_policy is not None
    chunk = 100
    t0 = time.perf_counter()
    for i in range(int(steps)):
        if uses_policy:
            if edge_policy is not None:
                act(edge_policy, edge_agents, obs, infos)
            if cloud_policy is not None and env.batched.cloud_decides[0]:
                act(cloud_policy, [CLOUD_AGENT], obs, infos)  # ignored on other steps
        if held is not None and held.due(i):  # the phases stay in `actions` in between
            phases = held.decide(np.stack([obs[a] for a in signal_agents])[None])[0]
            actions.update(zip(signal_agents, phases.tolist(), strict=True))
        obs, _, _, _, infos = step(actions)
        if step_hook is not None:
            step_hook(env, i + 1)
        if update is not None and (i + 1) % chunk == 0:
            update(chunk)
    wall = time.perf_counter() - t0
    _close_bar(bar, steps)

    result = _result(env.summary(), cfg, scheme, steps, wall, steps, float(cfg.density_vplh),
                     int(seed), coordinator_actions)
    env.close()
    return result


def evaluate_batch(
    scheme: str,
    rows: int,
    cols: int,
    densities: float | Sequence[float],
    steps: int,
    seeds: Sequence[int],
    *,
    policies: Mapping[str, Policy] | None = None,
    progress: bool = True,
    warn: bool = True,
    on_step: Callable[[Any, np.ndarray | None, np.ndarray | None, Any], None] | None = None,
    stack_policies: bool = False,
    **config_overrides: Any,
) -> list[dict[str, Any]]:
    """Run every (density, seed) pair of one configuration as one batch of environments.

    Args:
        scheme, rows, cols, steps, policies, progress, warn, config_overrides: as for
            :func:`evaluate_scheme`.
        densities: one density or several [veh/lane/h].
        seeds: the seeds; each density runs every seed.
        on_step: called after every step as ``on_step(before, edge, cloud, after)``: the
            :class:`~mivecc_env.batched.BatchStep` the actions were chosen on, the given
            (B, n_edge, K) edge and (B, K) cloud actions [m/s^2] (``None`` where the scheme
            has none; NaN cloud rows for the environments whose cloud does not decide on
            this step, ``cloud_period`` > 1: their policy is not called) and the step's
            result (rewards, next observations); ``comaddpg``: ``edge`` and ``cloud`` are
            None.
        stack_policies: ``False`` (default): one call per environment, so no environment's
            trajectory depends on the batch; ``True``: one call on all environments where
            :func:`stacking_is_exact` says that is exact (faster; rare one-ulp differences on
            real graphs remain possible; module docstring).

    Returns:
        One result per (density, seed), densities outer and seeds inner, each with the keys of
        :func:`evaluate_scheme` (the same values for the traffic metrics, bit for bit with
        ``stack_policies=False``; a stacked call can leave that in rare steps); ``steps_per_s`` is
        the environment steps of the whole batch per wall-clock second and ``batch_size`` the
        number of environments B.

    Raises:
        ConfigError: a bad scheme, step count, seed, density or config value.
    """
    from mivecc_env.batched import BatchedMiVeCCEnv

    dens = [densities] if isinstance(densities, int | float | np.number) else list(densities)
    seeds = list(seeds)
    if not dens or not seeds:
        raise ConfigError(f"densities and seeds: need at least one each, got {dens}, {seeds}")
    try:
        dens = [float(d) for d in dens]
    except (TypeError, ValueError):
        raise ConfigError(f"densities: must be numbers [veh/lane/h], got {dens!r}") from None
    for seed in seeds:
        _check_args(scheme, steps, seed, policies, config_overrides)
    policies = dict(policies or {})
    overrides = scheme_overrides(scheme, config_overrides)
    adopt_cloud_period(policies, overrides, overrides["scheme"])
    pairs = [(d, int(s)) for d in dens for s in seeds]
    vehicle_policy = policies["vehicle"] if scheme in VEHICLE_AGENT_SCHEMES else None
    needed = () if vehicle_policy is not None else _needed_policies(overrides["scheme"])
    env = BatchedMiVeCCEnv(
        batch_size=len(pairs), densities=[d for d, _ in pairs], observe=set(needed),
        rows=rows, cols=cols, density=dens[0], max_steps=int(steps),
        signal_agents=scheme in LEARNED_SIGNAL_SCHEMES, **overrides,
    )
    cfg = env.config
    coordinator_actions = _coordinator_actions(scheme, needed, policies, warn)
    held = _held_phases(scheme, policies, cfg)
    if held is not None or vehicle_policy is not None:
        coordinator_actions = "policy"
    a_max = cfg.a_max_mps2
    b = len(pairs)

    step = env.reset(seed=[s for _, s in pairs])
    bar = _progress_bar(progress, steps, f"{scheme} {rows}x{cols} x{b}")
    edge_policy, cloud_policy = policies.get("edge"), policies.get("cloud")
    # one call for the whole batch where it gives the per-environment calls' bits
    edge_stacked = stack_policies and "edge" in needed and stacking_is_exact(
        edge_policy, b, env.n_edge, env.k_edge)
    n_cloud = cfg.n_cloud_graphs  # the cloud's graphs per environment (1, or one per lane)
    cloud_stacked = stack_policies and "cloud" in needed and stacking_is_exact(
        cloud_policy, b, n_cloud, env.k_cloud)
    chunk = 100
    t0 = time.perf_counter()
    for i in range(int(steps)):
        edge = cloud = None
        if vehicle_policy is not None:  # the vehicles in the control areas are the agents
            agents = observe_vehicles(env.sim, vehicle_policy.k)
            accel = vehicle_accelerations(vehicle_policy, agents, b, a_max)
            before, step = step, env.step_vehicles(vehicle_commands(agents, accel, b))
            if on_step is not None:
                on_step(before, None, None, step)
            if bar is not None and (i + 1) % chunk == 0:
                bar.update(chunk)
            continue
        if "edge" in needed:
            edge = batch_actions(edge_policy, step.edge_obs, step.edge_mask, a_max,
                                 edge_stacked)
        if "cloud" in needed:
            # the env ignores the cloud action of an environment that does not decide on this
            # step (cloud_period > 1): its policy is not called there
            decides = env.cloud_decides
            k = env.k_cloud
            cloud = batch_actions(cloud_policy, step.cloud_obs.reshape(b, n_cloud, k, k, 3),
                                  step.cloud_mask.reshape(b, n_cloud, k), a_max, cloud_stacked,
                                  np.flatnonzero(decides).tolist()
                                  ).reshape(b, *env.cloud_action_shape)
        signal = None
        if held is not None:
            signal = held.decide(step.signal_obs) if held.due(i) else held.phases
        before, step = step, env.step(edge, cloud, signal_action=signal)
        if on_step is not None:
            on_step(before, edge, cloud if cloud is None or decides.all()
                    else np.where(decides.reshape(-1, *[1] * (cloud.ndim - 1)), cloud, np.nan),
                    step)
        if bar is not None and (i + 1) % chunk == 0:
            bar.update(chunk)
    wall = time.perf_counter() - t0
    _close_bar(bar, steps)

    summary = env.summary()
    results = []
    for j, (density, seed) in enumerate(pairs):
        results.append(_result({k: float(v[j]) for k, v in summary.items()}, cfg, scheme, steps,
                               wall, b * steps, density, seed, coordinator_actions,
                               batch_size=b))
    return results


def aggregate(results: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Mean and (population) standard deviation over runs of every numeric key.

    A key on which all runs agree keeps its value (standard deviation 0 when numeric);
    ``seed`` becomes the list of seeds; other non-numeric keys that differ are left out. A
    numeric key without data in some run (NaN or inf, e.g. ``min_ttc_s`` before any vehicle
    pair was measured) has no mean or spread: both are NaN (``null`` in the CLI's JSON), with
    no numpy warning.
    """
    mean: dict[str, Any] = {}
    std: dict[str, Any] = {}
    for key in results[0]:
        values = [r.get(key) for r in results]
        numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)
        if key == "seed":
            mean[key] = std[key] = values
        elif numeric and not all(v == values[0] for v in values):
            arr = np.asarray(values, dtype=np.float64)
            if np.isfinite(arr).all():
                mean[key], std[key] = float(arr.mean()), float(arr.std())
            else:
                mean[key] = std[key] = math.nan
        elif all(v == values[0] for v in values):
            mean[key] = values[0]
            std[key] = 0.0 if numeric else values[0]
    return {"mean": mean, "std": std}


def stacking_is_exact(policy: Policy | None, n_envs: int, n_agents: int, k: int) -> bool:
    """Whether one call of ``policy`` on the graphs of ``n_envs`` environments stacked gives,
    bit for bit, what one call per environment gives.

    A network's float rounding can depend on the batch size it is called with (which shipped
    actors stack depends on the CPU and the thread count; ``docs/training.md``, "Evaluation").
    It is checked once per shape, on random graphs and masks (a
    generator seeded here). That is a sample, not a proof: whether two summation orders round
    alike depends on the values: the shipped released shield edge, which passes this check,
    rounded one action of real graphs differently in 14 of 9000 environment-steps with two
    torch threads (3x3, 6 environments; session 33) and in 183 of 63 000 with one (1x1, 21
    environments; session 34; ``benchmarks/stacking_audit.py``). ``evaluate_batch`` stacks
    only with ``stack_policies=True``. A policy that fails on the stacked shapes is not
    stacked.

    Args:
        n_envs / n_agents / k: the batch, the agents per environment, the graph size K
            (each at least 1: a ``ValueError`` names the first that is not).
    """
    for name, value in (("n_envs", n_envs), ("n_agents", n_agents), ("k", k)):
        check_positive_int(name, value)
    if policy is None or n_envs == 1:
        return policy is not None
    rng = np.random.default_rng(0)
    obs = rng.uniform(-1.0, 1.0, (n_envs, n_agents, k, k, 3)).astype(np.float32)
    mask = (rng.uniform(size=(n_envs, n_agents, k)) < 0.9).astype(np.float32)
    try:
        stacked = np.asarray(policy(obs.reshape(-1, k, k, 3), mask.reshape(-1, k)), np.float32)
    except Exception:  # e.g. a policy written for one environment's rows
        return False
    one_by_one = np.concatenate(
        [np.asarray(policy(obs[i], mask[i]), np.float32) for i in range(n_envs)])
    return stacked.shape == one_by_one.shape and stacked.tobytes() == one_by_one.tobytes()
