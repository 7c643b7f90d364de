"""Stage II with a cloud deciding every n steps: decision flags, macro transitions, training."""

from __future__ import annotations

import pytest
import torch

pytest.importorskip("torchrl")

from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from mivecc_agents.checkpoints import load_checkpoint
from mivecc_agents.macro_steps import MacroStepError, cloud_macro_transitions
from mivecc_agents.torchrl_env import MiVeCCTorchEnv
from mivecc_agents.training import _buffer_keys, train
from tests.agents.tiny import TINY, train_tiny_edge

KEYS = _buffer_keys("cloud")


def _frames(b: int, t: int, period: int) -> TensorDict:
    """Synthetic frames: reward = frame index, observation = frame index, done at the end."""
    idx = torch.arange(t, dtype=torch.float32).expand(b, t)
    decides = torch.zeros(b, t, 1, dtype=torch.bool)
    decides[:, ::period] = True
    done = torch.zeros(b, t, 1, 1, dtype=torch.bool)
    done[:, -1] = True
    obs = idx[..., None, None].expand(b, t, 1, 2)
    cloud = {"observation": obs, "mask": obs, "action": obs,
             "info": TensorDict({"decides": decides}, batch_size=(b, t, 1))}
    nxt = {"observation": obs + 1, "mask": obs + 1, "reward": idx[..., None, None],
           "done": done, "terminated": done.clone()}
    return TensorDict({"cloud": TensorDict(cloud, (b, t, 1)),
                       "next": {"cloud": TensorDict(nxt, (b, t, 1))}}, batch_size=(b, t))


def test_macro_transitions_join_each_decision_block():
    out = cloud_macro_transitions(_frames(2, 12, 4), 4, KEYS)
    assert out.batch_size == (2, 3)
    # the decision's observation and action, the observation n steps later
    assert out["cloud", "observation"][0, :, 0, 0].tolist() == [0, 4, 8]
    assert out["cloud", "action"][0, :, 0, 0].tolist() == [0, 4, 8]
    assert out["next", "cloud", "observation"][0, :, 0, 0].tolist() == [4, 8, 12]
    # mean of the n per-step rewards; done where the block ended the episode
    assert out["next", "cloud", "reward"][0, :, 0, 0].tolist() == [1.5, 5.5, 9.5]
    assert out["next", "cloud", "done"][0, :, 0, 0].tolist() == [False, False, True]


def test_macro_transitions_reject_misaligned_frames():
    with pytest.raises(MacroStepError, match="not a multiple of cloud_period"):
        cloud_macro_transitions(_frames(1, 10, 4), 4, KEYS)
    bad = _frames(1, 12, 4)
    bad["cloud", "info", "decides"][0, 6] = True  # an episode restarted mid-block
    with pytest.raises(MacroStepError, match="multiples of cloud_period"):
        cloud_macro_transitions(bad, 4, KEYS)


def test_torchrl_env_exposes_the_decision_flag():
    env = MiVeCCTorchEnv(densities=[1500, 900], rows=1, cols=1, scheme="EEC", cloud_period=3,
                         max_steps=12, seed=0)
    check_env_specs(env)
    roll = env.rollout(7)
    flags = roll["cloud", "info", "decides"][..., 0]
    assert flags[0].tolist() == [True, False, False, True, False, False, True]
    plain = MiVeCCTorchEnv(rows=1, cols=1, scheme="EEC", seed=0)
    assert ("cloud", "info", "decides") not in plain.observation_spec.keys(True)


def test_cloud_stage_trains_on_decisions(tmp_path):
    edge = train_tiny_edge(tmp_path / "edge")
    tiny = TINY.replace(frames_per_batch=40, warmup_frames=8, batch_size=8,
                        updates_per_frame=0.05, episode_steps=40)
    path = train("cloud", tiny, frames=160, rows=1, cols=1, densities=1500, seed=3,
                 out_dir=tmp_path / "cloud", edge_checkpoint=edge, progress=False,
                 config_overrides={"cloud_period": 4})
    ck = load_checkpoint(path, expected_kind="cloud")
    assert ck["config"]["cloud_period"] == 4
    assert ck["frames"] == 160 and ck["updates"] > 0
    # 160 frames of 2 envs, one decision every 4 frames: 40 transitions stored
    assert ck["extra"]["n_envs"] == 2 and ck["metrics"]["buffer"] == 40
