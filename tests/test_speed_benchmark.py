"""Tests of the speed benchmark (``benchmarks/speed.py``) in its ``--quick`` mode."""

from __future__ import annotations

import csv
import importlib.util
import json
from pathlib import Path
from types import ModuleType

import pytest

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "speed.py"


def _load() -> ModuleType:
    spec = importlib.util.spec_from_file_location("mivecc_speed_benchmark", _PATH)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


speed = _load()


def test_quick_run_writes_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert speed.main(["--quick", "--out", str(tmp_path), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "| grid |" in out and "Floor" in out
    with open(tmp_path / "speed.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    engines = {r["engine"] for r in rows}
    assert {"env", "core B=1", "core B=4"} <= engines
    for r in rows:
        assert float(r["steps_per_s"]) > 0
        assert float(r["vehicle_steps_per_s"]) >= 0
    doc = json.loads((tmp_path / "speed.json").read_text())
    assert doc["settings"]["steps"] == 30
    assert doc["machine"]["cpu_count"] >= 1
    assert set(doc["floors"]) == {"env_vs_sumo_steps", "core_b64_vs_sumo_vehicle_steps"}
    # The quick run has no 3x3 / 2100 / B=64 measurement: the floors are not assumed.
    assert all(f["met"] is None for f in doc["floors"].values())
    if speed.sumo_reference.sumo_available():
        assert "sumo" in engines
        assert doc["ratios"] and doc["ratios"][0]["env_vs_sumo_steps"] > 0
    assert (tmp_path / "speed.md").read_text().startswith("Command: `python benchmarks/speed.py")


def test_floors_are_computed_from_measurements() -> None:
    def row(engine: str, batch: int, sps: float, vsps: float) -> dict:
        return {"rows": 3, "cols": 3, "density": 2100.0, "engine": engine, "batch": batch,
                "steps_per_s": sps, "vehicle_steps_per_s": vsps}

    results = [row("env", 1, 800.0, 1e5), row("core B=64", 64, 100.0, 3e6),
               row("sumo", 1, 700.0, 4e5)]
    floor = speed.floors(speed.ratios(results))
    assert floor["env_vs_sumo_steps"]["met"] is True
    assert floor["env_vs_sumo_steps"]["measured_ratio"] == pytest.approx(800 / 700)
    assert floor["core_b64_vs_sumo_vehicle_steps"]["met"] is False
    assert floor["core_b64_vs_sumo_vehicle_steps"]["measured_ratio"] == pytest.approx(7.5)


def test_core_measurement_counts_vehicles() -> None:
    r = speed.measure_core(1, 1, 2100, batch=2, steps=20, warmup=100, seed=0)
    assert r["engine"] == "core B=2" and r["env_steps_per_s"] == pytest.approx(
        2 * r["steps_per_s"])
    assert r["mean_vehicles"] > 0


def test_bad_arguments_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert speed.main(["--steps", "0", "--no-progress"]) == 2
    with pytest.raises(SystemExit):
        speed.main(["--grids", "3by3"])
