"""``benchmarks/speed_paired.py``: equal windows round-robin, per-cycle ratios, floors."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from tests.scripts import load_benchmark

paired = load_benchmark("speed_paired", "mivecc_speed_paired")
needs_sumo = pytest.mark.skipif(not paired.sumo_reference.sumo_available(),
                                reason="Eclipse SUMO not installed")


def _window(cycle: int, engine: str, vsps: float, batch: int = 1, steps: int = 10) -> dict:
    return {"cycle": cycle, "engine": engine, "batch": batch, "steps": steps,
            "elapsed_s": 0.25, "vehicle_steps": vsps * 0.25, "vehicle_steps_per_s": vsps,
            "mean_vehicles": vsps * 0.25 / (steps * batch)}


def test_ratios_pair_each_window_with_the_same_cycles_sumo() -> None:
    # SUMO's speed swings by 2x between cycles; the engine is always 5x SUMO of its own cycle
    sumo = [100.0, 200.0, 100.0, 200.0, 150.0]
    windows = [_window(c, "sumo unregulated", v) for c, v in enumerate(sumo)]
    windows += [_window(c, "batched B=64", 5 * v, batch=64) for c, v in enumerate(sumo)]
    (row,) = [r for r in paired.summarise(windows) if r["engine"] == "batched B=64"]
    assert row["ratio_median"] == pytest.approx(5.0)
    assert row["ratio_q1"] == pytest.approx(5.0) and row["ratio_q3"] == pytest.approx(5.0)
    assert row["ratio_of_best"] == pytest.approx(5.0)
    assert row["windows"] == 5 and row["batch"] == 64
    (peer,) = [r for r in paired.summarise(windows) if r["engine"] == "sumo unregulated"]
    assert "ratio_median" not in peer and peer["median_vehicle_steps_per_s"] == 150.0


def test_estimators_differ_when_one_window_is_lucky() -> None:
    # one quiet moment makes SUMO's single fastest window 3x its usual speed
    sumo = [100.0, 100.0, 300.0, 100.0, 100.0]
    engine = [500.0, 520.0, 480.0, 510.0, 490.0]
    windows = [_window(c, "sumo unregulated", v) for c, v in enumerate(sumo)]
    windows += [_window(c, "core B=64", v, batch=64) for c, v in enumerate(engine)]
    (row,) = [r for r in paired.summarise(windows) if r["engine"] == "core B=64"]
    assert row["ratio_median"] == pytest.approx(5.0)
    assert row["ratio_of_best"] == pytest.approx(520.0 / 300.0)
    assert row["ratio_min"] == pytest.approx(1.6) and row["ratio_max"] == pytest.approx(5.2)


def test_floors_judge_the_fastest_windows_only_at_3x3_2100() -> None:
    # typical windows 5.5x, but SUMO's quietest window is 1.2x its typical one
    windows = [_window(0, "sumo unregulated", 100.0), _window(1, "sumo unregulated", 120.0)]
    windows += [_window(c, "batched B=64", 550.0 + c, 64) for c in (0, 1)]
    windows += [_window(c, "core B=64", 1400.0, 64) for c in (0, 1)]
    windows += [_window(c, "env EEC", 90.0) for c in (0, 1)]
    summary = paired.summarise(windows)
    floor = paired.floors(summary, (3, 3), 2100.0)
    assert floor["batched_b64"]["measured_ratio"] == pytest.approx(551.0 / 120.0)
    assert floor["batched_b64"]["met"] is False  # 4.59x, though the per-cycle median is 5.0x
    (b64,) = [r for r in summary if r["engine"] == "batched B=64"]
    assert b64["ratio_median"] == pytest.approx((5.5 + 551.0 / 120.0) / 2)
    assert floor["core_b64"]["met"] is False and floor["env_b1"]["met"] is False
    assert all(f["met"] is None for f in paired.floors(summary, (1, 1), 2100.0).values())


@needs_sumo
def test_quick_run_writes_every_window(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                       ) -> None:
    assert paired.main(["--quick", "--out", str(tmp_path), "--no-progress"]) == 0
    assert "fastest windows" in capsys.readouterr().out
    with open(tmp_path / "speed_paired.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    engines = ["env EEC", "batched B=2", "core B=2", "sumo unregulated"]
    assert [r["engine"] for r in rows[:4]] == engines  # cycle 0 starts with the first engine
    assert [r["engine"] for r in rows[4:8]] == engines[1:] + engines[:1]  # then rotates
    assert len(rows) == 3 * 4
    for r in rows:
        assert int(r["steps"]) >= 1 and float(r["elapsed_s"]) >= 0.02
    for engine in engines:  # every engine carried vehicles (a window may be too short to)
        assert sum(float(r["vehicle_steps"]) for r in rows if r["engine"] == engine) > 0, engine
    doc = json.loads((tmp_path / "speed_paired.json").read_text())
    assert doc["sumo"]["teleports"] == 0 and doc["sumo"]["inserted"] > 0
    assert all(f["met"] is None for f in doc["floors"].values())  # 1x1: no floor measured
    assert {r["engine"] for r in doc["summary"]} == set(engines)


@needs_sumo
def test_sumo_session_windows_and_horizon() -> None:
    with paired.sumo_reference.SumoSession(1, 1, 900, horizon_s=3.0) as sumo:
        steps, elapsed, moved = sumo.run_for(0.0)
        assert steps == 1 and elapsed >= 0.0 and moved >= 0
        elapsed, moved = sumo.run_steps(29)  # 30 steps of 0.1 s: the whole horizon
        assert sumo.steps_done == 30
        with pytest.raises(RuntimeError, match="demand horizon"):
            sumo.run_steps(1)
        with pytest.raises(RuntimeError, match="demand horizon"):
            sumo.run_for(10.0)  # a window stops at the horizon instead of draining the grid


@pytest.mark.parametrize(("argv", "expected"), [
    (["--cycles", "0"], "argument --cycles: must be an integer >= 1, got '0'"),
    (["--window-s", "0"], "argument --window-s: must be a number in [0.001, 60]"),
    (["--grid", "3by3"], "argument --grid: must look like 3x3"),
])
def test_bad_arguments_exit_2(argv: list[str], expected: str,
                              capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        paired.main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1 and expected in err, err


def test_without_sumo_is_one_line_exit_2(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(paired.sumo_reference, "sumo_available", lambda: False)
    status = paired.cli_args.run(lambda: paired.main(["--quick", "--out", str(tmp_path)]),
                                 "speed_paired.py")
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "pip install mivecc[sumo]" in err, err
