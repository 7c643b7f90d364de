"""Stage-I training through TorchRL's ``RayCollector`` on a local Ray instance.

``train(..., ray_address="local")`` starts a single-node Ray runtime (owned by the collector,
shut down when the collector shuts down), runs one remote ``Collector`` actor (1 CPU) and
trains in this process. Skipped when ``ray`` (the ``mivecc[ray]`` extra) is not installed,
except the missing-ray error test, which simulates the absence of ray.
"""

from __future__ import annotations

import math
import subprocess
import sys
from functools import partial

import pytest
import torch

pytest.importorskip("torchrl")

from mivecc_agents.checkpoints import load_checkpoint
from mivecc_agents.training import TrainingError, train
from tests.agents.tiny import TINY, train_tiny_edge


@pytest.fixture
def ray_mod():
    """ray, with no runtime left initialised after the test."""
    ray = pytest.importorskip("ray")
    if ray.is_initialized():
        ray.shutdown()
    yield ray
    if ray.is_initialized():
        ray.shutdown()


def _no_ray_processes_left(wait_s: float = 15.0) -> bool:
    """No live raylet / gcs_server child of this process (polled for up to ``wait_s``)."""
    import os
    import time

    me = str(os.getpid())
    deadline = time.monotonic() + wait_s
    while True:
        out = subprocess.run(
            ["ps", "-o", "ppid=,stat=,args=", "-e"], capture_output=True, text=True, check=False
        ).stdout
        left = [
            line
            for line in out.splitlines()
            if line.split()[:1] == [me]
            and not line.split()[1].startswith("Z")  # reaped later, not running
            and ("raylet" in line or "gcs_server" in line)
        ]
        if not left or time.monotonic() > deadline:
            return not left
        time.sleep(0.5)


@pytest.mark.ray  # about 20 s on the shared 2-core box, so not marked slow
def test_edge_stage_trains_on_local_ray(ray_mod, tmp_path):
    from mivecc_agents.networks import make_actor

    torch.manual_seed(0)
    init_actor = make_actor("edge", "edge").module.state_dict()
    path = train_tiny_edge(tmp_path, ray_address="local")
    # the collector started the runtime, so it shut it down again
    assert not ray_mod.is_initialized()
    assert _no_ray_processes_left()
    ck = load_checkpoint(path, expected_kind="edge")
    assert path == tmp_path / "edge.pt"
    assert ck["stage"] == "edge" and ck["frames"] == 200 and ck["updates"] > 0
    assert any(not torch.equal(v, ck["actor"][k]) for k, v in init_actor.items())
    assert math.isfinite(ck["metrics"]["critic_loss"])
    # 120-step (12 s) episodes on 1x1: no vehicle can exit (shortest trip ~23 s): no data
    assert math.isnan(ck["metrics"]["avg_velocity_mps"])
    rows = (tmp_path / "train_log.csv").read_text().splitlines()
    # the local collector's iterations: 2 environments x 50 steps (frames_per_batch is per
    # environment), so 2 iterations of 100 frames
    assert [int(r.split(",")[1]) for r in rows[1:]] == [100, 200]
    assert (tmp_path / "learning_curve.png").is_file()


@pytest.mark.ray
@pytest.mark.slow
def test_ray_collector_two_workers_sync_weights_and_noise(ray_mod):
    """Two remote collectors: the batch has the local ``(n_densities, T)`` layout, and
    update_policy_weights_() (called by train after each update) reaches both of them."""
    from torchrl.modules import AdditiveGaussianModule

    from mivecc_agents.collectors import make_collector
    from mivecc_agents.networks import make_actor
    from mivecc_agents.train_envs import _make_batched_env
    from mivecc_agents.training import make_env, make_policy

    overrides = {"rows": 1, "cols": 1, "max_steps": 120}
    probe = make_env({**overrides, "density": 1500.0}, "EE")
    spec = probe.full_action_spec["edge", "action"]
    probe.close()
    actor = make_actor("edge", "edge")
    noise = AdditiveGaussianModule(
        spec=spec,
        sigma_init=1.0,
        sigma_end=0.1,
        annealing_num_steps=100,
        action_key=("edge", "action"),
    )
    policy = make_policy("edge", actor, noise)
    env_fn = partial(_make_batched_env, [1500.0, 2100.0], overrides, "EE")
    collector = make_collector(env_fn, policy, 100, 200, 2, "local")
    try:
        assert len(collector.remote_collectors) == 2
        for data in collector:
            # 2 workers x 2 density envs x 25 steps, joined along time per density
            assert data.batch_size == (2, 50)
            assert data["next", "edge", "reward"].isfinite().all()
            with torch.no_grad():
                for p in actor.parameters():
                    p.add_(0.5)
            noise.step(50)
            collector.update_policy_weights_()
            local_sd = policy.state_dict()
            for remote in collector.remote_collectors:
                remote_sd = ray_mod.get(remote.state_dict.remote())["policy_state_dict"]
                assert local_sd.keys() == remote_sd.keys()
                for k, v in local_sd.items():
                    torch.testing.assert_close(remote_sd[k], v, msg=k)
                assert float(remote_sd["module.1.sigma"]) == pytest.approx(float(noise.sigma))
    finally:
        collector.shutdown()
    assert not ray_mod.is_initialized()


@pytest.mark.ray
def test_auto_address_without_cluster_is_a_training_error(ray_mod, tmp_path, monkeypatch):
    from ray._private import services

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    if services.find_gcs_addresses() or services.find_bootstrap_address(None):
        pytest.skip("a Ray instance is running on this machine")
    with pytest.raises(TrainingError, match="cannot connect to Ray"):
        train("edge", TINY, frames=50, out_dir=tmp_path, ray_address="auto", progress=False)


def test_missing_ray_is_a_training_error(tmp_path, monkeypatch):
    """Without the extra (simulated: ``import ray`` fails) the message says how to install it."""
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(TrainingError, match=r"mivecc\[ray\]"):
        train("edge", TINY, frames=50, out_dir=tmp_path, ray_address="local", progress=False)
