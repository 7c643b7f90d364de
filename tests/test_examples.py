"""The examples/ scripts, each run for a few iterations in the environment of its library.

Each test is marked for its extra (``torchrl``, ``rllib``, ``sb3``, ``benchmarl``) and skipped,
naming the missing package, where that library is not installed. The heavy libraries are not in
``.[dev]``; docs/integrations.md says how each was run (its own virtual environment).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def load(name: str, *needs: str) -> ModuleType:
    """Import ``examples/<name>.py``, skipping the test if a package it needs is missing."""
    for package in needs:
        pytest.importorskip(package, reason=f"examples/{name}.py needs {package!r} (see "
                           "docs/integrations.md for its install command)")
    spec = importlib.util.spec_from_file_location(f"examples_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.torchrl
@pytest.mark.slow
@pytest.mark.parametrize("algo", ["mappo", "maddpg"])
def test_torchrl_example(algo: str) -> None:
    mod = load("torchrl_marl", "torchrl")
    returns = mod.main(["--algo", algo, "--iters", "2", "--frames", "32", "--batch", "16"])
    assert len(returns) == 2


@pytest.mark.rllib
@pytest.mark.parametrize(("view", "obs"), [("edges", "graph"), ("full", "graph"),
                                           ("full", "flat")])
def test_rllib_example(view: str, obs: str) -> None:
    mod = load("rllib_ppo", "ray.rllib")
    results = mod.main(["--iters", "1", "--view", view, "--obs", obs])
    assert results[-1]["env_runners"]["num_env_steps_sampled_lifetime"] >= 100


@pytest.mark.sb3
def test_sb3_supersuit_ppo_example() -> None:
    mod = load("sb3_ppo_supersuit", "stable_baselines3", "supersuit")
    model = mod.main(["--steps", "512"])
    assert model.num_timesteps >= 512


@pytest.mark.sb3
def test_sb3_sac_gymnasium_example() -> None:
    mod = load("sb3_sac_gymnasium", "stable_baselines3")
    model = mod.main(["--steps", "150"])
    assert model.num_timesteps >= 150


@pytest.mark.benchmarl
@pytest.mark.parametrize(("algo", "task"), [("mappo", "edges"), ("ippo", "edges"),
                                            ("maddpg", "edges"), ("mappo", "full"),
                                            ("maddpg", "full")])
def test_benchmarl_example(algo: str, task: str) -> None:
    mod = load("benchmarl_marl", "benchmarl")
    experiment = mod.main(["--algo", algo, "--task", task, "--iters", "2", "--frames", "50"])
    assert experiment.n_iters_performed == 2


def _needs_cuda() -> None:
    torch = pytest.importorskip("torch")
    if not torch.cuda.is_available():
        pytest.skip("torch sees no CUDA device")


@pytest.mark.torchrl
@pytest.mark.parametrize("algo", ["mappo", "maddpg"])
def test_torchrl_example_on_cuda(algo: str) -> None:
    _needs_cuda()
    mod = load("torchrl_marl", "torchrl")
    env = mod.make_env(0, max_steps=8, device="cuda")
    assert env.rollout(3)["edge", "observation"].device.type == "cuda"
    returns = mod.main(["--algo", algo, "--iters", "2", "--frames", "32", "--batch", "16",
                        "--device", "cuda"])
    assert len(returns) == 2


@pytest.mark.benchmarl
@pytest.mark.parametrize(("algo", "task"), [("mappo", "edges"), ("maddpg", "full")])
def test_benchmarl_example_on_cuda(algo: str, task: str) -> None:
    _needs_cuda()
    mod = load("benchmarl_marl", "benchmarl")
    experiment = mod.main(["--algo", algo, "--task", task, "--iters", "2", "--frames", "50",
                           "--device", "cuda"])
    assert experiment.n_iters_performed == 2
    assert {p.device.type for p in experiment.policy.parameters()} == {"cuda"}


@pytest.mark.torchrl
@pytest.mark.slow
def test_torchrl_signal_dqn_example(capsys: pytest.CaptureFixture) -> None:
    mod = load("torchrl_signal_dqn", "torchrl")
    rows = mod.main(["--frames", "1200", "--warmup", "400", "--updates-per-batch", "5",
                     "--eval-steps", "400", "--eval-seeds", "100"])
    assert list(rows) == ["DQN", "fixed-time", "max-pressure"]
    for row in rows.values():
        assert row["avg_travel_velocity_mps"] > 0 and row["collisions"] == 0
    printed = capsys.readouterr().out
    assert "batch 3: 1200 frames" in printed and "max-pressure: avg travel velocity" in printed
