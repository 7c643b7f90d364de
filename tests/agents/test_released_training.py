"""The released trainer's pieces: preset fields, continuous chunks, raw edge actions, scalar
exploration, released networks, per-model shipped policies."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("torchrl")

from mivecc_agents.exploration import ScalarGaussianModule, make_exploration
from mivecc_agents.networks import get_network_spec, make_actor_net, make_critic_net
from mivecc_agents.presets import PRESETS, preset_with
from mivecc_agents.torchrl_env import MiVeCCTorchEnv
from mivecc_env.batched import BatchedMiVeCCEnv
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import end_node
from tests.agents.tiny import TINY


def test_released_preset_fields():
    p = PRESETS["released"]
    assert (p.lr_actor, p.lr_critic, p.lr_schedule) == (1e-3, 1e-2, "constant")
    assert (p.gamma, p.batch_size, p.tau) == (0.8, 48, 0.01)
    assert (p.exploration, p.sigma_init, p.sigma_end) == ("scalar", 0.1, 0.1)
    assert (p.raw_edge_period, p.continuous, p.network) == (2, True, "released")
    assert (p.updates_per_frame, p.warmup_frames, p.buffer_size, p.episode_steps) == (
        1.0, 5000, 100_000, 3000)
    env = dict(p.env_overrides)
    assert env == {"edge_selection": "lowest_sv", "reward_sv_weight": 1.0,
                   "edge_reward_scope": "decisions", "collision_penalty": 0.0}
    cloud = p.for_stage("cloud")
    assert (cloud.exploration, cloud.warmup_frames, cloud.buffer_size, cloud.episode_steps) == (
        "none", 500, 50_000, 1000)
    assert cloud.raw_edge_period == 0  # the raw edge action exists in stage I only
    assert p.for_stage("edge") == p
    # the other presets keep the earlier behaviour
    for name in ("paper", "stable"):
        q = PRESETS[name]
        assert (q.lr_schedule, q.exploration, q.raw_edge_period, q.continuous, q.network) == (
            "linear", "per_column", 0, False, "paper")


def test_preset_with_converts_and_names_bad_fields():
    p = preset_with("released", {"updates_per_frame": "0.25", "batch_size": "192",
                                 "continuous": "false", "warmup_frames": "100"})
    assert (p.updates_per_frame, p.batch_size, p.continuous) == (0.25, 192, False)
    assert p.for_stage("cloud").warmup_frames == 100  # an explicit change holds in stage II
    with pytest.raises(ValueError, match="unknown field 'nope'"):
        preset_with("released", {"nope": "1"})
    with pytest.raises(ValueError, match="batch_size"):
        preset_with("released", {"batch_size": "1.5"})
    with pytest.raises(ValueError, match="exploration"):
        preset_with("released", {"exploration": "loud"})
    with pytest.raises(ValueError, match="gamma"):
        preset_with("released", {"gamma": "nan"})


def test_fuse_raw_edge_skips_gate_veto_and_max():
    c = MiVeCCConfig(edge_sv_gate=-2.0)
    a_end = np.array([1.0, 1.0, -1.0, 2.0, 0.5])
    sv = np.array([0.0, -5.0, 0.0, 0.0, 0.0])
    a_edge = np.array([-2.0, 2.5, 1.5, 1.0, np.nan])
    normal = end_node.fuse(a_end, sv, a_edge, None, c)
    # vetoed (opposite sign), gated (SV < -2), vetoed, max(1, 2) = 2, no action
    np.testing.assert_array_equal(normal, [1.0, 1.0, -1.0, 2.0, 0.5])
    raw = end_node.fuse(a_end, sv, a_edge, None, c, raw_edge=np.ones(5, dtype=bool))
    np.testing.assert_array_equal(raw, [-2.0, 2.5, 1.5, 1.0, 0.5])
    some = end_node.fuse(a_end, sv, a_edge, None, c,
                         raw_edge=np.array([True, False, False, True, True]))
    np.testing.assert_array_equal(some, [-2.0, 1.0, -1.0, 1.0, 0.5])


def test_raw_edge_period_executes_raw_actions_on_alternate_steps_only(monkeypatch):
    env = MiVeCCTorchEnv(2, rows=1, cols=1, density=1500, scheme="EE", groups=("edge",),
                         raw_edge_period=2, seed=0)
    seen = []
    original = env.batched_env.step

    def spy(*args, **kwargs):
        seen.append(None if kwargs.get("raw_edge") is None else kwargs["raw_edge"].tolist())
        return original(*args, **kwargs)

    monkeypatch.setattr(env.batched_env, "step", spy)
    env.rollout(6, break_when_any_done=False)
    assert seen == [[False, False], [True, True]] * 3


def test_raw_edge_changes_the_trajectory_only_on_raw_steps():
    """A constant -3 edge action: vetoed where the rule accelerates, executed when raw."""
    def run(raw_steps):
        env = BatchedMiVeCCEnv(batch_size=1, rows=1, cols=1, density=2100, scheme="EE",
                               max_steps=100)
        step = env.reset(seed=3)
        vs = []
        for t in range(150):
            act = -3.0 * step.edge_mask.astype(np.float64)
            step = env.step(act, raw_edge=np.array([t in raw_steps]))
            vs.append(env.sim.v[env.sim.active].sum())
        return np.array(vs)

    never = run(set())
    late = run({120, 121})
    np.testing.assert_array_equal(never[:120], late[:120])  # identical before the raw steps
    assert late[121] < never[121]  # the raw -3 brakes where the rule would not


def test_continuous_chunks_truncate_without_reset():
    env = BatchedMiVeCCEnv(batch_size=2, rows=1, cols=1, density=2100, max_steps=350,
                           continuous=True)
    env.reset(seed=0)
    ref = BatchedMiVeCCEnv(batch_size=2, rows=1, cols=1, density=2100, max_steps=10_000)
    ref.reset(seed=0)
    for _ in range(350):
        step = env.step()
        ref.step()
    assert step.truncated.all() and (step.episode_steps == 350).all()
    in_net = env.sim.in_network.copy()
    before = env.summary()
    assert before["throughput"].sum() > 0
    step = env.start_chunk(np.array([True, False]))
    assert step.truncated.tolist() == [False, True]
    assert step.episode_steps.tolist() == [0, 350]
    np.testing.assert_array_equal(env.sim.in_network, in_net)  # the traffic stays
    after = env.summary()
    assert after["throughput"][0] == 0 and after["throughput"][1] == before["throughput"][1]
    assert after["sim_time_s"].tolist() == [0.0, 35.0]
    for _ in range(100):
        env.step()
        ref.step()
    # the continuing simulation is the one that was never cut
    np.testing.assert_array_equal(env.sim.s, ref.sim.s)
    np.testing.assert_array_equal(env.sim.exited, ref.sim.exited)
    chunk = env.summary()["throughput"][0]
    assert chunk == ref.sim.exited[0] - before["throughput"][0]
    with pytest.raises(RuntimeError, match="continuous"):
        BatchedMiVeCCEnv(batch_size=1, rows=1, cols=1).start_chunk([0])


def test_continuous_torchrl_env_starts_chunks_in_place():
    env = MiVeCCTorchEnv(2, rows=1, cols=1, density=2100, scheme="EE", groups=("edge",),
                         max_steps=5, continuous=True, seed=0)
    td = env.rollout(12, break_when_any_done=False)
    assert td["next", "done"][:, 4].all() and td["next", "done"][:, 9].all()
    assert env.batched_env.sim.step_count == 12  # never reset: one simulation
    assert env.batched_env.episode_steps.tolist() == [2, 2]


def test_edge_reward_scope_decisions_is_the_decision_vehicles_mean():
    env = BatchedMiVeCCEnv(batch_size=1, rows=1, cols=1, density=2100, scheme="EE",
                           edge_reward_scope="decisions", reward_sv_weight=1.0)
    step = env.reset(seed=1)
    for _ in range(250):
        step = env.step(np.zeros_like(step.edge_mask, dtype=np.float64))
    vi = env._edge.view_index[0, 0]
    v = env.sim.v.ravel()[env.sim.view.vehicle]
    expected = np.mean(v[vi[vi >= 0]] - 12.0)
    assert step.edge_terms["reward_velocity"][0, 0] == pytest.approx(expected)
    area = BatchedMiVeCCEnv(batch_size=1, rows=1, cols=1, density=2100, scheme="EE")
    s2 = area.reset(seed=1)
    for _ in range(250):
        s2 = area.step(np.zeros_like(s2.edge_mask, dtype=np.float64))
    v2 = area.sim.v.ravel()[area.sim.view.vehicle]
    inside = area._area >= 0
    assert inside.sum() > (area._edge.view_index[0, 0] >= 0).sum()  # more than the decisions
    assert s2.edge_terms["reward_velocity"][0, 0] == pytest.approx(np.mean(v2[inside] - 12.0))


def test_scalar_noise_is_one_number_per_environment():
    from tensordict import TensorDict
    from torchrl.data import Bounded

    spec = Bounded(-3.0, 3.0, (4, 2, 5))
    noise = make_exploration("scalar", spec, 0.5, 0.5, 10, "action")
    assert isinstance(noise, ScalarGaussianModule)
    td = TensorDict({"action": torch.zeros(4, 2, 5)}, batch_size=[4])
    out = noise(td)["action"]
    per_env = out.reshape(4, -1)
    assert (per_env == per_env[:, :1]).all()  # shared by agents and columns
    assert per_env[:, 0].unique().numel() == 4  # one draw per environment
    assert make_exploration("none", spec, 0.1, 0.1, 10, "action") is None
    with pytest.raises(ValueError, match="exploration"):
        make_exploration("loud", spec, 0.1, 0.1, 10, "action")


def test_released_networks():
    for kind, widths in (("edge", (96, 96, 48, 24, 1)), ("cloud", (512, 256, 64, 1))):
        spec = get_network_spec(kind, "released")
        assert spec.critic_layers == widths and spec.variant == "released"
        actor = make_actor_net(kind, variant="released", generator=torch.Generator().manual_seed(0))
        critic = make_critic_net(kind, variant="released")
        assert isinstance(actor.input_norm, torch.nn.LayerNorm)
        assert isinstance(critic.feature_norm, torch.nn.LayerNorm)
        assert any(isinstance(m, torch.nn.Tanh) for m in actor.convs.modules())
        linears = [m for m in list(actor.mlp.modules()) + list(critic.mlp.modules())
                   if isinstance(m, torch.nn.Linear)]
        assert all(m.weight.abs().max() <= 3e-3 for m in linears)
        k = spec.grid_size
        obs, mask = torch.randn(3, k, k, 3), torch.ones(3, k)
        assert actor(obs, mask).abs().max() < 0.5  # starts near 0 m/s^2, far from +-3
        assert critic(obs, torch.zeros(3, k), mask).shape == (3, 1)
    # the paper variant is unchanged (its state dict has no norm entries)
    assert not any("norm" in key for key in make_actor_net("edge").state_dict())
    with pytest.raises(ValueError, match="variant"):
        get_network_spec("edge", "huge")


def test_released_training_run_writes_a_released_network(tmp_path):
    from mivecc_agents.checkpoints import load_checkpoint
    from mivecc_agents.policies import load_policy
    from mivecc_agents.training import train

    preset = PRESETS["released"].replace(
        frames_per_batch=TINY.frames_per_batch, warmup_frames=48, buffer_size=500,
        updates_per_frame=0.05, episode_steps=60, envs_per_density=2)
    path = train("edge", preset, frames=200, rows=1, cols=1, densities=1500, seed=0,
                 out_dir=tmp_path, progress=False)
    ck = load_checkpoint(path)
    assert ck["network"] == "released"
    assert ck["config"]["reward_sv_weight"] == 1.0
    assert ck["config"]["edge_reward_scope"] == "decisions"
    policy = load_policy(path, expected_kind="edge")
    obs, mask = np.zeros((1, 15, 15, 3), np.float32), np.ones((1, 15), np.float32)
    np.testing.assert_array_equal(policy(obs, mask), policy(obs, mask))
    log = (tmp_path / "train_log.csv").read_text().splitlines()
    assert len(log) >= 2 and ",0.001,0.01," in log[-1]  # constant learning rates


@pytest.mark.parametrize("model", ["paper", "released"])
def test_shipped_policies_per_model_load_and_evaluate_deterministically(model):
    import argparse

    from mivecc_agents.cli import evaluation_policies
    from mivecc_agents.evaluation import evaluate_batch
    from mivecc_agents.policies import pretrained_path, pretrained_policies

    paths = {kind: pretrained_path(kind, model) for kind in ("edge", "cloud")}
    assert all(p is not None for p in paths.values())
    assert (paths["edge"].parent.name == "released") == (model == "released")
    policies = pretrained_policies(model)
    runs = [evaluate_batch("EEC", 3, 3, 2100, 120, [0], policies=policies, progress=False,
                           warn=False, model=model)[0] for _ in range(2)]
    keys = ("mean_speed_mps", "in_network", "min_distance_m", "min_ttc_s", "collisions")
    assert runs[0]["coordinator_actions"] == "policy"
    assert [runs[0][k] for k in keys] == [runs[1][k] for k in keys]
    # `mivecc evaluate` picks the shipped policies of the config's model
    args = argparse.Namespace(no_pretrained=False, edge_checkpoint=None, cloud_checkpoint=None)
    chosen = evaluation_policies(args, MiVeCCConfig(model=model, rows=3, cols=3, scheme="EEC"))
    assert {k: p.checkpoint for k, p in chosen.items()} == {k: str(p) for k, p in paths.items()}
    # a scheme that uses neither coordinator loads no shipped policy
    assert evaluation_policies(args, MiVeCCConfig(model=model, rows=3, cols=3)) == {}


@pytest.mark.parametrize("model", ["paper", "released"])
def test_shipped_shield_edges_load_record_their_training_and_are_picked(model):
    # docs/training.md, "The shield edges": each model ships an edge trained under the shield
    # (its reward over the whole control area, no SV term); its cloud is the one shipped
    # without the shield (the clouds retrained under it did worse), picked by the fallback
    import argparse

    from mivecc_agents.cli import evaluation_policies
    from mivecc_agents.evaluation import evaluate_batch
    from mivecc_agents.policies import pretrained_path, pretrained_policies

    paths = {kind: pretrained_path(kind, model, safety_shield=True) for kind in ("edge", "cloud")}
    assert paths["edge"].parent.name == "shield"
    assert paths["edge"] != pretrained_path("edge", model)
    assert paths["cloud"] == pretrained_path("cloud", model)
    policies = pretrained_policies(model, safety_shield=True)
    edge = policies["edge"].config
    assert {k: edge.get(k) for k in ("model", "safety_shield", "reward_sv_weight",
                                     "edge_reward_scope")} == {
        "model": model, "safety_shield": True, "reward_sv_weight": 0.0,
        "edge_reward_scope": "area"}
    runs = [evaluate_batch("EEC", 3, 3, 2100, 120, [0], policies=policies, progress=False,
                           warn=False, model=model, safety_shield=True)[0] for _ in range(2)]
    keys = ("mean_speed_mps", "in_network", "min_distance_m", "min_ttc_s", "collisions")
    assert runs[0]["coordinator_actions"] == "policy"
    assert [runs[0][k] for k in keys] == [runs[1][k] for k in keys]
    # `mivecc evaluate` picks the shield edge when the config has the shield, not without it
    args = argparse.Namespace(no_pretrained=False, edge_checkpoint=None, cloud_checkpoint=None)
    config = MiVeCCConfig(model=model, rows=3, cols=3, scheme="EEC", safety_shield=True)
    chosen = evaluation_policies(args, config)
    assert {k: p.checkpoint for k, p in chosen.items()} == {k: str(p) for k, p in paths.items()}
    plain = evaluation_policies(args, config.replace(safety_shield=False))
    assert {k: p.checkpoint for k, p in plain.items()} == {
        k: str(pretrained_path(k, model)) for k in ("edge", "cloud")}


@pytest.mark.parametrize(("model", "seed", "frames"), [("released", 8, 30_600),
                                                    ("paper", 1, 40_800)])
def test_shipped_shield_edges_record_their_recipe(model, seed, frames):
    # session 32's runs with uniform draws, each policy kept by the 3x3 picking evaluation;
    # docs/training.md, sections
    # "Uniform draws on nine training seeds: the released shield edge replaced" and
    # "The default model's shield edge with uniform draws"
    import torch

    from mivecc_agents.policies import pretrained_path

    ckpt = torch.load(pretrained_path("edge", model, safety_shield=True),
                      map_location="cpu", weights_only=False)
    preset = ckpt["preset"]
    assert {k: preset[k] for k in ("exploration", "sigma_init", "sigma_end",
                                   "explore_uniform_prob", "eval_select", "critic_members",
                                   "algorithm")} == {
        "exploration": "per_column", "sigma_init": 1.0, "sigma_end": 0.3,
        "explore_uniform_prob": 0.05, "eval_select": "min_ceiling_share", "critic_members": 1,
        "algorithm": "ddpg"}
    assert ckpt["config"]["model"] == model
    assert ckpt["frames"] == frames and ckpt["extra"]["seed"] == seed


def test_constant_policy_is_the_ceiling_coordinator():
    from mivecc_agents.policies import constant_policy

    fn = constant_policy("edge", 3.0, 15)
    mask = np.array([[1, 1, 0] + [0] * 12], dtype=np.float32)
    out = fn(np.zeros((1, 15, 15, 3), np.float32), mask)
    np.testing.assert_array_equal(out, 3.0 * mask)
    assert out.dtype == np.float32 and fn.kind == "edge" and fn.grid_size == 15
    with pytest.raises(ValueError, match="accel_mps2"):
        constant_policy("cloud", 3.5, 60)


def test_shipped_policies_record_their_documented_training_settings():
    # docs/training.md, "Shipped pretrained policies": every pair trained with the released
    # trainer; the released model's edge with SV weight 0.1 (session 9), the default model's
    # with 0 (session 17); both clouds decide every 10 steps.
    from mivecc_agents.checkpoints import load_checkpoint, network_variant
    from mivecc_agents.policies import pretrained_path, pretrained_policies

    expected = {
        ("paper", "edge"): {"model": "paper", "reward_sv_weight": 0.0},
        ("paper", "cloud"): {"model": "paper", "cloud_period": 10},
        ("released", "edge"): {"model": "released", "reward_sv_weight": 0.1,
                               "collision_penalty": 0.0},
        ("released", "cloud"): {"model": "released", "cloud_period": 10},
    }
    for (model, kind), settings in expected.items():
        config = pretrained_policies(model)[kind].config
        assert {k: config.get(k) for k in settings} == settings, (model, kind)
    # both clouds (released model: session 15, default model: session 16) have per-pick
    # networks, the released model's edge the released ones
    for model in ("paper", "released"):
        assert network_variant(load_checkpoint(pretrained_path("cloud", model))) == "per_pick"
    assert network_variant(load_checkpoint(pretrained_path("edge", "released"))) == "released"
