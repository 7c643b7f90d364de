"""``benchmarks/speed_summary.py``: the committed speed runs' summary, and the docs quoting it.

The summary table of ``docs/performance.md`` and ``docs/results/performance/summary.md`` are the
script's output on the committed ``session<N>/speed_run<R>.json`` files; when a run is added,
these tests fail until both are regenerated. The README's B=64 spread is checked against the
same files.
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import speed_summary  # noqa: E402

from mivecc_env import cli_args  # noqa: E402

RUNS = ROOT / "docs" / "results" / "performance"


def _run_doc(b64: float, sumo: float = 1700.0, commit: str = "abcdef0123") -> dict:
    """A minimal ``speed.json`` with the fields the summary reads."""
    values = (("env_b1", "env EEC", 1.9, 1.0), ("batched_b64", "batched B=64", b64, 5.0),
              ("core_b64", "core B=64", 18.0, 15.0))
    return {
        "machine": {"cpu": "Test CPU", "cpu_flags": ["avx2"], "git_commit": commit,
                    "date_utc": "2026-01-02T03:04:05+00:00"},
        "results": [{"engine": "sumo unregulated", "steps_per_s": sumo}],
        "ratios": [{"engine": engine, "vehicle_steps_ratio": value}
                   for _, engine, value, _ in values] + [
            {"engine": "core B=1", "vehicle_steps_ratio": 6.0}],
        "floors": {key: {"engine": engine, "measured_ratio": value, "required_ratio": need}
                   for key, engine, value, need in values},
    }


def _write(folder: Path, session: int, run: int, doc: dict | str) -> None:
    path = folder / f"session{session}" / f"speed_run{run}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc), encoding="utf-8")


def test_committed_summary_is_current() -> None:
    records = speed_summary.load_runs(RUNS)
    assert len(records) >= 16
    text = speed_summary.summary_text(RUNS)
    assert (RUNS / "summary.md").read_text(encoding="utf-8") == text
    performance = (ROOT / "docs" / "performance.md").read_text(encoding="utf-8")
    assert text in performance


def test_readme_quotes_the_latest_machine_spread() -> None:
    records = speed_summary.load_runs(RUNS)
    machine = records[-1]["machine"]
    group = [r for r in records if r["machine"] == machine]
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    speed = readme[readme.index("Speed (`docs/performance.md`"):readme.index("## Documentation")]
    assert f"{len(group)} runs" in speed
    for key, need in (("env_b1", 1.0), ("batched_b64", 5.0), ("core_b64", 15.0)):
        values = [r[key] for r in group]
        assert f"{min(values):.2f}-{max(values):.2f}x" in speed, key
        assert f"median {statistics.median(values):.2f}x" in speed, key
        met = sum(x >= need for x in values)
        assert f"{need:g}x: met in {met} of {len(values)} runs" in speed, key


def test_readme_quotes_the_latest_paired_runs() -> None:
    records = speed_summary.load_paired_runs(RUNS)
    assert records, "no committed speed_paired runs"
    machine = records[-1]["machine"]
    group = [r for r in records if r["machine"] == machine]
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    speed = " ".join(readme[readme.index("Speed (`docs/performance.md`"):
                            readme.index("## Documentation")].split())
    assert f"{len(group)} runs" in speed
    for key, _ in speed_summary.FLOOR_COLUMNS:
        best = [r["floors"][key]["best"] for r in group]
        assert f"{min(best):.2f}-{max(best):.2f}x" in speed, key
    met_all = all(r["floors"][k]["best"] >= r["floors"][k]["required"]
                  for r in group for k, _ in speed_summary.FLOOR_COLUMNS)
    assert (f"every floor met in {len(group)} of {len(group)} runs" in speed) == met_all
    medians = [r["floors"]["batched_b64"]["median"] for r in group]
    assert f"{min(medians):.2f}-{max(medians):.2f}x at B = 64" in speed


def test_summary_marks_misses_and_groups_by_cpu(tmp_path: Path) -> None:
    _write(tmp_path, 2, 1, _run_doc(5.5))
    _write(tmp_path, 2, 2, _run_doc(4.5, sumo=1650.4))
    _write(tmp_path, 10, 1, _run_doc(6.0))  # session 10 sorts after session 2
    records = speed_summary.load_runs(tmp_path)
    assert [(r["session"], r["run"]) for r in records] == [(2, 1), (2, 2), (10, 1)]
    text = speed_summary.markdown(records)
    assert "| 2 | 2 | `abcdef0` | 2026-01-02 03:04 | Test CPU, AVX2 | 1,650 |" in text
    assert "4.50 (missed)" in text and "5.50 (missed)" not in text
    assert "Test CPU, AVX2: 3 runs, sessions 2-10;" in text
    row = "| batched env, EEC observations, B=64 | 4.50-6.00x | 5.50x | 5x: met in 2 of 3 |"
    assert row in text
    assert "| bare core, B=1 | 6.00-6.00x | 6.00x | - |" in text
    assert "batched env, EEC observations, B=1 |" not in text  # not measured: no row


def _paired_doc(b64: float, best: float, sumo_steps_per_s: float = 1400.0) -> dict:
    """A minimal ``speed_paired.json`` with the fields the summary reads."""
    values = (("env_b1", "env EEC", 1.8, 1.0), ("batched_b64", "batched B=64", b64, 5.0),
              ("core_b64", "core B=64", 17.0, 15.0))
    summary = [{"engine": engine, "ratio_median": value, "ratio_q1": value - 0.5,
                "ratio_q3": value + 0.5, "ratio_of_best": best if key == "batched_b64" else value}
               for key, engine, value, _ in values]
    summary.append({"engine": "sumo unregulated", "median_steps_per_s": sumo_steps_per_s})
    return {
        "machine": {"cpu": "Test CPU", "cpu_flags": ["avx512f"], "git_commit": "0123456789",
                    "date_utc": "2026-11-27T16:00:00+00:00"},
        "settings": {"window_s": 0.25},
        "summary": summary,
        "floors": {key: {"engine": engine, "measured_ratio": value, "required_ratio": need}
                   for key, engine, value, need in values},
    }


def test_paired_runs_follow_the_speed_runs(tmp_path: Path) -> None:
    _write(tmp_path, 23, 1, _run_doc(5.2))
    for run, (b64, best) in enumerate(((5.3, 5.1), (5.15, 4.95), (4.9, 5.0)), start=1):
        path = tmp_path / "session23" / f"speed_paired_run{run}.json"
        path.write_text(json.dumps(_paired_doc(b64, best)), encoding="utf-8")
    text = speed_summary.summary_text(tmp_path)
    assert text.startswith(speed_summary.markdown(speed_summary.load_runs(tmp_path)))
    assert "| 23 | 2 | `0123456` | 2026-11-27 16:00 | Test CPU, AVX-512 | 1,400 |" in text
    assert "4.95 (missed); 5.15 [4.65-5.65]" in text
    assert "Test CPU, AVX-512: 3 paired runs;" in text
    row = ("| batched env, B=64 (floor 5x) | 4.95-5.10x, 5.00x | 2 of 3 | 4.90-5.30x, 5.15x "
           "| 2 of 3 |")
    assert row in text


def test_without_paired_runs_the_summary_is_the_speed_runs(tmp_path: Path) -> None:
    _write(tmp_path, 2, 1, _run_doc(5.5))
    text = speed_summary.summary_text(tmp_path)
    assert text == speed_summary.markdown(speed_summary.load_runs(tmp_path))
    assert "Paired windows" not in text


def test_a_cpu_seen_in_one_session_is_named_once(tmp_path: Path) -> None:
    _write(tmp_path, 21, 1, _run_doc(5.5))
    _write(tmp_path, 21, 2, _run_doc(4.5))
    text = speed_summary.markdown(speed_summary.load_runs(tmp_path))
    assert "Test CPU, AVX2: 2 runs, session 21;" in text
    assert "sessions 21-21" not in text


def test_cli_writes_the_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _write(tmp_path, 1, 1, _run_doc(5.2))
    out = tmp_path / "out" / "s.md"
    assert speed_summary.main(["--runs", str(tmp_path), "--out", str(out)]) == 0
    assert out.read_text(encoding="utf-8") in capsys.readouterr().out


@pytest.mark.parametrize("content", ["{not json", json.dumps({"machine": {}})])
def test_corrupt_run_file_is_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str
) -> None:
    _write(tmp_path, 3, 1, content)
    assert cli_args.run(lambda: speed_summary.main(["--runs", str(tmp_path)]), "s.py") == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "speed_run1.json" in err and "not a speed.py result" in err


def test_no_runs_is_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli_args.run(lambda: speed_summary.main(["--runs", str(tmp_path)]), "s.py") == 2
    assert "no session<N>/speed_run<R>.json files" in capsys.readouterr().err
