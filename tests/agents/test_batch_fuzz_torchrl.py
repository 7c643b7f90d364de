"""The native TorchRL env against its batched twin on random combinations
(``benchmarks/batch_fuzz_torchrl.py``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from mivecc_agents.torchrl_env import MiVeCCTorchEnv  # noqa: E402
from mivecc_env.batched import BatchedMiVeCCEnv  # noqa: E402
from tests.scripts import load_benchmark  # noqa: E402

load_benchmark("batch_fuzz")  # the sibling it imports
fuzz = load_benchmark("batch_fuzz_torchrl")


def test_random_combinations_pack_what_the_batched_env_returns(tmp_path: Path) -> None:
    assert fuzz.main(["--cases", "8", "--out", str(tmp_path), "--no-progress"]) == 0
    records = [json.loads(line) for line in
               (tmp_path / "batch_fuzz_torchrl.jsonl").read_text().splitlines()]
    ran = [r for r in records if r["status"] == "same"]
    assert len(ran) >= 4 and sum(r["restarts"] for r in ran) > 0
    assert "8 cases in" in (tmp_path / "batch_fuzz_torchrl.md").read_text()


def test_a_packing_difference_is_named() -> None:
    kw = {"rows": 1, "cols": 2, "density": 2100, "scheme": "EEC", "cloud_period": 2}
    env = MiVeCCTorchEnv(2, groups=("edge", "cloud"), **kw)
    twin = BatchedMiVeCCEnv(batch_size=2, observe={"edge", "cloud"}, **kw)
    td = env.reset(seed=[1, 2])
    out = twin.reset(seed=[1, 2])
    for _ in range(40):
        td["edge", "action"] = torch.zeros(2, 2, 15)
        td["cloud", "action"] = torch.zeros(2, 1, 60)
        full, td = env.step_and_maybe_reset(td)
        out = twin.step(np.zeros((2, 2, 15)), np.zeros((2, 60)))
    nxt = full["next"]
    args = (out, twin.summary(), env, twin.cloud_decides)
    assert fuzz.torch_differences(nxt, *args, with_reward=True) == []
    flipped = ~twin.cloud_decides
    assert fuzz.torch_differences(nxt, out, twin.summary(), env, flipped,
                                  with_reward=False) == ["cloud/info/decides"]
    nxt["cloud", "reward"] = nxt["cloud", "reward"] + 1e-3
    nxt["edge", "info", "reward_sv"] = nxt["edge", "info", "reward_sv"] - 1.0
    assert fuzz.torch_differences(nxt, *args, with_reward=True) == [
        "edge/info/reward_sv", "cloud/reward"]
