"""The AEC versions of the parallel environments: PettingZoo's conversion, each action checked
when it is given.

PettingZoo's ``parallel_to_aec`` collects the actions of a cycle and steps the parallel env
after the last agent's turn, so a bad action was reported one or more turns late, by the turn of
another agent. :class:`ActionCheckingAEC` asks the parallel env (its ``check_action(agent,
action)``: the rule and message of its ``step``) at once; the turn is not taken.
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec_wrapper
from pettingzoo.utils.env import AECEnv, ParallelEnv

__all__ = ["ActionCheckingAEC", "checked_aec"]


class ActionCheckingAEC(parallel_to_aec_wrapper):
    """``parallel_to_aec_wrapper`` whose ``step`` checks the action before taking the turn."""

    def reset(self, seed: int | None = None, options: dict | None = None) -> None:
        """PettingZoo's reset; an episode that ends inside the parallel env's ``reset`` (no
        agent ever acts: the vehicle env when no vehicle reaches a control area within
        ``max_steps``) leaves ``agents`` empty and ``agent_selection`` None, so
        ``agent_iter()`` yields nothing, where the conversion itself would fail."""
        not_reset = object()
        self._observations = not_reset  # the conversion sets it once the parallel env reset
        try:
            super().reset(seed=seed, options=options)
        except Exception:
            if self._observations is not_reset or self.agents:
                raise  # the parallel env's reset failed, or something other than no agents
            self.agent_selection = None
            for name in ("terminations", "truncations", "rewards", "_cumulative_rewards"):
                setattr(self, name, {})
            self.infos, self.new_agents, self.new_values = {}, [], {}

    def step(self, action: Any) -> None:
        agent = self.agent_selection
        if action is not None and not (self.terminations[agent] or self.truncations[agent]):
            self.env.check_action(agent, action)
        super().step(action)


def checked_aec(par_env: ParallelEnv) -> AECEnv:
    """The AEC env of ``par_env`` as ``parallel_to_aec`` builds it (order enforced), with
    :class:`ActionCheckingAEC` in place of PettingZoo's conversion."""
    return wrappers.OrderEnforcingWrapper(ActionCheckingAEC(par_env))
