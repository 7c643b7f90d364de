"""``benchmarks/paper_targets.py``: issue 10's targets judged from paper_table runs, and the
README / results files that quote its tables."""

from __future__ import annotations

import re
import shlex
from pathlib import Path
from typing import Any

import pytest

from mivecc_env import cli_args
from tests.scripts import load_benchmark

ROOT = Path(__file__).resolve().parents[1]
targets = load_benchmark("paper_targets")
PAPER = targets.PAPER_3X3
DENSITIES = (900, 1500, 1800, 2100)


def _run(scheme: str, density: int, seed: int, velocity: float, events: int = 0,
         model: str = "released", period: int = 1) -> dict[str, Any]:
    return {"rows": 3, "cols": 3, "scheme": scheme, "density": density, "seed": seed,
            "collisions": events, "model": model, "cloud_period": period,
            "released_velocity_mps": velocity, "avg_travel_velocity_mps": velocity - 1.0}


def _table(gains: dict[str, dict[int, float]], events: dict[tuple[str, int], int] | None = None,
           ) -> list[dict[str, Any]]:
    """Two seeds per cell; E at 12 m/s, every other scheme ``gains[scheme][density]`` % over
    its base (EE, EE+3: E; EEC, EEC+3: EE)."""
    base = {"EE": "E", "EE+3": "E", "EEC": "EE", "EEC+3": "EE"}
    velocity = {("E", d): 12.0 for d in DENSITIES}
    for scheme in ("EE", "EE+3", "EEC", "EEC+3"):
        for d in DENSITIES:
            velocity[(scheme, d)] = velocity[(base[scheme], d)] * (1 + gains[scheme][d] / 100)
    return [_run(s, d, seed, v, (events or {}).get((s, d), 0) if seed == 0 else 0,
                 period=10 if s.startswith("EEC") else 1)
            for (s, d), v in velocity.items() for seed in (0, 1)]


def _gains(**overrides: dict[int, float]) -> dict[str, dict[int, float]]:
    """Gains that meet every target (the paper's EE, its EEC vs EE, ceilings equal)."""
    ee = {d: PAPER["EE vs E"][d] + 0.1 for d in DENSITIES}
    eec = {d: PAPER["EEC vs EE"][d] for d in DENSITIES}
    return {"EE": ee, "EE+3": dict(ee), "EEC": eec, "EEC+3": dict(eec), **overrides}


def _verdicts(rows: list[dict[str, Any]]) -> dict[str, str]:
    return dict(targets.judge(rows, "released_velocity_mps"))


def test_every_target_met() -> None:
    verdicts = _verdicts(_table(_gains()))
    assert len(verdicts) == 7
    assert all(v.startswith("met") for v in verdicts.values()), verdicts


def test_each_target_can_fail() -> None:
    short_ee = {d: PAPER["EE vs E"][d] + (0.1 if d < 2100 else -0.08) for d in DENSITIES}
    weak_cloud = {d: PAPER["EEC vs EE"][d] / 2 - (0.07 if d == 900 else -0.01) for d in DENSITIES}
    verdicts = _verdicts(_table(
        _gains(EE=short_ee, EEC=weak_cloud,
               **{"EE+3": {d: v + 0.5 for d, v in short_ee.items()}}),
        events={("E", 2100): 1, ("EEC", 1800): 2, ("EEC", 2100): 1}))
    assert verdicts["EE vs E [%] at least the paper's from 1500 on"].startswith(
        "not met at 2100: +1.57 / +2.02 / +2.04 against 1.47 / 1.92 / 2.12")
    assert verdicts["0 strict events in every cell (E, EE, EEC)"] == (
        "not met: E 1 (2100), EEC 3 (1800, 2100)")
    assert verdicts["EEC vs EE [%] at least half the paper's"] == (
        "not met at 900: +0.45 against 0.515 at 900")
    assert verdicts["EEC vs EE [%] positive at every density"].startswith("met")
    assert verdicts["the learned edge at or above the constant +3 edge (EE+3)"].startswith(
        "not met at any density")
    cloud = "the learned cloud at or above the constant +3 cloud (EEC+3)"
    assert verdicts[cloud].startswith("not met at 900 / 1500 / 1800 / 2100")
    assert "(every 10 steps)" in verdicts[cloud]


def test_order_and_sign_failures_and_missing_schemes() -> None:
    gains = _gains(EEC={d: (-0.01 if d == 1500 else 0.6) for d in DENSITIES})
    verdicts = _verdicts(_table(gains))
    assert verdicts["EEC > EE > E at every density"] == "not met at 1500: 900-2100"
    assert verdicts["EEC vs EE [%] positive at every density"] == (
        "not met at 1500: -0.01 to +0.60")
    only_rules = [r for r in _table(_gains()) if r["scheme"] in ("E", "EE")]
    verdicts = _verdicts(only_rules)
    assert verdicts["EEC > EE > E at every density"] == "no data (needs E, EE, EEC)"
    assert verdicts["EE vs E [%] at least the paper's from 1500 on"].startswith("met")


def test_column_metric_follows_the_model_and_refuses_mixed_runs() -> None:
    rows = _table(_gains())
    assert targets.column_metric(rows, "model", "x")[0] == "released_velocity_mps"
    paper_rows = [{**r, "model": "paper"} for r in rows]
    assert targets.column_metric(paper_rows, "model", "x")[0] == "avg_travel_velocity_mps"
    with pytest.raises(cli_args.InputError, match="runs of one model expected"):
        targets.column_metric(rows + paper_rows, "model", "x")
    # the default model's headline metric differs here (avg = released - 1): other gains
    text = targets.markdown([("paper", paper_rows)])
    assert "| target | paper (average travel velocity; seeds 0, 1) |" in text


def _command_argv(path: Path) -> list[str]:
    """The argv of the command a results file records on its first line."""
    command = re.match(r"Command: `python benchmarks/paper_targets.py (.*)`",
                       path.read_text(encoding="utf-8").splitlines()[0])
    assert command, path
    return shlex.split(command.group(1))


@pytest.mark.parametrize("name", ["paper_targets_released.md", "paper_targets_default.md"])
def test_committed_target_files_are_current(
    name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    committed = ROOT / "docs" / "results" / name
    argv = _command_argv(committed)
    fresh = tmp_path / name
    argv[argv.index("--out") + 1] = str(fresh)
    monkeypatch.chdir(ROOT)
    targets.main(argv)
    table = committed.read_text(encoding="utf-8").split("\n", 2)[2]
    assert fresh.read_text(encoding="utf-8").split("\n", 2)[2] == table


def test_readme_quotes_the_scripts_table(monkeypatch: pytest.MonkeyPatch) -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = readme[readme.index("python benchmarks/paper_targets.py \\"):]
    block = block[:block.index("```")]
    argv = shlex.split(block.replace("\\\n", " ").split("#")[0])[2:]
    monkeypatch.chdir(ROOT)
    table = targets.main(argv)
    assert table in readme
