"""The learner of one agent group: TorchRL ``DDPGLoss`` (or ``TD3Loss``) + ``SoftUpdate`` + Adam.

One object owns the loss (actor, critic and their target copies), the optimiser and the linear
learning-rate decay, and performs gradient updates from a replay buffer. Training
(:mod:`mivecc_agents.training`) and the throughput benchmark (``benchmarks/train_speed.py``)
use the same :meth:`DDPGLearner.update`, so the benchmark times exactly what training runs.
Thread settings: :func:`mivecc_agents.presets.thread_settings`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import nn

from mivecc_agents.networks import ACTION_SCALE_MPS2
from mivecc_agents.presets import TrainPreset

__all__ = [
    "SATURATED_Z", "DDPGLearner", "UpdateStats", "make_loss", "preactivation_penalty",
    "saturated_share",
]


def make_loss(actor: Any, critic: Any, group: str, gamma: float,
              twin: Any | None = None, preset: TrainPreset | None = None) -> Any:
    """Loss of one agent group: target actor and critic(s), per-group keys, TD(0).

    Args:
        actor, critic: The group's actor and critic modules.
        group: Agent group name (the keys are ``(group, ...)``).
        gamma: Discount factor.
        twin: A second critic, initialised apart from ``critic``: the loss is then TorchRL's
            ``TD3Loss`` over the pair (``preset`` gives its target-action noise [m/s^2]);
            ``None``: ``DDPGLoss``.
        preset: The hyper-parameters (needed with ``twin``).
    """
    from torchrl.objectives import DDPGLoss, TD3Loss, ValueEstimators

    keys = dict(
        state_action_value=(group, "state_action_value"),
        reward=(group, "reward"),
        done=(group, "done"),
        terminated=(group, "terminated"),
        priority=(group, "td_error"),  # one priority key per group, not a shared root key
    )
    if twin is None:
        loss = DDPGLoss(actor, critic, delay_actor=True, delay_value=True)
    else:
        if preset is None:
            raise ValueError("preset: TD3 (a twin critic) needs the preset's noise settings")
        loss = TD3Loss(
            actor, [critic, twin], bounds=(-ACTION_SCALE_MPS2, ACTION_SCALE_MPS2),
            policy_noise=preset.td3_target_noise, noise_clip=preset.td3_noise_clip,
            loss_function="l2", delay_actor=True, delay_qvalue=True,
        )
        keys["action"] = (group, "action")
    loss.set_keys(**keys)
    loss.make_value_estimator(ValueEstimators.TD0, gamma=gamma)
    return loss


def preactivation_penalty(
    net: Any, batch: Any, group: str, bound: float
) -> torch.Tensor:
    """Mean squared excess of the actor's pre-tanh outputs over ``bound``, real columns only.

    ``mean over (sample, real column) of max(|z| - bound, 0)^2`` with ``z`` from
    :meth:`mivecc_agents.networks.MiVeCCActorNet.preactivation` on the minibatch's observations.
    Zero while every ``|z| <= bound``; added to the DDPG loss, it keeps the actor out of deep
    tanh saturation, where its gradient vanishes and a column stays at a bound whatever the
    critic says (measured on the shipped clouds: ``docs/training.md``).

    Args:
        net: The actor network (:class:`~mivecc_agents.networks.MiVeCCActorNet`).
        batch: A replay minibatch with ``(group, "observation")`` and ``(group, "mask")``.
        group: Agent group name.
        bound: Largest ``|z|`` without penalty (with 3, the largest action without penalty
            is ``3 tanh(3)`` = 2.985 m/s^2).
    """
    z = net.preactivation(batch[group, "observation"])
    mask = batch[group, "mask"].to(z.dtype)
    excess = torch.relu(z.abs() - bound)
    return (excess.square() * mask).sum() / mask.sum().clamp_min(1.0)


#: A pre-tanh output beyond this is saturated: the action's gradient ``3 (1 - tanh(z)^2)`` is
#: below 2e-4, so the critic can no longer move that column.
SATURATED_Z = 5.0

#: Rows :func:`saturated_share` looks at, at most (evenly spaced over the ones given).
SATURATION_ROWS = 512


@torch.no_grad()
def saturated_share(net: Any, observation: torch.Tensor, mask: torch.Tensor) -> float:
    """Share of the real columns whose pre-tanh output has ``|z| >`` :data:`SATURATED_Z`.

    Args:
        net: The actor network (:class:`~mivecc_agents.networks.MiVeCCActorNet`).
        observation / mask: ``(..., K, K, 3)`` graphs and ``(..., K)`` masks; at most
            :data:`SATURATION_ROWS` rows, evenly spaced, are evaluated.

    Returns:
        The share in [0, 1], NaN if no column is real.
    """
    k = mask.shape[-1]
    obs = observation.reshape(-1, *observation.shape[-3:])
    real = mask.reshape(-1, k) > 0
    step = max(1, -(-obs.shape[0] // SATURATION_ROWS))
    obs, real = obs[::step], real[::step]
    if not bool(real.any()):
        return math.nan
    z = net.preactivation(obs)
    return float((z.abs() > SATURATED_Z)[real].float().mean())


@dataclass
class UpdateStats:
    """Losses of the updates of one call of :meth:`DDPGLearner.update` (means, NaN if none)."""

    n_updates: int = 0
    critic_loss: float = math.nan
    actor_loss: float = math.nan
    q_mean: float = math.nan
    seconds: float = 0.0
    _parts: dict[str, list[torch.Tensor]] = field(default_factory=dict, repr=False)


class DDPGLearner:
    """Loss, optimiser, soft target update and learning-rate decay of one group.

    Args:
        actor: The group's actor (``TensorDictModule``), weights already loaded if warm-started.
        critic: The group's critic (``ValueOperator``).
        group: Agent group name (``"edge"`` or ``"cloud"``).
        preset: Hyper-parameters (learning rates, gamma, tau, clipping, minibatch size).
        progress: Callable returning the fraction of the run done in [0, 1] (drives the linear
            learning-rate decay to 0); default: no decay. Ignored when the preset's
            ``lr_schedule`` is ``"constant"``.
        twin: With the preset's ``algorithm="td3"``: the second critic (same architecture,
            its own initialisation); the critics are then trained as TD3's pair and
            ``critic`` itself only receives the first one's weights in
            :meth:`critic_state_dict`.

    Raises:
        ValueError: ``algorithm="td3"`` without a ``twin``, or a ``twin`` with ``"ddpg"``.
    """

    def __init__(
        self,
        actor: Any,
        critic: Any,
        group: str,
        preset: TrainPreset,
        progress: Callable[[], float] | None = None,
        twin: Any | None = None,
    ) -> None:
        from torchrl.objectives import SoftUpdate

        self.td3 = preset.algorithm == "td3"
        if self.td3 != (twin is not None):
            raise ValueError(f"twin: algorithm {preset.algorithm!r} needs "
                             f"{'a second critic' if self.td3 else 'no second critic'}")
        self.group = group
        self.preset = preset
        self.actor, self.critic = actor, critic
        self.loss = make_loss(actor, critic, group, preset.gamma, twin=twin, preset=preset)
        self.updater = SoftUpdate(self.loss, tau=preset.tau)
        self._actor_params = list(actor.parameters())
        # TD3's critics live stacked in the loss (copies of ``critic`` and ``twin``)
        self._critic_params = (list(self.loss.qvalue_network_params.values(True, True))
                               if self.td3 else list(critic.parameters()))
        self.optimizer = torch.optim.Adam(
            [
                {"params": self._actor_params, "lr": preset.lr_actor},
                {"params": self._critic_params, "lr": preset.lr_critic},
            ]
        )
        frac = progress or (lambda: 0.0)
        if preset.lr_schedule == "constant":  # the released trainer
            frac = lambda: 0.0  # noqa: E731
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(
            self.optimizer, lambda _: max(0.0, 1.0 - frac())
        )
        self.updates = 0

    # ----------------------------------------------------------------------------------------
    def update(
        self, buffer: Any, n: int, should_stop: Callable[[], bool] | None = None
    ) -> UpdateStats:
        """Run ``n`` gradient updates on minibatches sampled from ``buffer``.

        Args:
            buffer: A TorchRL replay buffer whose ``sample()`` returns a minibatch.
            n: Number of updates.
            should_stop: Checked before every update; stops early when it returns True.

        Returns:
            The mean losses and the number of updates done.
        """
        import time

        p = self.preset
        t0 = time.perf_counter()
        cl, al, qm = [], [], []
        for _ in range(n):
            if should_stop is not None and should_stop():
                break
            batch = buffer.sample()
            # TD3: the actor and the targets move on every td3_policy_delay-th update only
            actor_step = not self.td3 or (self.updates + len(cl) + 1) % p.td3_policy_delay == 0
            critic_loss, actor_loss, pred_value = self._losses(batch, actor_step)
            total = critic_loss if actor_loss is None else critic_loss + actor_loss
            if actor_step and p.actor_preact_bound is not None:
                total = total + p.actor_preact_weight * preactivation_penalty(
                    self.actor.module, batch, self.group, p.actor_preact_bound)
            self.optimizer.zero_grad(set_to_none=True)
            total.backward()
            if p.max_grad_norm is not None:
                nn.utils.clip_grad_norm_(self._actor_params, p.max_grad_norm)
                nn.utils.clip_grad_norm_(self._critic_params, p.max_grad_norm)
            self.optimizer.step()  # (Adam skips the actor's parameters without a gradient)
            if actor_step:
                self.updater.step()
                al.append(actor_loss.detach())
            cl.append(critic_loss.detach())
            qm.append(pred_value.detach().mean())
        done = len(cl)
        self.updates += done
        if done:  # (stepping the scheduler before the first optimizer.step() only warns)
            self.scheduler.step()
        return UpdateStats(
            n_updates=done,
            critic_loss=_mean(cl),
            actor_loss=_mean(al),
            q_mean=_mean(qm),
            seconds=time.perf_counter() - t0,
        )

    def _losses(self, batch: Any, actor_step: bool
                ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """Critic loss, actor loss (``None`` when ``actor_step`` is False; TD3 only) and the
        critics' predicted values of one minibatch."""
        if not self.td3:
            out = self.loss(_for_members(batch, self.group, self.preset.critic_members))
            return out["loss_value"], out["loss_actor"], out["pred_value"]
        critic_loss, meta = self.loss.value_loss(batch)
        actor_loss = self.loss.actor_loss(batch)[0] if actor_step else None
        return critic_loss, actor_loss, meta["pred_value"]

    def critic_state_dict(self) -> dict[str, torch.Tensor]:
        """The critic's weights as checkpoints store them (TD3: the first critic's, the one
        the actor climbs)."""
        if self.td3:
            from tensordict import TensorDict

            TensorDict.from_module(self.critic).data.update_(
                self.loss.qvalue_network_params[0].data)
        return self.critic.module.state_dict()

    def lr(self) -> tuple[float, float]:
        """Current learning rates (actor, critic)."""
        return self.optimizer.param_groups[0]["lr"], self.optimizer.param_groups[1]["lr"]

    def state_dict(self) -> dict[str, Any]:
        """Loss (networks + targets) and optimiser state, as stored in checkpoints."""
        return {"loss": self.loss.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict`, with the learning rates of the restored progress."""
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizer"])
        # what scheduler.step() would set, without its "step before optimizer.step()" warning
        for group, base, factor in zip(self.optimizer.param_groups, self.scheduler.base_lrs,
                                       self.scheduler.lr_lambdas, strict=True):
            group["lr"] = base * factor(0)


def _for_members(batch: Any, group: str, members: int) -> Any:
    """The minibatch as an ensemble of ``members`` critics needs it: reward, done and
    terminated repeated along their last axis, so that TD(0) gives each member (one column of
    the critic's output) its own target. ``DDPGLoss`` then averages the members' squared
    errors, and the actor's loss is minus the mean of their values."""
    if members == 1:
        return batch
    batch = batch.clone(False)
    for name in ("reward", "done", "terminated"):
        key = ("next", group, name)
        value = batch.get(key)
        batch.set(key, value.expand(*value.shape[:-1], members))
    return batch


def _mean(xs: list[torch.Tensor]) -> float:
    return float(torch.stack(xs).mean()) if xs else math.nan
