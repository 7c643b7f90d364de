"""The PA-DQN parts of the ``mivecc`` command line.

* ``mivecc evaluate --scheme pa-dqn [--signal-checkpoint FILE]``: :func:`signal_policies` loads
  the signal policy (default: the shipped one).
* ``mivecc train-signal --out DIR``: trains a PA-DQN policy (:mod:`mivecc_agents.signal_dqn`)
  and writes ``DIR/signal_dqn.pt``, ``DIR/train_log.csv`` and ``DIR/learning_curve.png``;
  one progress line per episode on stderr, the checkpoint's path on stdout.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

from mivecc_env import cli_args
from mivecc_env.config import ConfigError

PROG = "mivecc"


def signal_policies(args: argparse.Namespace) -> dict[str, Any]:
    """``{"signal": policy}`` from ``--signal-checkpoint`` or the shipped policy of the grid
    (``--rows``, ``--cols``); a file that is missing or not a signal policy is a
    :class:`ConfigError` naming the option."""
    from mivecc_agents.checkpoints import CheckpointError
    from mivecc_agents.signal_dqn import SignalDQNPolicy, shipped_policy_path

    path, option = args.signal_checkpoint, "--signal-checkpoint"
    if path is None:
        if args.no_pretrained:
            raise ConfigError("--no-pretrained: scheme pa-dqn needs a signal policy; give "
                              "--signal-checkpoint")
        path, option = shipped_policy_path(args.rows, args.cols), "shipped signal policy"
    try:
        return {"signal": SignalDQNPolicy.load(path)}
    except CheckpointError as exc:
        raise ConfigError(f"{option}: {exc}") from exc


def add_train_signal_parser(subparsers: Any) -> argparse.ArgumentParser:
    """The ``train-signal`` subcommand: every :class:`SignalDQNSettings` field but ``config``
    as an option (``--set KEY=VALUE`` for config fields)."""
    from mivecc_agents.signal_dqn_settings import SignalDQNSettings

    p = subparsers.add_parser(
        "train-signal", help="train the PA-DQN signal policy (learned signal comparator)",
        description="Train PA-DQN signal agents (DQN, one shared Q-network, a decision every "
        "decision_period_s) on the single intersection, or on a grid with --rows/--cols; "
        "docs/comparators.md.",
    )
    p.add_argument("--out", type=Path, required=True,
                   help="folder for signal_dqn.pt, train_log.csv and learning_curve.png")
    for f in dataclasses.fields(SignalDQNSettings):
        if f.name == "config":
            continue
        option = "--" + f.name.replace("_", "-")
        if f.name == "densities":
            p.add_argument(option, type=float, nargs="+", default=list(f.default),
                           help=f"{f.metadata['help']} (default "
                           f"{' '.join(f'{d:g}' for d in f.default)})")
            continue
        kind = int if isinstance(f.default, int) else float
        p.add_argument(option, type=kind, default=f.default,
                       help=f"{f.metadata['help']} (default {f.default})")
    p.add_argument("--set", dest="set_items", action="append", metavar="KEY=VALUE", default=None,
                   help="a MiVeCCConfig field of the training environments (repeatable)")
    p.add_argument("--threads", type=cli_args.count(1), default=1,
                   help="torch threads (default 1: fastest for this small network)")
    p.set_defaults(func=cmd_train_signal)
    return p


def cmd_train_signal(args: argparse.Namespace) -> int:
    """Run ``mivecc train-signal``."""
    from mivecc_agents.cli import parse_set_items, set_inference_threads

    settings_kw = {f.name: getattr(args, f.name) for f in _settings_fields()}
    settings_kw["densities"] = tuple(args.densities)
    settings_kw["config"] = parse_set_items(args.set_items)
    from mivecc_agents.signal_dqn_settings import SignalDQNSettings

    settings = SignalDQNSettings(**settings_kw).check()
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out: {out} is a file; give a folder")
    set_inference_threads(args.threads)
    from mivecc_agents.signal_dqn import plot_learning_curve, train_signal_dqn, write_log

    def progress(row: dict[str, float]) -> None:
        print(f"episode {row['episode']:.0f}/{settings.episodes}: reward/decision "
              f"{row['reward_per_decision']:.3f}, throughput {row['throughput']:.1f} veh, "
              f"backlog {row['backlog']:.1f} veh, epsilon {row['epsilon']:.2f}, loss "
              f"{row['loss']:.4f}, {row['wall_s']:.0f} s", file=sys.stderr, flush=True)

    policy, log = train_signal_dqn(settings, on_episode=progress)
    path = policy.save(out / "signal_dqn.pt")  # its settings say how it was trained
    write_log(log, out / "train_log.csv")
    plot_learning_curve(log, out / "learning_curve.png")
    print(path)
    return 0


def _settings_fields() -> list[dataclasses.Field]:
    from mivecc_agents.signal_dqn_settings import SignalDQNSettings

    return [f for f in dataclasses.fields(SignalDQNSettings)
            if f.name not in ("config", "densities")]
