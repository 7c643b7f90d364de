"""Stage-II transitions of a cloud that decides every n steps (``cloud_period``).

With ``cloud_period = n > 1`` the env uses the cloud's action on steps ``0, n, 2n, ...`` only
(:mod:`mivecc_env.cloud_hold`). The collector still steps the env once per frame (the frozen
edge acts on every step), so a batch of ``T`` frames per environment holds ``T / n`` cloud
decisions. :func:`cloud_macro_transitions` turns the frames into those decisions: the
observation, mask and action of the decision step; the observation and mask ``n`` steps later;
the mean of the ``n`` per-step rewards in between (the sum divided by ``n``: the same scale as
``n = 1``); done if the block ended an episode. The discount then applies per decision
(``gamma`` per ``n`` steps: gamma 0.8 with ``n = 10`` looks about 5 s ahead instead of 0.5 s).
"""

from __future__ import annotations

from tensordict import TensorDictBase


class MacroStepError(ValueError):
    """The collected frames do not split into whole cloud decision blocks."""


def cloud_macro_transitions(
    data: TensorDictBase, period: int, keys: list, group: str = "cloud"
) -> TensorDictBase:
    """``(B, T)`` frames -> ``(B, T / period)`` decision transitions (module docstring).

    Args:
        data: collected frames with batch dims ``(B, T)`` and ``(group, "info", "decides")``
            (the env's decision flags, ``(B, T, 1)``).
        period: the env's ``cloud_period`` n.
        keys: the keys to keep (the replay buffer's: root ``observation``/``mask``/``action``
            and ``next`` ``observation``/``mask``/``reward``/``done``/``terminated``).
        group: the cloud group.

    Raises:
        MacroStepError: ``T`` not a multiple of ``period``, or decision flags not on frames
            ``0, n, 2n, ...`` of every environment (episodes must last a multiple of n steps).
    """
    if data.batch_dims != 2:
        raise MacroStepError(f"expected frames with batch dims (B, T), got {data.batch_size}")
    b, t = data.batch_size
    if t % period:
        raise MacroStepError(f"{t} frames per environment: not a multiple of cloud_period "
                             f"{period}")
    decides = data.get((group, "info", "decides")).reshape(b, t)
    expected = decides.new_zeros((b, t))
    expected[:, ::period] = True
    if not bool((decides == expected).all()):
        raise MacroStepError(
            "the cloud's decision steps do not start every block of cloud_period frames: "
            "episodes (max_steps) and frames per batch must be multiples of cloud_period"
        )
    blocks = t // period
    frames = data.select(*keys)
    out = frames[:, ::period].clone()
    last = frames[:, period - 1 :: period]
    for key in keys:
        if key[0] != "next":
            continue
        if key[-1] == "reward":
            r = frames.get(key)
            out.set(key, r.reshape(b, blocks, period, *r.shape[2:]).mean(2))
        elif key[-1] in ("done", "terminated", "truncated"):
            d = frames.get(key)
            out.set(key, d.reshape(b, blocks, period, *d.shape[2:]).any(2))
        else:
            out.set(key, last.get(key).clone())
    return out
