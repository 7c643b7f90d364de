"""Grid geometry: lanes, conflict points, positions along lanes and control areas."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.network import GridNetwork

# 3x3 lane ids: eastbound rows 0..2, westbound rows 3..5, northbound cols 6..8,
# southbound cols 9..11.
E0, E2, W0, N0, N1, S0, S1 = 0, 2, 3, 6, 7, 9, 10


@pytest.fixture(scope="module")
def net3() -> GridNetwork:
    return GridNetwork.from_config(MiVeCCConfig())


@pytest.fixture(scope="module")
def net1() -> GridNetwork:
    return GridNetwork.from_config(MiVeCCConfig(rows=1, cols=1))


def test_counts_3x3(net3: GridNetwork) -> None:
    assert net3.n_lanes == 12  # 2R + 2C
    np.testing.assert_array_equal(net3.lane_length, np.full(12, 600.0))  # (3 + 1) * 150
    assert net3.n_cp == 36  # 6 horizontal x 6 vertical lanes
    np.testing.assert_array_equal(np.bincount(net3.cp_intersection), np.full(9, 4))
    assert net3.extent_m == (600.0, 600.0)
    np.testing.assert_array_equal(net3.intersection_xy[0], [150.0, 150.0])
    np.testing.assert_array_equal(net3.intersection_xy[5], [450.0, 300.0])  # r=1, c=2


def test_lane_origins_and_headings(net3: GridNetwork) -> None:
    # right-hand traffic, 5 m from the road centreline
    np.testing.assert_array_equal(net3.lane_origin[E0], [0.0, 145.0])
    np.testing.assert_array_equal(net3.lane_origin[W0], [600.0, 155.0])
    np.testing.assert_array_equal(net3.lane_origin[N0], [155.0, 0.0])
    np.testing.assert_array_equal(net3.lane_origin[S0], [145.0, 600.0])
    np.testing.assert_array_equal(net3.lane_heading, [0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3, 3])


def _cp(net: GridNetwork, h: int, v: int) -> int:
    (idx,) = np.flatnonzero((net.cp_lane[:, 0] == h) & (net.cp_lane[:, 1] == v))
    return int(idx)


@pytest.mark.parametrize(
    ("h", "v", "xy", "s_h", "s_v", "intersection"),
    [
        (E0, S0, (145.0, 145.0), 145.0, 455.0, 0),  # 600 - 145 on the southbound lane
        (E0, N0, (155.0, 145.0), 155.0, 145.0, 0),
        (W0, S0, (145.0, 155.0), 455.0, 445.0, 0),
        (W0, N0, (155.0, 155.0), 445.0, 155.0, 0),
        (E0, S1, (295.0, 145.0), 295.0, 455.0, 1),
        (E2, N0, (155.0, 445.0), 155.0, 445.0, 6),
    ],
)
def test_conflict_points(
    net3: GridNetwork, h: int, v: int, xy: tuple[float, float], s_h: float, s_v: float,
    intersection: int,
) -> None:
    k = _cp(net3, h, v)
    np.testing.assert_array_equal(net3.cp_xy[k], xy)
    np.testing.assert_array_equal(net3.cp_s[k], [s_h, s_v])
    assert net3.cp_intersection[k] == intersection


def test_every_conflict_point_lies_on_both_lanes(net3: GridNetwork) -> None:
    for side in (0, 1):
        xy = net3.xy(net3.cp_lane[:, side], net3.cp_s[:, side])
        np.testing.assert_allclose(xy, net3.cp_xy, atol=1e-12)
    # the 4 conflict points of an intersection are its centre +- 5 m on each axis
    centre = net3.intersection_xy[net3.cp_intersection]
    np.testing.assert_array_equal(np.abs(net3.cp_xy - centre), np.full((36, 2), 5.0))


def test_lane_conflict_tables(net3: GridNetwork) -> None:
    np.testing.assert_array_equal(net3.lane_cp_s[E0], [145, 155, 295, 305, 445, 455])
    np.testing.assert_array_equal(net3.lane_cp_other_lane[E0], [S0, N0, S1, N1, 11, 8])
    np.testing.assert_array_equal(net3.lane_cp_other_s[E0], [455, 145, 455, 145, 455, 145])
    np.testing.assert_array_equal(net3.lane_centres_s[E0], [150, 300, 450])
    np.testing.assert_array_equal(net3.lane_intersections[E0], [0, 1, 2])
    np.testing.assert_array_equal(net3.lane_intersections[W0], [2, 1, 0])
    np.testing.assert_array_equal(net3.lane_intersections[S0], [6, 3, 0])
    np.testing.assert_array_equal(net3.lane_intersections[N1], [1, 4, 7])


def test_xy_of_lane_positions(net3: GridNetwork) -> None:
    lanes = np.array([E0, W0, N0, S0])
    s = np.array([100.0, 100.0, 100.0, 100.0])
    np.testing.assert_array_equal(
        net3.xy(lanes, s), [[100, 145], [500, 155], [155, 100], [145, 500]]
    )
    # broadcasting over a (2, 2) batch
    out = net3.xy(np.array([[E0, N0], [W0, S0]]), np.array([[0.0, 600.0], [600.0, 0.0]]))
    np.testing.assert_array_equal(out, [[[0, 145], [155, 600]], [[0, 155], [145, 600]]])


@pytest.mark.parametrize(
    ("lane", "s", "area"),
    [
        (E0, 74.999, -1),  # before the first area
        (E0, 75.0, 0),  # [150 - 75, 150 + 75): closed below
        (E0, 224.999, 0),
        (E0, 225.0, 1),  # open above: the next area starts here
        (E0, 524.999, 2),
        (E0, 525.0, -1),  # exit link
        (W0, 75.0, 2),  # westbound meets column 2 first
        (S0, 80.0, 6),  # southbound meets row 2 first
        (N1, 300.0, 4),
    ],
)
def test_control_area_boundaries(net3: GridNetwork, lane: int, s: float, area: int) -> None:
    assert int(net3.control_area(np.array([lane]), np.array([s]))[0]) == area


def test_next_stop(net3: GridNetwork) -> None:
    out = net3.next_stop_s(np.array([E0, E0, E0, E0]), np.array([0.0, 145.0, 146.0, 500.0]))
    np.testing.assert_array_equal(out, [145.0, 145.0, 155.0, 600.0])  # lane end after 455


def test_single_intersection(net1: GridNetwork) -> None:
    assert net1.n_lanes == 4
    np.testing.assert_array_equal(net1.lane_length, [300.0] * 4)
    assert net1.n_cp == 4
    np.testing.assert_array_equal(
        np.sort(net1.cp_xy, axis=0), [[145, 145], [145, 145], [155, 155], [155, 155]]
    )
    np.testing.assert_array_equal(net1.lane_cp_s[0], [145.0, 155.0])  # eastbound
    np.testing.assert_array_equal(net1.lane_cp_other_lane[0], [3, 2])  # south, then north
    np.testing.assert_array_equal(net1.lane_cp_other_s[0], [155.0, 145.0])
    area = net1.control_area(np.zeros(4, dtype=np.int64), np.array([74.9, 75.0, 224.9, 225.0]))
    np.testing.assert_array_equal(area, [-1, 0, 0, -1])


def test_rectangular_grid() -> None:
    net = GridNetwork.from_config(MiVeCCConfig(rows=1, cols=2))
    assert net.n_lanes == 6
    np.testing.assert_array_equal(net.lane_length, [450, 450, 300, 300, 300, 300])
    assert net.n_cp == 8
    # a northbound lane passes one intersection; past its area there is none
    north1 = 3  # east 0, west 1, north cols 2..3
    area = net.control_area(np.array([north1, north1]), np.array([100.0, 260.0]))
    np.testing.assert_array_equal(area, [1, -1])
