"""Motion model (eq. 1) with the acceleration clipped to keep v in its range."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.sim.end_node import bounded_motion

V_LO, V_HI, DT = 6.0, 13.0, 0.1


def test_constant_velocity_one_second() -> None:
    s, v = np.array([0.0]), np.array([10.0])
    for _ in range(10):
        s, v, a = bounded_motion(s, v, np.array([0.0]), V_LO, V_HI, DT)
        assert a[0] == 0.0
    assert s[0] == pytest.approx(10.0, abs=1e-12)
    assert v[0] == 10.0


def test_one_accelerating_step() -> None:
    # x += v T + a T^2 / 2 = 1.0 + 0.015, v += a T = 10.3
    s, v, a = bounded_motion(np.array([5.0]), np.array([10.0]), np.array([3.0]), V_LO, V_HI, DT)
    assert s[0] == pytest.approx(6.015, abs=1e-12)
    assert v[0] == pytest.approx(10.3, abs=1e-12)
    assert a[0] == 3.0


def test_acceleration_reduced_at_v_max() -> None:
    # from 12.9 only 0.1 m/s is left: applied a = 1.0, x += 1.29 + 0.005
    s, v, a = bounded_motion(np.array([0.0]), np.array([12.9]), np.array([3.0]), V_LO, V_HI, DT)
    assert a[0] == pytest.approx(1.0, abs=1e-9)
    assert v[0] == 13.0
    assert s[0] == pytest.approx(1.295, abs=1e-9)


def test_deceleration_reduced_at_v_min() -> None:
    # from 6.1 only 0.1 m/s of braking is left: applied a = -1.0, x += 0.61 - 0.005
    s, v, a = bounded_motion(np.array([0.0]), np.array([6.1]), np.array([-3.0]), V_LO, V_HI, DT)
    assert a[0] == pytest.approx(-1.0, abs=1e-9)
    assert v[0] == 6.0
    assert s[0] == pytest.approx(0.605, abs=1e-9)


def test_at_the_bounds_acceleration_is_zero() -> None:
    s, v, a = bounded_motion(
        np.array([0.0, 0.0]), np.array([13.0, 6.0]), np.array([3.0, -3.0]), V_LO, V_HI, DT
    )
    np.testing.assert_allclose(a, [0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(v, [13.0, 6.0])
    np.testing.assert_allclose(s, [1.3, 0.6])


def test_stopping_with_floor_zero() -> None:
    # signalized floor 0: from 0.2 m/s braking at -3 is cut to -2, x += 0.02 - 0.01
    s, v, a = bounded_motion(np.array([0.0]), np.array([0.2]), np.array([-3.0]), 0.0, V_HI, DT)
    assert a[0] == pytest.approx(-2.0, abs=1e-9)
    assert v[0] == 0.0
    assert s[0] == pytest.approx(0.01, abs=1e-12)


def test_vectorised_and_accelerates_to_v_max_in_one_second() -> None:
    # 10 -> 13 m/s at 3 m/s^2 takes 1 s and 11.5 m ((13^2 - 10^2) / 6)
    s, v = np.zeros(3), np.full(3, 10.0)
    for _ in range(10):
        s, v, _ = bounded_motion(s, v, np.full(3, 3.0), V_LO, V_HI, DT)
    np.testing.assert_allclose(v, 13.0, atol=1e-9)
    np.testing.assert_allclose(s, 11.5, atol=1e-9)
