"""Batch invariance across random feature combinations: a fuzz check of the batched env.

The project promises the same trajectory for the same seed and config, whatever the batch
size. The tests check that for chosen configurations; this script checks it for random
combinations of every choice field of :class:`~mivecc_env.config.MiVeCCConfig` (model preset,
scheme, control mode and signal controller, safety shield, cloud graphs, populations, views and
rewards, the released model's switches, rule readings, ...), numeric fields (geometry, vehicle
and speed bounds, time step, headways, graph sizes, fusion weights, cloud period, gates,
reward weights, comparator parameters), grid sizes, mixed demands, continuous runs, signal agents,
partial resets and the released trainer's raw edge actions.

Each case runs ``B`` environments as one :class:`~mivecc_env.batched.BatchedMiVeCCEnv` and
each of them alone (``B = 1``) with the same seed, demand and actions, and compares at every
step, bit for bit, every array the env returns (graphs, masks, rewards and their terms, signal
agents' arrays, flags, step counts) and the episode summary; outside continuous runs the
PettingZoo ``ParallelEnv`` runs environment 0 too (its actions as agent dicts, with no raw edge
actions there) and its observations, masks, rewards, reward terms, truncations and summary are
compared with the batch's. It also checks that no vehicle is
lost (arrived = queued + in network + exited + collided, per environment, from the simulator's
own counters) and that observations are finite and inside [-1, 1].

Each case also records a SHA-256 digest of the batch's whole trajectory (every array it
returned and its summary, at every step). ``--against RUN.jsonl`` compares the digests with
another run's, case by case: run once as usual and once with ``MIVECC_NO_NUMBA=1`` to check
that the compiled kernels equal the numpy reference paths on every combination.

A case whose drawn configuration the config refuses (two fields that do not go together) is
counted as ``refused`` with the config's message, not run. Any difference or exception
(``error``) exits 1
and names the case; ``--start N --cases 1`` reruns that case alone.

Writes ``batch_fuzz.jsonl`` (one line per case) and ``batch_fuzz.md`` (the summary) under
``--out`` and prints the summary.

Usage:
    python benchmarks/batch_fuzz.py --cases 400 --start 0 --out runs/batch_fuzz
    MIVECC_NO_NUMBA=1 python benchmarks/batch_fuzz.py --cases 400 --start 0 \
        --out runs/batch_fuzz_numpy --against runs/batch_fuzz/batch_fuzz.jsonl
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from mivecc_env import ConfigError, cli_args, mivecc_v0
from mivecc_env.batched import BatchedMiVeCCEnv, BatchStep
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim._numba import HAVE_NUMBA

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "batch_fuzz"

#: Choice fields drawn by the preset (``model``) or separately; every other choice field of
#: the config is drawn from its choices (half of the cases leave each at its default).
NOT_DRAWN = ("model",)
#: Choice fields added to the config after the committed digests were made: drawn last, in this
#: order, from a generator of their own, so every other draw of a case stays as it was.
LATE_CHOICES = ("comparator_entry", "signal_keep_clear")
#: Numeric fields, each drawn in 15 % of the cases from a moderate part of its range:
#: (low, high, integer). Values that do not fit together are refused by the config.
NUMERIC: dict[str, tuple[float, float, bool]] = {
    "segment_length_m": (60.0, 300.0, False),
    "lane_offset_m": (2.0, 8.0, False),
    "vehicle_length_m": (1.0, 5.0, False),
    "v_min_mps": (0.0, 8.0, False),
    "v_max_mps": (8.0, 20.0, False),
    "v_init_mps": (0.0, 15.0, False),
    "a_max_mps2": (1.0, 5.0, False),
    "dt_s": (0.05, 0.2, False),
    "min_headway_s": (0.0, 3.0, False),
    "entry_clearance_m": (0.0, 30.0, False),
    "control_radius_m": (30.0, 150.0, False),
    "projection_window_m": (20.0, 150.0, False),
    "k_edge": (2, 20, True),
    "k_cloud": (2, 80, True),
    "di_n": (1, 10, True),
    "eta": (0.5, 10.0, False),
    "omega": (0.0, 1.0, False),
    "cloud_period": (1, 5, True),
    "shield_gap_m": (0.0, 10.0, False),
    "same_lane_rule_horizon_m": (0.0, 100.0, False),
    "edge_sv_gate": (-10.0, 10.0, False),
    "reward_sv_weight": (0.0, 1.0, False),
    "collision_penalty": (0.0, 20.0, False),
    "signal_green_s": (5.0, 60.0, False),
    "signal_yellow_s": (0.0, 5.0, False),
    "actuated_gap_s": (0.5, 5.0, False),
    "reservation_buffer_s": (0.0, 1.0, False),
    "optimisation_max_vehicles": (1, 8, True),
    "idm_time_headway_s": (0.5, 2.0, False),
}
#: Control modes whose batch may restart single environments (``reset_at``).
RESETTABLE = ("unsignalized", "signalized")


def choice_fields() -> dict[str, tuple[Any, ...]]:
    """Every choice field of the config and its choices (from the field metadata)."""
    return {f.name: f.metadata["choices"] for f in dataclasses.fields(MiVeCCConfig)
            if "choices" in f.metadata and f.name not in (*NOT_DRAWN, *LATE_CHOICES)}


@dataclasses.dataclass(frozen=True)
class Case:
    """One drawn case (everything :func:`run_case` needs, reproducible from ``index``)."""

    index: int
    overrides: dict[str, Any]
    batch_size: int
    seeds: list[int]
    densities: list[float]
    steps: int
    continuous: bool
    signal_agents: bool


def draw_case(index: int) -> Case:
    """The case of number ``index`` (its own generator: the same case on every machine)."""
    rng = np.random.default_rng([index, 0x6D697665])
    kw: dict[str, Any] = {"model": ("paper", "released")[int(rng.integers(2))]}
    for name, choices in choice_fields().items():
        if rng.random() < 0.5:
            kw[name] = choices[int(rng.integers(len(choices)))]
    for name, (lo, hi, integer) in NUMERIC.items():
        if rng.random() < 0.15:
            kw[name] = int(rng.integers(lo, hi + 1)) if integer else float(rng.uniform(lo, hi))
    kw["rows"], kw["cols"] = (int(x) for x in rng.integers(1, 4, 2))
    period = int(kw.get("cloud_period", 1))
    kw["max_steps"] = max(period, int(rng.integers(40, 200)) // period * period)
    batch = int(rng.integers(2, 5))
    late = np.random.default_rng([index, 0x6D697665, 1])
    choices = {f.name: f.metadata.get("choices") for f in dataclasses.fields(MiVeCCConfig)}
    for name in LATE_CHOICES:
        if late.random() < 0.5:
            kw[name] = choices[name][int(late.integers(len(choices[name])))]
    return Case(
        index=index,
        overrides=kw,
        batch_size=batch,
        seeds=[int(s) for s in rng.integers(0, 2**31, batch)],
        densities=[round(float(d), 1) for d in rng.uniform(300.0, 3000.0, batch)],
        steps=int(rng.integers(60, 300)),
        continuous=bool(rng.random() < 0.2),
        signal_agents=kw.get("control") == "signalized" and bool(rng.random() < 0.5),
    )


def differences(batch: BatchStep, b: int, single: BatchStep) -> list[str]:
    """Names of the arrays of environment ``b`` of ``batch`` that differ, bit for bit, from
    environment 0 of ``single`` (a field present in one and ``None`` in the other differs)."""
    out = []
    for field in dataclasses.fields(BatchStep):
        x, y = getattr(batch, field.name), getattr(single, field.name)
        if x is None or y is None:
            if (x is None) != (y is None):
                out.append(field.name)
            continue
        pairs = ({k: (x[k][b], y[k][0]) for k in x.keys() | y.keys() if k in x and k in y}
                 if isinstance(x, dict) else {"": (x[b], y[0])})
        if isinstance(x, dict) and x.keys() != y.keys():
            out.append(f"{field.name} (keys)")
        for key, (u, v) in pairs.items():
            u, v = np.asarray(u), np.asarray(v)
            if u.dtype != v.dtype or u.shape != v.shape or u.tobytes() != v.tobytes():
                out.append(f"{field.name}[{key}]" if key else field.name)
    return out


def parallel_differences(pz: Any, step: tuple, out: BatchStep, summary: dict[str, Any]
                         ) -> list[str]:
    """What differs between a PettingZoo ``ParallelEnv`` step (``(obs, rewards, truncations,
    infos)``, rewards and truncations ``None`` after a reset) and environment 0 of ``out``
    (``summary``: the batch's summary)."""
    obs, rewards, truncations, infos = step
    found = []
    wanted: dict[str, tuple] = {}
    for i, agent in enumerate(pz.edge_agents):
        wanted[agent] = (out.edge_obs, (0, i), out.edge_mask, out.edge_reward, out.edge_terms)
    if out.cloud_obs is not None:  # the batch observes the cloud under EEC only
        wanted["cloud_0"] = (out.cloud_obs, (0,), out.cloud_mask, out.cloud_reward,
                             out.cloud_terms)
    for agent, (graphs, at, masks, reward, terms) in wanted.items():
        if obs[agent].tobytes() != graphs[at].tobytes():
            found.append(f"{agent} observation")
        if infos[agent]["mask"].tobytes() != masks[at].tobytes():
            found.append(f"{agent} mask")
        if rewards is not None and not _same(rewards[agent], reward[at]):
            found.append(f"{agent} reward")
        found += [f"{agent} {k}" for k in terms if rewards is not None
                  and not _same(infos[agent][k], terms[k][at])]
    if out.signal_obs is not None:
        for i, agent in enumerate(pz.signal_agents):
            if obs[agent].tobytes() != out.signal_obs[0, i].tobytes():
                found.append(f"{agent} observation")
            if rewards is not None and not _same(rewards[agent], out.signal_reward[0, i]):
                found.append(f"{agent} reward")
    if truncations is not None and any(v != bool(out.truncated[0]) for v in truncations.values()):
        found.append("truncations")
    found += [f"summary {k}" for k, v in summary.items()
              if k in infos["cloud_0"] and not _same(infos["cloud_0"][k], v[0])]
    return found


def _same(x: Any, y: Any) -> bool:
    """Two numbers equal as float64 bits (NaN equals NaN)."""
    return np.float64(x).tobytes() == np.float64(y).tobytes()


def _agent_actions(pz: Any, edge: np.ndarray | None, cloud: np.ndarray | None,
                   signal: np.ndarray | None) -> dict[str, Any]:
    """Environment 0's batch actions as the ParallelEnv's agent dict (left out: no action)."""
    actions: dict[str, Any] = {}
    if edge is not None:
        actions |= {agent: edge[0, i] for i, agent in enumerate(pz.edge_agents)}
    if cloud is not None:
        actions["cloud_0"] = cloud[0]
    if signal is not None:
        actions |= {agent: int(signal[0, i]) for i, agent in enumerate(pz.signal_agents)
                    if signal[0, i] >= 0}
    return actions


def _digest_update(digest: Any, out: BatchStep, summary: dict[str, np.ndarray]) -> None:
    """Add every array of a batch step and the batch's summary to ``digest``."""
    for field in dataclasses.fields(BatchStep):
        value = getattr(out, field.name)
        items = sorted(value.items()) if isinstance(value, dict) else [("", value)]
        for key, array in items:
            if array is not None:
                digest.update(f"{field.name}{key}".encode())
                digest.update(np.ascontiguousarray(array).tobytes())
    for key in sorted(summary):
        digest.update(key.encode())
        digest.update(summary[key].tobytes())


def _problems(env: BatchedMiVeCCEnv, out: BatchStep, b: int) -> list[str]:
    """Accounting and observation-bound violations of environment ``b``."""
    sim, found = env.sim, []
    held = sim.queued[b] + sim.in_network[b] + sim.exited[b] + sim.collided[b]
    if held != sim.arrived[b]:
        found.append(f"accounting: arrived {sim.arrived[b]}, accounted for {held}")
    for name in ("edge_obs", "cloud_obs"):
        obs = getattr(out, name)
        if obs is not None and not (np.isfinite(obs[b]).all() and np.abs(obs[b]).max() <= 1.0):
            found.append(f"{name}: not finite or outside [-1, 1]")
    return found


@dataclasses.dataclass(frozen=True)
class _Actions:
    """One step's actions of the whole batch (``None``: that coordinator sends none)."""

    edge: np.ndarray | None
    cloud: np.ndarray | None
    signal: np.ndarray | None
    raw: np.ndarray

    def of(self, b: int) -> dict[str, Any]:
        """Environment ``b``'s actions as ``step`` keywords of a B = 1 env."""
        one = slice(b, b + 1)
        return {"edge_action": None if self.edge is None else self.edge[one],
                "cloud_action": None if self.cloud is None else self.cloud[one],
                "signal_action": None if self.signal is None else self.signal[one],
                "raw_edge": self.raw[one]}


def _draw_actions(rngs: list[np.random.Generator], shared: np.random.Generator,
                  env: BatchedMiVeCCEnv, signal_agents: bool, raw_in_env_0: bool) -> _Actions:
    """Uniform accelerations of every column, raw edge actions in 30 % of the environments,
    random phases (-1: the controller) and, batch-wide, no edge (10 %) or no cloud (10 %)
    action; each environment's draws come from its own generator."""
    a_max = env.config.a_max_mps2
    edge = np.stack([r.uniform(-a_max, a_max, (env.n_edge, env.k_edge)) for r in rngs])
    cloud = np.stack([r.uniform(-a_max, a_max, env.cloud_action_shape) for r in rngs])
    raw = np.array([r.random() < 0.3 for r in rngs])
    raw[0] &= raw_in_env_0
    signal = (np.stack([r.integers(-1, 2, env.n_edge) for r in rngs])
              if signal_agents else None)
    u = shared.random()
    return _Actions(None if u < 0.1 else edge, None if 0.1 <= u < 0.2 else cloud, signal, raw)


class _Lockstep:
    """A case's batch, each of its environments alone, and (outside continuous runs) the
    ParallelEnv running environment 0, stepped together."""

    def __init__(self, case: Case, extra: dict[str, Any]) -> None:
        self.case = case
        self.batch = BatchedMiVeCCEnv(batch_size=case.batch_size, densities=case.densities,
                                      **case.overrides, **extra)
        self.singles = [BatchedMiVeCCEnv(batch_size=1, densities=[d], **case.overrides,
                                         **extra) for d in case.densities]
        self.pz = None if case.continuous else mivecc_v0.parallel_env(
            density=case.densities[0], signal_agents=case.signal_agents, **case.overrides)
        self.resettable = self.batch.config.control in RESETTABLE and not case.continuous
        self.out = self.batch.reset(seed=case.seeds)
        self.refs = [env.reset(seed=s) for env, s in zip(self.singles, case.seeds, strict=True)]
        self.pz_step: tuple | None = None
        if self.pz is not None:
            obs, info = self.pz.reset(seed=case.seeds[0])
            self.pz_step = (obs, None, None, info)

    def problems(self, t: int, summary: dict[str, np.ndarray]) -> tuple[int, list[str]] | None:
        """The first environment whose arrays differ from its lone run (or whose accounting
        or observations are wrong) and what differs; ``None`` if none."""
        for b in range(self.case.batch_size):
            found = [f"step {t}: {name}" for name in differences(self.out, b, self.refs[b])]
            alone = self.singles[b].summary()
            found += [f"step {t}: summary {k}" for k in summary
                      if summary[k][b].tobytes() != alone[k][0].tobytes()]
            found += [f"step {t}: {p}" for p in _problems(self.batch, self.out, b)]
            if b == 0 and self.pz_step is not None:
                found += [f"step {t}: ParallelEnv {name}" for name in
                          parallel_differences(self.pz, self.pz_step, self.out, summary)]
            if found:
                return b, found
        return None

    def step(self, act: _Actions) -> None:
        self.out = self.batch.step(act.edge, act.cloud, signal_action=act.signal,
                                   raw_edge=act.raw)
        self.refs = [env.step(**act.of(b)) for b, env in enumerate(self.singles)]
        if self.pz is not None:
            obs, rew, _, trunc, info = self.pz.step(
                _agent_actions(self.pz, act.edge, act.cloud, act.signal))
            self.pz_step = (obs, rew, trunc, info)
            if self.out.truncated[0] and not self.resettable:
                self.pz = self.pz_step = None  # its episode ended; environment 0 runs on

    def restart(self, envs: list[int]) -> None:
        """Next chunk (continuous runs) or ``reset_at`` of ``envs``, in every runner."""
        if self.case.continuous:
            self.out = self.batch.start_chunk(envs)
            for b in envs:
                self.refs[b] = self.singles[b].start_chunk([0])
            return
        self.out = self.batch.reset_at(envs)
        for b in envs:
            self.refs[b] = self.singles[b].reset()
        if self.pz is not None and 0 in envs:
            obs, info = self.pz.reset()
            self.pz_step = (obs, None, None, info)


def run_case(case: Case) -> dict[str, Any]:
    """Run one case (module docstring); returns its record (``status``: ``same``,
    ``refused`` or ``differs``, and the workload); an exception of the env propagates."""
    record: dict[str, Any] = {"case": case.index, **dataclasses.asdict(case)}
    del record["index"]
    extra: dict[str, Any] = {"continuous": True} if case.continuous else {}
    if case.signal_agents:
        extra["signal_agents"] = True
    try:
        run = _Lockstep(case, extra)
    except ConfigError as exc:
        return record | {"status": "refused", "detail": str(exc)}
    n = case.batch_size
    rngs = [np.random.default_rng([case.index, 1, b]) for b in range(n)]
    shared = np.random.default_rng([case.index, 2])  # batch-wide choices
    vehicle_steps = restarts = 0
    digest = hashlib.sha256()
    for t in range(case.steps + 1):
        summary = run.batch.summary()
        _digest_update(digest, run.out, summary)
        found = run.problems(t, summary)
        if found is not None:
            return record | {"status": "differs", "env": found[0],
                             "detail": "; ".join(found[1][:5]), "vehicle_steps": vehicle_steps}
        vehicle_steps += int(run.batch.sim.in_network.sum())
        if t == case.steps:
            break
        run.step(_draw_actions(rngs, shared, run.batch, case.signal_agents, run.pz is None))
        chosen = set(np.flatnonzero(run.out.truncated).tolist())
        if run.resettable:
            chosen |= {b for b in range(n) if rngs[b].random() < 0.01}
        if chosen and (run.resettable or case.continuous):  # others run on, truncated
            restarts += len(chosen)
            run.restart(sorted(chosen))
    return record | {"status": "same", "vehicle_steps": vehicle_steps, "restarts": restarts,
                     "env_steps": n * case.steps, "digest": digest.hexdigest()}


def compare_digests(records: list[dict[str, Any]], other: Path) -> tuple[int, list[int]]:
    """(cases compared, cases whose trajectory digest differs) against another run's
    ``batch_fuzz.jsonl``: the cases both ran to the end (status ``same``)."""
    theirs = {}
    for line in other.read_text().splitlines():
        record = json.loads(line)
        if record.get("digest"):
            theirs[record["case"]] = record["digest"]
    pairs = [(r["case"], r["digest"], theirs[r["case"]]) for r in records
             if r.get("digest") and r["case"] in theirs]
    return len(pairs), [case for case, mine, them in pairs if mine != them]


def summarise(records: list[dict[str, Any]], command: str, wall_s: float,
              against: tuple[Path, int, list[int]] | None = None) -> str:
    """Markdown summary of the cases (``against``: the other run, cases compared, cases
    whose digest differs)."""
    status = Counter(r["status"] for r in records)
    ran = [r for r in records if r["status"] != "refused"]
    lines = [
        f"Command: `{command}`", "",
        f"{len(records)} cases in {wall_s:.0f} s: " + ", ".join(
            f"{status[s]} {s}" for s in ("same", "differs", "error", "refused") if status[s])
        + f". Kernels: {'numba' if HAVE_NUMBA else 'numpy reference paths (MIVECC_NO_NUMBA)'}.",
        "",
        "| cases run | environments | env-steps | vehicle-steps | restarts (reset_at or next "
        "chunk) | continuous | signal agents |",
        "|---:|---:|---:|---:|---:|---:|---:|",
        f"| {len(ran)} | {sum(r['batch_size'] for r in ran)} | "
        f"{sum(r.get('env_steps', 0) for r in ran):,} | "
        f"{sum(r.get('vehicle_steps', 0) for r in ran):,} | "
        f"{sum(r.get('restarts', 0) for r in ran):,} | "
        f"{sum(r['continuous'] for r in ran)} | {sum(r['signal_agents'] for r in ran)} |",
        "", "Cases run per value of each drawn field (preset: left at the model preset's value):",
        "", "| field | cases per value |", "|---|---|",
    ]
    for name in ("model", *choice_fields(), *NUMERIC):
        values = Counter(str(r["overrides"].get(name, "preset")) for r in ran)
        if name in NUMERIC:
            drawn = sum(v for k, v in values.items() if k != "preset")
            values = Counter({"drawn": drawn, "preset": values["preset"]})
        lines.append(f"| `{name}` | " + ", ".join(f"{k} {v}" for k, v in sorted(values.items()))
                     + " |")
    bad = [r for r in records if r["status"] in ("differs", "error")]
    if bad:
        lines += ["", "Differences:", ""] + [
            f"- case {r['case']} env {r['env']}: {r['detail']} (rerun: `--start {r['case']} "
            "--cases 1`)" for r in bad]
    if against is not None:
        path, compared, differ = against
        lines += ["", f"Trajectory digests against `{path}`: {compared - len(differ)} of "
                  f"{compared} cases equal" + (f"; differ: {differ}" if differ else "") + "."]
    refused = Counter(r["detail"].split(":")[0] for r in records if r["status"] == "refused")
    if refused:
        lines += ["", "Refused by the config (fields that do not go together), by field: "
                  + ", ".join(f"{k} {v}" for k, v in sorted(refused.items())) + "."]
    return "\n".join(lines) + "\n"


def add_case_options(p: argparse.ArgumentParser, default_out: Path) -> None:
    """The options of every fuzz script: ``--cases``, ``--start``, ``--out``, ``--no-progress``."""
    p.add_argument("--cases", type=cli_args.count(1), default=100,
                   help="number of cases (default 100)")
    p.add_argument("--start", type=cli_args.count(0), default=0,
                   help="number of the first case (default 0)")
    p.add_argument("--out", type=Path, default=default_out,
                   help=f"output folder (default {default_out.relative_to(HERE.parent)})")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run_cases(indices: range, run: Callable[[Case], dict[str, Any]], log_path: Path,
              progress: bool) -> list[dict[str, Any]]:
    """``run`` on the cases ``indices``, one JSON line each in ``log_path`` (written as they
    end); an exception is a finding, recorded as status ``error`` naming the case."""
    records = []
    with log_path.open("w") as log:
        for index in tqdm(indices, disable=not progress, unit="case"):
            case = draw_case(index)
            try:
                record = run(case)
            except Exception as exc:
                record = {"case": index, **dataclasses.asdict(case), "status": "error",
                          "env": "-", "detail": f"{type(exc).__name__}: {exc}"}
                del record["index"]
            records.append(record)
            log.write(json.dumps(record) + "\n")
            log.flush()
            if record["status"] in ("differs", "error"):
                tqdm.write(f"case {index} env {record.get('env', '-')}: {record['detail']}")
    return records


def build_parser() -> argparse.ArgumentParser:
    p = cli_args.Parser(description=__doc__.split("\n\n")[0],
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    add_case_options(p, DEFAULT_OUT)
    p.add_argument("--against", type=cli_args.existing_file, default=None,
                   help="another run's batch_fuzz.jsonl: compare the trajectory digests case "
                   "by case (e.g. a MIVECC_NO_NUMBA=1 run against a numba one)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the cases, write and print the summary; 1 if any case differs."""
    args = build_parser().parse_args(argv)
    out_dir = cli_args.writable_dir("--out", args.out)
    command = "python benchmarks/batch_fuzz.py " + " ".join(
        sys.argv[1:] if argv is None else list(argv))
    t0 = time.perf_counter()
    records = run_cases(range(args.start, args.start + args.cases), run_case,
                        out_dir / "batch_fuzz.jsonl", not args.no_progress)
    against = None
    if args.against is not None:
        against = (args.against, *compare_digests(records, args.against))
    text = summarise(records, command.strip(), time.perf_counter() - t0, against)
    (out_dir / "batch_fuzz.md").write_text(text)
    print(text, end="")
    failed = any(r["status"] in ("differs", "error") for r in records)
    return 1 if failed or (against is not None and against[2]) else 0


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
