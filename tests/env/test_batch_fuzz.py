"""Batch invariance across random feature combinations (``benchmarks/batch_fuzz.py``)."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mivecc_env import mivecc_v0
from mivecc_env.batched import BatchedMiVeCCEnv
from tests.scripts import load_benchmark

batch_fuzz = load_benchmark("batch_fuzz")


@pytest.mark.parametrize("index", range(8))
def test_random_combinations_run_alike_in_a_batch_and_alone(index: int) -> None:
    record = batch_fuzz.run_case(batch_fuzz.draw_case(index))
    assert record["status"] in ("same", "refused"), record.get("detail")
    if record["status"] == "same":
        assert record["vehicle_steps"] > 0  # vehicles were compared, not empty networks


@pytest.mark.slow
def test_two_hundred_combinations(tmp_path: Path) -> None:
    assert batch_fuzz.main(["--cases", "200", "--start", "8", "--out", str(tmp_path),
                            "--no-progress"]) == 0


def test_cases_are_reproducible_and_cover_the_choice_fields() -> None:
    assert batch_fuzz.draw_case(5) == batch_fuzz.draw_case(5)
    assert batch_fuzz.draw_case(5) != batch_fuzz.draw_case(6)
    drawn = {name for i in range(40) for name in batch_fuzz.draw_case(i).overrides}
    assert set(batch_fuzz.choice_fields()) <= drawn
    assert {"scheme", "control", "safety_shield", "cloud_graphs", "sections"} <= drawn
    assert set(batch_fuzz.LATE_CHOICES) <= drawn


def test_fields_added_later_leave_every_other_draw_alone(monkeypatch: pytest.MonkeyPatch
                                                         ) -> None:
    """The committed digests stay comparable: without the late fields each case is drawn as
    before they existed."""
    with_late = [batch_fuzz.draw_case(i) for i in range(30)]
    late = batch_fuzz.LATE_CHOICES
    monkeypatch.setattr(batch_fuzz, "NOT_DRAWN", (*batch_fuzz.NOT_DRAWN, *late))
    monkeypatch.setattr(batch_fuzz, "LATE_CHOICES", ())  # as if the config had no such field
    for case, before in zip(with_late, map(batch_fuzz.draw_case, range(30)), strict=True):
        assert dataclasses.replace(case, overrides={
            k: v for k, v in case.overrides.items() if k not in late}) == before


def test_a_difference_is_named() -> None:
    env = BatchedMiVeCCEnv(batch_size=2, rows=1, cols=2, density=1800, scheme="EEC")
    out = env.reset(seed=[3, 4])
    for _ in range(30):
        out = env.step()
    alone = BatchedMiVeCCEnv(batch_size=1, rows=1, cols=2, density=1800, scheme="EEC")
    single = alone.reset(seed=4)
    for _ in range(30):
        single = alone.step()
    assert batch_fuzz.differences(out, 1, single) == []
    changed = dataclasses.replace(single, cloud_reward=single.cloud_reward + 1e-12,
                                  edge_terms={**single.edge_terms,
                                              "reward_sv": single.edge_terms["reward_sv"] + 1.0})
    assert set(batch_fuzz.differences(out, 1, changed)) >= {"cloud_reward",
                                                             "edge_terms[reward_sv]"}
    # environment 0 of the batch ran another seed: its graphs differ from the single run's
    assert "cloud_obs" in batch_fuzz.differences(out, 0, single)


def test_a_lost_vehicle_is_reported() -> None:
    env = BatchedMiVeCCEnv(batch_size=2, rows=1, cols=1, density=1800)
    out = env.reset(seed=0)
    for _ in range(50):
        out = env.step()
    assert batch_fuzz._problems(env, out, 0) == []
    env.sim.exited[0] += 1  # a vehicle counted twice
    assert batch_fuzz._problems(env, out, 0)[0].startswith("accounting")
    out.edge_obs[1, 0, 0, 0, 0] = np.nan
    assert batch_fuzz._problems(env, out, 1) == ["edge_obs: not finite or outside [-1, 1]"]


def test_script_writes_its_summary_and_one_line_per_case(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture) -> None:
    assert batch_fuzz.main(["--cases", "2", "--start", "3", "--out", str(tmp_path),
                            "--no-progress"]) == 0
    lines = (tmp_path / "batch_fuzz.jsonl").read_text().splitlines()
    assert [json.loads(line)["case"] for line in lines] == [3, 4]
    text = (tmp_path / "batch_fuzz.md").read_text()
    assert "2 cases in" in text and "| `scheme` |" in text
    assert text in capsys.readouterr().out


def test_an_error_of_the_env_is_a_finding(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(case: object) -> dict:
        raise RuntimeError("boom")

    monkeypatch.setattr(batch_fuzz, "run_case", broken)
    assert batch_fuzz.main(["--cases", "1", "--out", str(tmp_path), "--no-progress"]) == 1
    text = (tmp_path / "batch_fuzz.md").read_text()
    assert "1 error" in text and "RuntimeError: boom (rerun: `--start 0 --cases 1`)" in text


def test_the_parallel_env_is_compared_with_environment_0() -> None:
    kw = {"rows": 1, "cols": 2, "density": 2100, "scheme": "EEC"}
    batch = BatchedMiVeCCEnv(batch_size=2, **kw)
    pz = mivecc_v0.parallel_env(**kw)
    out = batch.reset(seed=[7, 8])
    obs, infos = pz.reset(seed=7)
    for _ in range(60):
        out = batch.step()
        obs, rewards, _, truncations, infos = pz.step({})
    step = (obs, rewards, truncations, infos)
    assert batch_fuzz.parallel_differences(pz, step, out, batch.summary()) == []
    obs = {**obs, "edge_1": obs["edge_1"] + 1.0}
    rewards = {**rewards, "cloud_0": rewards["cloud_0"] + 1e-9}
    found = batch_fuzz.parallel_differences(pz, (obs, rewards, truncations, infos), out,
                                            batch.summary())
    assert found == ["edge_1 observation", "cloud_0 reward"]
    other = batch_fuzz.parallel_differences(pz, step, dataclasses.replace(
        out, truncated=~out.truncated), batch.summary())
    assert other == ["truncations"]


def test_digests_repeat_and_a_changed_one_fails_the_comparison(tmp_path: Path) -> None:
    ran = [r for r in map(batch_fuzz.run_case, map(batch_fuzz.draw_case, range(6)))
           if r["status"] == "same"]
    assert len(ran) >= 2  # the drawn configurations are mostly accepted
    first, second = ran[:2]
    case = first["case"]
    assert batch_fuzz.run_case(batch_fuzz.draw_case(case))["digest"] == first["digest"]
    assert second["digest"] != first["digest"]
    other = tmp_path / "other.jsonl"
    other.write_text(json.dumps({**first, "digest": "0" * 64}) + "\n")
    assert batch_fuzz.compare_digests([first], other) == (1, [case])
    other.write_text(json.dumps(first) + "\n")
    assert batch_fuzz.compare_digests([first], other) == (1, [])
    out = tmp_path / "run"
    args = ["--cases", "1", "--start", str(case), "--out", str(out), "--no-progress",
            "--against", str(other)]
    assert batch_fuzz.main(args) == 0
    assert "1 of 1 cases equal" in (out / "batch_fuzz.md").read_text()
    other.write_text(json.dumps({**first, "digest": "0" * 64}) + "\n")
    assert batch_fuzz.main(args) == 1
    assert f"0 of 1 cases equal; differ: [{case}]" in (out / "batch_fuzz.md").read_text()


def test_numpy_reference_paths_give_the_kernels_trajectories(tmp_path: Path) -> None:
    # the same cases in this process (numba) and in one with MIVECC_NO_NUMBA=1: equal digests
    assert batch_fuzz.main(["--cases", "6", "--out", str(tmp_path / "numba"),
                            "--no-progress"]) == 0
    ran = sum(json.loads(line)["status"] == "same"
              for line in (tmp_path / "numba" / "batch_fuzz.jsonl").read_text().splitlines())
    assert ran >= 3
    script = Path(batch_fuzz.__file__)
    done = subprocess.run(
        [sys.executable, str(script), "--cases", "6", "--out", str(tmp_path / "numpy"),
         "--no-progress", "--against", str(tmp_path / "numba" / "batch_fuzz.jsonl")],
        env={**os.environ, "MIVECC_NO_NUMBA": "1",
             "PYTHONPATH": str(script.parents[1])}, capture_output=True, text=True,
        timeout=600, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "Kernels: numpy reference paths" in done.stdout
    assert f"{ran} of {ran} cases equal." in done.stdout


def test_restarts_count_only_what_was_restarted() -> None:
    # reservation plans run on one clock for the batch: no reset_at, truncated envs run on
    cases = (c for c in map(batch_fuzz.draw_case, range(400))
             if c.overrides.get("control") == "reservation" and not c.continuous
             and c.steps > c.overrides["max_steps"])
    record = next(r for r in map(batch_fuzz.run_case, cases) if r["status"] == "same")
    assert record["restarts"] == 0
