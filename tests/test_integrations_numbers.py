"""docs/integrations.md's session 37 figures, recomputed from the committed reports.

The example commands of each MARL library were timed with ``benchmarks/time_commands.py``
(whole processes, each library in its own fresh venv); its reports, per-run JSON and the
commands' output are under ``docs/results/integrations/session37/``, with the logs of the
example tests and of the lowest-versions run.
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest

from tests.scripts import load_benchmark

timer = load_benchmark("time_commands")

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results" / "integrations" / "session37"


def _flat(path: Path) -> str:
    """A Markdown file's text with every run of whitespace made one space."""
    return " ".join(path.read_text(encoding="utf-8").split())


DOC = _flat(ROOT / "docs" / "integrations.md")
TRAINING = _flat(ROOT / "docs" / "training.md")

#: report name -> (the documented command, the time cell of its table row)
TIMED = {
    "torchrl_mappo": ("examples/torchrl_marl.py --algo mappo", "11.9 s"),
    "torchrl_maddpg": ("examples/torchrl_marl.py --algo maddpg", "12.2 s"),
    "rllib_ppo": ("examples/rllib_ppo.py --iters 2", "21.4 s"),
    "rllib_ppo_full_flat": ("examples/rllib_ppo.py --iters 1 --view full --obs flat", "22.1 s"),
    "sb3_ppo_supersuit": ("examples/sb3_ppo_supersuit.py --steps 1024", "9.7 s"),
    "sb3_sac_gymnasium": ("examples/sb3_sac_gymnasium.py --steps 300", "9.4 s"),
}
BENCHMARL = ("benchmarl_mappo", "benchmarl_ippo", "benchmarl_maddpg")


def _runs(name: str) -> tuple[str, list[dict]]:
    side = json.loads((RESULTS / f"{name}.json").read_text(encoding="utf-8"))["A"]
    return side["command"], side["runs"]


def _csv_rows(name: str) -> list[dict[str, str]]:
    """The rows of a committed ``train_log.csv`` copy."""
    with open(RESULTS / name, encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _median_wall(name: str) -> str:
    return f"{timer.spread([r['wall_s'] for r in _runs(name)[1]])[1]:.1f} s"


def _row(command: str) -> str:
    """The table row of ``docs/integrations.md``'s session 37 table that runs ``command``."""
    at = DOC.index("Re-run in session 37 at the code of")
    table = DOC[at:DOC.index("Every run exited 0", at)]
    hits = [row for row in table.split(" | |") if f"`python {command}`" in row]
    assert len(hits) == 1, command
    return hits[0]


@pytest.mark.parametrize("name", sorted(TIMED))
def test_each_documented_time_is_its_reports_median(name: str) -> None:
    command, cell = TIMED[name]
    timed, runs = _runs(name)
    assert timed.endswith(f"python {command}")
    assert all(r["exit_code"] == 0 for r in runs)
    assert len(runs) == (2 if name.startswith("rllib") else 3)
    assert _median_wall(name) == cell
    assert f"| {cell} " in _row(command) + " "


def test_benchmarl_times_and_returns() -> None:
    cells = " / ".join(_median_wall(name) for name in BENCHMARL)
    assert cells == "11.8 s / 11.2 s / 12.5 s"
    assert cells in _row("examples/benchmarl_marl.py --algo mappo")
    finals = {}
    for name in BENCHMARL:
        assert all(r["exit_code"] == 0 for r in _runs(name)[1])
        text = (RESULTS / f"{name}.log").read_text(encoding="utf-8")
        returns = re.findall(r"mean return = ([0-9.]+): 100%", text)
        assert len(returns) == 8  # 2 progress lines per run, warm-up + 3 counted runs
        assert len(set(returns)) == 1  # every run ends on the same mean return
        finals[name] = returns[0]
    assert finals["benchmarl_mappo"] == finals["benchmarl_ippo"] == "16.674747467041016"
    assert finals["benchmarl_maddpg"] == "20.470550537109375"
    for value in ("16.674747467041016", "20.470550537109375"):
        assert value in DOC


def test_torchrl_runs_print_the_same_rewards() -> None:
    for name in ("torchrl_mappo", "torchrl_maddpg"):
        text = (RESULTS / f"{name}.log").read_text(encoding="utf-8")
        rewards = re.findall(r"mean edge reward per round (\[.*\])", text)
        assert len(rewards) == 4 and len(set(rewards)) == 1
    assert "`[0.0, 0.6331794261932373]`" in DOC
    assert "[0.0, 0.6331794261932373]" in (RESULTS / "torchrl_mappo.log").read_text()


def test_first_run_compile_times() -> None:
    ppo = re.findall(r"1024 agent-steps in ([0-9.]+) s",
                     (RESULTS / "sb3_ppo_supersuit.log").read_text(encoding="utf-8"))
    assert ppo[0] == "24.6" and {min(ppo[1:]), max(ppo[1:])} == {"0.6", "0.8"}
    mappo = re.findall(r"200 frames in ([0-9.]+) s",
                       (RESULTS / "benchmarl_mappo.log").read_text(encoding="utf-8"))
    assert mappo[:2] == ["24.5", "2.4"]
    assert "24.6 s for the SB3 PPO steps (0.6-0.8 s in the counted runs)" in DOC
    assert "24.5 s for BenchMARL MAPPO (2.4 s)" in DOC


@pytest.mark.parametrize(("marker", "summary", "seconds"), [
    ("sb3", "2 passed, 14 deselected", "10 s"),
    ("benchmarl", "5 passed, 2 skipped, 9 deselected", "23 s"),
    ("rllib", "3 passed, 13 deselected", "40 s"),
])
def test_example_test_logs(marker: str, summary: str, seconds: str) -> None:
    last = (RESULTS / f"pytest_{marker}.log").read_text(encoding="utf-8").splitlines()[-1]
    found = re.fullmatch(rf"{summary} in ([0-9.]+)s", last)
    assert found, last
    assert f"{float(found.group(1)):.0f} s" == seconds
    assert f"{seconds})" in DOC or f"{seconds};" in DOC


def test_lowest_versions_log() -> None:
    text = (RESULTS / "lowest_versions_tests.log").read_text(encoding="utf-8")
    found = re.search(r"(\d+) passed, (\d+) skipped, \d+ warnings in ([0-9.]+)s", text)
    assert found and found.groups()[:2] == ("582", "11")
    assert f"{float(found.group(3)):.0f} s" == "111 s"
    assert "**582 passed, 11 skipped**" in DOC and "in 111 s, no failure" in DOC


def test_ray_training_figures() -> None:
    """docs/training.md's Ray timing: whole processes from the report, the training loop's
    figures from the last runs' ``train_log.csv``, the Ray tests from their log."""
    report = json.loads((RESULTS / "ray_train.json").read_text(encoding="utf-8"))
    ray, local = report["A"], report["B"]
    assert "--ray-address local" in ray["command"] and "--ray-address" not in local["command"]
    assert all(r["exit_code"] == 0 for r in ray["runs"] + local["runs"])
    wall = {side: timer.spread([r["wall_s"] for r in runs["runs"]])[1]
            for side, runs in (("ray", ray), ("local", local))}
    peak = {side: timer.spread([r["peak_mib"] for r in runs["runs"]])[1]
            for side, runs in (("ray", ray), ("local", local))}
    low, median, high = timer.spread(timer.paired_ratios(
        [timer.Run(**r) for r in ray["runs"]], [timer.Run(**r) for r in local["runs"]],
        "wall_s"))
    assert (f"**{wall['ray']:.1f} s with Ray against {wall['local']:.1f} s without** (median; "
            f"paired ratio {median:.2f}, {low:.2f}-{high:.2f}), peak memory of the driver "
            f"{peak['ray']:.0f} MiB against {peak['local']:.0f} MiB") in TRAINING
    rows = {}
    for side in ("ray", "local"):
        rows[side] = _csv_rows(f"ray_train_log_{side}.csv")[-1]
        assert (rows[side]["frames"], rows[side]["updates"]) == ("1008", "126")
    figure = {key: [float(rows[side][key]) for side in ("ray", "local")]
              for key in ("wall_s", "fps_collect", "fps_optim")}
    assert ("took {:.1f} s against {:.1f} s, collection {:.0f} against {:.0f} frames/s, "
            "optimisation {:.0f} against {:.0f} samples/s").format(
        *figure["wall_s"], *figure["fps_collect"], *figure["fps_optim"]) in TRAINING
    last = (RESULTS / "pytest_ray.log").read_text(encoding="utf-8")
    found = re.search(r"^(\d+) passed in ([0-9.]+)s", last, flags=re.MULTILINE)
    assert found and found.group(1) == "4"
    assert f"4 passed in {float(found.group(2)):.0f} s" in TRAINING


def test_two_workers_overshoot() -> None:
    rows = _csv_rows("workers2_train_log.csv")
    assert [(r["iteration"], r["frames"]) for r in rows] == [("1", "480")]
    assert "there 480 frames for the 400 asked (one iteration of 2 x 240" in TRAINING
    assert "--frames 400 --episode-steps 300 --buffer-size 2000 --workers 2" in TRAINING


def test_install_records() -> None:
    """What pip installed in each fresh venv and how long it took."""
    seconds, versions = {}, {}
    for lib in ("sb3", "rllib", "benchmarl", "lowest", "ray"):
        lines = (RESULTS / f"install_{lib}.txt").read_text(encoding="utf-8").splitlines()
        assert lines[0].startswith("Successfully installed ") and lines[-1] == "rc=0"
        seconds[lib] = float(lines[1].split()[0])
        versions[lib] = set(lines[0].split()[2:])
    assert f"{min(seconds[x] for x in ('sb3', 'rllib', 'benchmarl')):.0f}-" \
        f"{max(seconds[x] for x in ('sb3', 'rllib', 'benchmarl')):.0f} s each" in DOC
    assert f"the install took {seconds['lowest']:.0f} s" in DOC
    assert f'".[dev,ray]"`, {seconds["ray"]:.0f} s: ray 2.60.0' in TRAINING
    assert {"ray-2.60.0", "torch-2.13.0+cpu"} <= versions["rllib"]
    assert {"stable-baselines3-2.9.2", "supersuit-3.11.0"} <= versions["sb3"]
    assert {"benchmarl-1.5.2", "torchrl-0.11.1", "tensordict-0.11.0"} <= versions["benchmarl"]
    assert {"numpy-1.24.4", "numba-0.61.0", "gymnasium-1.1.0",
            "pettingzoo-1.24.0"} <= versions["lowest"]
    assert {"ray-2.60.0", "torchrl-0.14.1"} <= versions["ray"]


def test_lowest_versions_give_the_readme_bits() -> None:
    lines = (RESULTS / "lowest_versions_e_run.txt").read_text(encoding="utf-8").splitlines()[1:]
    assert len(lines) == 3
    figures = {tuple(line.split(": ")[-1].split()) for line in lines}
    assert figures == {("12.446051785431159", "12.447966657973723")}
    # the README command's output, as docs/training.md records it
    assert "same bits as without (12.446051785431159 m/s" in TRAINING
    assert "prints `12.446051785431159 12.447966657973723` in both venvs" in DOC


def test_ray_against_a_running_head() -> None:
    log = (RESULTS / "ray_auto.log").read_text(encoding="utf-8").splitlines()
    assert len(log) == 5
    assert "Connecting to existing Ray cluster" in log[0] and log[-1].endswith("/edge.pt")
    assert [r["frames"] for r in _csv_rows("ray_auto_train_log.csv")] == ["1008"]
    assert "trained its 1008 frames and wrote `edge.pt`, printing 5 lines" in TRAINING
