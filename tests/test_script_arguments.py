"""Bad input to the benchmark scripts: one line on stderr naming the option and its range, exit
status 2, no traceback (``mivecc_env.cli_args``, shared with the ``mivecc`` CLI)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from types import ModuleType

import pytest

from mivecc_env import cli_args
from mivecc_env.config import ConfigError
from tests.scripts import BENCHMARKS, ParsedError, load_benchmark, stop_after_parsing


def _script(name: str) -> ModuleType:
    """A benchmark script as a module (by path: it is not a package)."""
    return load_benchmark(name, f"script_{name}")


def _status(name: str, argv: list[str]) -> int:
    """Exit status of ``python benchmarks/<name>.py *argv`` (in this process)."""
    module = _script(name)
    try:
        return cli_args.run(lambda: module.main(argv), prog=f"{name}.py")
    except SystemExit as exc:  # argparse's usage errors exit inside main
        return int(exc.code or 0)


@pytest.mark.parametrize(("name", "argv", "expected"), [
    ("paper_table", ["--steps", "0"], "argument --steps: must be an integer >= 1, got '0'"),
    ("paper_table", ["--seeds", "-1"], "argument --seeds: must be an integer >= 0, got '-1'"),
    ("paper_table", ["--densities", "0"],
     "argument --densities: must be a number in [1.0, 3600.0], got 0.0"),
    ("paper_table", ["--grids", "20x20"], "argument --grids: must be an integer in [1, 16]"),
    ("paper_table", ["--seeds", "1", "1"], "--seeds: each value at most once, got 1 twice"),
    ("paper_table", ["--set", "cloud_graphs=lanes"],
     "cloud_graphs: must be one of ['network', 'per_lane'], got 'lanes'"),
    ("paper_table", ["--set", "k_cloud=1"], "k_cloud: must be an integer in [2, 512], got 1"),
    ("paper_table", ["--set", "colz=2"], "colz: unknown configuration field"),
    ("paper_table", ["--set", "density=900"], "density: use --densities instead of --set"),
    ("paper_table", ["--set", "omega"], "--set: expected key=value, got 'omega'"),
    ("cloud_pick_counts", ["--warmup", "10", "--steps", "10"],
     "--warmup: must be below --steps (10), got 10"),
    ("cloud_pick_counts", ["--grid", "0x3"], "argument --grid: must be an integer in [1, 16]"),
    ("shield_stress", ["--steps", "0"], "argument --steps: must be an integer >= 1, got '0'"),
    ("ceiling_resolution", ["--kind", "edge", "--deltas", "0"],
     "argument --deltas: must be a number in (0, 6], got '0'"),
    ("ceiling_resolution", ["--kind", "edge", "--deltas", "ulp", "ulp"],
     "--deltas: each value at most once"),
    ("stacking_audit", ["--threads", "0"], "argument --threads: must be an integer >= 1"),
    ("stacking_audit", ["--set", "model=paper"], "model: use --model instead of --set"),
    ("shield_stress", ["--models", "paper", "paper"],
     "--models: each value at most once, got 'paper' twice"),
    ("rules_study", ["--densities", "nan"], "argument --densities: must be a number in"),
    ("rules_study", ["--out", "NOTES/sub"], "--out: cannot create NOTES/sub"),
    ("speed", ["--grids", "0x3"], "argument --grids: must be an integer in [1, 16], got 0"),
    ("speed", ["--repeats", "0"], "argument --repeats: must be an integer >= 1, got '0'"),
    ("profile_step", ["--grid", "3"], "argument --grid: must look like 3x3 (ROWSxCOLS)"),
    ("profile_step", ["--batched-env", "0"], "argument --batched-env: must be an integer >= 1"),
    ("comparison", ["--densities", "2100.5"], "argument --densities: must be a whole number"),
    ("heatmaps", ["--cell", "0"], "argument --cell: must be a finite number > 0, got '0'"),
    ("train_speed", ["--repeats", "0"], "argument --repeats: must be an integer >= 1"),
    ("learner_devices", ["--devices", "gpu"],
     "argument --devices: must be cpu, cuda or cuda:N, got 'gpu'"),
    ("critic_check", ["--kind", "edge", "--constants", "5"],
     "argument --constants: must be a number in [-3, 3], got '5'"),
    ("critic_check", ["--kind", "edge", "--set", "density_vplh=900"],
     "density_vplh: use --densities instead of --set"),
    ("edge_reward_check", ["--set", "max_steps=10"], "max_steps: use --steps instead of --set"),
    ("edge_reward_check", ["--set", "scheme=E"],
     "--set scheme: this check always runs MiVeCC-EE"),
    ("edge_reward_check", ["--skip", "2000"], "--skip: must be in [0, --steps - 1]"),
    ("table_diff", ["NOTES", "NOTES"], "a: NOTES is not a paper_table.csv"),
    ("machine_info", ["--bogus", "1"], "unrecognized arguments: --bogus 1"),
    ("comparison", ["--tabulate-only", "--from-csv", "absent.csv"],
     "argument --from-csv: must be an existing file, got 'absent.csv'"),
    ("paper_table", ["--from-csv", "absent.csv"],
     "argument --from-csv: must be an existing file, got 'absent.csv'"),
    ("machine_info", ["extra"], "unrecognized arguments: extra"),
    ("headroom_search", ["--kind", "edge", "--population", "4", "--elite", "5"],
     "--elite: must be in [1, --population] = [1, 4], got 5"),
    ("headroom_search", ["--kind", "cloud", "--set", "cloud_period=5"],
     "cloud_period: use --cloud-period instead of --set"),
    ("headroom_search", ["--kind", "edge", "--sigma", "0"],
     "argument --sigma: must be a finite number > 0"),
    ("headroom_search", ["--kind", "edge", "--grid", "1x1", "--densities", "300", "--steps",
                         "20", "--population", "2", "--elite", "1"],
     "the constant +3 edge gains nothing over the baseline at any of the search's densities"),
    ("paper_targets", ["--column", "x"], "--column 'x': needs at least one CSV after the label"),
    ("paper_targets", ["--column", "x", "absent.csv"], "--column: no such file 'absent.csv'"),
    ("paper_targets", ["--column", "x", "NOTES"],
     "--column: NOTES is not a paper_table.csv with runs (no column 'rows')"),
])
def test_bad_script_argument_is_one_line_exit_2(
    name: str, argv: list[str], expected: str, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
) -> None:
    monkeypatch.setattr(sys, "argv", [f"{name}.py"])  # argparse's program name
    monkeypatch.chdir(tmp_path)
    Path("NOTES").write_text("root:x:0:0:root:/root:/bin/bash\nnot, a, table\n")
    status = _status(name, argv)
    err = capsys.readouterr().err
    assert status == 2, err
    assert "Traceback" not in err and err.count("\n") == 1, err
    assert f"{name}.py: error: " in err and expected in err, err


def test_count_and_number_types() -> None:
    assert cli_args.count(0)("0") == 0 and cli_args.count(1)("7") == 7
    for bad in ("0", "-3", "1.5", "x", ""):
        with pytest.raises(argparse.ArgumentTypeError, match="integer >= 1"):
            cli_args.count(1)(bad)
    assert cli_args.number(0.0, low_ok=False)("0.5") == 0.5
    for bad in ("0", "nan", "inf", "-1", "x"):
        with pytest.raises(argparse.ArgumentTypeError, match="finite number > 0"):
            cli_args.number(0.0, low_ok=False)(bad)
    assert cli_args.number(-3.0, 3.0)("-3") == -3.0
    with pytest.raises(argparse.ArgumentTypeError, match=r"\[-3, 3\]"):
        cli_args.number(-3.0, 3.0)("3.5")


def test_config_ranged_types() -> None:
    assert cli_args.density("2100") == 2100.0
    assert cli_args.whole_density("900") == 900 and isinstance(cli_args.whole_density("900"), int)
    assert cli_args.grid("3X2") == (3, 2)
    for parse, bad in ((cli_args.density, "0"), (cli_args.density, "inf"),
                       (cli_args.whole_density, "2100.5"), (cli_args.grid, "17x1"),
                       (cli_args.grid, "3x"), (cli_args.grid, "-1x2")):
        with pytest.raises(argparse.ArgumentTypeError):
            parse(bad)
    assert not math.isnan(cli_args.density("1"))


def test_check_distinct() -> None:
    cli_args.check_distinct("--seeds", [0, 1, 2])
    cli_args.check_distinct("--seeds", None)
    with pytest.raises(cli_args.InputError, match="--grids: each value at most once, got"):
        cli_args.check_distinct("--grids", [(1, 1), (3, 3), (1, 1)])


def test_run_maps_input_errors_to_exit_2_and_lets_bugs_through(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    def config_error() -> None:
        raise ConfigError("steps: must be an integer >= 1, got 0")

    def missing_file() -> None:
        (tmp_path / "absent.csv").read_text()

    assert cli_args.run(config_error, prog="x.py") == 2
    assert capsys.readouterr().err == "x.py: error: steps: must be an integer >= 1, got 0\n"
    assert cli_args.run(missing_file, prog="x.py") == 2
    err = capsys.readouterr().err
    assert err.startswith("x.py: error: No such file or directory: ") and "absent.csv" in err
    assert cli_args.run(lambda: 3) == 3 and cli_args.run(lambda: [1]) == 0
    assert cli_args.run(lambda: None) == 0

    def bug() -> None:
        raise ZeroDivisionError("a bug, not bad input")

    with pytest.raises(ZeroDivisionError):
        cli_args.run(bug)


@pytest.mark.parametrize("path", sorted(BENCHMARKS.glob("*.py")), ids=lambda p: p.name)
def test_every_script_with_options_uses_the_shared_entry(path: Path) -> None:
    """A script that takes options parses them with ``cli_args.Parser`` and runs through
    ``cli_args.run`` (a new script copying an old one keeps the one-line errors)."""
    text = path.read_text(encoding="utf-8")
    if "main(" not in text or path.name == "__init__.py":
        return
    assert 'sys.exit(cli_args.run(main))' in text, path.name
    assert "argparse.ArgumentParser(" not in text, path.name


@pytest.mark.parametrize(("name", "argv"), [
    ("train_speed", ["--e2e-frames", "0", "0"]),  # documented: 0 skips the end-to-end runs
    ("trace_collisions", ["--history", "0"]),
    ("released_reference", ["--scene", "scene.py", "--check-cloud-view", "0"]),
])
def test_documented_zero_values_still_parse(
    name: str, argv: list[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    stop_after_parsing(monkeypatch)
    with pytest.raises(ParsedError):
        _script(name).main(argv)
