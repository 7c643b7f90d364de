"""Checks and output hygiene of ``mivecc train``, run before any training starts.

* :func:`check_train_args` rejects every bad option value with one line naming the option and
  its allowed range (:class:`~mivecc_env.config.ConfigError`, exit status 2), before torch is
  imported: frames, episode steps, grid, densities, ``--set`` fields, replay size, workers,
  threads and an output folder that cannot be written.
* :func:`check_network_sizes` rejects ``--set k_edge=...`` / ``k_cloud`` values that the
  networks (fixed K) cannot read.
* :func:`quiet_train_output` keeps standard output for the checkpoint path only: TorchRL's
  console log goes to stderr, and TorchRL's note that it was tested with another PettingZoo
  version is not shown (one per env; this package's tests run the versions it pins; a
  "once" filter does not hold because TorchRL's ``catch_warnings`` blocks reset it).
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

from mivecc_agents.presets import preset_with
from mivecc_env.config import ALIASES, ConfigError, from_overrides

__all__ = ["check_network_sizes", "check_train_args", "quiet_train_output"]

#: Start of TorchRL's warning about the PettingZoo version it was tested with.
PETTINGZOO_VERSION_NOTE = "PettingZoo in TorchRL is tested"


def _int_at_least(option: str, value: Any, low: int, why: str = "") -> None:
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ConfigError(f"{option}: must be an integer >= {low}{why}, got {value!r}")


def _config_value(option: str, **field: Any) -> None:
    """Validate one config field given by a dedicated option; the message names the option."""
    try:
        from_overrides(None, **field)
    except ConfigError as exc:
        text = str(exc)
        name = next(iter(field))
        name = ALIASES.get(name, name)
        raise ConfigError(f"{option}: {text.removeprefix(name + ': ')}") from None


def _check_out_dir(out: str | os.PathLike) -> None:
    """The output folder exists (or can be made) and a file can be written in it."""
    path = Path(out)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise ConfigError(
            f"--out: cannot write to folder {str(path)!r}: {exc.strerror or exc}"
        ) from None


def check_train_args(args: argparse.Namespace) -> None:
    """Raise :class:`ConfigError` naming the first bad ``mivecc train`` option.

    Frames must cover at least one collection batch (the preset's frames per batch times the
    number of densities); the replay buffer must hold at least one minibatch.
    """
    from mivecc_agents.cli import parse_set_items

    try:
        preset = preset_with(args.preset, parse_set_items(getattr(args, "preset_items", [])))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    preset = preset.for_stage(args.stage)
    n_dens = len(args.density)
    per_batch = preset.frames_per_batch * n_dens
    _int_at_least("--frames", args.frames, per_batch,
                  f" (one collection batch: {preset.frames_per_batch} frames x {n_dens} "
                  "densities)")
    _int_at_least("--episode-steps", args.episode_steps, 1)
    _int_at_least("--workers", args.workers, 1)
    _int_at_least("--threads", args.threads, 1)
    _int_at_least("--buffer-size", args.buffer_size, preset.batch_size,
                  f" (one minibatch of preset {preset.name!r})")
    for option, name in (("--rows", "rows"), ("--cols", "cols")):
        value = getattr(args, name)
        if value is not None:
            _config_value(option, **{name: value})
    for d in args.density:
        if not math.isfinite(d):
            raise ConfigError(f"--density: must be finite, got {d!r}")
        _config_value("--density", density=d)
    if args.episode_steps is not None:
        _config_value("--episode-steps", max_steps=args.episode_steps)
    overrides = parse_set_items(args.set_items)
    from_overrides(None, **overrides)  # the message names the --set field
    _check_out_dir(args.out)


def check_network_sizes(args: argparse.Namespace) -> None:
    """``--set k_edge=/k_cloud=`` must equal the K the networks are built for."""
    from mivecc_agents.cli import parse_set_items
    from mivecc_agents.networks import get_network_spec

    overrides = parse_set_items(args.set_items)
    for kind in ("edge", "cloud"):
        name = f"k_{kind}"
        if name in overrides:
            k = get_network_spec(kind).grid_size
            if overrides[name] != k:
                raise ConfigError(
                    f"{name}: the {kind} network reads K={k} state graphs, got {overrides[name]!r}"
                )


def quiet_train_output() -> None:
    """TorchRL's console log to stderr; its PettingZoo version warning silenced.

    Also set for worker processes (``TORCHRL_CONSOLE_STREAM``, ``PYTHONWARNINGS``).
    """
    import warnings

    os.environ.setdefault("TORCHRL_CONSOLE_STREAM", "stderr")
    note = f"ignore:{PETTINGZOO_VERSION_NOTE}:UserWarning"
    current = os.environ.get("PYTHONWARNINGS", "")
    if note not in current:
        os.environ["PYTHONWARNINGS"] = f"{current},{note}" if current else note
    warnings.filterwarnings("ignore", message=PETTINGZOO_VERSION_NOTE, category=UserWarning)
    import torchrl  # noqa: F401 - creates the "torchrl" logger

    for handler in logging.getLogger("torchrl").handlers:
        if type(handler) is logging.StreamHandler and handler.stream is not _STDERR:
            with handler.lock:  # (not setStream: it flushes the old stream, maybe closed)
                handler.stream = _STDERR


class _CurrentStderr:
    """Writes to whatever ``sys.stderr`` is at the time (it may be replaced after import)."""

    def write(self, text: str) -> int:
        return sys.stderr.write(text)

    def flush(self) -> None:
        sys.stderr.flush()


_STDERR = _CurrentStderr()
