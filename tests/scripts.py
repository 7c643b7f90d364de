"""Load a benchmark script as a module, by its path (``benchmarks/`` is not a package)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType
from typing import Any, NoReturn

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def load_benchmark(name: str, module_name: str | None = None) -> ModuleType:
    """Execute ``benchmarks/<name>.py`` as a fresh module named ``module_name`` (default
    ``name``); the folder goes on ``sys.path`` first, since the scripts import their siblings."""
    if str(BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(module_name or name, BENCHMARKS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # as an import does (dataclasses look their module up)
    spec.loader.exec_module(module)
    return module


class ParsedError(Exception):
    """Raised by :func:`stop_after_parsing`'s parser with the parsed options (nothing runs)."""


def stop_after_parsing(monkeypatch: Any) -> None:
    """Make every ``cli_args.Parser`` (the ``mivecc`` CLI's and each script's) raise
    :class:`ParsedError` holding the options as soon as ``parse_args`` has parsed them.

    Args:
        monkeypatch: pytest's ``MonkeyPatch`` (undone at the end of the test).
    """
    from mivecc_env import cli_args

    original = cli_args.Parser.parse_args

    def parse_then_stop(self: Any, args: Any = None, namespace: Any = None) -> NoReturn:
        raise ParsedError(original(self, args, namespace))

    monkeypatch.setattr(cli_args.Parser, "parse_args", parse_then_stop)
