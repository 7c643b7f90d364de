"""The uniform column replacement of the exploration (``explore_uniform_prob``)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

pytest.importorskip("torchrl")

from mivecc_agents.checkpoints import load_checkpoint
from mivecc_agents.exploration import UniformColumnsModule, make_exploration
from mivecc_agents.presets import get_preset, preset_with
from tests.agents.tiny import TINY, train_tiny_edge


def _noise(prob: float, sigma: float = 0.0) -> UniformColumnsModule:
    from torchrl.data import Bounded

    spec = Bounded(-3.0, 3.0, (400, 2, 15))
    return make_exploration("per_column", spec, sigma, sigma, 10, "action", uniform_prob=prob)


def _actions(noise: torch.nn.Module, value: float = -3.0) -> torch.Tensor:
    from tensordict import TensorDict

    td = TensorDict({"action": torch.full((400, 2, 15), value)}, batch_size=[400])
    return noise(td)["action"]


def test_field_and_its_errors() -> None:
    assert get_preset("released").explore_uniform_prob == 0.0  # every preset keeps none
    assert preset_with("stable", {"explore_uniform_prob": "0.05"}).explore_uniform_prob == 0.05
    for bad in (-0.1, 1.5):
        with pytest.raises(ValueError, match="explore_uniform_prob"):
            TINY.replace(explore_uniform_prob=bad)
    with pytest.raises(ValueError, match="explore_uniform_prob: must be 0 with exploration"):
        TINY.replace(exploration="none", explore_uniform_prob=0.1)
    with pytest.raises(ValueError, match="explore_uniform_prob: must be 0 with exploration"):
        make_exploration("none", None, 0.1, 0.1, 10, "action", uniform_prob=0.1)


def test_columns_are_replaced_by_uniform_draws_at_the_given_rate() -> None:
    torch.manual_seed(0)
    noise = _noise(0.1)
    assert isinstance(noise, UniformColumnsModule)
    out = _actions(noise)  # sigma 0: a column moves from -3 only where it was replaced
    replaced = out != -3.0
    assert 0.09 < replaced.float().mean() < 0.11  # 12 000 columns, p = 0.1
    values = out[replaced]
    assert values.min() >= -3.0 and values.max() <= 3.0
    assert 0.4 < (values > 0).float().mean() < 0.6  # uniform over [-3, 3]: half above 0
    assert float(noise.sigma) == 0.0
    everything = _actions(_noise(1.0))
    assert (everything != -3.0).all()
    assert not isinstance(_noise(0.0), UniformColumnsModule)  # 0: the Gaussian module alone


def test_deterministic_evaluation_adds_nothing() -> None:
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    with set_exploration_type(ExplorationType.DETERMINISTIC):
        assert (_actions(_noise(1.0, sigma=1.0)) == -3.0).all()


def test_training_run_with_uniform_columns(tmp_path: Path) -> None:
    path = train_tiny_edge(tmp_path, TINY.replace(explore_uniform_prob=0.2))
    assert load_checkpoint(path)["preset"]["explore_uniform_prob"] == 0.2
