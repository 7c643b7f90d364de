"""benchmarks/comparison.py tables: seed statistics, CSV precedence, rebuild from CSVs alone."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import comparison

FIELDS = ("scheme", "rows", "cols", "density", "seed", "steps", "avg_travel_velocity_mps",
          "upper_bound_mps", "collisions", "collided_vehicles", "throughput_vph")


def _write(path: Path, runs: list[tuple]) -> Path:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(FIELDS)
        for scheme, density, seed, v, coll in runs:
            w.writerow([scheme, 1, 1, float(density), seed, 3000, v, 12.9, float(coll),
                        2.0 * coll, 1000.0])
    return path


def test_summary_statistics_over_seeds() -> None:
    rows = [{"scheme": "max-pressure", "rows": "1", "cols": "1", "density": "900",
             "seed": str(s), "steps": "3000", "avg_travel_velocity_mps": str(v),
             "upper_bound_mps": "10.0", "collisions": str(c), "collided_vehicles": str(2 * c),
             "throughput_vph": "900", "source": "x.csv"}
            for s, v, c in ((0, 6.0, 1), (1, 7.0, 0), (2, 8.0, 2))]
    (t,) = comparison.summarise(rows, [(1, 1)], ["max-pressure"], [900])
    assert t["runs"] == 3 and t["seeds"] == "0 1 2"
    assert t["velocity_mean_mps"] == pytest.approx(7.0)
    assert t["velocity_sd_mps"] == pytest.approx(1.0)  # sample sd of 6, 7, 8
    assert (t["velocity_min_mps"], t["velocity_max_mps"]) == (6.0, 8.0)
    assert (t["collisions"], t["collided_vehicles"]) == (3, 6)
    assert t["share_of_upper_bound"] == pytest.approx(0.7)
    assert comparison.summarise(rows, [(3, 3)], ["max-pressure"], [900]) == []


def test_gain_uses_the_seeds_both_schemes_have() -> None:
    rows = [{"scheme": s, "rows": "1", "cols": "1", "density": "600", "seed": str(seed),
             "avg_travel_velocity_mps": str(v)}
            for s, seed, v in (("fixed-time", 0, 5.0), ("fixed-time", 1, 7.0),
                               ("fixed-time", 2, 100.0), ("max-pressure", 0, 6.0),
                               ("max-pressure", 1, 6.0))]
    assert comparison.gain(rows, (1, 1), 600) == pytest.approx(0.0)  # 6 vs (5 + 7) / 2
    assert comparison.gain(rows, (1, 1), 900) is None


def test_tabulate_only_rebuilds_from_csvs_and_the_last_csv_wins(tmp_path: Path) -> None:
    old = _write(tmp_path / "old.csv", [("E", 300, 0, 11.0, 4), ("E", 300, 1, 11.0, 4),
                                        ("reservation", 300, 0, 9.0, 0),
                                        ("reservation", 300, 1, 10.0, 0)])
    new = _write(tmp_path / "new.csv", [("E", 300, 0, 12.0, 1), ("E", 300, 1, 12.5, 0)])
    out = tmp_path / "out"
    argv = ["--tabulate-only", "--grids", "1x1", "--densities", "300", "600", "--seeds", "0",
            "1", "--schemes", "E", "reservation", "--from-csv", str(old), str(new),
            "--out", str(out)]
    assert comparison.main(argv) == 0
    with open(out / "comparison_table.csv", newline="", encoding="utf-8") as fh:
        table = {r["scheme"]: r for r in csv.DictReader(fh)}
    assert float(table["E"]["velocity_mean_mps"]) == pytest.approx(12.25)  # from new.csv
    assert int(table["E"]["collisions"]) == 1
    assert table["E"]["source"] == str(new)
    assert float(table["reservation"]["velocity_mean_mps"]) == pytest.approx(9.5)
    with open(out / "comparison.csv", newline="", encoding="utf-8") as fh:
        assert len(list(csv.DictReader(fh))) == 4
    md = (out / "comparison.md").read_text(encoding="utf-8")
    assert "| 300 | 12.25 +- 0.35 (1) | 9.50 +- 0.71 (0) | 12.90 |" in md
    assert "--tabulate-only" in md.splitlines()[0]  # the command that wrote it
    assert (out / "comparison_1x1.png").stat().st_size > 1000
    # the rebuilt CSV, read back alone, gives the same tables
    again = [*argv[:-5], "--from-csv", str(out / "comparison.csv"), "--out", str(tmp_path / "b")]
    assert comparison.main(again) == 0
    assert (tmp_path / "b" / "comparison_table.csv").read_text() == (
        out / "comparison_table.csv").read_text()


@pytest.mark.parametrize("argv, match", [
    (["--grids", "3by3"], "--grids"),
    (["--steps-for", "optimisation:1000"], "--steps-for"),
    (["--steps-for", "bogus=10"], "--steps-for"),
])
def test_bad_arguments_are_named(argv: list[str], match: str, tmp_path: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    """One line on stderr naming the option, exit status 2 (as ``python comparison.py``)."""
    from mivecc_env import cli_args

    def run() -> int:
        return comparison.main([*argv, "--tabulate-only", "--out", str(tmp_path)])

    try:
        status = cli_args.run(run, prog="comparison.py")
    except SystemExit as exc:  # argparse's usage errors exit inside main
        status = exc.code
    err = capsys.readouterr().err
    assert status == 2 and match in err and err.count("\n") == 1


def test_optimisation_cost_benchmark_counts_schedules() -> None:
    import optimisation_cost

    (r,) = optimisation_cost.main(["--windows", "3", "--density", "1500", "--steps", "200"])
    assert r["schedules"] >= 5 and r["milps_per_schedule"] >= 1.0
    assert r["full_window_mean_ms"] > 0 and r["wall_s"] > 0
    # the wrappers are removed again
    from mivecc_env.sim import optimisation as op

    assert op.schedule_milp.__name__ == "schedule_milp" and op._solve.__name__ == "_solve"


def test_runs_of_another_env_model_are_not_mixed_in(tmp_path: Path) -> None:
    paper = _write(tmp_path / "paper.csv", [("E", 300, 0, 12.0, 0)])
    released = tmp_path / "released.csv"
    released.write_text(paper.read_text().replace("scheme,", "model,scheme,", 1)
                        .replace("\nE,", "\nreleased,E,").replace("12.0,", "5.0,"))
    rows = comparison.load_rows([paper, released])
    assert [float(r["avg_travel_velocity_mps"]) for r in rows.values()] == [12.0]


def test_shipped_comparison_is_complete_and_its_table_rebuilds(tmp_path: Path) -> None:
    # docs/results/comparison: every scheme, grid and density with seeds 0-2 at 3000 steps,
    # and comparison_table.csv is what --tabulate-only makes of comparison.csv
    docs = Path(__file__).resolve().parents[1] / "docs" / "results" / "comparison"
    assert comparison.main(["--tabulate-only", "--from-csv", str(docs / "comparison.csv"),
                            "--out", str(tmp_path)]) == 0
    with open(tmp_path / "comparison_table.csv", newline="", encoding="utf-8") as fh:
        table = list(csv.DictReader(fh))
    cells = sum(comparison.runs_on(s, g, g) for g in (1, 3) for s in comparison.SCHEMES)
    assert len(table) == cells * len(comparison.DENSITIES)  # Coder on 3x3 only
    assert all(r["seeds"] == "0 1 2" and r["steps"] == "3000" for r in table)
    assert (tmp_path / "comparison_table.csv").read_text() == (
        docs / "comparison_table.csv").read_text()


def test_coder_runs_on_grids_with_regions_and_its_gain_table() -> None:
    assert not comparison.runs_on("coder", 1, 1) and comparison.runs_on("coder", 3, 3)
    assert comparison.runs_on("fixed-time", 1, 1)
    rows = [{"scheme": s, "rows": str(g), "cols": str(g), "density": "900", "seed": str(seed),
             "steps": "3000", "avg_travel_velocity_mps": str(v), "upper_bound_mps": "12.0",
             "collisions": "0", "throughput_vph": "1000"}
            for g, s, seed, v in ((3, "EEC", 0, 12.0), (3, "EEC", 1, 12.0), (3, "coder", 0, 6.0),
                                  (3, "coder", 1, 4.0), (3, "fixed-time", 0, 4.0),
                                  (1, "EEC", 0, 12.0), (1, "fixed-time", 0, 6.0))]
    md = comparison.markdown(rows, [(1, 1), (3, 3)], ["EEC", "fixed-time", "coder"], [900])
    first, second = md.split("### 3x3: average travel velocity [m/s]")
    assert "| density | EEC | fixed-time | upper bound |" in first  # no coder column on 1x1
    assert "EEC vs Coder" not in first
    assert "| density | EEC | fixed-time | coder | upper bound |" in second
    # 12 against the mean of 6 and 4 on seeds 0 and 1; against 4 on seed 0 only
    assert "| 900 | +140.0 % | +146.6 % | +200.0 % |" in second


def test_a_zero_backlog_of_a_fresh_run_is_zero_not_missing() -> None:
    """Runs simulated in the same process carry numbers, not CSV strings: a backlog of 0.0 is
    a full entry, not a missing value."""
    run = {"scheme": "coder", "rows": 3, "cols": 3, "density": 300.0, "seed": 0, "steps": 3000,
           "avg_travel_velocity_mps": 7.0, "upper_bound_mps": 12.9, "collisions": 0,
           "throughput_vph": 2600.0, "backlog": 0.0, "arrived": 301,
           "avg_travel_velocity_no_wait_mps": 7.4}
    (t,) = comparison.summarise([run], [(3, 3)], ["coder"], [300])
    assert (t["backlog_mean"], t["entered_share"]) == (0.0, 1.0)
    (t,) = comparison.summarise([{**run, "backlog": ""}], [(3, 3)], ["coder"], [300])
    assert np.isnan(t["backlog_mean"]) and np.isnan(t["entered_share"])


def _write_tagged(path: Path, column: str, tags: dict[str, str]) -> Path:
    """One run per scheme (3x3, 900 veh/lane/h, seed 0) with its value of an extra column."""
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow([*FIELDS, column])
        for scheme, tag in tags.items():
            w.writerow([scheme, 3, 3, 900.0, 0, 3000, 9.0, 12.9, 0.0, 0.0, 1000.0, tag])
    return path


def test_runs_are_reused_only_under_the_same_comparator_entry(tmp_path: Path) -> None:
    path = _write_tagged(tmp_path / "runs.csv", "comparator_entry", {
        "E": "", "fixed-time": "", "reservation": "slowed", "max-pressure": "stop_clearance"})
    # (rows without a signal_keep_clear column were made without the keep-clear rule)
    default = {k[0] for k in comparison.load_rows([path], signal_keep_clear=False)}
    slowed = {k[0] for k in comparison.load_rows([path], comparator_entry="slowed",
                                                 signal_keep_clear=False)}
    assert default == {"E", "fixed-time", "max-pressure"}  # no column: the default rule
    assert slowed == {"E", "reservation"}  # MiVeCC's runs do not depend on it


def test_signal_runs_are_reused_only_under_the_same_keep_clear_rule(tmp_path: Path) -> None:
    path = _write_tagged(tmp_path / "runs.csv", "signal_keep_clear", {
        "E": "", "reservation": "", "fixed-time": "", "actuated": "True", "pa-dqn": "False",
        "coder": "True"})
    assert comparison.SIGNAL_KEEP_CLEAR is MiVeCCConfig().signal_keep_clear is True
    on = {k[0] for k in comparison.load_rows([path])}
    off = {k[0] for k in comparison.load_rows([path], signal_keep_clear=False)}
    assert on == {"E", "reservation", "actuated", "coder"}
    assert off == {"E", "reservation", "fixed-time", "pa-dqn"}  # no column: made without it


def test_comaddpg_runs_ignore_the_comparators_entry_rule() -> None:
    # CoMADDPG enters like MiVeCC: its 42 runs under comparator_entry="slowed" are those of the
    # default (docs/comparators.md, "CoMADDPG")
    docs = Path(__file__).resolve().parents[1] / "docs" / "results"
    keys = ("avg_travel_velocity_mps", "collisions", "throughput", "backlog", "min_pet_s")

    def runs(folder: str) -> dict[tuple, tuple]:
        with open(docs / folder / "comparison.csv", newline="", encoding="utf-8") as fh:
            return {(r["rows"], r["density"], r["seed"]): tuple(r[k] for k in keys)
                    for r in csv.DictReader(fh) if r["scheme"] == "comaddpg"}

    default, slowed = runs("comparison"), runs("comparison_slowed_entry")
    assert len(default) == 42 and default == slowed


def test_paper_tables_coder_runs_are_the_comparisons() -> None:
    # benchmarks/paper_table.py ran Coder as one batch of 21 environments, the comparison one
    # run at a time: the same trajectories (velocity, collisions, throughput, backlog)
    docs = Path(__file__).resolve().parents[1] / "docs" / "results"
    keys = ("avg_travel_velocity_mps", "collisions", "throughput", "backlog")

    def runs(path: Path) -> dict[tuple, tuple]:
        with open(path, newline="", encoding="utf-8") as fh:
            return {(float(r["density"]), int(r["seed"])): tuple(float(r[k]) for k in keys)
                    for r in csv.DictReader(fh) if r["scheme"] == "coder"}

    table = runs(docs / "paper_table" / "paper_table.csv")
    assert len(table) == 21
    assert table == runs(docs / "paper_table" / "signal_runs" / "paper_table.csv")
    assert table == runs(docs / "comparison" / "comparison.csv")
