"""Potential-based shaping of a group's training reward (``reward_shaping="potential"``).

The stage's reward ``r`` is mostly the level of the traffic's speed, ``mean (v - v_ref)`` over
the group's vehicles, which the state sets and one action barely moves (a cloud action moves the
network's mean speed by about 0.01 m/s per step). The critic must learn that level before it
can see the action's effect. Shaping adds ``gamma Phi(s') - Phi(s)`` with the potential
``Phi(s) = u(s) / (1 - gamma)``, where ``u(s)`` is the reward's velocity term
(``info["reward_velocity"]``) in state ``s``:

    r' = r + (gamma u(s') - u(s)) / (1 - gamma)

For a reward that is exactly ``u(s')`` this is ``(u(s') - u(s)) / (1 - gamma)``: the change of
the speed level, not the level. A potential-based term leaves the optimal policies of every
discounted problem with the same ``gamma`` unchanged (Ng, Harada and Russell, ICML 1999):
``Q'(s, a) = Q(s, a) - Phi(s)``, so the greedy action of every state is the same. The env's
episodes are never terminated (only truncated and bootstrapped), so ``Phi(s')`` applies on
every transition. ``u`` of a freshly reset, empty network is 0, as the env reports it.

With a cloud that decides every ``n`` steps (:mod:`mivecc_agents.macro_steps`) the shaping
applies per decision: ``u(s)`` of the decision step, ``u(s')`` after its ``n`` steps, and the
decision's ``gamma``.
"""

from __future__ import annotations

from tensordict import TensorDictBase

__all__ = ["POTENTIAL_KEY", "potential_keys", "shape_rewards"]

#: The info entry that holds ``u(s)``: the reward's velocity term in the current state.
POTENTIAL_KEY = ("info", "reward_velocity")


def potential_keys(group: str) -> list[tuple[str, ...]]:
    """The keys :func:`shape_rewards` reads: ``u`` of the state and of the next state."""
    return [(group, *POTENTIAL_KEY), ("next", group, *POTENTIAL_KEY)]


def shape_rewards(data: TensorDictBase, group: str, gamma: float) -> TensorDictBase:
    """Add ``(gamma u(s') - u(s)) / (1 - gamma)`` to ``("next", group, "reward")``, in place.

    Args:
        data: transitions with the reward ``(..., n_agents, 1)`` and the keys of
            :func:`potential_keys` ``(..., n_agents)``.
        group: the trained agent group.
        gamma: the learner's discount per transition, in [0, 1).

    Returns:
        ``data`` (the same object), its reward shaped.

    Raises:
        ValueError: ``gamma`` outside [0, 1).
    """
    if not 0.0 <= gamma < 1.0:
        raise ValueError(f"gamma: potential shaping needs 0 <= gamma < 1, got {gamma!r}")
    u_now, u_next = (data.get(k) for k in potential_keys(group))
    key = ("next", group, "reward")
    reward = data.get(key)
    shaping = (gamma * u_next - u_now) / (1.0 - gamma)
    data.set(key, reward + shaping.unsqueeze(-1).to(reward.dtype))
    return data
