"""Where, and on what code and libraries, a benchmark or an experiment ran.

Results with learned policies depend on the CPU as well as on the code: torch's CPU kernels
(MKL, oneDNN) pick their code path by instruction set and vendor, so a float32 network rounds
its outputs differently on another CPU and the trajectories it drives diverge
(``docs/training.md``, "Reproducing these numbers on another CPU"). :func:`machine_info`
records what a reader needs to tell whether a rerun should match bit for bit; its policy
digests tell it in seconds (``python benchmarks/machine_info.py``).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import importlib.util
import os
import platform
import subprocess
from pathlib import Path
from typing import Any

import numpy as np

from mivecc_env import cli_args

HERE = Path(__file__).resolve().parent

#: CPU flags that select different numerical code paths in numpy and torch.
ISA_FLAGS = ("avx2", "fma", "avx512f")


def _git(*args: str) -> str | None:
    try:
        return subprocess.run(["git", *args], cwd=HERE, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def _cpuinfo() -> tuple[str | None, list[str]]:
    """The CPU's model name and which of :data:`ISA_FLAGS` it has (Linux; else what
    ``platform`` knows and no flags)."""
    fields: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:  # the first CPU's entries
                key, _, value = line.partition(":")
                fields.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    have = set(fields.get("flags", "").split())
    return (fields.get("model name") or platform.processor() or None,
            [f for f in ISA_FLAGS if f in have])


def _actions_digest(path: Path, kind: str) -> str:
    """md5 of a policy's float32 actions on fixed random graphs (a generator seeded here; an
    edge on 9 graphs at once, a cloud on 1)."""
    from mivecc_agents.policies import load_policy

    policy = load_policy(path, expected_kind=kind)
    rng = np.random.default_rng(0)
    k = policy.grid_size
    n = 9 if kind == "edge" else 1
    obs = rng.uniform(-1.0, 1.0, (n, k, k, 3)).astype(np.float32)
    mask = (rng.uniform(size=(n, k)) < 0.9).astype(np.float32)
    actions = np.asarray(policy(obs, mask), dtype=np.float32)
    return hashlib.md5(actions.tobytes()).hexdigest()


def policy_digests() -> dict[str, str]:
    """``"<model>/<kind>" -> md5`` of each shipped policy's actions (:func:`_actions_digest`),
    and ``"<model>/shield/<kind>"`` for a policy shipped for the safety shield. Two machines
    with the same digests round the shipped networks alike, so their runs with these policies
    should match bit for bit; different digests mean they will diverge."""
    from mivecc_agents.policies import pretrained_path

    out: dict[str, str] = {}
    for model in ("paper", "released"):
        for kind in ("cloud", "edge"):
            plain = pretrained_path(kind, model)
            shielded = pretrained_path(kind, model, safety_shield=True)
            if plain is not None:
                out[f"{model}/{kind}"] = _actions_digest(plain, kind)
            if shielded not in (None, plain):
                out[f"{model}/shield/{kind}"] = _actions_digest(shielded, kind)
    return out


def machine_info(with_torch: bool = False) -> dict[str, Any]:
    """The CPU (model, instruction-set flags), platform, Python, numpy (and with
    ``with_torch`` torch's version and CPU capability and the :func:`policy_digests`), the git
    commit and whether the tree had uncommitted changes, and the UTC time."""
    cpu, flags = _cpuinfo()
    status = _git("status", "--porcelain", "--untracked-files=no")
    info: dict[str, Any] = {
        "cpu": cpu, "cpu_flags": flags, "cpu_count": os.cpu_count(),
        "affinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "platform": platform.platform(), "python": platform.python_version(),
        "numpy": np.__version__,
    }  # fmt: skip
    if with_torch and importlib.util.find_spec("torch") is not None:
        import torch

        info["torch"] = torch.__version__
        info["torch_cpu_capability"] = torch.backends.cpu.get_cpu_capability()
        info["policy_digests"] = policy_digests()
    info.update(git_commit=_git("rev-parse", "HEAD"),
                git_dirty=bool(status) if status is not None else None,
                date_utc=dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"))
    return info


def describe(info: dict[str, Any]) -> str:
    """One line of :func:`machine_info` for a results page."""
    flags = "/".join(info.get("cpu_flags") or []) or "no flags read"
    torch_part = (f", torch {info['torch']} ({info['torch_cpu_capability']})"
                  if "torch" in info else "")
    commit = (info.get("git_commit") or "unknown")[:7] + (" + changes" if info.get("git_dirty")
                                                          else "")
    return (f"{info.get('cpu') or 'unknown CPU'} ({flags}), {info.get('cpu_count')} CPUs, "
            f"numpy {info['numpy']}{torch_part}, Python {info['python']}, commit {commit}")


def main(argv: list[str] | None = None) -> int:
    """Print :func:`machine_info` (with torch and the policy digests) as JSON; no options."""
    import json

    cli_args.Parser(description=__doc__.splitlines()[0]).parse_args(argv)
    print(json.dumps(machine_info(with_torch=True), indent=2))
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(cli_args.run(main))
