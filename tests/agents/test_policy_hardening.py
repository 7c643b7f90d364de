"""Policies and checkpoints: global RNG untouched, config mismatches reported, stale temp files
of killed saves removed, weight-shape errors in one line."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from mivecc_agents.checkpoints import CheckpointError, load_checkpoint, save_checkpoint
from mivecc_agents.networks import make_actor_net, make_critic_net
from mivecc_agents.policies import check_policy_config, load_policy
from mivecc_env.config import MiVeCCConfig


def _payload(kind: str = "edge", config: dict | None = None) -> dict:
    return {
        "stage": kind, "kind": kind, "grid_size": 15 if kind == "edge" else 60,
        "actor": make_actor_net(kind).state_dict(), "critic": make_critic_net(kind).state_dict(),
        "frames": 0, "updates": 0, "metrics": {}, "preset": {},
        "config": config if config is not None else MiVeCCConfig(
            rows=1, cols=1, scheme="EE" if kind == "edge" else "EEC").to_dict(),
    }


def test_load_policy_leaves_the_global_torch_rng_alone(tmp_path: Path) -> None:
    path = save_checkpoint(tmp_path / "edge.pt", _payload())
    torch.manual_seed(123)
    before = torch.random.get_rng_state().clone()
    policy = load_policy(path)
    after = torch.random.get_rng_state()
    assert torch.equal(before, after)
    assert policy.kind == "edge"


def test_weight_shape_error_is_one_line(tmp_path: Path) -> None:
    payload = _payload()
    payload["actor"] = make_actor_net("cloud").state_dict()  # a K=60 actor labelled edge
    path = save_checkpoint(tmp_path / "edge.pt", payload)
    with pytest.raises(CheckpointError) as info:
        load_policy(path, expected_kind="edge")
    message = str(info.value)
    assert "\n" not in message
    assert "do not fit the edge network (K=15)" in message


def test_config_mismatch_is_reported(tmp_path: Path) -> None:
    cloud = load_policy(save_checkpoint(
        tmp_path / "cloud.pt", _payload("cloud", MiVeCCConfig(rows=3, cols=3, scheme="EEC")
                                        .to_dict())))
    edge = load_policy(save_checkpoint(tmp_path / "edge.pt", _payload("edge")))
    same = MiVeCCConfig(rows=3, cols=3, scheme="EEC", density_vplh=2100)
    assert check_policy_config(cloud, same) == []
    assert check_policy_config(edge, same) == []  # edge policies are trained on 1x1 by design

    grid = check_policy_config(cloud, same.replace(rows=1, cols=1))
    assert len(grid) == 1 and "trained on a 3x3 grid, the environment is 1x1" in grid[0]
    unused = check_policy_config(cloud, same.replace(scheme="EE"))
    assert any("scheme EE does not use cloud actions" in m for m in unused)
    dyn = check_policy_config(edge, same.replace(dt_s=0.05))
    assert any("dt_s=0.1 (here 0.05)" in m for m in dyn)
    with pytest.raises(CheckpointError, match=r"reads K=15 state graphs, the environment has "
                                              r"k_edge=10"):
        check_policy_config(edge, same.replace(k_edge=10))


def test_killed_save_leaves_no_temp_file_after_next_save_or_load(tmp_path: Path) -> None:
    """A save killed (SIGKILL) while writing leaves its temp file; the next save removes it,
    and so does a load."""
    target = tmp_path / "edge.pt"
    script = (
        "import os, signal, torch\n"
        "from mivecc_agents import checkpoints\n"
        "def dying_save(obj, fh):\n"
        "    fh.write(b'x' * 100000); fh.flush(); os.kill(os.getpid(), signal.SIGKILL)\n"
        "torch.save = dying_save\n"
        f"checkpoints.save_checkpoint({str(target)!r}, {{'kind': 'edge'}})\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}

    def killed_save() -> list[Path]:
        proc = subprocess.run([sys.executable, "-c", script], env=env, check=False)
        assert proc.returncode == -9
        left = sorted(tmp_path.glob(".edge.pt.*.tmp"))
        assert left and left[0].stat().st_size >= 100000
        return left

    killed_save()
    save_checkpoint(target, _payload())
    assert not list(tmp_path.glob(".*.tmp"))
    killed_save()
    load_checkpoint(target)
    assert not list(tmp_path.glob(".*.tmp"))


def test_temp_file_of_a_running_save_is_kept(tmp_path: Path) -> None:
    """Only temp files of dead writers (or old, PID-less ones) are deleted."""
    target = tmp_path / "edge.pt"
    mine = tmp_path / f".edge.pt.pid{os.getpid()}.abc.tmp"
    legacy_new = tmp_path / ".edge.pt.xyz.tmp"
    legacy_old = tmp_path / ".edge.pt.old.tmp"
    other = tmp_path / ".cloud.pt.pid1.abc.tmp"
    for p in (mine, legacy_new, legacy_old, other):
        p.write_bytes(b"x")
    old = time.time() - 3600
    os.utime(legacy_old, (old, old))
    save_checkpoint(target, _payload())
    assert mine.exists() and legacy_new.exists() and other.exists()
    assert not legacy_old.exists()
