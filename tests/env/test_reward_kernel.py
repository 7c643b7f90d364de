"""The compiled reward sums and control areas equal their numpy references, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.batched import BatchedMiVeCCEnv
from mivecc_env.sim import graph_kernel, reward_kernel

pytestmark = pytest.mark.skipif(not reward_kernel.HAVE_NUMBA, reason="numba not available")


@pytest.mark.parametrize(("extra", "raw", "steps"), [({}, None, 150),
                                                     ({"model": "released"}, True, 300)])
def test_reward_terms_match_numpy(monkeypatch: pytest.MonkeyPatch, extra: dict,
                                  raw: bool | None, steps: int) -> None:
    """Terms and rewards (compiled in one call) equal the numpy path; the released model with
    raw edge actions removes vehicles by collision, so the penalty terms are compared too."""
    kw = {"rows": 2, "cols": 2, "scheme": "EEC", "max_steps": 1000, **extra}
    fast = BatchedMiVeCCEnv(batch_size=3, densities=[600.0, 1800.0, 2700.0], **kw)
    ref = BatchedMiVeCCEnv(batch_size=3, densities=[600.0, 1800.0, 2700.0], **kw)
    fast.reset(seed=4)
    ref.reset(seed=4)
    rng = np.random.default_rng(0)
    rewarded = collided = 0
    for _ in range(steps):
        edge = rng.uniform(-3, 3, (3, fast.n_edge, fast.k_edge))
        cloud = rng.uniform(-3, 3, (3, fast.k_cloud))
        a = fast.step(edge, cloud, raw_edge=raw)
        with monkeypatch.context() as m:
            m.setattr(reward_kernel, "HAVE_NUMBA", False)
            m.setattr(graph_kernel, "HAVE_NUMBA", False)
            b = ref.step(edge, cloud, raw_edge=raw)
        for terms_a, terms_b in ((a.edge_terms, b.edge_terms), (a.cloud_terms, b.cloud_terms)):
            for key in terms_a:
                assert terms_a[key].tobytes() == terms_b[key].tobytes(), key
        assert a.edge_reward.tobytes() == b.edge_reward.tobytes()
        assert a.cloud_reward.tobytes() == b.cloud_reward.tobytes()
        collided += int(np.count_nonzero(a.edge_terms["reward_collision"]))
        # The graphs for the default model only: under model="released" the compiled and the
        # numpy cloud graph differ in the last float32 bits (an open issue of the graph paths,
        # not of the reward terms compared here).
        if not extra:
            assert a.edge_obs.tobytes() == b.edge_obs.tobytes()
            assert a.cloud_obs.tobytes() == b.cloud_obs.tobytes()
        rewarded += int(np.count_nonzero(a.edge_terms["reward_velocity"]))
    assert rewarded > 500
    if raw:  # the released model with raw actions collides: the penalty terms were compared
        assert collided > 0


def test_control_area_kernel_matches_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    env = BatchedMiVeCCEnv(batch_size=2, rows=3, cols=3, density=2100.0)
    env.reset(seed=1)
    for _ in range(200):
        env.step()
    net, view = env.sim.network, env.sim.view
    rng = np.random.default_rng(1)
    # the view's vehicles, plus points on the area borders and far outside
    lane = np.concatenate([view.lane, rng.integers(0, net.n_lanes, 400)])
    centres = net.lane_centres_s[lane[view.lane.size:], rng.integers(0, 3, 400)]
    border = centres + rng.choice([-1.0, 1.0], 400) * net.control_radius_m
    s = np.concatenate([view.s, border])
    s[-5:] = [0.0, -1.0, 1e6, net.lane_length.max(), 75.0]
    fast = net.control_area(lane, s)
    with monkeypatch.context() as m:
        m.setattr(graph_kernel, "HAVE_NUMBA", False)
        ref = net.control_area(lane, s)
    assert fast.dtype == ref.dtype and fast.tobytes() == ref.tobytes()
    assert (fast >= 0).sum() > 100 and (fast < 0).sum() > 100
