"""Saving and loading MiVeCC training checkpoints.

A checkpoint is a plain ``dict`` written with :func:`torch.save` (only tensors, numbers, strings,
lists and dicts, so it loads with ``torch.load(weights_only=True)``, no pickled code):

=====================  ==============================================================
key                    content
=====================  ==============================================================
``format``             :data:`CHECKPOINT_FORMAT` (marks a mivecc checkpoint)
``format_version``     :data:`CHECKPOINT_FORMAT_VERSION`
``package_version``    ``mivecc_env.__version__`` when written
``env_version``        ``mivecc_env.ENV_VERSION`` (``"mivecc_v0"``)
``config``             the environment config as a dict (``MiVeCCConfig.to_dict()``)
``stage``              ``"edge"`` (stage I) or ``"cloud"`` (stage II)
``kind``               network kind trained, ``"edge"`` or ``"cloud"``
``grid_size``          K of the network (15 or 60)
``preset``             the training preset as a dict
``actor``              actor network state dict (``MiVeCCActorNet``)
``critic``             critic network state dict (``MiVeCCCriticNet``; ``CriticEnsembleNet``, keys
                       ``members.<i>.``, with ``critic_members`` > 1)
``loss``               DDPGLoss (or TD3Loss) state dict (actor, critic(s), their target copies)
``optimizer``          Adam state dict
``frames``             environment frames collected so far
``updates``            gradient updates done so far
``metrics``            last logged metrics (dict of floats; a best-policy checkpoint adds its
                       ``eval_select`` rule by name)
``extra``              free-form (e.g. the edge checkpoint used in stage II)
=====================  ==============================================================

Files are written atomically (temporary file in the same folder, then :func:`os.replace`), so
an interrupted save never leaves a truncated checkpoint behind. The temporary file is named
``.<name>.pid<PID>.<random>.tmp``; one left by a killed save (its process is gone) is deleted by
the next :func:`save_checkpoint` or :func:`load_checkpoint` of that path.
"""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import torch

import mivecc_env
from mivecc_agents.networks import get_network_spec

__all__ = [
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_FORMAT_VERSION",
    "ENV_VERSION",
    "CheckpointError",
    "export_policy",
    "load_checkpoint",
    "read_checkpoint",
    "remove_stale_temp_files",
    "save_checkpoint",
]

CHECKPOINT_FORMAT = "mivecc-checkpoint"
CHECKPOINT_FORMAT_VERSION = 1
ENV_VERSION = mivecc_env.ENV_VERSION  #: the env a checkpoint was trained on
_REQUIRED = ("format_version", "kind", "grid_size", "actor", "critic", "stage")


class CheckpointError(Exception):
    """A file is not a usable mivecc checkpoint (missing, corrupt, wrong kind or version)."""


#: Temporary files without a writer PID (older versions) are stale after this long [s].
_LEGACY_TMP_AGE_S = 600.0


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):  # exists but belongs to someone else
        return True
    return True


def remove_stale_temp_files(path: str | os.PathLike) -> list[Path]:
    """Delete the temporary files that interrupted saves of ``path`` left in its folder.

    A temporary file is stale when the process named in it (``.pid<PID>.``) no longer runs; one
    of an older version (no PID) when it is older than 10 minutes. Files that cannot be deleted
    (read-only folder) are left alone.

    Returns:
        The files deleted.
    """
    path = Path(path)
    pattern = re.compile(re.escape(f".{path.name}.") + r"(?:pid(\d+)\.)?[^/]*\.tmp")
    removed = []
    try:
        candidates = [p for p in path.parent.iterdir() if pattern.fullmatch(p.name)]
    except OSError:
        return removed
    for tmp in candidates:
        match = pattern.fullmatch(tmp.name)
        try:
            if match and match.group(1) is not None:
                pid = int(match.group(1))
                if pid == os.getpid() or _process_alive(pid):
                    continue
            elif time.time() - tmp.stat().st_mtime < _LEGACY_TMP_AGE_S:
                continue
            tmp.unlink()
            removed.append(tmp)
        except OSError:
            continue
    return removed


def _plain(value: Any) -> Any:
    """Convert numpy scalars / tuples to plain Python so ``weights_only=True`` can load them."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, torch.Tensor) or value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        return float(value)
    if hasattr(value, "item"):  # numpy scalar
        return value.item()
    if isinstance(value, Path):
        return str(value)
    return value


def network_variant(ckpt: dict[str, Any]) -> str:
    """The network variant a checkpoint was trained with: its ``network`` entry, else its
    preset's, else ``"paper"`` (checkpoints written before network variants)."""
    return str(ckpt.get("network") or (ckpt.get("preset") or {}).get("network") or "paper")


def save_checkpoint(path: str | os.PathLike, payload: dict[str, Any]) -> Path:
    """Write a checkpoint atomically.

    Args:
        path: Destination file (parent folders are created).
        payload: The checkpoint content (see the module docstring); ``format``,
            ``format_version``, ``package_version`` and ``env_version`` are filled in.

    Returns:
        The path written.

    Raises:
        IsADirectoryError: ``path`` is a folder.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder; a checkpoint needs a file name "
                                f"(e.g. {path / 'policy.pt'})")
    path.parent.mkdir(parents=True, exist_ok=True)
    data = dict(payload)
    data.update(
        format=CHECKPOINT_FORMAT,
        format_version=CHECKPOINT_FORMAT_VERSION,
        package_version=mivecc_env.__version__,
        env_version=ENV_VERSION,
    )
    data = _plain(data)
    remove_stale_temp_files(path)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}.pid{os.getpid()}.", suffix=".tmp", dir=path.parent
    )
    try:
        with os.fdopen(fd, "wb") as fh:
            torch.save(data, fh)
            fh.flush()
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _first_sentence(text: str, limit: int = 120) -> str:
    """The first sentence of an error message, at most ``limit`` characters (torch's loader
    errors go on with advice, such as unpickling untrusted files, that does not apply)."""
    first = text.strip().splitlines()[0] if text.strip() else ""
    first = first.split(". ")[0]
    return first if len(first) <= limit else first[: limit - 3] + "..."


def require_keys(path: str | os.PathLike, data: dict[str, Any], keys: Sequence[str]) -> None:
    """``CheckpointError`` naming the file and the ``keys`` that ``data`` lacks, if any."""
    missing = [k for k in dict.fromkeys(keys) if k not in data]
    if missing:
        raise CheckpointError(f"{path}: corrupt mivecc checkpoint, missing {missing}")


def read_checkpoint(path: str | os.PathLike, required: Sequence[str]) -> dict[str, Any]:
    """Read a mivecc checkpoint file and check what every kind shares: the file exists and
    loads, it has the mivecc marker and the ``required`` keys, its format version is not newer
    than this package's and its env version is this package's.

    Raises:
        CheckpointError: naming the file and what is wrong.
    """
    path = Path(path)
    remove_stale_temp_files(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle/zip/EOF errors of many kinds
        raise CheckpointError(
            f"{path}: not a readable mivecc checkpoint (corrupt or truncated file?): "
            f"{type(exc).__name__}: {_first_sentence(str(exc))}"
        ) from exc
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: not a mivecc checkpoint (no '{CHECKPOINT_FORMAT}' marker)")
    require_keys(path, data, ("format_version", *required))
    version = data["format_version"]
    if not isinstance(version, int) or version > CHECKPOINT_FORMAT_VERSION:
        raise CheckpointError(
            f"{path}: checkpoint format version {version!r} is newer than this mivecc "
            f"(reads up to {CHECKPOINT_FORMAT_VERSION}); upgrade mivecc"
        )
    if data.get("env_version", ENV_VERSION) != ENV_VERSION:
        raise CheckpointError(
            f"{path}: trained on env {data.get('env_version')!r}, this package provides "
            f"{ENV_VERSION!r}"
        )
    return data


def read_policy_file(path: str | os.PathLike, kind: str, required: Sequence[str]
                     ) -> dict[str, Any]:
    """:func:`read_checkpoint` of a file that must hold the ``kind`` policy and the
    ``required`` keys (``CheckpointError`` naming the kind it holds, or the missing keys)."""
    data = read_checkpoint(path, ("kind",))
    if data["kind"] != kind:
        raise CheckpointError(f"{path}: holds the {data['kind']!r} policy, but a {kind!r} "
                              "policy is needed")
    require_keys(path, data, required)
    return data


@contextlib.contextmanager
def corrupt_policy(path: str | os.PathLike, what: str) -> Iterator[None]:
    """Turn a ``TypeError``, ``ValueError``, ``RuntimeError`` or ``KeyError`` raised while a
    checkpoint's content is built into networks into a one-line ``CheckpointError``:
    ``"<path>: corrupt <what>: <error type>: <its first line>"``."""
    try:
        yield
    except (TypeError, ValueError, RuntimeError, KeyError) as exc:
        raise CheckpointError(f"{path}: corrupt {what}: {type(exc).__name__}: "
                              f"{_first_sentence(str(exc))}") from exc


def load_checkpoint(path: str | os.PathLike, expected_kind: str | None = None) -> dict[str, Any]:
    """Load and validate a checkpoint.

    Args:
        path: Checkpoint file.
        expected_kind: If given, the network kind (``"edge"``/``"cloud"``) the caller needs.

    Returns:
        The checkpoint dict.

    Raises:
        CheckpointError: If the file is missing, unreadable/corrupt/truncated, not a mivecc
            checkpoint, of a newer format version, of another network kind, or its K does not
            match the network spec.
    """
    data = read_checkpoint(path, ("kind",))
    kind = data["kind"]
    if expected_kind is not None and kind != expected_kind:
        raise CheckpointError(
            f"{path}: holds the {kind!r} policy, but the {expected_kind!r} policy is needed"
        )
    require_keys(path, data, _REQUIRED)
    try:
        spec = get_network_spec(kind)
    except ValueError as exc:
        raise CheckpointError(f"{path}: unknown network kind {kind!r}") from exc
    if data["grid_size"] != spec.grid_size:
        raise CheckpointError(
            f"{path}: K mismatch, checkpoint has K={data['grid_size']} but the {kind} network "
            f"uses K={spec.grid_size}"
        )
    return data


def export_policy(src: str | os.PathLike, dst: str | os.PathLike) -> Path:
    """Write a slim copy of a checkpoint for shipping/evaluation: without the optimiser state
    and the DDPGLoss copy (targets), so it cannot be resumed but loads with ``load_policy``.

    Args:
        src: Full training checkpoint.
        dst: Destination.

    Returns:
        The path written.
    """
    data = load_checkpoint(src)
    slim = {k: v for k, v in data.items() if k not in ("loss", "optimizer")}
    slim["extra"] = {**(slim.get("extra") or {}), "exported_from": str(src)}
    return save_checkpoint(dst, slim)
