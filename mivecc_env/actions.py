"""Validation of coordinator actions: the one rule used by every environment front end.

Rule (documented in the README, "The environment in five lines", and ``docs/batched.md``):

* An action is anything ``numpy`` converts to a float array of the expected shape. A torch
  tensor (detected by duck typing, so this module does not need torch) is accepted whatever
  its ``requires_grad`` or device: it is detached and copied to host memory first.
* Columns whose mask is 0 (padding: no vehicle) are ignored, so NaN there is accepted and
  means nothing. Every other value -- real columns, and finite or infinite values in padded
  ones -- must lie in ``[-a_max, a_max]`` m/s^2; NaN/inf in a real column or a value outside
  the box raises ``ValueError`` naming the action (agent) and the first offending column.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: Slack on ``a_max`` [m/s^2] so that float32 actions at the box edge pass.
A_MAX_SLACK = 1e-6


def to_host(action: Any) -> Any:
    """``action`` with a torch-like tensor (has ``detach``) detached and moved to host memory.

    Anything else is returned unchanged. A tensor that requires grad cannot be converted by
    numpy directly; a user passing a policy output most likely wants its values.
    """
    detach = getattr(action, "detach", None)
    if detach is None or not callable(detach):
        return action
    out = detach()
    cpu = getattr(out, "cpu", None)
    return cpu() if callable(cpu) else out


def checked_action(
    action: Any,
    name: str,
    shape: tuple[int, ...],
    a_max: float,
    mask: NDArray[Any] | None = None,
    hint: str = "",
) -> FloatArray:
    """``action`` as a float64 array of ``shape`` that obeys the rule above, else ``ValueError``.

    Args:
        action: the action (array-like or torch tensor) [m/s^2].
        name: how the error names it (e.g. ``"actions['edge_0']"`` or ``"edge_action"``).
        shape: the expected shape; its trailing axis is the column axis.
        a_max: the box half-width [m/s^2].
        mask: real-column mask broadcastable to ``shape`` (nonzero: real column), or ``None``
            (every column real).
        hint: appended to the out-of-box message.

    Returns:
        A float64 array (a new array when the input was not float64 already); NaN may remain
        in padded columns (callers map only real columns, NaN means "no action").
    """
    expected = f"expected shape {shape} with values in [{-a_max}, {a_max}] m/s^2"
    try:
        arr = np.asarray(to_host(action), dtype=np.float64)
    except (TypeError, ValueError, RuntimeError) as err:
        raise ValueError(f"{name}: {expected}, got non-numeric "
                         f"{type(action).__name__}") from err
    if arr.shape != shape:
        raise ValueError(f"{name}: {expected}, got shape {arr.shape}")
    # NaN compares False, so this also catches NaN (and inf, which is out of the box).
    ok = np.abs(arr) <= a_max + A_MAX_SLACK
    if ok.all():
        return arr
    nan = np.isnan(arr)
    if mask is not None:
        ok |= nan & ~np.broadcast_to(np.asarray(mask) != 0, shape)
        if ok.all():
            return arr
    first = tuple(int(i) for i in np.argwhere(~ok)[0])
    where = f"(first at index {first[0] if len(first) == 1 else first})"
    if not np.isfinite(arr[~ok]).all():
        raise ValueError(f"{name}: {expected}, got NaN or inf {where}; NaN is accepted only "
                         "in padded columns (mask 0)")
    bad = arr[~ok]
    raise ValueError(f"{name}: {expected}, got min {bad.min():.3f} max {bad.max():.3f} "
                     f"{where}{hint}")
