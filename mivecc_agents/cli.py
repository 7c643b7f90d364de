"""The ``mivecc`` command line.

Commands (one ``add_<command>_parser`` and one ``cmd_<command>`` function each; a new command
is added by writing those two and listing the first in :data:`COMMANDS`):

* ``mivecc fields``: list the configuration fields that ``--set`` accepts.
* ``mivecc evaluate``: run a scheme (``E``, ``EE``, ``EEC`` or a comparator, e.g. ``max-pressure``)
  for some steps on one or more seeds and print the traffic metrics (a table, or JSON with
  ``--json``).
* ``mivecc train`` / ``mivecc train-signal`` / ``mivecc train-coder`` / ``mivecc
  train-comaddpg``: train the coordinators (two-stage DDPG) / the PA-DQN or Coder signal policy /
  the CoMADDPG vehicle policy (:mod:`mivecc_agents.cli_signal`).

Examples::

    mivecc evaluate --scheme E --rows 3 --cols 3 --density 2100 --steps 3000 --seed 0 --json
    mivecc evaluate --scheme signalized --seeds 0 1 2 --out results.json
    mivecc evaluate --scheme E --end-rule literal --same-lane-rule --set omega=0.3

A bad configuration value exits with status 2 and the message on stderr (no traceback).
Standard output holds only the result (the table, the JSON, or ``train``'s checkpoint path);
logs, warnings and progress bars go to stderr. Metrics that have no data yet (e.g. travel
velocity before any vehicle has exited) are ``null`` in the JSON.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from mivecc_agents.cli_signal import (
    add_train_coder_parser,
    add_train_comaddpg_parser,
    add_train_signal_parser,
    comparator_policies,
    signal_policies,
    vehicle_policies,
)
from mivecc_agents.evaluation import (
    LEARNED_SIGNAL_SCHEMES,
    SCHEMES,
    VEHICLE_AGENT_SCHEMES,
    adopt_cloud_period,
    aggregate,
    evaluate_batch,
    evaluate_scheme,
)
from mivecc_env import __version__, cli_args
from mivecc_env.config import ALIASES, ConfigError, MiVeCCConfig, describe_fields
from mivecc_env.config import from_overrides as _config_from

PROG = "mivecc"

#: Default arrival density [veh/lane/h] of every command: the config field's default.
DEFAULT_DENSITY: float = MiVeCCConfig.__dataclass_fields__["density_vplh"].default

#: Default torch intra-op threads of ``evaluate``: inference of the small coordinator networks
#: is fastest on one thread (measured 7-10x faster than torch's default on a shared 2-core box).
DEFAULT_EVAL_THREADS = 1

#: Config fields that have their own option; ``--set`` may not give them too.
_DEDICATED = {
    "rows": "--rows", "cols": "--cols", "density_vplh": "--density", "max_steps": "--steps",
    "scheme": "--scheme",
}

#: Keys printed (in this order) by the readable table of ``evaluate``.
_TABLE_KEYS: tuple[str, ...] = (
    "avg_travel_velocity_mps", "avg_travel_velocity_no_wait_mps", "upper_bound_mps",
    "mean_speed_mps", "throughput", "throughput_vph", "collisions", "collided_vehicles",
    "released_check_collisions", "backlog", "in_network", "arrived", "mean_trip_time_s",
    "mean_wait_time_s", "sim_time_s",
    "released_velocity_mps", "released_passed", "min_ttc_s", "ttc_p1_s", "min_pet_s",
    "pet_under_1s", "pet_samples", "min_distance_m", "steps", "steps_per_s",
)


# ----------------------------------------------------------------------------------------------
# shared option groups (reusable by later commands, e.g. ``train``)
def parse_set_value(text: str) -> Any:
    """Turn the value of ``--set key=value`` into a bool, None, int, float or string."""
    low = text.strip().lower()
    if low in ("true", "yes", "on"):
        return True
    if low in ("false", "no", "off"):
        return False
    if low in ("none", "null"):
        return None
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def parse_set_items(items: Sequence[str] | None) -> dict[str, Any]:
    """``["key=value", ...]`` -> ``{key: value}``; a malformed item raises ConfigError."""
    out: dict[str, Any] = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"--set: expected key=value, got {item!r}")
        out[key] = parse_set_value(value)
    return out


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    """Options that shape the simulated network and model (grid, demand, rule readings)."""
    g = parser.add_argument_group("configuration")
    g.add_argument("--rows", type=int, default=3, help="intersection rows (default 3)")
    g.add_argument("--cols", type=int, default=3, help="intersection columns (default 3)")
    g.add_argument("--density", type=float, default=DEFAULT_DENSITY,
                   help=f"arrivals per entry lane [veh/lane/h] (default {DEFAULT_DENSITY:g})")
    g.add_argument("--end-rule", choices=("sensible", "literal"), default=None,
                   help="end-node rule reading (default: the config's, 'sensible')")
    g.add_argument("--same-lane-rule", action="store_true", default=None,
                   help="enable the released code's same-lane rule")
    g.add_argument("--set", dest="set_items", metavar="KEY=VALUE", nargs="+", action="extend",
                   default=[], help="any other config field, e.g. --set omega=0.3 "
                   "edge_sv_gate=-2 (`mivecc fields` lists them)")


def set_overrides(items: Sequence[str] | None, dedicated: Mapping[str, str]) -> dict[str, Any]:
    """``--set`` items as config overrides; a field that has its own option (``dedicated``:
    field -> option) raises ConfigError naming that option."""
    overrides = parse_set_items(items)
    for key in overrides:
        name = ALIASES.get(key, key)
        if name in dedicated:
            raise ConfigError(f"{key}: use {dedicated[name]} instead of --set")
    return overrides


def config_overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """Config overrides from :func:`add_config_arguments` options (not rows/cols/density)."""
    overrides = set_overrides(args.set_items, _DEDICATED)
    for name, value in (("end_rule", args.end_rule), ("same_lane_rule", args.same_lane_rule)):
        if value is None:
            continue
        if name in overrides and overrides[name] != value:
            raise ConfigError(f"{name}: given both as --{name.replace('_', '-')} and --set")
        overrides[name] = value
    return overrides


# ----------------------------------------------------------------------------------------------
# evaluate
def add_evaluate_parser(subparsers: Any) -> argparse.ArgumentParser:
    """The ``evaluate`` subcommand."""
    p = subparsers.add_parser(
        "evaluate", help="run a scheme and print its traffic metrics",
        description="Run one episode of the MiVeCC ParallelEnv per seed and print its metrics. "
        "EE/EEC without trained policies run with zero coordinator actions (with a warning).",
    )
    p.add_argument("--scheme", choices=SCHEMES, default="E",
                   help="E, EE, EEC, or a comparator: fixed-time (alias signalized), actuated, "
                   "max-pressure, reservation, optimisation, pa-dqn, coder (learned signals), "
                   "comaddpg (learned vehicle agents; docs/comparators.md; default E)")
    add_config_arguments(p)
    p.add_argument("--steps", type=int, default=3000, help="env steps of 0.1 s (default 3000)")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--seeds", type=int, nargs="+", default=None,
                   help="several seeds: one result per seed plus their mean (overrides --seed)")
    p.add_argument("--json", action="store_true",
                   help="print JSON: one object, or {runs, mean, std} for several seeds")
    p.add_argument("--out", type=Path, default=None,
                   help="also write the JSON result to this file")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--edge-checkpoint", type=Path, default=None,
                   help="edge policy checkpoint (default: the shipped pretrained one)")
    p.add_argument("--cloud-checkpoint", type=Path, default=None,
                   help="cloud policy checkpoint (default: the shipped pretrained one)")
    p.add_argument("--signal-checkpoint", type=Path, default=None,
                   help="schemes pa-dqn and coder: signal policy checkpoint (default: the "
                   "shipped one; mivecc train-signal / train-coder write one)")
    p.add_argument("--vehicle-checkpoint", type=Path, default=None,
                   help="scheme comaddpg: the vehicles' policy checkpoint (default: the shipped "
                   "one; mivecc train-comaddpg writes one)")
    p.add_argument("--no-pretrained", action="store_true",
                   help="ignore the shipped checkpoints: EE/EEC act with zero coordinator "
                   "actions (pa-dqn and coder then need --signal-checkpoint, comaddpg "
                   "--vehicle-checkpoint)")
    p.add_argument("--threads", type=int, default=DEFAULT_EVAL_THREADS,
                   help="torch threads for the policies' inference (default "
                   f"{DEFAULT_EVAL_THREADS}: fastest for these small networks)")
    p.add_argument("--stack-policies", action="store_true",
                   help="with several seeds: call each policy once on all seeds' graphs stacked "
                   "where a check finds that exact (faster; a run can then differ from its "
                   "single run in rare steps); default: one call per seed")
    p.add_argument("--workers", type=cli_args.count(1), default=1,
                   help="with several seeds: processes that share the seeds (default 1; at most "
                   "one per seed); each run is the same as with one process, except with "
                   "--stack-policies, whose stacks then hold each process's seeds")
    p.set_defaults(func=cmd_evaluate)
    return p


def _fmt(value: Any) -> str:
    if isinstance(value, float) and math.isnan(value):
        return "no data"
    if isinstance(value, float):
        if math.isfinite(value) and value == int(value) and abs(value) < 1e12:
            return str(int(value))
        return f"{value:.4g}" if abs(value) >= 1e4 else f"{value:.3f}"
    return str(value)


def format_table(results: list[dict[str, Any]], mean: dict[str, Any] | None = None) -> str:
    """A readable table: one column per run (and a mean column for several runs)."""
    first = results[0]
    head = (f"scheme {first['scheme']}  grid {first['rows']}x{first['cols']}  "
            f"density {_fmt(first['density'])} veh/lane/h  end_rule {first['end_rule']}  "
            f"same_lane_rule {first['same_lane_rule']}  coordinator actions "
            f"{first['coordinator_actions']}")
    columns = [f"seed {r['seed']}" for r in results]
    cells = [[_fmt(r.get(k, "")) for r in results] for k in _TABLE_KEYS]
    if mean is not None:
        columns.append("mean")
        for row, k in zip(cells, _TABLE_KEYS, strict=True):
            row.append(_fmt(mean.get(k, "")))
    w0 = max(len(k) for k in _TABLE_KEYS)
    widths = [max(len(c), *(len(row[j]) for row in cells)) for j, c in enumerate(columns)]
    lines = [head, "", "  ".join([" " * w0, *(c.rjust(w) for c, w in zip(columns, widths,
                                                                           strict=True))])]
    for k, row in zip(_TABLE_KEYS, cells, strict=True):
        lines.append("  ".join([k.ljust(w0), *(v.rjust(w) for v, w in zip(row, widths,
                                                                          strict=True))]))
    return "\n".join(lines)


def evaluation_policies(
    args: argparse.Namespace, config: MiVeCCConfig | None = None,
    overrides: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Coordinator policies for ``evaluate``: given checkpoints, else the shipped ones of the
    config's ``model`` (``pretrained/`` for ``paper``, ``pretrained/released/``).

    With ``config`` (the evaluation's), each policy's training config is compared with it: a
    K that does not fit is an error, other differences are warned about on stderr. With
    ``overrides`` (the evaluation's config overrides) as well, a learned cloud's training
    ``cloud_period`` is adopted first (:func:`adopt_cloud_period`).
    """
    if not _loads_policies(args):  # nothing to load: torch is not imported
        return {}
    from mivecc_agents.checkpoints import CheckpointError
    from mivecc_agents.policies import (
        check_policy_config,
        load_policy,
        pretrained_path,
        uses_policy,
    )

    # the shipped policies per model, and per shield setting where the model has shield ones
    model = config.model if config is not None else "paper"
    shield = config.safety_shield if config is not None else False
    paths = {}
    for kind in ("edge", "cloud"):
        # a shipped policy the scheme does not use is not loaded (a given one is, and warned
        # about below)
        unused = config is not None and not uses_policy(config, kind)
        paths[kind] = None if args.no_pretrained or unused else pretrained_path(kind, model, shield)
    given = {"edge": args.edge_checkpoint, "cloud": args.cloud_checkpoint}
    policies, options = {}, {}
    for kind in ("edge", "cloud"):
        path, options[kind] = given[kind], f"--{kind}-checkpoint"
        if path is None:
            path, options[kind] = paths[kind], f"shipped {kind} policy"
        if path is None:
            continue
        try:
            policies[kind] = load_policy(path, expected_kind=kind)
        except CheckpointError as exc:  # a user error: exit 2 with the message
            raise ConfigError(f"{options[kind]}: {exc}") from exc
    if config is not None:
        if overrides is not None and adopt_cloud_period(policies, overrides, config.scheme):
            config = _config_from(config, cloud_period=overrides["cloud_period"])
        for kind, policy in policies.items():
            try:
                messages = check_policy_config(policy, config)
            except CheckpointError as exc:
                raise ConfigError(f"{options[kind]}: {exc}") from exc
            for message in messages:
                print(f"{PROG}: warning: {options[kind]}: {message}", file=sys.stderr)
    return policies


def _loads_policies(args: argparse.Namespace) -> bool:
    """Whether ``evaluate`` loads a policy: a checkpoint is given, or the shipped ones are used
    (the scheme decides which of them)."""
    given = (args.edge_checkpoint, args.cloud_checkpoint)
    return not args.no_pretrained or any(path is not None for path in given)


def _check_checkpoint_files(args: argparse.Namespace) -> None:
    """A given checkpoint path that is no file is an error before anything is imported
    (loading it would import torch first, several seconds)."""
    for kind in ("edge", "cloud", "signal", "vehicle"):
        path = getattr(args, f"{kind}_checkpoint")
        if path is not None and not Path(path).is_file():
            raise ConfigError(f"--{kind}-checkpoint: {path}: no such checkpoint file")


def _check_threads(option: str, threads: Any) -> int:
    """``threads`` as an int, or ``ConfigError`` naming ``option`` if it is not >= 1."""
    if threads is None or threads < 1:
        raise ConfigError(f"{option}: must be an integer >= 1, got {threads!r}")
    return int(threads)


def set_inference_threads(threads: int) -> None:
    """Limit torch to ``threads`` intra-op threads (and OpenMP, if torch is not loaded yet)."""
    if "torch" not in sys.modules:
        os.environ["OMP_NUM_THREADS"] = str(threads)
    import torch

    torch.set_num_threads(threads)


def json_document(document: Any) -> str:
    """``document`` as JSON, with NaN / inf ("no data", e.g. no vehicle has exited) as null."""
    def clean(value: Any) -> Any:
        if isinstance(value, float) and not math.isfinite(value):
            return None
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, list | tuple):
            return [clean(v) for v in value]
        return value

    return json.dumps(clean(document), indent=2, allow_nan=False)


def _write_out(option: str, path: Path, text: str) -> None:
    """Write ``text`` to ``path``; an unwritable path is a user error (exit 2)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{option}: cannot write {path}: {exc.strerror or exc}") from exc


def _evaluation_config(args: argparse.Namespace, overrides: dict[str, Any]) -> MiVeCCConfig:
    scheme = {"scheme": "E", "control": "signalized"} if args.scheme == "signalized" else {
        "scheme": args.scheme}
    return _config_from(None, **{**overrides, **scheme, "rows": args.rows, "cols": args.cols,
                                 "density_vplh": args.density})


def _check_unused_checkpoints(args: argparse.Namespace) -> None:
    """A scheme without coordinators (E, signalized) ignores ``--edge-checkpoint`` and
    ``--cloud-checkpoint``: a given file must still load (a wrong path is an error), and a
    warning says that it is not used. Without a checkpoint nothing is imported (torch's import
    would double the time of a rules-only evaluation)."""
    given = [(kind, path) for kind in ("edge", "cloud")
             if (path := getattr(args, f"{kind}_checkpoint")) is not None]
    if not given:
        return
    from mivecc_agents.checkpoints import CheckpointError
    from mivecc_agents.policies import load_policy

    for kind, path in given:
        try:
            load_policy(path, expected_kind=kind)
        except CheckpointError as exc:
            raise ConfigError(f"--{kind}-checkpoint: {exc}") from exc
        print(f"{PROG}: warning: --{kind}-checkpoint: scheme {args.scheme} runs without "
              "coordinators: the policy is ignored", file=sys.stderr)


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Run ``evaluate``: one episode per seed, print and optionally save the metrics."""
    overrides = config_overrides_from_args(args)
    seeds = args.seeds if args.seeds else [args.seed]
    cli_args.check_distinct("--seeds", seeds)
    threads = _check_threads("--threads", args.threads)
    _check_checkpoint_files(args)
    policies = {}
    if args.scheme in ("EE", "EEC"):
        config = _evaluation_config(args, overrides)
        if _loads_policies(args):
            set_inference_threads(threads)
        policies = evaluation_policies(args, config, overrides)
    elif args.scheme in (*LEARNED_SIGNAL_SCHEMES, *VEHICLE_AGENT_SCHEMES):
        _check_unused_checkpoints(args)
        set_inference_threads(threads)
        policies = comparator_policies(args)
    else:
        _check_unused_checkpoints(args)
    for kind, users, load in (("signal", LEARNED_SIGNAL_SCHEMES, signal_policies),
                              ("vehicle", VEHICLE_AGENT_SCHEMES, vehicle_policies)):
        if getattr(args, f"{kind}_checkpoint") is not None and args.scheme not in users:
            load(args)  # a given file must load, even when it is not used
            print(f"{PROG}: warning: --{kind}-checkpoint: scheme {args.scheme} has no "
                  f"learned {kind} agents: the policy is ignored", file=sys.stderr)
    if len(seeds) == 1:
        results = [evaluate_scheme(args.scheme, args.rows, args.cols, args.density, args.steps,
                                   seeds[0], policies=policies, progress=not args.no_progress,
                                   **overrides)]
    else:  # the seeds as batches of environments (same results as one run per seed)
        results = _evaluate_seeds(args, overrides, seeds, policies)
    for result in results:
        for kind, policy in policies.items():
            result[f"{kind}_checkpoint"] = getattr(policy, "checkpoint", "")
    _note_box_blocking(results)
    if len(results) == 1:
        document: dict[str, Any] = results[0]
        stats = None
    else:
        stats = aggregate(results)
        document = {"runs": results, **stats}
    text = json_document(document)
    if args.out is not None:
        _write_out("--out", args.out, text + "\n")
    if args.json:
        print(text)
    else:
        print(format_table(results, stats["mean"] if stats else None))
    return 0


def _note_box_blocking(results: list[dict[str, Any]]) -> None:
    """One line on stderr when signal runs without the keep-clear rule collided: such events
    are often vehicles that drove into a blocked box, not the phases' doing."""
    events = sum(r["collisions"] for r in results
                 if r.get("control") == "signalized" and not r.get("signal_keep_clear"))
    if events:
        print(f"{PROG}: note: {events:.0f} strict collision events under signals without the "
              "keep-clear rule; vehicles that drive into a blocked box collide there: rerun "
              "with the rule (the default, signal_keep_clear=true) to tell them apart "
              "(docs/comparators.md, \"Keeping the box clear\")", file=sys.stderr)


def _evaluate_seeds(args: argparse.Namespace, overrides: dict[str, Any], seeds: list[int],
                    policies: dict[str, Any]) -> list[dict[str, Any]]:
    """Results of several seeds, in their order: one batch of environments, or with
    ``--workers N`` one batch per worker process, each a contiguous share of the seeds."""
    workers = min(args.workers, len(seeds))
    if workers == 1:
        return _evaluate_share((args, overrides, seeds, 0), policies)
    from mivecc_env.processes import map_jobs

    size, extra = divmod(len(seeds), workers)
    bounds = [i * size + min(i, extra) for i in range(workers + 1)]
    jobs = [(args, overrides, seeds[bounds[i]:bounds[i + 1]], i) for i in range(workers)]
    batches = map_jobs(_evaluate_share, jobs, workers, f"{args.scheme} seeds in {workers} "
                       "processes", show=not args.no_progress, unit="share", leave=False)
    return [row for batch in batches for row in batch]


def _evaluate_share(job: tuple[argparse.Namespace, dict[str, Any], list[int], int],
                    policies: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """One share of the seeds as one batch of environments. In a worker process (``policies``
    None) the policies of the evaluation's config are loaded again, without repeating the
    parent's warnings and without a progress bar; only the first share warns about missing
    policies."""
    args, overrides, seeds, index = job
    in_worker = policies is None
    if policies is None:
        policies = {}
        if args.scheme in ("EE", "EEC") and _loads_policies(args):
            set_inference_threads(args.threads)
            with contextlib.redirect_stderr(io.StringIO()):  # the parent has warned
                policies = evaluation_policies(args, _evaluation_config(args, overrides))
        elif args.scheme in (*LEARNED_SIGNAL_SCHEMES, *VEHICLE_AGENT_SCHEMES):
            set_inference_threads(args.threads)
            policies = comparator_policies(args)
    return evaluate_batch(args.scheme, args.rows, args.cols, args.density, args.steps, seeds,
                          policies=policies, progress=not (in_worker or args.no_progress),
                          warn=index == 0,
                          stack_policies=args.stack_policies, **overrides)


# ----------------------------------------------------------------------------------------------
# fields
def add_fields_parser(subparsers: Any) -> argparse.ArgumentParser:
    """The ``fields`` subcommand."""
    p = subparsers.add_parser(
        "fields", help="list the configuration fields (for --set) with their defaults",
        description="List every MiVeCCConfig field with its default and meaning.",
    )
    p.set_defaults(func=cmd_fields)
    return p


def cmd_fields(args: argparse.Namespace) -> int:
    """Run ``fields``: print every config field, its default and its description."""
    for name, default, doc in describe_fields():
        print(f"{name} = {default!r}\n    {doc}")
    return 0


# ----------------------------------------------------------------------------------------------
#: Subcommand builders, in the order ``--help`` lists them.
COMMANDS: list[Callable[[Any], argparse.ArgumentParser]] = [add_evaluate_parser, add_fields_parser]


def add_train_parser(subparsers: Any) -> argparse.ArgumentParser:
    """``mivecc train``: two-stage DDPG training (see :mod:`mivecc_agents.training`)."""
    from mivecc_agents.presets import add_train_arguments

    p = subparsers.add_parser("train", help="train the edge (stage I) or cloud (stage II) policy")
    add_train_arguments(p)
    p.set_defaults(func=cmd_train)
    return p


def cmd_train(args: argparse.Namespace) -> int:
    """Run ``mivecc train`` (imports torch only now)."""
    from mivecc_agents.train_checks import (
        check_network_sizes,
        check_train_args,
        quiet_train_output,
    )

    check_train_args(args)
    # OpenMP reads its thread count when torch is first imported; torch.set_num_threads later
    # does not reach every thread, and oversubscribed cores slowed training ~10x (measured).
    from mivecc_agents.presets import thread_settings

    for name, value in thread_settings(args.stage, args.threads).items():
        if args.threads is not None and name == "OMP_NUM_THREADS":
            os.environ[name] = value  # an explicit --threads wins
        else:
            os.environ.setdefault(name, value)
    quiet_train_output()
    check_network_sizes(args)
    check_train_checkpoints(args)
    from mivecc_agents.training import train_from_args

    return train_from_args(args)


def check_train_checkpoints(args: argparse.Namespace) -> None:
    """Load ``--edge-checkpoint`` (stage II) and ``--resume`` as policies before training, so a
    wrong file, kind or weight shape is one line and exit 2 (not a traceback mid-setup)."""
    from mivecc_agents.checkpoints import CheckpointError
    from mivecc_agents.policies import check_policy_config, load_policy

    checks = [("--edge-checkpoint", args.edge_checkpoint, "edge")] if args.stage == "cloud" else []
    checks.append(("--resume", args.resume, args.stage))
    for option, path, kind in checks:
        if path is None:
            continue
        try:
            policy = load_policy(path, expected_kind=kind)
            if option == "--edge-checkpoint":  # frozen in stage II: does it fit that env?
                for message in check_policy_config(policy, _stage2_config(args)):
                    print(f"{PROG}: warning: {option}: {message}", file=sys.stderr)
        except CheckpointError as exc:
            raise ConfigError(f"{option}: {exc}") from exc


def _stage2_config(args: argparse.Namespace) -> MiVeCCConfig:
    """The stage-II training env's config (as ``mivecc train`` builds it, first density)."""
    return _config_from(None, **{**parse_set_items(args.set_items), "rows": args.rows or 3,
                                 "cols": args.cols or 3, "density": args.density[0],
                                 "scheme": "EEC"})


COMMANDS.extend([add_train_parser, add_train_signal_parser, add_train_coder_parser,
                 add_train_comaddpg_parser])


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one subparser per entry of :data:`COMMANDS`."""
    parser = cli_args.Parser(
        prog=PROG, description="MiVeCC: multi-intersection vehicular cooperative control.",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for add in COMMANDS:
        add(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mivecc`` console script; returns the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version and usage errors
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    if getattr(args, "func", None) is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(args.func(args))
    except ConfigError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `mivecc fields | head`
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - silence the flush at exit
        return 0


if __name__ == "__main__":
    sys.exit(main())
