"""Trained policies for evaluation: numpy in, numpy out, deterministic (no noise).

``load_policy(path)`` returns ``fn(obs (n_agents, K, K, 3), mask (n_agents, K)) -> actions
(n_agents, K)`` [m/s^2], the signature ``evaluate_scheme(..., policies={"edge": fn, "cloud": fn})``
expects. :func:`pretrained_path` finds the checkpoints shipped in ``mivecc_agents/pretrained/``.
:func:`check_policy_config` compares a policy's training config with the config it is used in.

Inference speed: these networks are small, and torch's default of one thread per core is
several times slower than one thread on a busy machine; ``mivecc evaluate`` sets
``torch.set_num_threads(1)`` (option ``--threads``). Do the same in scripts that call policies
in a loop.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mivecc_agents.checkpoints import CheckpointError, load_checkpoint, network_variant
from mivecc_agents.networks import ACTION_SCALE_MPS2, make_actor_net
from mivecc_env.model_presets import MODEL_PRESETS

__all__ = [
    "CEILING_ACCEL_MPS2",
    "PRETRAINED_DIR",
    "Policy",
    "ceiling_policy",
    "check_policy_config",
    "constant_policy",
    "load_policy",
    "pretrained_path",
    "pretrained_policies",
]

PRETRAINED_DIR = Path(__file__).resolve().parent / "pretrained"
"""Package data folder of the shipped checkpoints (``edge.pt``, ``cloud.pt``)."""

Policy = Callable[[np.ndarray, np.ndarray], np.ndarray]


def load_policy(path: str | Path, expected_kind: str | None = None) -> Policy:
    """Load a checkpoint's actor as a deterministic numpy policy.

    Args:
        path: Checkpoint file written by training.
        expected_kind: ``"edge"``/``"cloud"`` to check the kind (``None``: any).

    Returns:
        ``fn(obs, mask) -> actions``; ``obs`` is ``(n, K, K, 3)`` (or ``(K, K, 3)``), ``mask``
        ``(n, K)`` (or ``(K,)``); actions are float32 in [-3, 3], 0 in padded columns. The
        function carries ``.kind``, ``.grid_size``, ``.checkpoint`` and ``.config`` (the
        training environment's config as a dict, empty if the checkpoint has none) attributes.

    Raises:
        CheckpointError: If the file is not a usable checkpoint, or the state dict does not fit.

    Torch's global random generator is left as it was (the network is built inside
    ``torch.random.fork_rng`` before its weights are overwritten).
    """
    ckpt = load_checkpoint(path, expected_kind=expected_kind)
    kind = ckpt["kind"]
    variant = network_variant(ckpt)
    with torch.random.fork_rng(devices=[]):  # the random initial weights are overwritten
        try:
            net = make_actor_net(kind, variant=variant)
        except ValueError as exc:
            raise CheckpointError(f"{path}: {exc}") from exc
    k_net = net.spec.grid_size
    try:
        net.load_state_dict(ckpt["actor"])
    except (RuntimeError, KeyError, TypeError) as exc:
        lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
        detail = next((line for line in lines[1:] if "mismatch" in line or "key" in line),
                      lines[0] if lines else type(exc).__name__)
        more = f" (+{len(lines) - 2} more)" if len(lines) > 2 else ""
        raise CheckpointError(
            f"{path}: actor weights do not fit the {kind} network (K={k_net}): {detail}{more}"
        ) from exc
    net.eval()
    for prm in net.parameters():
        prm.requires_grad_(False)
    policy = actor_policy(net, kind)
    policy.checkpoint = str(path)  # type: ignore[attr-defined]
    policy.config = dict(ckpt.get("config") or {})  # type: ignore[attr-defined]
    return policy


def actor_policy(net: torch.nn.Module, kind: str) -> Policy:
    """A deterministic numpy policy calling an actor network (no gradients).

    The network is used as it is, not copied: a policy made during training acts with the
    weights of the moment it is called. Carries ``.kind``, ``.grid_size`` and ``.net`` (the
    network itself, e.g. for its pre-tanh outputs).
    """
    k = net.spec.grid_size

    def policy(obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        o = torch.as_tensor(np.asarray(obs, dtype=np.float32))
        m = torch.as_tensor(np.asarray(mask, dtype=np.float32))
        if o.shape[-3:] != (k, k, 3) or m.shape[-1:] != (k,) or o.shape[:-3] != m.shape[:-1]:
            raise ValueError(
                f"{kind} policy expects obs (..., {k}, {k}, 3) and mask (..., {k}) with the "
                f"same leading shape, got {tuple(o.shape)} and {tuple(m.shape)}"
            )
        with torch.no_grad():
            a = net(o, m).clamp(-ACTION_SCALE_MPS2, ACTION_SCALE_MPS2)
        return a.numpy().astype(np.float32, copy=False)

    policy.kind = kind  # type: ignore[attr-defined]
    policy.grid_size = k  # type: ignore[attr-defined]
    policy.net = net  # type: ignore[attr-defined]
    return policy


#: Config fields that change what an observation or an action means: a policy trained with
#: other values sees states it was not trained on (warned about by :func:`check_policy_config`).
DYNAMICS_FIELDS: tuple[str, ...] = (
    "control", "dt_s", "v_min_mps", "v_max_mps", "a_max_mps2", "segment_length_m",
    "lane_offset_m", "vehicle_length_m", "control_radius_m", "projection_window_m",
)

#: Schemes that use each coordinator's actions.
USED_BY: dict[str, tuple[str, ...]] = {"edge": ("EE", "EEC"), "cloud": ("EEC",)}


def uses_policy(config: Any, kind: str) -> bool:
    """Whether an environment of ``config`` uses the actions of a ``kind`` coordinator."""
    return config.scheme in USED_BY[kind] or config.control == "signalized"


def check_policy_config(policy: Any, config: Any) -> list[str]:
    """Compare a loaded policy's training config with the config it is used in.

    Args:
        policy: A policy from :func:`load_policy` (``.kind``, ``.grid_size``, ``.config``).
        config: The :class:`~mivecc_env.config.MiVeCCConfig` of the environment.

    Returns:
        Warnings (empty when all fits): the scheme does not use this coordinator; a cloud
        policy on another grid than it was trained on (the cloud sees the whole grid; an edge
        policy sees one intersection, so it is trained on 1x1 and used on any grid); a cloud
        policy used with another ``cloud_period`` than it was trained with; any of
        :data:`DYNAMICS_FIELDS` that differ; and another ``safety_shield`` than the policy's
        training (when its checkpoint records one).

    Raises:
        CheckpointError: The environment's state-graph size K differs from the policy's.
    """
    kind = policy.kind
    k_env = getattr(config, f"k_{kind}")
    where = getattr(policy, "checkpoint", "policy")
    if k_env != policy.grid_size:
        raise CheckpointError(
            f"{where}: the {kind} policy reads K={policy.grid_size} state graphs, the "
            f"environment has k_{kind}={k_env}"
        )
    trained = getattr(policy, "config", None) or {}
    out = []
    if not uses_policy(config, kind):  # nothing else about it matters
        return [f"scheme {config.scheme} does not use {kind} actions: the policy is ignored"]
    if kind == "cloud" and trained and (trained.get("rows"), trained.get("cols")) != (
        config.rows, config.cols
    ):
        out.append(
            f"the cloud policy was trained on a {trained.get('rows')}x{trained.get('cols')} "
            f"grid, the environment is {config.rows}x{config.cols}"
        )
    if kind == "cloud" and trained and trained.get("cloud_period", 1) != config.cloud_period:
        out.append(f"the cloud policy was trained deciding every {trained.get('cloud_period', 1)}"
                   f" steps, the environment has cloud_period={config.cloud_period}")
    diff = [f"{name}={trained[name]!r} (here {getattr(config, name)!r})"
            for name in DYNAMICS_FIELDS if name in trained and trained[name] != getattr(
                config, name)]
    if diff:
        out.append(f"trained with other dynamics: {', '.join(diff)}")
    shield = trained.get("safety_shield")  # absent from policies trained before the shield
    if shield is not None and shield != config.safety_shield:
        out.append(f"the {kind} policy was trained with safety_shield={shield!r}, the "
                   f"environment has safety_shield={config.safety_shield!r}")
    return out


def pretrained_path(kind: str, model: str = "paper", safety_shield: bool = False) -> Path | None:
    """Path of the shipped pretrained checkpoint of a kind for a model, or ``None``.

    Args:
        kind: ``"edge"`` or ``"cloud"``.
        model: The env config's ``model``: ``"paper"`` (the default model; files
            ``pretrained/<kind>.pt``) or ``"released"`` (``pretrained/released/<kind>.pt``,
            trained on the released model).
        safety_shield: The env config's ``safety_shield``. When true and the model has a
            policy of this kind trained under the shield (``<model folder>/shield/<kind>.pt``),
            that one; otherwise the model's policy trained without it.

    Raises:
        ValueError: an unknown ``kind`` or ``model`` (a misspelt model would otherwise find
            no shipped policy).
    """
    if kind not in ("edge", "cloud"):
        raise ValueError(f"kind: must be 'edge' or 'cloud', got {kind!r}")
    if model not in MODEL_PRESETS:
        raise ValueError(f"model: must be one of {sorted(MODEL_PRESETS)}, got {model!r}")
    folder = PRETRAINED_DIR if model == "paper" else PRETRAINED_DIR / str(model)
    candidates = [folder / "shield" / f"{kind}.pt"] if safety_shield else []
    candidates.append(folder / f"{kind}.pt")
    return next((path for path in candidates if path.is_file()), None)


def pretrained_policies(
    model: str = "paper", edge: str | Path | None = None, cloud: str | Path | None = None,
    safety_shield: bool = False,
) -> dict[str, Policy]:
    """The shipped policies of a model (and shield setting, see :func:`pretrained_path`) as
    ``{"edge": fn, "cloud": fn}`` (the kinds shipped); a checkpoint given as ``edge`` /
    ``cloud`` replaces that kind's shipped policy (an unknown ``model`` is a ``ValueError``
    either way)."""
    given = {"edge": edge, "cloud": cloud}
    out: dict[str, Policy] = {}
    for kind in ("edge", "cloud"):
        shipped = pretrained_path(kind, model, safety_shield)
        path = given[kind] or shipped
        if path is not None:
            out[kind] = load_policy(path, expected_kind=kind)
    return out


def constant_policy(kind: str, accel_mps2: float, grid_size: int) -> Policy:
    """A coordinator that always outputs ``accel_mps2`` [m/s^2] in every real column (the
    constant-action ceilings of ``benchmarks/paper_table.py``).

    Raises:
        ValueError: ``accel_mps2`` outside [-3, 3] or not finite.
    """
    if not np.isfinite(accel_mps2) or abs(accel_mps2) > ACTION_SCALE_MPS2:
        raise ValueError(f"accel_mps2: must be in [-3, 3] m/s^2, got {accel_mps2!r}")

    def policy(obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        return (np.float32(accel_mps2) * np.asarray(mask, dtype=np.float32)).astype(np.float32)

    policy.kind = kind  # type: ignore[attr-defined]
    policy.grid_size = int(grid_size)  # type: ignore[attr-defined]
    policy.checkpoint = f"constant {accel_mps2:+g} m/s^2"  # type: ignore[attr-defined]
    policy.config = {}  # type: ignore[attr-defined]
    return policy


#: The action of the constant-action ceilings EE+3 and EEC+3 [m/s^2].
CEILING_ACCEL_MPS2 = 3.0


def ceiling_policy(kind: str, config: Any) -> Policy:
    """The constant-action ceiling of a coordinator kind: :func:`constant_policy` at
    :data:`CEILING_ACCEL_MPS2`, sized to the config's ``k_edge`` / ``k_cloud`` (used by
    ``benchmarks/paper_table.py`` and the training's periodic evaluation)."""
    return constant_policy(kind, CEILING_ACCEL_MPS2, getattr(config, f"k_{kind}"))
