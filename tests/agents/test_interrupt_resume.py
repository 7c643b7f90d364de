"""Ctrl-C during training saves a checkpoint and the plots; resuming from policy-only files."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from mivecc_agents.checkpoints import export_policy, load_checkpoint  # noqa: E402
from mivecc_agents.cli import main  # noqa: E402
from mivecc_agents.policies import pretrained_path  # noqa: E402
from mivecc_agents.training import train  # noqa: E402
from tests.agents.tiny import TINY, train_tiny_edge  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_ctrl_c_saves_checkpoint_and_plots(tmp_path: Path) -> None:
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONWARNINGS": "ignore"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "mivecc_agents.cli", "train", "--stage", "edge", "--frames",
         "1000000", "--episode-steps", "60", "--envs-per-density", "1", "--density", "900",
         "--buffer-size", "500", "--out", str(out), "--no-progress"],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    log = out / "train_log.csv"
    deadline = time.monotonic() + 240
    try:
        # wait until at least one training iteration is logged
        while not (log.is_file() and len(log.read_text().splitlines()) >= 2):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "training did not start"
            time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, stderr
    ckpt = out / "edge.pt"
    assert stdout.strip().splitlines()[-1] == str(ckpt)
    assert "checkpoint saved" in stderr and "Traceback" not in stderr
    data = load_checkpoint(ckpt, expected_kind="edge")
    assert 0 < data["frames"] < 1_000_000
    assert (out / "learning_curve.png").stat().st_size > 5000


def test_resume_from_exported_policy_is_a_warm_start(tmp_path: Path, capsys) -> None:
    full = train_tiny_edge(tmp_path / "a")
    slim = export_policy(full, tmp_path / "slim.pt")
    path = train("edge", TINY, frames=100, rows=1, cols=1, densities=1500, seed=0,
                 out_dir=tmp_path / "b", resume=slim, progress=False, envs_per_density=1)
    assert "warm start" in capsys.readouterr().err
    ck = load_checkpoint(path, expected_kind="edge")
    assert ck["frames"] == 100  # counts from 0, not from the exported run's frames
    assert ck["extra"]["warm_start_from"] == str(slim)
    assert "loss" in ck and "optimizer" in ck  # a full checkpoint again


def test_cli_resume_from_shipped_policy(tmp_path: Path, capsys) -> None:
    edge = pretrained_path("edge")
    if edge is None:
        pytest.skip("no shipped edge policy")
    code = main(["train", "--stage", "edge", "--resume", str(edge), "--frames", "100",
                 "--episode-steps", "50", "--envs-per-density", "1", "--density", "900",
                 "--out", str(tmp_path), "--no-progress"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert captured.out.strip() == str(tmp_path / "edge.pt")
    assert "warm start" in captured.err and "Traceback" not in captured.err


def test_cli_resume_from_wrong_kind_is_one_line_exit_2(tmp_path: Path, capsys) -> None:
    cloud = pretrained_path("cloud")
    if cloud is None:
        pytest.skip("no shipped cloud policy")
    code = main(["train", "--stage", "edge", "--resume", str(cloud), "--frames", "100",
                 "--out", str(tmp_path), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "cloud" in err, err
