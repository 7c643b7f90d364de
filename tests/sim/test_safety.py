"""Safety value (eqs. safe_value), hand-computed cases and guards."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.safety import safety_value, time_to_collision

CFG = MiVeCCConfig()
INF = np.inf


def sv(d: float, ttc: float = INF, d_front: float = INF, acc: float = 0.0,
       config: MiVeCCConfig = CFG) -> float:
    out = safety_value(np.array([d]), np.array([ttc]), np.array([d_front]), np.array([acc]),
                       config)
    return float(out[0])


def test_distance_term_only() -> None:
    # 10 ln(20 / 10) + 2 = 6.9315 + 2
    assert sv(20.0) == pytest.approx(8.931471805599454, abs=1e-9)
    # at d = alpha_d = 10 m the log vanishes: SV = SV_t = 2
    assert sv(10.0) == pytest.approx(2.0, abs=1e-12)
    # 10 ln(0.5) + 2
    assert sv(5.0) == pytest.approx(-4.931471805599453, abs=1e-9)


def test_time_to_collision_term() -> None:
    # d = 10 (SV_d = 0), TTC 0.5 s: -(1.5 / tanh 0.5)^2 = -(1.5 / 0.462117)^2
    assert sv(10.0, ttc=0.5) == pytest.approx(-10.536062347870132, abs=1e-9)
    # TTC >= 1 s or not closing in: SV_t = 2
    assert sv(10.0, ttc=1.0) == pytest.approx(2.0)
    assert sv(10.0, ttc=3.0) == pytest.approx(2.0)


def test_acceleration_term() -> None:
    # d_nearest = d_front = 15, front decelerating at -3:
    # SV_d = 10 ln 1.5 = 4.0547; SV_acc = 0.2 * -3 * 12 * ln(min(15 / 10, 1.5)) = -2.9193
    assert sv(15.0, d_front=15.0, acc=-3.0) == pytest.approx(3.1353023027028604, abs=1e-9)
    # the min(., alpha_acc) caps the ratio at 1.5: 30 m gives the same SV_acc
    assert sv(15.0, d_front=30.0, acc=-3.0) - sv(15.0) == pytest.approx(
        -2.919348778378784, abs=1e-9
    )
    # no front vehicle: the acceleration is ignored
    assert sv(15.0, d_front=INF, acc=-3.0) == sv(15.0)


def test_clipping_and_guards() -> None:
    assert sv(1e9) == 20.0  # 10 ln 1e8 = 184 -> clipped
    assert sv(INF) == 20.0  # empty road: the safest case
    assert sv(INF, d_front=INF, acc=3.0) == 20.0
    assert sv(0.0) == -20.0  # touching
    assert sv(0.0, ttc=0.0, d_front=0.0, acc=-3.0) == -20.0
    assert sv(1.0, ttc=0.1) == -20.0  # -23.0 - 225 -> clipped


def test_config_changes_constants() -> None:
    cfg = CFG.replace(sv_alpha_d=20.0, sv_max=5.0)
    assert sv(20.0, config=cfg) == pytest.approx(2.0)  # ln 1 = 0
    assert sv(1e6, config=cfg) == 5.0


def test_time_to_collision() -> None:
    gap = np.array([10.0, 10.0, 10.0, 0.0])
    closing = np.array([2.0, 0.0, -1.0, 5.0])
    np.testing.assert_array_equal(time_to_collision(gap, closing), [5.0, INF, INF, 0.0])


distances = st.one_of(
    st.floats(min_value=0.0, max_value=1e12, allow_nan=False), st.just(INF), st.just(0.0)
)
accels = st.floats(min_value=-3.0, max_value=3.0, allow_nan=False)


@settings(deadline=None, max_examples=200)
@given(
    d=st.lists(distances, min_size=1, max_size=8),
    ttc=st.lists(st.one_of(distances, st.floats(-10.0, 0.0)), min_size=8, max_size=8),
    d_front=st.lists(distances, min_size=8, max_size=8),
    acc=st.lists(accels, min_size=8, max_size=8),
    acc_source=st.sampled_from(["front", "ego"]),
)
def test_never_nan(
    d: list[float], ttc: list[float], d_front: list[float], acc: list[float], acc_source: str
) -> None:
    n = len(d)
    cfg = CFG.replace(sv_acc_source=acc_source)
    with np.errstate(divide="raise", invalid="raise"):  # no 1/0, no inf - inf
        out = safety_value(np.array(d), np.array(ttc[:n]), np.array(d_front[:n]),
                           np.array(acc[:n]), cfg)
    assert out.shape == (n,)
    assert np.all(np.isfinite(out))
    assert np.all((out >= -20.0) & (out <= 20.0))
