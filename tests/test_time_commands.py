"""benchmarks/time_commands.py: whole-process timing, A and B in turn, paired ratios."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from tests.scripts import load_benchmark

timer = load_benchmark("time_commands")


def _run(wall: float, user: float = 1.0, code: int = 0) -> object:
    return timer.Run(wall_s=wall, user_s=user, sys_s=0.5, peak_mib=10.0, exit_code=code)


def test_ratios_are_taken_pair_by_pair() -> None:
    a = [_run(2.0), _run(6.0), _run(3.0)]
    b = [_run(1.0), _run(2.0), _run(3.0)]
    assert timer.paired_ratios(a, b, "wall_s") == [2.0, 3.0, 1.0]
    assert timer.spread(timer.paired_ratios(a, b, "wall_s")) == (1.0, 2.0, 3.0)
    # the ratio of medians (3 / 2) is not the median of the paired ratios (2)
    assert timer.paired_ratios(a, b, "cpu_s") == [1.0, 1.0, 1.0]


def test_report_rows_hold_min_median_max_and_failures() -> None:
    text = timer.report("cmd a", [_run(2.0), _run(4.0, code=1), _run(3.0)], "cmd b",
                        [_run(1.0), _run(1.0), _run(2.0)], warmup=1)
    lines = {line.split("  ")[0]: line.split() for line in text.splitlines()}
    assert lines["A wall s"][-3:] == ["2.000", "3.000", "4.000"]
    assert lines["A/B wall"][-3:] == ["1.5000", "2.0000", "4.0000"]
    assert "A FAILED in runs [2] (exit [1])" in text
    assert "B exit 0 in all 3 runs" in text
    assert "warm-up runs before them, not counted: 1 each" in text


def test_commands_alternate_and_their_figures_are_measured(tmp_path: Path) -> None:
    """A B A B order (each run appends its letter), walls at least the commands' sleeps, exit
    status 0, and the report and JSON written."""
    order = tmp_path / "order.txt"
    code = ("import sys, time; open(sys.argv[1], 'a').write(sys.argv[2]); "
            "time.sleep(float(sys.argv[3]))")
    out = tmp_path / "timing.txt"
    status = timer.main(["-n", "2", "--warmup", "1", "--out", str(out), "--vs",
                         f"{sys.executable} -c \"{code}\" {order} B 0.05", "--",
                         sys.executable, "-c", code, str(order), "A", "0.2"])
    assert status == 0
    assert order.read_text() == "ABABAB"
    runs = json.loads(out.with_suffix(".json").read_text())
    assert [len(runs[s]["runs"]) for s in "AB"] == [2, 2]
    assert all(r["wall_s"] >= 0.2 and r["exit_code"] == 0 for r in runs["A"]["runs"])
    assert all(r["wall_s"] >= 0.05 and r["peak_mib"] > 0 for r in runs["B"]["runs"])
    assert "A/B wall" in out.read_text()


def test_a_failing_command_is_reported_and_exits_1(tmp_path: Path) -> None:
    log = tmp_path / "log.txt"
    status = timer.main(["-n", "1", "--warmup", "0", "--log", str(log), "--", sys.executable,
                         "-c", "print('hello'); raise SystemExit(3)"])
    assert status == 1
    assert log.read_text() == "hello\n"


@pytest.mark.parametrize("argv", [["-n", "0", "--", "true"], [], ["--vs", "", "--", "true"]])
def test_bad_arguments_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        timer.main(argv)
    assert exc.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_a_command_that_cannot_start_is_one_line_and_exit_2() -> None:
    import subprocess

    done = subprocess.run([sys.executable, str(Path(timer.__file__)), "-n", "1", "--warmup", "0",
                           "--", "no-such-command-here"], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "time_commands.py: error: No such file or directory: no-such-command-here"]
