"""Argument types and the script entry shared by the ``mivecc`` CLI and the benchmark scripts.

Bad input to a command is one line on stderr and exit status 2, never a traceback: the
:class:`Parser` prints argparse's errors on one line, the types below check each value's range
(the message names the option and the allowed range), and :func:`run` turns the input errors a
run can still raise (:class:`~mivecc_env.config.ConfigError` and its :class:`InputError`, a corrupt
checkpoint, a path that cannot be read or written) into that line too.

Scripts use it as::

    from mivecc_env import cli_args

    parser = cli_args.Parser(description=...)
    parser.add_argument("--steps", type=cli_args.count(1), default=3000)
    ...
    if __name__ == "__main__":
        sys.exit(cli_args.run(main))
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

from mivecc_env.config import ConfigError, from_overrides

__all__ = [
    "InputError", "Parser", "check_distinct", "count", "density", "existing_file", "grid",
    "number", "run", "seed", "whole_density", "writable_dir",
]


class InputError(ConfigError):
    """Bad input a script finds after parsing (a file, a combination of options); a
    :class:`ConfigError`, so that every entry reporting those reports it too."""


class Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr (exit status 2)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def count(low: int) -> Callable[[str], int]:
    """Argument type: an integer >= ``low``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < low:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text!r}")
        return value

    parse.__name__ = f"integer >= {low}"
    return parse


#: Argument type of a seed: an integer >= 0.
seed = count(0)


def number(low: float, high: float | None = None, *, low_ok: bool = True) -> Callable[[str], float]:
    """Argument type: a finite number >= ``low`` (> ``low`` unless ``low_ok``), <= ``high``."""
    allowed = (f"a finite number {'>=' if low_ok else '>'} {low:g}" if high is None
               else f"a number in {'[' if low_ok else '('}{low:g}, {high:g}]")

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        ok = math.isfinite(value) and (value >= low if low_ok else value > low)
        if not ok or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}")
        return value

    parse.__name__ = allowed
    return parse


def _config_field(name: str, value: Any) -> Any:
    """``value`` if the config accepts it for field ``name``; its range in the message if not."""
    try:
        from_overrides(None, **{name: value})
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc).split(": ", 1)[-1]) from None
    return value


def density(text: str) -> float:
    """Argument type: a demand [veh/lane/h] in the config's ``density_vplh`` range."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number [veh/lane/h], got {text!r}") from None
    return float(_config_field("density_vplh", value))


def whole_density(text: str) -> int:
    """Argument type: a whole demand [veh/lane/h] in the config's ``density_vplh`` range."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"must be a whole number [veh/lane/h], got {text!r}") from None
    return int(_config_field("density_vplh", float(value)))


def grid(text: str) -> tuple[int, int]:
    """Argument type: ``ROWSxCOLS``, each in the config's ``rows`` / ``cols`` range."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise argparse.ArgumentTypeError(f"must look like 3x3 (ROWSxCOLS), got {text!r}")
    rows, cols = int(parts[0]), int(parts[1])
    _config_field("rows", rows)
    _config_field("cols", cols)
    return rows, cols


def existing_file(text: str) -> Path:
    """Argument type: the path of a file that exists (an input; checked before any work)."""
    path = Path(text)
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"must be an existing file, got {text!r}")
    return path


def writable_dir(option: str, path: str | os.PathLike[str]) -> Path:
    """Create the output folder ``path`` now, before any work, so that a path that cannot be
    written fails at once (:class:`InputError` naming ``option``), not after a long run."""
    folder = Path(path)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{option}: cannot create {folder}: {exc.strerror or exc}") from None
    if not os.access(folder, os.W_OK):
        raise InputError(f"{option}: cannot write in {folder}")
    return folder


def check_distinct(option: str, values: Sequence[Any] | None) -> None:
    """:class:`InputError` if a value of ``option`` is given twice (a seed run twice would count
    twice in every mean)."""
    seen: set[Any] = set()
    repeated = [v for v in values or () if v in seen or seen.add(v)]
    if repeated:
        raise InputError(f"{option}: each value at most once, got {repeated[0]!r} twice")


def _input_errors() -> tuple[type[BaseException], ...]:
    """The exception types that mean bad input (a checkpoint error only if checkpoints were
    loaded: without the module none can have been raised)."""
    errors: list[type[BaseException]] = [ConfigError]
    checkpoints = sys.modules.get("mivecc_agents.checkpoints")
    if checkpoints is not None:
        errors.append(checkpoints.CheckpointError)
    return tuple(errors)


def run(main: Callable[[], Any], prog: str | None = None) -> int:
    """Call a script's ``main()`` and return its exit status: bad input (including an
    ``OSError`` of a path) is one line on stderr and 2; an interrupt 130; an integer result is
    the status, anything else 0."""
    prog = prog or os.path.basename(sys.argv[0])
    try:
        result = main()
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:  # a path given that cannot be read or written
        where = f": {exc.filename}" if exc.filename is not None else ""
        print(f"{prog}: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return 2
    except Exception as exc:
        if not isinstance(exc, _input_errors()):
            raise
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    return result if isinstance(result, int) and not isinstance(result, bool) else 0
