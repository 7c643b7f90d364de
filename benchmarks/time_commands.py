"""Whole-process timing of one command, or of two in turn (A B A B ...), with paired ratios.

What the docs' timing paragraphs quote (``docs/training.md``, "What the per-environment calls
cost", "Seeds in several processes"; ``docs/performance.md``, "The safety shield's cost"; the
README's command times): each run is a fresh process,
timed from its start to its exit (interpreter start-up, imports and numba's cache loading
included, as a user experiences it), with the operating system's accounting of the finished
process and the children it waited for (user and system CPU seconds, largest resident set).
With ``--vs`` the two commands alternate, and the ratio A/B is taken pair by pair, so that a
machine whose speed drifts during the call moves both sides of each ratio alike. Every figure
is printed as min, median and max over the counted runs; quote the median. A child's peak
memory cannot read below the size of this timer (Linux counts the pages a child shares with
its parent until it starts its program): the report prints that floor (about 100 MiB).

The commands run without a shell (write ``sh -c '...'`` for a pipe or a redirection), with an
empty standard input; what they print goes to ``--log`` (default: thrown away). Each runs in
its own process group, and whatever it leaves running there is killed after it exits (not in
the figures). A command that exits non-zero is reported and makes this script exit 1.

Usage (minutes; the per-environment-call cost of the released paper table, session 36):
    python benchmarks/time_commands.py -n 2 --warmup 0 --out runs/timing.txt \\
        --vs "python benchmarks/paper_table.py --grids 3x3 --schemes EE --seeds 0 1 2 \\
              --steps 3000 --model released --workers 1 --out runs/stacked" \\
        -- python benchmarks/paper_table.py --grids 3x3 --schemes EE --seeds 0 1 2 \\
           --steps 3000 --model released --workers 1 --per-env-calls --out runs/per_env
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import resource
import shlex
import signal
import statistics
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from mivecc_env import cli_args

#: The per-run figures, in the order of the report: attribute, row label.
FIGURES = (("user_s", "user s"), ("sys_s", "sys s"), ("cpu_s", "cpu s"),
           ("wall_s", "wall s"), ("peak_mib", "peak MiB"))
#: The paired ratios A/B reported.
RATIOS = (("user_s", "A/B user"), ("cpu_s", "A/B cpu"), ("wall_s", "A/B wall"))


@dataclass(frozen=True)
class Run:
    """One finished process: what it cost and how it ended."""

    wall_s: float  #: monotonic clock from just before the start to just after reaping [s]
    user_s: float  #: user CPU time of the process and the children it waited for [s]
    sys_s: float  #: system CPU time, as ``user_s`` [s]
    peak_mib: float  #: largest resident set of that process tree's single largest member [MiB]
    exit_code: int  #: the exit status; minus the signal number if a signal ended it

    @property
    def cpu_s(self) -> float:
        """User plus system CPU time [s]."""
        return self.user_s + self.sys_s


def run_once(command: Sequence[str], log: Path | None = None) -> Run:
    """Start ``command``, wait for it and return its figures (Linux: ``ru_maxrss`` in KiB)."""
    out = open(log, "ab") if log is not None else subprocess.DEVNULL  # noqa: SIM115
    try:
        start = time.monotonic()
        process = subprocess.Popen(list(command), stdin=subprocess.DEVNULL, stdout=out,
                                   stderr=subprocess.STDOUT, start_new_session=True)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.monotonic() - start
        process.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
    finally:
        if log is not None:
            out.close()
    # what the command left running in its group is not part of the figures
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(process.pid, signal.SIGKILL)
    return Run(wall_s=wall, user_s=usage.ru_utime, sys_s=usage.ru_stime,
               peak_mib=usage.ru_maxrss / 1024.0, exit_code=process.returncode)


def spread(values: Sequence[float]) -> tuple[float, float, float]:
    """(min, median, max) of ``values``."""
    return min(values), statistics.median(values), max(values)


def paired_ratios(a: Sequence[Run], b: Sequence[Run], figure: str) -> list[float]:
    """``figure`` of A's i-th run over B's i-th run, for every pair."""
    return [getattr(x, figure) / getattr(y, figure) for x, y in zip(a, b, strict=False)]


def _cpu_name() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux), else what :mod:`platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _row(label: str, values: Sequence[float], digits: int) -> str:
    return f"{label:<12}" + "".join(f"{v:>12.{digits}f}" for v in spread(values))


def report(a_command: str, a: Sequence[Run], b_command: str | None = None,
           b: Sequence[Run] = (), warmup: int = 0) -> str:
    """The printed report: commands, machine, exit codes, then min / median / max rows."""
    lines = [f"A = {a_command}"]
    if b_command is not None:
        lines.append(f"B = {b_command}")
    lines.append(f"{time.strftime('%Y-%m-%d', time.gmtime())} UTC | {_cpu_name()} | "
                 f"{os.cpu_count()} logical CPUs | Python {platform.python_version()}")
    sides = [("A", a)] + ([("B", b)] if b_command is not None else [])
    order = "in turn (A B A B ...)" if b_command is not None else "one after another"
    lines.append(f"runs counted: {', '.join(f'{n} {len(r)}' for n, r in sides)}, {order}; "
                 f"warm-up runs before them, not counted: {warmup} each")
    for name, runs in sides:
        failed = [i + 1 for i, r in enumerate(runs) if r.exit_code != 0]
        codes = [runs[i - 1].exit_code for i in failed]
        lines.append(f"{name} exit 0 in all {len(runs)} runs" if not failed else
                     f"{name} FAILED in runs {failed} (exit {codes})")
    lines.append(f"peak floor: about {_own_peak_mib():.1f} MiB (this timer's size, which a child "
                 "shares until it starts its program)")
    lines.append(f"{'':<12}{'min':>12}{'median':>12}{'max':>12}   whole process")
    for name, runs in sides:
        for attr, label in FIGURES:
            lines.append(_row(f"{name} {label}", [getattr(r, attr) for r in runs],
                              1 if attr == "peak_mib" else 3))
    if b_command is not None:
        for attr, label in RATIOS:
            lines.append(_row(label, paired_ratios(a, b, attr), 4))
    return "\n".join(lines) + "\n"


def _own_peak_mib() -> float:
    """This process's largest resident set so far [MiB]: the floor of a child's peak."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def build_parser() -> argparse.ArgumentParser:
    p = cli_args.Parser(
        description="Time whole commands (A, or A and B in turn) and print min / median / max.")
    p.add_argument("-n", "--runs", type=cli_args.count(1), default=5,
                   help="counted runs of each command (default 5)")
    p.add_argument("--warmup", type=cli_args.count(0), default=1,
                   help="runs of each command first, not counted (default 1)")
    p.add_argument("--vs", metavar="COMMAND_B", default=None,
                   help="a second command (one string, split as a shell splits words): "
                   "A and B then alternate and the ratios A/B are paired")
    p.add_argument("--log", type=Path, default=None,
                   help="append every run's output here (default: thrown away)")
    p.add_argument("--out", type=Path, default=None,
                   help="also write the report here, and the runs' figures beside it as JSON")
    p.add_argument("command", nargs=argparse.REMAINDER,
                   help="command A, after --")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Time the commands, print the report (and write it); 1 if any run failed."""
    parser = build_parser()
    args = parser.parse_args(argv)
    a_command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not a_command:
        parser.error("command: give the command to time after --")
    b_command = shlex.split(args.vs) if args.vs is not None else None
    if b_command == []:
        parser.error("--vs: an empty command")
    for option, path in (("--log", args.log), ("--out", args.out)):
        if path is not None:
            cli_args.writable_dir(option, path.parent)
    sides = [("A", a_command)] + ([("B", b_command)] if b_command else [])
    runs: dict[str, list[Run]] = {name: [] for name, _ in sides}
    total = args.warmup + args.runs
    for i in range(total):
        for name, command in sides:
            run = run_once(command, args.log)
            counted = i >= args.warmup
            if counted:
                runs[name].append(run)
            what = f"run {i - args.warmup + 1}/{args.runs}" if counted else "warm-up"
            print(f"{name} {what}: {run.wall_s:.2f} s wall, exit {run.exit_code}",
                  file=sys.stderr, flush=True)
    text = report(shlex.join(a_command), runs["A"],
                  shlex.join(b_command) if b_command else None, runs.get("B", ()), args.warmup)
    print(text, end="")
    if args.out is not None:
        args.out.write_text(text, encoding="utf-8")
        args.out.with_suffix(".json").write_text(json.dumps(
            {name: {"command": shlex.join(cmd), "runs": [asdict(r) for r in runs[name]]}
             for name, cmd in sides}, indent=1) + "\n", encoding="utf-8")
    return int(any(r.exit_code != 0 for rs in runs.values() for r in rs))


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
