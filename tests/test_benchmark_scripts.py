"""Smoke runs of the experiment scripts in benchmarks/ (tiny settings, real work)."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import comparison
import paper_table
import rules_study
import trace_collisions


def test_rules_study_writes_its_table(tmp_path: Path) -> None:
    rows = rules_study.main(["--rows", "1", "--cols", "1", "--densities", "900", "--seeds", "0",
                             "--steps", "300", "--readings", "sensible/acc=ego",
                             "literal/acc=ego", "--out", str(tmp_path)])
    assert [r["reading"] for r in rows] == ["sensible/acc=ego", "literal/acc=ego"]
    assert all(r["arrived_total"] > 0 for r in rows)
    assert (tmp_path / "rules_study.md").read_text().count("| ") > 4
    assert all(r["released_velocity_mps"] > 0 and r["min_distance_m"] > 0 for r in rows)


def test_paper_table_runs_and_merges(tmp_path: Path) -> None:
    out = paper_table.main(["--grids", "1x1", "--densities", "1500", "--schemes", "E", "EE",
                            "--seeds", "0", "--steps", "400", "--workers", "1",
                            "--out", str(tmp_path / "a")])
    with open(out / "paper_table.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["scheme"] for r in rows} == {"E", "EE"}
    assert (out / "velocity_vs_density_1x1.png").stat().st_size > 5000
    merged = paper_table.main(["--grids", "1x1", "--out", str(tmp_path / "b"), "--from-csv",
                               str(out / "paper_table.csv")])
    text = (merged / "paper_table.md").read_text()
    assert "EE vs E [%]" in text and "| 1500 |" in text
    assert "E released-style v [m/s]" in text and "| EE | 1500 |" in text


@pytest.mark.parametrize("new, old, expected", [(11.0, 10.0, 10.0), (9.0, 10.0, -10.0)])
def test_improvement_rate(new: float, old: float, expected: float) -> None:
    assert paper_table.improvement(new, old) == pytest.approx(expected)


def test_comparison_runs_reuses_and_tabulates(tmp_path: Path) -> None:
    args = ["--grids", "1x1", "--densities", "1500", "--schemes", "fixed-time", "max-pressure",
            "reservation", "--seeds", "0", "--steps", "300", "--out", str(tmp_path / "a")]
    assert comparison.main(args) == 0
    with open(tmp_path / "a" / "comparison.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert sorted(r["scheme"] for r in rows) == ["fixed-time", "max-pressure", "reservation"]
    assert all(float(r["arrived"]) == float(rows[0]["arrived"]) for r in rows)  # same demand
    md = (tmp_path / "a" / "comparison.md").read_text()
    assert "| 1500 |" in md and "max-pressure vs fixed-time" in md
    assert (tmp_path / "a" / "comparison_1x1.png").stat().st_size > 1000
    # a second call reuses every run of the first CSV
    again = ["--from-csv", str(tmp_path / "a" / "comparison.csv"),
             *[a if a != str(tmp_path / "a") else str(tmp_path / "b") for a in args]]
    assert comparison.main(again) == 0
    with open(tmp_path / "b" / "comparison.csv") as fh:
        assert [r["avg_travel_velocity_mps"] for r in csv.DictReader(fh)] == [
            r["avg_travel_velocity_mps"] for r in rows]



def test_trace_collisions_finds_the_documented_event(capsys: pytest.CaptureFixture[str]) -> None:
    # docs/results/released_study.md, "Traced collisions": E, released, 2100, seed 1, step 1184.
    records = trace_collisions.main(["--density", "2100", "--seed", "1", "--steps", "1185",
                                     "--history", "2"])
    out = capsys.readouterr().out
    assert [r["step"] for r in records] == [1184]
    assert sorted(records[0]["vehicles"]) == [619, 696] and 7 in records[0]["areas"]
    assert "v619 lane 2 s= 292.24" in out and "collision events: 1" in out
