"""Released-style passing times: the metric mark's geometry and hand-computed trips."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.network import GridNetwork
from mivecc_env.sim.passing import PassingTimes, mark_s


def test_mark_is_455_m_on_3x3() -> None:
    # centres at 150, 300, 450 m from every entry; the mark is 5 m past the last one
    np.testing.assert_allclose(mark_s(GridNetwork.from_config(MiVeCCConfig())), 455.0)


def test_mark_on_a_rectangular_grid() -> None:
    # 1x2: horizontal lanes pass centres at 150 and 300 m, vertical lanes one at 150 m
    net = GridNetwork.from_config(MiVeCCConfig(rows=1, cols=2))
    np.testing.assert_allclose(mark_s(net), [305.0, 305.0, 155.0, 155.0, 155.0, 155.0])


def test_velocity_is_total_length_over_total_time() -> None:
    net = GridNetwork.from_config(MiVeCCConfig(rows=1, cols=2))
    p = PassingTimes(net, batch_size=2)
    # env 0: a horizontal vehicle crosses 305 m half-way through the step [20, 21] s (entered at
    # 0: 20.5 s), a vertical one crosses 155 m half-way through [10, 11] s (entered at 2: 8.5 s);
    # a third vehicle does not reach its mark; env 1 gets nothing.
    p.record(env=np.array([0, 0]), lane=np.array([0, 3]), s_old=np.array([300.0, 140.0]),
             s_new=np.array([310.0, 150.0]), t_enter=np.array([0.0, 0.0]),
             t0_s=np.array([20.0, 0.0]), dt_s=1.0)
    assert p.count.tolist() == [1, 0]
    p.record(env=np.array([0]), lane=np.array([2]), s_old=np.array([150.0]),
             s_new=np.array([160.0]), t_enter=np.array([2.0]), t0_s=10.0, dt_s=1.0)
    assert p.count.tolist() == [2, 0]
    v = p.velocity_mps()
    # (305 + 155) / (20.5 + 8.5), not the mean of 305 / 20.5 and 155 / 8.5 (16.56 m/s)
    assert v[0] == pytest.approx(460.0 / 29.0)
    assert v[1] == 0.0  # no vehicle passed


def test_reset_at_one_environment() -> None:
    net = GridNetwork.from_config(MiVeCCConfig(rows=1, cols=1))
    p = PassingTimes(net, batch_size=2)
    p.record(env=np.array([0, 1]), lane=np.array([0, 0]), s_old=np.array([150.0, 150.0]),
             s_new=np.array([160.0, 160.0]), t_enter=np.zeros(2), t0_s=10.0, dt_s=1.0)
    p.reset_at(np.array([0]))
    assert p.count.tolist() == [0, 1]
    assert p.velocity_mps()[0] == 0.0
    assert p.velocity_mps()[1] == pytest.approx(155.0 / 10.5)
