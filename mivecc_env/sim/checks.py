"""Input checks of the simulator's public API: seeds, batch sizes, environment indices and
action arrays.

Each check raises ``ValueError`` naming the argument and what is allowed, and costs a few
scalar tests (plus one pass over an action array for infinities), so it can run every step.
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = [
    "check_accel", "check_env_flags", "check_env_index", "check_env_indices",
    "check_int_at_least", "check_positive_int", "check_seed",
]

_SEED_RULE = "None, an integer >= 0, or a sequence of integers >= 0"


def _integer_at_least(name: str, value: Any, minimum: int, rule: str) -> int:
    """``value`` as a Python int >= ``minimum`` (numpy integers accepted, bools not)."""
    if isinstance(value, bool | np.bool_):
        raise ValueError(f"{name}: must be {rule}, got {value!r}")
    try:
        out = operator.index(value)
    except TypeError:
        raise ValueError(f"{name}: must be {rule}, got {value!r}") from None
    if out < minimum:
        raise ValueError(f"{name}: must be {rule}, got {value!r}")
    return out


def check_int_at_least(name: str, value: Any, minimum: int) -> int:
    """``value`` as a Python int >= ``minimum`` (numpy integers accepted, bools not);
    ``ValueError`` naming ``name`` otherwise."""
    return _integer_at_least(name, value, minimum, f"an integer >= {minimum}")


def check_positive_int(name: str, value: Any) -> int:
    """``value`` as a Python int >= 1 (numpy integers accepted); ``ValueError`` otherwise."""
    return check_int_at_least(name, value, 1)


def check_env_index(env: Any, batch_size: int) -> int:
    """``env`` as an int in ``[-batch_size, batch_size)`` (negative: numpy's meaning, from
    the end); ``IndexError`` naming ``env`` and the range otherwise."""
    if not isinstance(env, bool | np.bool_):
        try:
            index = operator.index(env)
        except TypeError:
            index = None
        if index is not None and -batch_size <= index < batch_size:
            return index
    raise IndexError(f"env: must be an integer in [-{batch_size}, {batch_size}) (the "
                     f"simulator holds {batch_size} environments), got {env!r}")


def check_env_indices(env_index: Any, batch_size: int, mask_ok: bool = False) -> np.ndarray:
    """``env_index`` as an int64 array of distinct indices in ``[0, batch_size)`` (order
    kept); ``ValueError`` naming ``env_index`` otherwise.

    With ``mask_ok``, a ``(batch_size,)`` bool mask is accepted too (its ``True`` entries);
    without, a bool array is refused (as integers it would name environments 0 and 1).
    """
    arr = np.asarray(env_index)
    rule = f"integers in [0, {batch_size - 1}]" + (
        f" or a ({batch_size},) bool mask" if mask_ok else "")
    if mask_ok and arr.dtype == np.bool_:
        if arr.shape != (batch_size,):
            raise ValueError(f"env_index: must be {rule}, got a bool mask of shape {arr.shape}")
        return np.flatnonzero(arr)
    if arr.size and arr.dtype.kind not in "iu":
        raise ValueError(f"env_index: must be {rule}, got dtype {arr.dtype}")
    arr = arr.astype(np.int64).reshape(-1)
    if arr.size and (arr.min() < 0 or arr.max() >= batch_size):
        raise ValueError(f"env_index: must be {rule}, got {arr.tolist()}")
    if np.unique(arr).size != arr.size:
        raise ValueError(f"env_index: repeated indices {arr.tolist()}")
    return arr


def check_env_flags(name: str, flags: Any, batch_size: int) -> np.ndarray | None:
    """``None``, or ``flags`` as a ``(batch_size,)`` bool array (one flag per environment);
    ``ValueError`` naming ``name`` otherwise."""
    if flags is None:
        return None
    arr = np.asarray(flags)
    if arr.shape != (batch_size,) or arr.dtype != np.bool_:
        raise ValueError(f"{name}: must be a ({batch_size},) bool array (one per environment), "
                         f"got {arr.dtype} of shape {arr.shape}")
    return arr


def _seed_int(name: str, value: Any) -> int:
    return _integer_at_least(name, value, 0, _SEED_RULE)


def check_seed(
    seed: Any, batch_size: int | None = None, name: str = "seed"
) -> int | list[int] | None:
    """Validate a seed: ``None``, an integer >= 0, or (with ``batch_size``) one per environment.

    Returns:
        ``None``, the seed as an ``int``, or the list of ``batch_size`` ints.

    Raises:
        ValueError: naming ``name`` for a negative, fractional, non-integer or wrong-length seed.
    """
    if seed is None:
        return None
    if isinstance(seed, int | np.integer) and not isinstance(seed, bool | np.bool_):
        return _seed_int(name, seed)
    if batch_size is None or isinstance(seed, str | bytes | dict) or not isinstance(
        seed, Sequence | np.ndarray
    ):
        raise ValueError(f"{name}: must be {_SEED_RULE}, got {seed!r}")
    try:
        items = list(seed)
    except TypeError:  # e.g. a 0-d array
        raise ValueError(f"{name}: must be {_SEED_RULE}, got {seed!r}") from None
    seeds = [_seed_int(name, x) for x in items]
    if len(seeds) != batch_size:
        raise ValueError(f"{name}: need one seed per environment ({batch_size}), got {len(seeds)}")
    return seeds


def check_accel(name: str, accel: Any, shape: tuple[int, int]) -> np.ndarray | None:
    """Validate a per-slot acceleration array of :meth:`Simulator.step`.

    Args:
        name: argument name for the message (``edge_accel`` / ``cloud_accel``).
        accel: ``None`` or a numeric array of ``shape``; NaN means "no action" for a slot.
        shape: ``(batch_size, capacity)`` of the simulator at the time of the call.

    Returns:
        ``accel`` as a numpy array (or ``None``).

    Raises:
        ValueError: wrong shape (e.g. transposed, or sized for an older capacity), a
            non-numeric dtype, or an infinite value.
    """
    if accel is None:
        return None
    if not isinstance(accel, np.ndarray):
        try:
            accel = np.asarray(accel)
        except Exception as exc:  # e.g. a torch tensor that requires grad
            raise ValueError(
                f"{name}: must be a numeric array of shape {shape} (batch_size, capacity), "
                f"got {type(accel).__name__} ({exc})"
            ) from None
    if accel.shape != shape:
        raise ValueError(
            f"{name}: must have shape {shape} (batch_size, capacity: read sim.capacity before "
            f"every step, it grows), got {accel.shape}"
        )
    kind = accel.dtype.kind
    if kind not in "fiu":
        raise ValueError(f"{name}: must be a numeric (float or int) array, got dtype {accel.dtype}")
    if kind == "f" and np.isinf(accel).any():
        raise ValueError(f"{name}: values must be finite or NaN (no action), got +-inf")
    return accel
