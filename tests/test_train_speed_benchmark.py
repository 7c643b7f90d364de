"""Smoke run of benchmarks/train_speed.py (tiny settings, both paths, real work)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("torchrl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


@pytest.mark.slow  # ~15 s idle, ~45 s on the shared box (both training paths are built)
def test_train_speed_smoke(tmp_path: Path) -> None:
    import torch
    import train_speed

    threads = torch.get_num_threads()
    try:
        out = train_speed.main([
            "--stages", "edge", "--repeats", "1", "--collect-frames", "10", "10",
            "--envs-per-density", "1", "1", "--steps-per-env", "5", "--learn-seconds", "0.1",
            "--e2e-frames", "30", "30", "--e2e-steps-per-env", "5", "5",
            "--out", str(tmp_path),
        ])
    finally:
        torch.set_num_threads(threads)
    measures = {(r["stage"], r["measure"]) for r in out["rows"]}
    assert measures == {("edge", m) for m in ("collect frames/s", "learner updates/s",
                                              "learner samples/s", "end-to-end frames/s")}
    assert all(r["old"] > 0 and r["new"] > 0 for r in out["rows"])
    text = (tmp_path / "train_speed.md").read_text()
    assert "python benchmarks/train_speed.py" in text and "| edge | collect frames/s |" in text


def test_learner_devices_smoke(tmp_path: Path) -> None:
    """benchmarks/learner_devices.py on the CPU: every (device, threads) row, real updates."""
    import learner_devices
    import torch

    threads = torch.get_num_threads()
    try:
        out = learner_devices.main([
            "--stages", "edge", "--devices", "cpu", "--threads", "1", "2", "--repeats", "1",
            "--collect-frames", "20", "20", "--envs-per-density", "1", "1",
            "--learn-seconds", "0.1", "--out", str(tmp_path),
        ])
    finally:
        torch.set_num_threads(threads)
    assert [(r["device"], r["threads"]) for r in out["rows"]] == [("cpu", 1), ("cpu", 2)]
    assert all(r["samples_per_s"] > 0 for r in out["rows"])
    assert out["rows"][0]["ratio"] == 1.0
    text = (tmp_path / "learner_devices.md").read_text()
    assert "python benchmarks/learner_devices.py" in text and "| edge | cpu | 2 |" in text
