"""Tests of the speed benchmark (``benchmarks/speed.py``) in its ``--quick`` mode."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from tests.scripts import load_benchmark

speed = load_benchmark("speed", "mivecc_speed_benchmark")


def test_quick_run_writes_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert speed.main(["--quick", "--out", str(tmp_path), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "| grid |" in out and "Floor" in out
    with open(tmp_path / "speed.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    engines = {r["engine"] for r in rows}
    assert {"env E", "env EEC", "core B=1", "core B=4"} <= engines
    if speed.batched_available():
        assert "batched B=2" in engines
    for r in rows:
        assert float(r["steps_per_s"]) > 0
        assert float(r["vehicle_steps_per_s"]) >= 0
        assert float(r["queue"]) >= 0
    doc = json.loads((tmp_path / "speed.json").read_text())
    assert doc["settings"]["steps"] == 30
    assert doc["machine"]["cpu_count"] >= 1
    assert set(doc["floors"]) == {"env_b1", "batched_b64", "core_b64"}
    # The quick run has no 3x3 / 2100 / B=64 measurement: the floors are not assumed.
    assert all(f["met"] is None for f in doc["floors"].values())
    if speed.sumo_reference.sumo_available():
        assert {"sumo unregulated", "sumo right_before_left", "sumo traffic_light"} <= engines
        # SUMO really carried vehicles (an unregulated net once ran empty).
        sumo_rows = [r for r in rows if r["engine"].startswith("sumo")]
        assert all(float(r["mean_vehicles"]) > 0 for r in sumo_rows)
        ratio = {r["engine"]: r for r in doc["ratios"]}
        assert ratio["env EEC"]["vehicle_steps_ratio"] > 0
        assert "sumo unregulated" not in ratio  # the peer itself
    assert (tmp_path / "speed.md").read_text().startswith("Command: `python benchmarks/speed.py")


def test_floors_are_computed_from_measurements() -> None:
    def row(engine: str, batch: int, sps: float, vsps: float, veh: float = 300.0) -> dict:
        return {"rows": 3, "cols": 3, "density": 2100.0, "engine": engine, "batch": batch,
                "steps_per_s": sps, "vehicle_steps_per_s": vsps, "mean_vehicles": veh,
                "queue": 0.0}

    results = [row("env EEC", 1, 800.0, 4e5), row("core B=64", 64, 100.0, 3e6),
               row("batched B=64", 64, 30.0, 2.5e6), row("sumo unregulated", 1, 1000.0, 3.5e5),
               row("sumo right_before_left", 1, 100.0, 3e4)]
    ratio = speed.ratios(results)
    floor = speed.floors(ratio)
    assert floor["env_b1"]["met"] is True
    assert floor["env_b1"]["measured_ratio"] == pytest.approx(4e5 / 3.5e5)
    assert floor["core_b64"]["met"] is False
    assert floor["core_b64"]["measured_ratio"] == pytest.approx(3e6 / 3.5e5)
    assert floor["batched_b64"]["met"] is True
    # the jammed SUMO grid is a row of its own, never the peer
    by_engine = {r["engine"]: r for r in ratio}
    assert by_engine["sumo right_before_left"]["vehicle_steps_ratio"] == pytest.approx(3e4 / 3.5e5)
    assert by_engine["env EEC"]["steps_ratio"] == pytest.approx(0.8)


def test_core_measurement_counts_vehicles() -> None:
    r = speed.measure_core(1, 1, 2100, batch=2, steps=20, warmup=100, seed=0)
    assert r["engine"] == "core B=2" and r["env_steps_per_s"] == pytest.approx(
        2 * r["steps_per_s"])
    assert r["mean_vehicles"] > 0


@pytest.mark.skipif(not speed.batched_available(), reason="mivecc_env.batched not on this branch")
def test_batched_measurement_counts_vehicles() -> None:
    r = speed.measure_batched(1, 1, 2100, batch=3, steps=10, warmup=100, seed=0)
    assert r["engine"] == "batched B=3" and r["mean_vehicles"] > 0


@pytest.mark.parametrize(("argv", "expected"), [
    (["--steps", "0", "--no-progress"], "argument --steps: must be an integer >= 1, got '0'"),
    (["--grids", "3by3"], "argument --grids: must look like 3x3"),
    (["--densities", "-1"], "argument --densities: must be a number in [1.0, 3600.0]"),
])
def test_bad_arguments_exit_2(
    argv: list[str], expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        speed.main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1 and expected in err, err
