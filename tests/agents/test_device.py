"""The TorchRL side on an accelerator: the native env, the networks, the DDPG update and the
checkpoints with ``device="cuda"`` behave as on the CPU.

Every test runs on the CPU as well, so CI checks the same code path; the ``cuda`` cases are
skipped where torch sees no GPU (they were run on an NVIDIA H200, see docs/integrations.md).
"""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from tensordict import TensorDict  # noqa: E402
from torchrl.collectors import Collector  # noqa: E402
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer  # noqa: E402
from torchrl.envs import check_env_specs  # noqa: E402

from mivecc_agents.checkpoints import save_checkpoint  # noqa: E402
from mivecc_agents.learner import DDPGLearner  # noqa: E402
from mivecc_agents.networks import make_actor, make_critic  # noqa: E402
from mivecc_agents.policies import load_policy  # noqa: E402
from mivecc_agents.presets import get_preset  # noqa: E402
from mivecc_agents.torchrl_env import MiVeCCTorchEnv  # noqa: E402

DEVICES = [
    "cpu",
    pytest.param("cuda", marks=pytest.mark.skipif(
        not torch.cuda.is_available(), reason="torch sees no CUDA device")),
]
CFG = {"rows": 1, "cols": 2, "scheme": "EEC", "max_steps": 6}
DENSITIES = [900.0, 2100.0]


def _env(device: str) -> MiVeCCTorchEnv:
    return MiVeCCTorchEnv(densities=DENSITIES, device=device, seed=3, **CFG)


def _fixed_actions(env: MiVeCCTorchEnv, steps: int) -> list[TensorDict]:
    """Action tensordicts drawn on the CPU from a seeded generator, moved to the env's device."""
    gen = torch.Generator().manual_seed(11)
    spec = env.full_action_spec
    out = []
    for _ in range(steps):
        td = TensorDict(batch_size=env.batch_size)
        for g in env.groups:
            shape = spec[g, "action"].shape
            td[g, "action"] = (torch.rand(shape, generator=gen) * 6.0 - 3.0).to(env.device)
        out.append(td)
    return out


def _run(env: MiVeCCTorchEnv, steps: int) -> list[TensorDict]:
    """``steps`` steps with fixed actions, resetting (partially) whatever ended."""
    from torchrl.envs.utils import step_mdp

    td = env.reset()
    trace = []
    for actions in _fixed_actions(env, steps):
        td.update(actions)
        td = env.step(td)
        trace.append(td.clone())
        td = env.reset(step_mdp(td)) if td["done"].any() else step_mdp(td)
    return trace


@pytest.mark.parametrize("device", DEVICES)
def test_native_env_specs_on_device(device: str) -> None:
    env = _env(device)
    check_env_specs(env, seed=0)
    assert env.full_observation_spec["edge", "observation"].device.type == device
    td = env.reset()
    assert td["cloud", "observation"].device.type == device
    assert td["edge", "info", "mask"].device.type == device


@pytest.mark.parametrize("device", DEVICES)
def test_native_env_on_device_matches_cpu(device: str) -> None:
    """The same seeds and actions give the same observations, rewards and summaries, across
    episode ends (max_steps = 6 over 14 steps: two partial resets per environment)."""
    ref = _run(_env("cpu"), 14)
    got = _run(_env(device), 14)
    assert sum(bool(t["done"].any()) for t in ref) == 2
    for r, g in zip(ref, got, strict=True):
        assert g.device.type == device
        torch.testing.assert_close(g.cpu(), r, rtol=0.0, atol=0.0)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("group", ["edge", "cloud"])
def test_collect_update_and_checkpoint_on_device(device: str, group: str, tmp_path) -> None:
    """Collect with the actor on the device, run DDPG updates there, then load the saved
    actor as the CPU policy evaluation uses: the same actions as the trained network."""
    torch.manual_seed(0)
    env = MiVeCCTorchEnv(densities=DENSITIES, device=device, seed=0, groups=(group,),
                         **{**CFG, "max_steps": 200,
                            "scheme": "EEC" if group == "cloud" else "EE"})
    actor = make_actor(group, group, device=device)
    critic = make_critic(group, group, device=device)
    # the network fills for about 70 steps before the first edge decision
    collector = Collector(lambda: env, actor, frames_per_batch=200, total_frames=200,
                          device=device)
    batch = next(iter(collector))
    collector.shutdown()
    assert batch[group, "action"].device.type == device
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(64, device=device),
                                    batch_size=4)
    flat = batch.reshape(-1)
    decided = flat[flat[group, "mask"].flatten(1).any(-1)]  # frames with a decision vehicle
    assert decided.numel() > 0
    buffer.extend(decided)
    preset = get_preset("stable")
    learner = DDPGLearner(actor, critic, group, preset)
    before = [p.detach().clone() for p in actor.parameters()]
    stats = learner.update(buffer, 3)
    assert stats.n_updates == 3
    assert all(map(torch.isfinite, (torch.tensor(stats.critic_loss),
                                    torch.tensor(stats.actor_loss))))
    assert all(p.device.type == device for p in actor.parameters())
    assert any(not torch.equal(b, p) for b, p in zip(before, actor.parameters(), strict=True))

    path = save_checkpoint(tmp_path / f"{group}.pt", {
        "stage": group, "kind": group, "grid_size": actor.module.spec.grid_size,
        "actor": actor.module.state_dict(), "critic": critic.module.state_dict(),
    })
    policy = load_policy(path, expected_kind=group)
    obs, mask = decided[group, "observation"], decided[group, "mask"]
    with torch.no_grad():
        want = actor.module(obs, mask).clamp(-3.0, 3.0).cpu().numpy()
    got = policy(obs.cpu().numpy(), mask.cpu().numpy())
    torch.testing.assert_close(torch.from_numpy(got), torch.from_numpy(want),
                               rtol=1e-5, atol=1e-5)


def _tensors(obj):
    if isinstance(obj, torch.Tensor):
        yield obj
    elif isinstance(obj, dict):
        for value in obj.values():
            yield from _tensors(value)
    elif isinstance(obj, list | tuple):
        for value in obj:
            yield from _tensors(value)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("stage", ["edge", "cloud"])
def test_training_with_the_learner_on_device(device: str, stage: str, tmp_path) -> None:
    """``train(device=...)``: updates run there, the acting (CPU) actor follows the learner's,
    the checkpoint holds CPU tensors only, and a resumed run continues on the device."""
    from mivecc_agents.checkpoints import load_checkpoint
    from mivecc_agents.training import train
    from tests.agents.tiny import TINY

    size = 1 if stage == "edge" else 2  # stage II over the shipped edge
    kw = {"rows": size, "cols": size, "densities": 1500, "seed": 0, "progress": False,
          "device": device}
    first = train(stage, TINY, frames=200, out_dir=tmp_path / "a", **kw)
    raw = torch.load(first, weights_only=True)  # no map_location: loads where it was saved
    assert {t.device.type for t in _tensors(raw)} == {"cpu"}
    ckpt = load_checkpoint(first)
    assert ckpt["updates"] > 0
    assert ckpt["extra"]["learner_device"] == device
    for name, value in ckpt["actor"].items():  # the acting actor is the learner's
        assert torch.equal(value, ckpt["loss"][f"actor_network_params.module.{name}"]), name
    second = train(stage, TINY, frames=400, resume=first, out_dir=tmp_path / "b", **kw)
    resumed = load_checkpoint(second)
    assert resumed["frames"] == 400
    assert resumed["updates"] > ckpt["updates"]


def test_training_device_must_be_usable() -> None:
    from mivecc_agents.training import TrainingError, learner_device

    with pytest.raises(TrainingError, match="device: must be cpu, cuda or cuda:N, got 'gpu'"):
        learner_device("gpu")
    if not torch.cuda.is_available():
        with pytest.raises(TrainingError, match="torch sees no CUDA device here"):
            learner_device("cuda")
    assert learner_device("cpu") == torch.device("cpu")


@pytest.mark.parametrize("variant", ["paper", "released", "per_pick"])
@pytest.mark.parametrize("kind", ["edge", "cloud"])
def test_separate_learner_actor_is_copied_back(kind: str, variant: str) -> None:
    """The learner's own actor (another device) starts equal to the acting one, is
    independent of it, and ``sync`` copies its weights back (checked on the CPU in CI), for
    every network variant."""
    from mivecc_agents.training import _learner_networks

    actor = make_actor(kind, kind, variant=variant)
    critic = make_critic(kind, kind, variant=variant)
    learn_actor, learn_critic, sync = _learner_networks(actor, critic, torch.device("cpu"),
                                                        separate=True)
    assert learn_actor is not actor and learn_critic is critic
    pairs = list(zip(actor.parameters(), learn_actor.parameters(), strict=True))
    assert all(torch.equal(a, b) and a.data_ptr() != b.data_ptr() for a, b in pairs)
    with torch.no_grad():
        for p in learn_actor.parameters():
            p.add_(1.0)
    assert not any(torch.equal(a, b) for a, b in pairs)
    sync()
    assert all(torch.equal(a, b) for a, b in pairs)
    same = _learner_networks(actor, critic, torch.device("cpu"))
    assert same[0] is actor and same[1] is critic
