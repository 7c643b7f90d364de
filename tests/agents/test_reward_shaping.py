"""Potential-based reward shaping (``reward_shaping="potential"``): formula, telescoping,
the env's potential across steps and chunks, macro transitions, and the trainer's wiring."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("torchrl")

from tensordict import TensorDict

from mivecc_agents import training
from mivecc_agents.checkpoints import load_checkpoint
from mivecc_agents.macro_steps import cloud_macro_transitions
from mivecc_agents.presets import preset_with
from mivecc_agents.reward_shaping import potential_keys, shape_rewards
from mivecc_agents.torchrl_env import MiVeCCTorchEnv
from tests.agents.tiny import TINY, train_tiny_edge


def _transitions(reward: torch.Tensor, u_now: torch.Tensor, u_next: torch.Tensor) -> TensorDict:
    """(T,) transitions of one cloud agent: reward (T, 1, 1), potentials (T, 1)."""
    t = reward.shape[0]
    return TensorDict({
        "cloud": TensorDict({"info": {"reward_velocity": u_now[:, None]}}, (t, 1)),
        "next": {"cloud": TensorDict({"reward": reward[:, None, None],
                                      "info": {"reward_velocity": u_next[:, None]}}, (t, 1))},
    }, batch_size=(t,))


def test_shaping_adds_the_potential_difference():
    data = _transitions(torch.tensor([0.5, -1.0]), torch.tensor([0.2, 0.0]),
                        torch.tensor([0.5, -0.4]))
    raw = data["next", "cloud", "reward"]
    out = shape_rewards(data, "cloud", gamma=0.8)
    assert out is data
    expected = torch.tensor([0.5 + (0.8 * 0.5 - 0.2) / 0.2, -1.0 + (0.8 * -0.4 - 0.0) / 0.2])
    torch.testing.assert_close(out["next", "cloud", "reward"][:, 0, 0], expected)
    assert raw[:, 0, 0].tolist() == [0.5, -1.0]  # a new tensor: the caller's is untouched


def test_shaped_return_differs_by_the_start_and_end_potentials_only():
    # sum_t gamma^t r'_t = sum_t gamma^t r_t - Phi(s_0) + gamma^T Phi(s_T): the action ranking
    # of every state is unchanged (Ng et al. 1999)
    gen = torch.Generator().manual_seed(0)
    gamma, t = 0.8, 50
    u = torch.randn(t + 1, generator=gen, dtype=torch.float64)
    r = torch.randn(t, generator=gen, dtype=torch.float64)
    shaped = shape_rewards(_transitions(r, u[:-1], u[1:]), "cloud", gamma)
    disc = gamma ** torch.arange(t, dtype=torch.float64)
    lhs = (disc * shaped["next", "cloud", "reward"][:, 0, 0]).sum()
    phi = u / (1 - gamma)
    torch.testing.assert_close(lhs, (disc * r).sum() - phi[0] + gamma**t * phi[-1])


def test_gamma_must_leave_a_finite_potential():
    data = _transitions(torch.zeros(1), torch.zeros(1), torch.zeros(1))
    with pytest.raises(ValueError, match="gamma: potential shaping needs 0 <= gamma < 1"):
        shape_rewards(data, "cloud", gamma=1.0)


@pytest.mark.parametrize("continuous", [False, True])
def test_env_potential_of_a_state_is_the_same_in_both_transitions(continuous):
    """u(s) read as a transition's start equals u(s) read as the previous transition's end,
    also across an episode (chunk) boundary of a continuous run; 0 after a fresh reset."""
    env = MiVeCCTorchEnv(densities=[1500, 2100], rows=1, cols=1, scheme="EEC", max_steps=30,
                         seed=0, continuous=continuous)
    roll = env.rollout(70, break_when_any_done=False)
    now, nxt = (roll.get(k)[..., 0] for k in potential_keys("cloud"))
    assert now[:, 0].tolist() == [0.0, 0.0]
    assert (nxt != 0).any()
    chunk_start = torch.zeros_like(now, dtype=torch.bool)
    chunk_start[:, 30::30] = True
    same = now[:, 1:] == nxt[:, :-1]
    if continuous:  # one simulation goes on: the potential carries over the chunk boundary
        assert bool(same.all())
    else:  # a reset starts from an empty network: u = 0 there, equal elsewhere
        assert bool(same[~chunk_start[:, 1:]].all())
        assert bool((now[chunk_start] == 0).all())


def test_macro_transitions_keep_the_decision_and_block_end_potentials():
    b, t, period = 1, 8, 4
    idx = torch.arange(t, dtype=torch.float32).expand(b, t)
    decides = torch.zeros(b, t, 1, dtype=torch.bool)
    decides[:, ::period] = True
    cloud = TensorDict({"info": {"decides": decides, "reward_velocity": idx[..., None]}},
                       (b, t, 1))
    nxt = TensorDict({"reward": idx[..., None, None] + 1,
                      "info": {"reward_velocity": idx[..., None] + 1}}, (b, t, 1))
    data = TensorDict({"cloud": cloud, "next": {"cloud": nxt}}, batch_size=(b, t))
    keys = [("next", "cloud", "reward"), *potential_keys("cloud")]
    out = cloud_macro_transitions(data, period, keys)
    assert out["cloud", "info", "reward_velocity"][0, :, 0].tolist() == [0, 4]
    assert out["next", "cloud", "info", "reward_velocity"][0, :, 0].tolist() == [4, 8]
    shaped = shape_rewards(out, "cloud", 0.5)["next", "cloud", "reward"][0, :, 0, 0]
    # mean block reward 2.5 / 6.5, plus (0.5 u' - u) / 0.5
    assert shaped.tolist() == [2.5 + (2.0 - 0.0) / 0.5, 6.5 + (4.0 - 4.0) / 0.5]


def test_cloud_stage_trains_on_shaped_rewards(tmp_path, monkeypatch):
    calls = []
    original = training.shape_rewards

    def spy(data, group, gamma):
        raw = data["next", group, "reward"].clone()
        out = original(data, group, gamma)
        calls.append((group, gamma, raw, out["next", group, "reward"].clone()))
        return out

    monkeypatch.setattr(training, "shape_rewards", spy)
    edge = train_tiny_edge(tmp_path / "edge")
    tiny = preset_with(TINY.replace(frames_per_batch=40, warmup_frames=8, batch_size=8,
                                    updates_per_frame=0.05, episode_steps=40),
                       {"reward_shaping": "potential", "gamma": "0.9"})
    path = training.train("cloud", tiny, frames=160, rows=1, cols=1, densities=1500, seed=3,
                          out_dir=tmp_path / "cloud", edge_checkpoint=edge, progress=False,
                          config_overrides={"cloud_period": 4})
    ck = load_checkpoint(path, expected_kind="cloud")
    assert ck["updates"] > 0 and ck["metrics"]["buffer"] == 40
    assert calls and all(g == "cloud" and gamma == 0.9 for g, gamma, _, _ in calls)
    # the stored rewards moved by the potential difference somewhere
    assert any(not np.allclose(raw.numpy(), new.numpy()) for *_, raw, new in calls)


def test_preset_field_rejects_unknown_shaping():
    with pytest.raises(ValueError, match="--preset-set reward_shaping: cannot use 'delta'"):
        preset_with(TINY, {"reward_shaping": "delta"})
