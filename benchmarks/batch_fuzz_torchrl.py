"""The native TorchRL env against the batched env it wraps, on random feature combinations.

Training runs through :class:`~mivecc_agents.torchrl_env.MiVeCCTorchEnv`: it converts the
actions of its groups (float32 tensors, integer phases), restarts environments from TorchRL's
``"_reset"`` entries (``reset_at``, or the next chunk of a continuous run), executes raw edge
actions every ``raw_edge_period`` steps and packs observations, masks, rewards, reward terms,
summaries and flags into tensordicts. This script checks all of that on the cases of
``benchmarks/batch_fuzz.py`` (the same configurations, seeds and demands): per case a TorchRL env
with the groups ``edge`` and ``cloud`` (whatever the scheme uses) and ``signal`` with signal agents
and a :class:`~mivecc_env.batched.BatchedMiVeCCEnv` twin are stepped with the same actions
(``step_and_maybe_reset``, plus random partial resets where the control mode allows them), and
every tensor is compared with the twin's array (the float64 rewards, terms and summaries as
float32, the env's documented conversion) after every step and every reset.

Writes ``batch_fuzz_torchrl.jsonl`` and ``batch_fuzz_torchrl.md`` under ``--out``; exits 1
naming any case that differs or raises (``--start N --cases 1`` reruns it). Needs the ``train``
extra (torch, torchrl).

Usage:
    python benchmarks/batch_fuzz_torchrl.py --cases 300 --start 0 --out runs/batch_fuzz_torchrl
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from batch_fuzz import RESETTABLE, Case, add_case_options, run_cases

from mivecc_agents.torchrl_env import MiVeCCTorchEnv
from mivecc_env import ConfigError, cli_args
from mivecc_env.batched import BatchedMiVeCCEnv, BatchStep
from mivecc_env.signal_agents import SIGNAL_GROUP

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "batch_fuzz_torchrl"


def _f32(a: Any) -> np.ndarray:
    return np.asarray(a, dtype=np.float32)


def torch_differences(td: Any, out: BatchStep, summary: dict[str, np.ndarray],
                      env: MiVeCCTorchEnv, decides: np.ndarray | None,
                      with_reward: bool) -> list[str]:
    """Keys of a TorchRL env's tensordict (a step's ``"next"`` or a reset's) that differ from
    the twin's step ``out`` (and ``summary``, ``decides``: its cloud decision flags)."""
    b = env.batch_size[0]
    wanted: dict[Any, np.ndarray] = {}
    for g in env.groups:
        n = len(env.group_map[g])
        if g == "edge":
            obs, mask, reward, terms = out.edge_obs, out.edge_mask, out.edge_reward, out.edge_terms
        elif g == "cloud":
            k = env.config.k_cloud
            obs, mask = out.cloud_obs.reshape(b, n, k, k, 3), out.cloud_mask.reshape(b, n, k)
            reward = np.broadcast_to(out.cloud_reward[:, None], (b, n))
            terms = {key: np.broadcast_to(v[:, None], (b, n))
                     for key, v in out.cloud_terms.items()}
            if decides is not None:
                wanted[g, "info", "decides"] = np.broadcast_to(decides[:, None], (b, n))
        else:
            obs, mask, reward, terms = out.signal_obs, None, out.signal_reward, out.signal_terms
        wanted[g, "observation"] = obs
        if mask is not None:
            wanted[g, "mask"] = wanted[g, "info", "mask"] = mask
        wanted |= {(g, "info", key): _f32(v) for key, v in terms.items()}
        if with_reward:
            wanted[g, "reward"] = _f32(reward)[..., None]
        if g == env.summary_group:
            wanted |= {(g, "info", key): np.broadcast_to(_f32(summary[key])[:, None], (b, n))
                       for key in env.summary_keys}
        for key in ("done", "truncated"):
            wanted[g, key] = np.broadcast_to(out.truncated[:, None, None], (b, n, 1))
    wanted["truncated"] = wanted["done"] = out.truncated[:, None]
    found = []
    for key, value in wanted.items():
        got = td.get(key).cpu().numpy()
        value = np.asarray(value)
        if got.shape != value.shape or got.dtype != value.dtype or not np.array_equal(
                got, value, equal_nan=value.dtype.kind == "f"):
            found.append("/".join(key) if isinstance(key, tuple) else key)
    return found


def _groups(case: Case) -> tuple[str, ...]:
    """The TorchRL groups of a case: both coordinators (whatever the scheme uses), and the
    signal agents where it has them."""
    return ("edge", "cloud", *((SIGNAL_GROUP,) if case.signal_agents else ()))


def run_case(case: Case) -> dict[str, Any]:
    """Run one case; returns its record (``status``: ``same``, ``refused`` or ``differs``)."""
    record: dict[str, Any] = {"case": case.index, "overrides": case.overrides,
                              "batch_size": case.batch_size, "continuous": case.continuous,
                              "signal_agents": case.signal_agents}
    extra: dict[str, Any] = {"continuous": True} if case.continuous else {}
    rng = np.random.default_rng([case.index, 3])
    period = int(rng.random() < 0.5) * 2  # raw edge actions every other step in half the cases
    try:
        groups = _groups(case)
        twin = BatchedMiVeCCEnv(batch_size=case.batch_size, densities=case.densities,
                                observe={"edge", "cloud"}, signal_agents=case.signal_agents,
                                **case.overrides, **extra)
        env = MiVeCCTorchEnv(case.batch_size, densities=case.densities, groups=groups,
                             raw_edge_period=period if "edge" in groups else 0,
                             **case.overrides, **extra)
    except ConfigError as exc:
        return record | {"status": "refused", "detail": str(exc)}
    record |= {"groups": list(groups), "raw_edge_period": period}
    c, b = twin.config, case.batch_size
    resettable = c.control in RESETTABLE and not case.continuous
    holds = c.cloud_period > 1 and c.scheme == "EEC" and "cloud" in groups
    td = env.reset(seed=case.seeds)
    out = twin.reset(seed=case.seeds)
    restarts = 0
    for t in range(case.steps + 1):
        decides = twin.cloud_decides if holds else None
        found = torch_differences(td, out, twin.summary(), env, decides, with_reward=False)
        if found:
            return record | {"status": "differs", "detail": f"step {t}: {found[:5]}"}
        if t == case.steps:
            break
        a = c.a_max_mps2
        act: dict[str, np.ndarray] = {}
        if "edge" in groups:
            act["edge"] = rng.uniform(-a, a, (b, twin.n_edge, twin.k_edge)).astype(np.float32)
        if "cloud" in groups:
            act["cloud"] = rng.uniform(-a, a, (b, c.n_cloud_graphs, twin.k_cloud)).astype(
                np.float32)
        if SIGNAL_GROUP in groups:
            act[SIGNAL_GROUP] = rng.integers(0, 2, (b, twin.n_edge))
        for g, value in act.items():
            td[g, "action"] = torch.from_numpy(value)
        full, td = env.step_and_maybe_reset(td)
        raw = np.full(b, t % period == period - 1) if period and "edge" in act else None
        out = twin.step(
            None if "edge" not in act else act["edge"].astype(np.float64),
            None if "cloud" not in act else act["cloud"].astype(np.float64).reshape(
                b, *twin.cloud_action_shape),
            signal_action=act.get(SIGNAL_GROUP), raw_edge=raw)
        found = torch_differences(full["next"], out, twin.summary(), env,
                                  decides=None if not holds else twin.cloud_decides,
                                  with_reward=True)
        if found:
            return record | {"status": "differs", "detail": f"step {t + 1}: {found[:5]}"}
        truncated = np.flatnonzero(out.truncated)
        if truncated.size:  # step_and_maybe_reset restarted them in the TorchRL env
            restarts += truncated.size
            if case.continuous:
                out = twin.start_chunk(truncated)
            elif truncated.size == b:
                out = twin.reset()
            else:
                out = twin.reset_at(truncated)
        extra_reset = rng.random(b) < 0.01
        if resettable and extra_reset.any():
            restarts += int(extra_reset.sum())
            td.set("_reset", torch.from_numpy(extra_reset)[:, None])
            td = env.reset(td)
            out = twin.reset_at(np.flatnonzero(extra_reset))
    return record | {"status": "same", "env_steps": b * case.steps, "restarts": restarts}


def summarise(records: list[dict[str, Any]], command: str, wall_s: float) -> str:
    """Markdown summary of the cases."""
    status = Counter(r["status"] for r in records)
    ran = [r for r in records if r["status"] != "refused"]
    groups = Counter("+".join(r["groups"]) for r in ran if "groups" in r)
    lines = [
        f"Command: `{command}`", "",
        f"{len(records)} cases in {wall_s:.0f} s: " + ", ".join(
            f"{status[s]} {s}" for s in ("same", "differs", "error", "refused") if status[s])
        + ".", "",
        f"Cases run: {len(ran)}; environment-steps {sum(r.get('env_steps', 0) for r in ran):,};"
        f" restarts {sum(r.get('restarts', 0) for r in ran):,}; continuous "
        f"{sum(r['continuous'] for r in ran)}; raw edge actions every other step "
        f"{sum(r.get('raw_edge_period', 0) == 2 for r in ran)}; groups: "
        + ", ".join(f"{k} {v}" for k, v in sorted(groups.items())) + ".",
    ]
    bad = [r for r in records if r["status"] in ("differs", "error")]
    if bad:
        lines += ["", "Differences:", ""] + [
            f"- case {r['case']}: {r['detail']} (rerun: `--start {r['case']} --cases 1`)"
            for r in bad]
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Run the cases, write and print the summary; 1 if any case differs or raises."""
    p = cli_args.Parser(description=__doc__.split("\n\n")[0])
    add_case_options(p, DEFAULT_OUT)
    args = p.parse_args(argv)
    out_dir = cli_args.writable_dir("--out", args.out)
    torch.set_num_threads(1)
    command = "python benchmarks/batch_fuzz_torchrl.py " + " ".join(
        sys.argv[1:] if argv is None else list(argv))
    t0 = time.perf_counter()
    records = run_cases(range(args.start, args.start + args.cases), run_case,
                        out_dir / "batch_fuzz_torchrl.jsonl", not args.no_progress)
    text = summarise(records, command.strip(), time.perf_counter() - t0)
    (out_dir / "batch_fuzz_torchrl.md").write_text(text)
    print(text, end="")
    return 1 if any(r["status"] in ("differs", "error") for r in records) else 0


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
