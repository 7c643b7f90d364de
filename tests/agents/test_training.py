"""Short end-to-end TorchRL training runs of both stages (1x1 grid, tiny buffers)."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

pytest.importorskip("torchrl")

from mivecc_agents.checkpoints import load_checkpoint
from mivecc_agents.policies import load_policy
from mivecc_agents.presets import PRESETS, get_preset
from mivecc_agents.training import make_env, train
from tests.agents.tiny import TINY, train_tiny_edge


@pytest.fixture(scope="module")
def edge_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("edge")
    torch.manual_seed(0)
    from mivecc_agents.networks import make_actor, make_critic

    torch.manual_seed(0)
    init_actor = make_actor("edge", "edge").module.state_dict()
    init_critic = make_critic("edge", "edge").module.state_dict()
    path = train_tiny_edge(out)
    return path, out, init_actor, init_critic


def test_env_has_mask_at_root_and_next():
    from torchrl.envs import check_env_specs

    env = make_env({"rows": 1, "cols": 1, "density": 1500, "max_steps": 20}, "EE")
    check_env_specs(env)
    td = env.rollout(3)
    assert td["edge", "mask"].shape == (3, 1, 15)
    assert td["next", "cloud", "mask"].shape == (3, 1, 60)


def test_edge_stage_trains(edge_run):
    path, out, init_actor, init_critic = edge_run
    ck = load_checkpoint(path, expected_kind="edge")
    assert ck["stage"] == "edge" and ck["frames"] == 200 and ck["updates"] > 0
    # seed 0 gives the same initial networks as the fixture's snapshot
    assert any(not torch.equal(v, ck["actor"][k]) for k, v in init_actor.items())
    assert any(not torch.equal(v, ck["critic"][k]) for k, v in init_critic.items())
    assert math.isfinite(ck["metrics"]["critic_loss"])
    assert math.isfinite(ck["metrics"]["actor_loss"])
    assert (out / "train_log.csv").is_file() and (out / "learning_curve.png").is_file()
    try:
        import tensorboard  # noqa: F401
    except ImportError:
        pass
    else:  # optional TensorBoard log next to the CSV
        assert any((out / "tb").glob("events.out.tfevents.*"))
    header = (out / "train_log.csv").read_text().splitlines()[0]
    for col in (
        "frames",
        "critic_loss",
        "actor_loss",
        "lr_actor",
        "fps_collect",
        "fps_optim",
        "avg_velocity_mps_d1500",
        "episode_velocity_mps_d1500",
        "reward_mean",
        "actor_saturated",
    ):
        assert col in header
    with open(out / "train_log.csv") as fh:
        shares = [float(row["actor_saturated"]) for row in csv.DictReader(fh)]
    # NaN while the network is still empty (no decision vehicle in the iteration's states)
    assert any(0.0 <= x <= 1.0 for x in shares)
    assert all(0.0 <= x <= 1.0 or math.isnan(x) for x in shares)


def test_saturated_share_counts_real_columns_beyond_the_bound() -> None:
    from mivecc_agents.learner import SATURATED_Z, saturated_share

    class Fixed(torch.nn.Module):  # pre-activations given per column
        def __init__(self, z: list[float]) -> None:
            super().__init__()
            self.z = torch.tensor(z)

        def preactivation(self, obs: torch.Tensor) -> torch.Tensor:
            return self.z.expand(obs.shape[0], -1)

    net = Fixed([SATURATED_Z + 1, -(SATURATED_Z + 1), 0.0, 100.0])
    obs = torch.zeros(10, 4, 4, 3)
    mask = torch.tensor([1.0, 1.0, 1.0, 0.0]).expand(10, -1)  # the 100 is padding
    assert saturated_share(net, obs, mask) == pytest.approx(2 / 3)
    assert math.isnan(saturated_share(net, obs, torch.zeros(10, 4)))


def test_open_log_continues_and_extends_an_older_header(tmp_path: Path) -> None:
    from mivecc_agents.training import open_log

    path = tmp_path / "train_log.csv"
    path.write_text("iteration,frames,gone\n1,100,x\n2,200,y\n")
    fh, writer = open_log(path, ["iteration", "frames", "actor_saturated"], append=True)
    writer.writerow({"iteration": 3, "frames": 300, "actor_saturated": 0.5})
    fh.close()
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    assert [r["frames"] for r in rows] == ["100", "200", "300"]  # old rows kept
    assert [r["actor_saturated"] for r in rows] == ["", "", "0.5"]
    assert "gone" not in rows[0]
    fh, writer = open_log(path, ["iteration"], append=False)  # a new run: a new file
    fh.close()
    assert path.read_text() == "iteration\n"


def test_checkpoint_roundtrip_actions(edge_run):
    path = edge_run[0]
    pol1, pol2 = load_policy(path), load_policy(path, expected_kind="edge")
    rng = np.random.default_rng(0)
    obs = rng.uniform(-1, 1, (3, 15, 15, 3)).astype(np.float32)
    mask = (rng.random((3, 15)) < 0.6).astype(np.float32)
    a1, a2 = pol1(obs, mask), pol2(obs, mask)
    np.testing.assert_array_equal(a1, a2)
    assert a1.shape == (3, 15) and a1.dtype == np.float32
    assert np.all(np.abs(a1) <= 3) and np.all(a1[mask == 0] == 0)
    # same actions as the training actor rebuilt from the checkpoint
    from mivecc_agents.networks import make_actor_net

    net = make_actor_net("edge")
    net.load_state_dict(load_checkpoint(path)["actor"])
    with torch.no_grad():
        ref = net(torch.as_tensor(obs), torch.as_tensor(mask)).numpy()
    np.testing.assert_array_equal(a1, ref)


def test_resume_continues_frames(edge_run, tmp_path):
    path = edge_run[0]
    new = train(
        "edge",
        TINY,
        frames=300,
        rows=1,
        cols=1,
        densities=1500,
        seed=1,
        out_dir=tmp_path,
        resume=path,
        progress=False,
    )
    ck = load_checkpoint(new)
    assert ck["frames"] == 300
    assert ck["updates"] > load_checkpoint(path)["updates"]


def _logged_sigmas(out: Path) -> list[tuple[int, float]]:
    """(frames, sigma) of every row of a run's train_log.csv."""
    with open(out / "train_log.csv") as fh:
        return [(int(row["frames"]), float(row["sigma"])) for row in csv.DictReader(fh)]


def test_resume_lays_the_exploration_schedule_over_the_new_total(edge_run, tmp_path):
    """A continuation starts at the schedule's sigma for the frames already done (documented
    in docs/training.md, "Resume"); one level throughout when sigma_init == sigma_end."""
    path, out = edge_run[0], edge_run[1]

    def schedule(frames: int, total: int) -> float:  # linear over sigma_anneal_fraction
        done = min(1.0, frames / (TINY.sigma_anneal_fraction * total))
        return TINY.sigma_init + (TINY.sigma_end - TINY.sigma_init) * done

    first = _logged_sigmas(out)
    assert [s for _, s in first] == pytest.approx([schedule(f, 200) for f, _ in first], abs=1e-5)
    assert first[-1][1] == pytest.approx(TINY.sigma_end, abs=1e-5)
    train("edge", TINY, frames=400, rows=1, cols=1, densities=1500, seed=1,
          out_dir=tmp_path / "grown", resume=path, progress=False)
    grown = _logged_sigmas(tmp_path / "grown")
    assert grown[0][0] == 300 and grown[0][1] > TINY.sigma_end  # above the first run's end
    assert [s for _, s in grown] == pytest.approx([schedule(f, 400) for f, _ in grown], abs=1e-5)
    level = TINY.replace(sigma_init=0.3, sigma_end=0.3)
    train("edge", level, frames=400, rows=1, cols=1, densities=1500, seed=1,
          out_dir=tmp_path / "level", resume=path, progress=False)
    assert [s for _, s in _logged_sigmas(tmp_path / "level")] == pytest.approx([0.3, 0.3], abs=1e-5)


def test_cloud_stage_keeps_edge_frozen(edge_run, tmp_path):
    edge_path = edge_run[0]
    edge_before = load_checkpoint(edge_path)["actor"]
    from mivecc_agents.networks import make_actor

    torch.manual_seed(3)
    init_actor = make_actor("cloud", "cloud").module.state_dict()
    tiny = TINY.replace(
        frames_per_batch=40, warmup_frames=48, updates_per_frame=0.05, buffer_size=200
    )
    path = train(
        "cloud",
        tiny,
        frames=120,
        rows=1,
        cols=1,
        densities=1500,
        seed=3,
        out_dir=tmp_path,
        edge_checkpoint=edge_path,
        progress=False,
    )
    ck = load_checkpoint(path, expected_kind="cloud")
    assert ck["stage"] == "cloud" and ck["updates"] > 0
    assert ck["config"]["scheme"] == "EEC"
    assert any(not torch.equal(v, ck["actor"][k]) for k, v in init_actor.items())
    assert math.isfinite(ck["metrics"]["critic_loss"])
    edge_after = load_checkpoint(edge_path)["actor"]
    for k, v in edge_before.items():
        assert torch.equal(v, edge_after[k])


def test_frozen_edge_module_gets_no_gradient(edge_run):
    from mivecc_agents.training import load_frozen_edge_actor

    actor = load_frozen_edge_actor(edge_run[0])
    assert all(not p.requires_grad for p in actor.parameters())


def test_presets_and_errors(tmp_path):
    assert PRESETS["paper"].lr_critic == 0.05 and PRESETS["paper"].gamma == 0.8
    assert PRESETS["paper"].batch_size == 48 and PRESETS["paper"].tau == 0.01
    with pytest.raises(ValueError):
        get_preset("nope")
    from mivecc_agents.training import TrainingError

    with pytest.raises(TrainingError):
        train("bogus", TINY, frames=10, out_dir=tmp_path, progress=False)
    with pytest.raises(TrainingError, match=r"mivecc\[ray\]"):
        try:
            import ray  # noqa: F401

            pytest.skip("ray installed")
        except ImportError:
            pass
        train("edge", TINY, frames=50, out_dir=tmp_path, ray_address="auto", progress=False)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"frames": -5}, r"^frames: must be an integer >= 1, got -5$"),
    ({"frames": 1.5}, r"^frames: must be an integer >= 1, got 1.5$"),
    ({"seed": "a"}, r"^seed: must be an integer >= 0, got 'a'$"),
    ({"workers": 0}, r"^workers: must be an integer >= 1, got 0$"),
    ({"save_every": -1}, r"^save_every: must be an integer >= 0, got -1$"),
    ({"densities": [900.0, -900.0]},
     r"^densities: each must be a number in \[1.0, 3600.0\] veh/lane/h, got -900.0$"),
    ({"densities": ["a"]},
     r"^densities: each must be a number in \[1.0, 3600.0\] veh/lane/h, got 'a'$"),
    ({"densities": []}, r"^at least one density is needed$"),
])
def test_bad_arguments_of_the_python_api_are_named(tmp_path, kwargs, message):
    from mivecc_agents.training import TrainingError

    args = {"frames": 50, "out_dir": tmp_path / "run", "progress": False, **kwargs}
    with pytest.raises(TrainingError, match=message):
        train("edge", TINY, **args)
    assert not (tmp_path / "run").exists()  # refused before anything was written


def test_an_output_path_that_is_a_file_is_refused(tmp_path):
    from mivecc_agents.training import TrainingError

    (tmp_path / "taken").write_text("")
    with pytest.raises(TrainingError, match=r"^out_dir: '.*taken' is a file, not a folder$"):
        train("edge", TINY, frames=50, out_dir=tmp_path / "taken", progress=False)


def test_training_leaves_the_global_torch_rng_alone(tmp_path):
    import torch

    from mivecc_agents.training import train

    torch.manual_seed(1234)
    expected = torch.rand(3)
    torch.manual_seed(1234)
    train("edge", frames=100, rows=1, cols=1, densities=900, seed=0, out_dir=tmp_path,
          progress=False, episode_steps=50, buffer_size=200)
    assert torch.equal(torch.rand(3), expected)


def test_a_run_of_partial_batches_collects_whole_batches_without_warning(tmp_path) -> None:
    """150 frames with batches of 2 environments x 50 steps: 2 whole batches (200 frames), as
    TorchRL collects anyway, without its "total_frames is not exactly divisible" warning."""
    import warnings

    from mivecc_agents.training import train
    from tests.agents.tiny import TINY

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        path = train("edge", TINY, frames=150, rows=1, cols=1, densities=1500, seed=0,
                     out_dir=tmp_path, progress=False)
    assert not [w for w in caught if "not exactly divisible" in str(w.message)]
    assert load_checkpoint(path, expected_kind="edge")["frames"] == 200
    rows = (tmp_path / "train_log.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[1]) for r in rows] == [100, 200]


@pytest.mark.slow
def test_two_collector_processes_train(tmp_path):
    """workers=2: MultiSyncCollector (two processes) feeds the same training loop."""
    import warnings

    from mivecc_agents.checkpoints import load_checkpoint
    from mivecc_agents.training import train

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        path = train("edge", frames=800, rows=1, cols=1, densities=900, seed=0,
                     out_dir=tmp_path, workers=2, progress=False, episode_steps=100,
                     buffer_size=500)
    ckpt = load_checkpoint(path, expected_kind="edge")
    assert ckpt["updates"] > 0  # past the 480-frame warm-up
    # 48 environments per worker share ceil(800 / 48) = 17 steps: 9 each, 2 x 48 x 9 frames,
    # asked for exactly (no TorchRL warning about a batch or total it must round up)
    assert ckpt["frames"] == 864
    assert not [w for w in caught if "not exactly divisible" in str(w.message)]


def test_learner_restore_sets_the_restored_progress_learning_rates() -> None:
    # A restored learner has the decayed learning rates of its progress at once, and restoring
    # does not step the scheduler before an optimiser step (torch's UserWarning on --resume).
    import warnings

    from mivecc_agents.learner import DDPGLearner
    from mivecc_agents.networks import make_actor, make_critic

    torch.manual_seed(0)
    source = DDPGLearner(make_actor("edge", "edge"), make_critic("edge", "edge"), "edge", TINY)
    restored = DDPGLearner(make_actor("edge", "edge"), make_critic("edge", "edge"), "edge",
                           TINY, progress=lambda: 0.75)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        restored.load_state_dict(source.state_dict())
    assert restored.lr() == pytest.approx((0.25 * TINY.lr_actor, 0.25 * TINY.lr_critic))


def test_preactivation_penalty_counts_only_the_excess_of_real_columns() -> None:
    from tensordict import TensorDict

    from mivecc_agents.learner import preactivation_penalty

    class Fixed(torch.nn.Module):  # an "actor" whose pre-activations are the observation's
        def preactivation(self, observation: torch.Tensor) -> torch.Tensor:
            return observation

    z = torch.tensor([[0.5, -4.0, 6.0], [3.0, -3.5, 100.0]])
    mask = torch.tensor([[1.0, 1.0, 1.0], [1.0, 1.0, 0.0]])  # the 100 is padding
    batch = TensorDict({("cloud", "observation"): z, ("cloud", "mask"): mask}, batch_size=[2])
    # excesses over 3 of the five real columns: 0, 1, 3, 0, 0.5
    expected = (1.0 + 9.0 + 0.25) / 5
    assert preactivation_penalty(Fixed(), batch, "cloud", 3.0).item() == pytest.approx(expected)
    assert preactivation_penalty(Fixed(), batch, "cloud", 200.0).item() == 0.0


def test_preactivation_bound_pulls_a_saturated_actor_back() -> None:
    """A saturated actor (|z| >> bound) is pulled towards the bound by the penalty, and left
    saturated without it: the penalty's gradient reaches the actor through the learner."""
    from tensordict import TensorDict
    from torchrl.data import LazyTensorStorage, ReplayBuffer

    from mivecc_agents.learner import DDPGLearner
    from mivecc_agents.networks import make_actor, make_critic

    def saturated_z(preset: Any) -> float:
        torch.manual_seed(0)
        actor, critic = make_actor("edge", "edge"), make_critic("edge", "edge")
        with torch.no_grad():  # every column deep in saturation (z about +20)
            actor.module.output_layer.bias.fill_(20.0)
        learner = DDPGLearner(actor, critic, "edge", preset)
        k = actor.module.spec.grid_size
        data = TensorDict({
            ("edge", "observation"): torch.rand(64, k, k, 3),
            ("edge", "mask"): torch.ones(64, k),
            ("edge", "action"): torch.zeros(64, k),
            ("next", "edge", "observation"): torch.rand(64, k, k, 3),
            ("next", "edge", "mask"): torch.ones(64, k),
            ("next", "edge", "reward"): torch.zeros(64, 1),
            ("next", "edge", "done"): torch.zeros(64, 1, dtype=torch.bool),
            ("next", "edge", "terminated"): torch.zeros(64, 1, dtype=torch.bool),
        }, batch_size=[64])
        buffer = ReplayBuffer(storage=LazyTensorStorage(64), batch_size=32)
        buffer.extend(data)
        learner.update(buffer, 30)
        with torch.no_grad():
            return actor.module.preactivation(data["edge", "observation"]).mean().item()

    base = TINY.replace(lr_actor=1e-2)
    assert saturated_z(base) > 19.5  # tanh' ~ 1e-17: no gradient moves it
    assert saturated_z(base.replace(actor_preact_bound=3.0, actor_preact_weight=1.0)) < 19.0


@pytest.mark.parametrize("field, value", [("actor_preact_bound", 0.0),
                                          ("actor_preact_bound", float("inf")),
                                          ("actor_preact_weight", -1.0)])
def test_preactivation_fields_are_checked(field: str, value: float) -> None:
    from mivecc_agents.presets import preset_with

    with pytest.raises(ValueError, match=field):
        preset_with("released", {field: str(value)})


def test_replay_buffer_keeps_each_batch_of_the_reused_collector_buffer() -> None:
    """The local collector yields its own buffer, overwritten by the next batch
    (``return_same_td``): copying a batch into the replay buffer, as the training loop
    does, keeps that batch's values after the collector has moved on."""
    from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
    from torchrl.modules import AdditiveGaussianModule

    from mivecc_agents.collectors import make_collector
    from mivecc_agents.networks import make_actor
    from mivecc_agents.training import env_factory, env_groups, make_policy

    overrides = {"rows": 1, "cols": 1, "max_steps": 1000}
    env_fn, _ = env_factory("native", [1500.0, 2100.0], overrides, "EE", seed=0)
    probe = env_fn()
    spec = probe.full_action_spec["edge", "action"]
    groups = env_groups(probe)
    probe.close()
    noise = AdditiveGaussianModule(spec=spec, action_key=("edge", "action"))
    policy = make_policy("edge", make_actor("edge", "edge"), noise, groups=groups)
    collector = make_collector(env_fn, policy, 400, -1, 1, None)  # 2 envs x 200 steps
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(800), batch_size=8)
    kept, yielded = [], []
    try:
        for data in collector:
            yielded.append(data)
            kept.append(data["next", "edge", "observation"].clone())
            buffer.extend(data.reshape(-1))
            if len(kept) == 2:
                break
    finally:
        collector.shutdown()
    assert yielded[0] is yielded[1]  # one buffer, overwritten by the second batch
    assert not torch.equal(kept[0], kept[1])
    stored = buffer[:]["next", "edge", "observation"]
    assert kept[1].abs().sum() > 0  # vehicles in the graphs
    torch.testing.assert_close(stored[:400], kept[0].reshape(400, *kept[0].shape[2:]))
    torch.testing.assert_close(stored[400:], kept[1].reshape(400, *kept[1].shape[2:]))


@pytest.mark.parametrize(("workers", "ray_address"), [(1, None), (2, None), (2, "local")])
def test_every_collector_keeps_the_env_as_given(monkeypatch, workers, ray_address) -> None:
    """The local, multi-process and Ray collectors (the Ray one through each worker's
    ``collector_kwargs``) all opt out of TorchRL's automatic policy transforms, so none warns
    or, from TorchRL 0.15, adds an InitTracker the local path does not have."""
    import sys
    import types

    import torchrl.collectors
    import torchrl.collectors.distributed

    from mivecc_agents.collectors import make_collector

    made = {}

    class Fake:
        def __init__(self, *args, **kwargs):
            made["kwargs"] = kwargs

        def update_policy_weights_(self):
            pass

    for name in ("Collector", "MultiSyncCollector"):
        monkeypatch.setattr(torchrl.collectors, name, Fake)
    monkeypatch.setattr(torchrl.collectors.distributed, "RayCollector", Fake)
    monkeypatch.setitem(sys.modules, "ray", types.ModuleType("ray"))  # ray need not be installed
    make_collector(lambda: None, None, 100, 200, workers, ray_address)
    kwargs = made["kwargs"]
    if ray_address is not None:
        from mivecc_agents.ray_worker import RayWorkerCollector

        # Ray prints an actor's multi-line repr as log lines: the workers' is one line
        assert kwargs["collector_class"] is RayWorkerCollector
        assert repr(object.__new__(RayWorkerCollector)) == "RayWorkerCollector()"
        kwargs = kwargs["collector_kwargs"]
    assert kwargs["auto_register_policy_transforms"] is False


@pytest.mark.parametrize(("kind", "variant"), [("edge", "paper"), ("edge", "released"),
                                               ("cloud", "per_pick")])
def test_start_near_sets_every_column_near_the_action(kind: str, variant: str) -> None:
    from mivecc_agents.networks import make_actor_net

    torch.manual_seed(0)
    net = make_actor_net(kind, variant=variant)
    k = net.spec.grid_size
    obs, mask = torch.rand(8, k, k, 3) * 2 - 1, torch.ones(8, k)
    assert net(obs, mask).abs().max() < 0.5  # the usual start: near 0
    net.start_near(2.9)
    assert torch.allclose(net(obs, mask), torch.full((8, k), 2.9), atol=0.05)
    net.start_near(-1.0)
    assert torch.allclose(net(obs, mask), torch.full((8, k), -1.0), atol=0.15)
    for bad in (3.0, -3.0, float("nan")):
        with pytest.raises(ValueError, match="accel_mps2"):
            net.start_near(bad)


def test_actor_init_action_starts_the_trained_actor_there(tmp_path: Path) -> None:
    """No update happens before the warm-up is full: the checkpoint's actor is the start."""
    from mivecc_agents.policies import load_policy
    from mivecc_agents.presets import preset_with

    path = train_tiny_edge(tmp_path, TINY.replace(warmup_frames=10_000, actor_init_action=2.5))
    policy = load_policy(path)
    obs = np.random.default_rng(0).uniform(-1, 1, (4, 15, 15, 3)).astype(np.float32)
    actions = policy(obs, np.ones((4, 15), np.float32))
    assert np.allclose(actions, 2.5, atol=0.1)
    for bad in ("3", "-3.5"):
        with pytest.raises(ValueError, match=r"actor_init_action: must be a number in \(-3"):
            preset_with("released", {"actor_init_action": bad})
    with pytest.raises(ValueError, match=r"cannot use 'nan' \(expected a finite number or none\)"):
        preset_with("released", {"actor_init_action": "nan"})
    assert preset_with("released", {"actor_init_action": "none"}).actor_init_action is None


@pytest.mark.parametrize(
    ("frames_per_batch", "remaining", "n_envs", "workers", "cloud_period", "expected"),
    [
        (100, 10**6, 48, 1, 1, 4800),  # the preset's 100 steps of each of 48 environments
        (100, 150, 2, 1, 1, 150),  # a short run: 75 steps of 2 environments
        (100, 151, 2, 1, 1, 152),  # whole steps: 76 steps, one frame more than asked
        (100, 10**6, 2, 2, 1, 200),  # two workers share the 100 steps: 50 steps each
        (100, 10**6, 3, 1, 10, 300),  # whole decision blocks of 10 steps
        (100, 5, 2, 1, 10, 20),  # at least one block per worker, even for 5 frames
        (100, 10**6, 2, 0, 1, 200),  # workers < 1 count as one
    ],
)
def test_iteration_frames_are_whole_steps_of_every_worker(
    frames_per_batch: int, remaining: int, n_envs: int, workers: int, cloud_period: int,
    expected: int,
) -> None:
    from mivecc_agents.training import iteration_frames

    assert iteration_frames(frames_per_batch, remaining, n_envs, workers,
                            cloud_period) == expected
