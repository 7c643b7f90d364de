"""The learned comparators' parts of the ``mivecc`` command line (PA-DQN, Coder, CoMADDPG).

* ``mivecc evaluate --scheme pa-dqn|coder [--signal-checkpoint FILE]``: :func:`signal_policies`
  loads the signal policy (default: the shipped one); ``--scheme comaddpg
  [--vehicle-checkpoint FILE]``: :func:`vehicle_policies` the vehicles' policy.
* ``mivecc train-signal --out DIR``: trains a PA-DQN policy (:mod:`mivecc_agents.signal_dqn`)
  and writes ``DIR/signal_dqn.pt``, ``DIR/train_log.csv`` and ``DIR/learning_curve.png``;
  ``mivecc train-coder --out DIR`` the same for Coder (:mod:`mivecc_agents.coder`,
  ``DIR/coder.pt``), ``mivecc train-comaddpg --out DIR`` for CoMADDPG
  (:mod:`mivecc_agents.comaddpg`, ``DIR/comaddpg.pt``). One progress line per episode on
  stderr, the checkpoint's path on stdout.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any, NamedTuple

from mivecc_env import cli_args
from mivecc_env.config import ConfigError

PROG = "mivecc"


def signal_policies(args: argparse.Namespace) -> dict[str, Any]:
    """``{"signal": policy}`` from ``--signal-checkpoint`` or the shipped policy of the scheme
    (``pa-dqn`` or ``coder``) and grid (``--rows``, ``--cols``); a file that is missing, not a
    signal policy or the other learned scheme's is a :class:`ConfigError` naming the option."""
    from mivecc_agents.checkpoints import CheckpointError
    from mivecc_agents.evaluation import LEARNED_SIGNAL_SCHEMES
    from mivecc_agents.signal_policy_files import load_signal_policy, shipped_signal_policy_path

    learned = args.scheme in LEARNED_SIGNAL_SCHEMES
    path, option = args.signal_checkpoint, "--signal-checkpoint"
    if path is None:
        if args.no_pretrained:
            raise ConfigError(f"--no-pretrained: scheme {args.scheme} needs a signal policy; "
                              "give --signal-checkpoint")
        path, option = shipped_signal_policy_path(args.scheme, args.rows, args.cols), (
            "shipped signal policy")
    try:
        policy = load_signal_policy(path)
    except CheckpointError as exc:
        raise ConfigError(f"{option}: {exc}") from exc
    if learned and policy.scheme != args.scheme:
        raise ConfigError(f"{option}: {path} holds a {policy.scheme} policy; scheme "
                          f"{args.scheme} needs a {args.scheme} policy")
    return {"signal": policy}


def vehicle_policies(args: argparse.Namespace) -> dict[str, Any]:
    """``{"vehicle": policy}`` from ``--vehicle-checkpoint`` or the shipped CoMADDPG policy; a
    file that is missing or not a CoMADDPG policy is a :class:`ConfigError` naming the
    option."""
    from mivecc_agents.checkpoints import CheckpointError
    from mivecc_agents.comaddpg import SHIPPED_PATH, CoMADDPGPolicy

    path, option = args.vehicle_checkpoint, "--vehicle-checkpoint"
    if path is None:
        if args.no_pretrained:
            raise ConfigError(f"--no-pretrained: scheme {args.scheme} needs a vehicle policy; "
                              "give --vehicle-checkpoint")
        path, option = SHIPPED_PATH, "shipped vehicle policy"
    try:
        return {"vehicle": CoMADDPGPolicy.load(path)}
    except CheckpointError as exc:
        raise ConfigError(f"{option}: {exc}") from exc


def comparator_policies(args: argparse.Namespace) -> dict[str, Any]:
    """The learned comparator's policies of ``args.scheme`` (:func:`signal_policies` or
    :func:`vehicle_policies`)."""
    from mivecc_agents.evaluation import VEHICLE_AGENT_SCHEMES

    return vehicle_policies(args) if args.scheme in VEHICLE_AGENT_SCHEMES else (
        signal_policies(args))


class TrainCommand(NamedTuple):
    """One training command: where its parts live (``module:name`` paths)."""

    settings: str  #: the settings class
    trainer: str  #: the trainer: ``(settings, on_episode) -> (policy, log)``
    checkpoint: str  #: the file written in ``--out``
    help: str  #: the one-line help
    description: str  #: the command's description
    log_module: str  #: the module with ``write_log``, ``plot_learning_curve``, ``progress_line``
    #: each ``(log) -> str | None``: a note (or a warning) about the finished training, or None
    log_checks: tuple[str, ...] = ()
    #: whether the trainer takes ``on_validated(row, policy)`` (then ``--save-validated``)
    validated: bool = False


#: Folder in ``--out`` of ``--save-validated``'s networks.
VALIDATED_DIR = "validated"


def validated_checkpoint(out: Path, episode: int) -> Path:
    """Where ``--save-validated`` writes the network validated after ``episode`` in ``--out``
    ``out``."""
    return Path(out) / VALIDATED_DIR / f"episode_{int(episode):02d}.pt"

#: The training commands by name.
TRAIN_COMMANDS = {
    "train-signal": TrainCommand("mivecc_agents.signal_dqn_settings:SignalDQNSettings",
                     "mivecc_agents.signal_dqn:train_signal_dqn", "signal_dqn.pt",
                     "train the PA-DQN signal policy (learned signal comparator)",
                     "Train PA-DQN signal agents (DQN, one shared Q-network, a decision every "
                     "decision_period_s) on the single intersection, or on a grid with "
                     "--rows/--cols; docs/comparators.md.", "mivecc_agents.signal_dqn",
                     ("mivecc_agents.signal_dqn:kept_note",), validated=True),
    "train-coder": TrainCommand("mivecc_agents.coder_settings:CoderSettings",
                    "mivecc_agents.coder:train_coder", "coder.pt",
                    "train the Coder signal policy (learned multi-intersection comparator)",
                    "Train Coder (regional DQN agents over 2x2 blocks, then the aggregation of "
                    "their values into the grid's Q-function; a decision every "
                    "decision_period_s) on 3x3, or another grid of 4-12 intersections with "
                    "--rows/--cols; docs/comparators.md.", "mivecc_agents.signal_dqn",
                    ("mivecc_agents.signal_dqn:kept_note",
                     "mivecc_agents.coder:training_shortfall")),
    "train-comaddpg": TrainCommand("mivecc_agents.comaddpg_settings:CoMADDPGSettings",
                       "mivecc_agents.comaddpg:train_comaddpg", "comaddpg.pt",
                       "train the CoMADDPG vehicle policy (learned unsignalized comparator)",
                       "Train CoMADDPG (every vehicle in a control area an agent: one shared "
                       "actor on its virtual-lane view, a centralised critic with its reference "
                       "vehicles' actions, MADDPG) on 3x3, or on another grid with "
                       "--rows/--cols; docs/comparators.md.", "mivecc_agents.comaddpg",
                       ("mivecc_agents.comaddpg:kept_note",), validated=True),
}


def _attr(spec: str) -> Any:
    import importlib

    module, name = spec.split(":")
    return getattr(importlib.import_module(module), name)


def add_train_signal_parser(subparsers: Any) -> argparse.ArgumentParser:
    """The ``train-signal`` subcommand (:func:`_add_train_parser`)."""
    return _add_train_parser(subparsers, "train-signal")


def add_train_coder_parser(subparsers: Any) -> argparse.ArgumentParser:
    """The ``train-coder`` subcommand (:func:`_add_train_parser`)."""
    return _add_train_parser(subparsers, "train-coder")


def add_train_comaddpg_parser(subparsers: Any) -> argparse.ArgumentParser:
    """The ``train-comaddpg`` subcommand (:func:`_add_train_parser`)."""
    return _add_train_parser(subparsers, "train-comaddpg")


def _add_train_parser(subparsers: Any, name: str) -> argparse.ArgumentParser:
    """A training subcommand of :data:`TRAIN_COMMANDS`: every field of its settings class but
    ``config`` as an option (``--set KEY=VALUE`` for config fields)."""
    command = TRAIN_COMMANDS[name]
    p = subparsers.add_parser(name, help=command.help, description=command.description)
    p.add_argument("--out", type=Path, required=True, help=f"folder for {command.checkpoint}, "
                   "train_log.csv and learning_curve.png")
    for f in dataclasses.fields(_attr(command.settings)):
        if f.name == "config":
            continue
        option = "--" + f.name.replace("_", "-")
        if f.name == "densities":
            p.add_argument(option, type=float, nargs="+", default=list(f.default),
                           help=f"{f.metadata['help']} (default "
                           f"{' '.join(f'{d:g}' for d in f.default)})")
            continue
        if f.metadata.get("choices"):
            p.add_argument(option, choices=f.metadata["choices"], default=f.default,
                           help=f"{f.metadata['help']} (default {f.default})")
            continue
        kind = int if isinstance(f.default, int) else float
        p.add_argument(option, type=kind, default=f.default,
                       help=f"{f.metadata['help']} (default {f.default})")
    p.add_argument("--set", dest="set_items", action="append", metavar="KEY=VALUE",
                   default=None,
                   help="a MiVeCCConfig field of the training environments (repeatable)")
    p.add_argument("--threads", type=cli_args.count(1), default=1,
                   help="torch threads (default 1: fastest for these small networks)")
    if command.validated:
        p.add_argument("--save-validated", action="store_true",
                       help=f"also write every validated network to {VALIDATED_DIR}/"
                       "episode_NN.pt in --out (with --keep-network best)")
    p.set_defaults(func=cmd_train_signal, train_command=name)
    return p


def train_settings(args: argparse.Namespace) -> Any:
    """The checked settings of a parsed training subcommand of :data:`TRAIN_COMMANDS`
    (:class:`ConfigError` naming the first bad field)."""
    from mivecc_agents.cli import parse_set_items

    settings_cls = _attr(TRAIN_COMMANDS[args.train_command].settings)
    settings_kw = {f.name: getattr(args, f.name) for f in dataclasses.fields(settings_cls)
                   if f.name not in ("config", "densities")}
    settings_kw["densities"] = tuple(args.densities)
    settings_kw["config"] = parse_set_items(args.set_items)
    return settings_cls(**settings_kw).check()


def cmd_train_signal(args: argparse.Namespace) -> int:
    """Run a training command of :data:`TRAIN_COMMANDS` (``mivecc train-signal``, ...)."""
    import importlib

    from mivecc_agents.cli import set_inference_threads
    from mivecc_agents.train_checks import quiet_train_output

    command = TRAIN_COMMANDS[args.train_command]
    settings = train_settings(args)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out: {out} is a file; give a folder")
    set_inference_threads(args.threads)
    quiet_train_output()  # TorchRL's log lines to stderr: stdout holds the checkpoint's path
    logs = importlib.import_module(command.log_module)
    total = settings.episodes + getattr(settings, "global_episodes", 0)

    def progress(row: dict[str, float]) -> None:
        print(logs.progress_line(row, total), file=sys.stderr, flush=True)

    extra: dict[str, Any] = {}
    if getattr(args, "save_validated", False):
        if settings.keep_network != "best":
            raise ConfigError("--save-validated: needs --keep-network best (with last no "
                              "network is validated)")

        def save_validated(row: dict[str, float], validated: Any) -> None:
            validated.save(validated_checkpoint(out, row["episode"]))

        extra["on_validated"] = save_validated
    policy, log = _attr(command.trainer)(settings, on_episode=progress, **extra)
    path = policy.save(out / command.checkpoint)  # its settings say how it was trained
    logs.write_log(log, out / "train_log.csv")
    logs.plot_learning_curve(log, out / "learning_curve.png")
    for check in command.log_checks:
        note = _attr(check)(log)
        if note:
            print(f"{PROG}: {note}", file=sys.stderr)
    print(path)
    return 0
