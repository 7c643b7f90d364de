"""State graphs and decision selection on a hand-built 1x1 scene (numbers worked out by hand)."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.state_graph import cloud_graphs, edge_graphs
from mivecc_env.sim.virtual_lane import density_indicator
from tests.sim._scenario import EAST, SOUTH, hand_sim, place

CFG = MiVeCCConfig(rows=1, cols=1)


@pytest.fixture()
def scene():
    sim = hand_sim(CFG)
    # 0: eastbound at 130 m (15 m before its first conflict point at 145 m), 10 m/s, +1 m/s^2
    # 1: eastbound at 100 m, 12 m/s, own-lane follower of 0
    # 2: southbound at 135 m, 20 m before its conflict point with the eastbound lane (at 155 m
    #    on the southbound lane): projected onto the eastbound lane at 145 - 20 = 125 m
    place(sim, [(EAST, 130.0, 10.0), (EAST, 100.0, 12.0), (SOUTH, 135.0, 11.0)],
          accel=[1.0, 0.0, -1.5])
    view = sim.view
    v = sim.v.ravel()[view.vehicle]
    a = sim.a.ravel()[view.vehicle]
    return sim, view, v, a


def column_of(graphs, vehicle_view_index: int, node: int = 0) -> int:
    cols = np.flatnonzero(graphs.view_index[0, node] == vehicle_view_index)
    assert cols.size == 1
    return int(cols[0])


def test_edge_graph_of_a_hand_built_scene(scene) -> None:
    sim, view, v, a = scene
    g = edge_graphs(sim.network, view, sim.safety.sv, v, a, 1, CFG)
    assert g.obs.shape == (1, 1, 15, 15, 3) and g.obs.dtype == np.float32
    np.testing.assert_array_equal(g.mask[0, 0], [1, 1, 1] + [0] * 12)
    # columns are ordered by increasing safety value
    sv_of_cols = sim.safety.sv[g.view_index[0, 0, :3]]
    assert np.all(np.diff(sv_of_cols) >= 0)

    col = column_of(g, 0)
    graph = g.obs[0, 0, :, col]  # (rows, channels) of vehicle 0's column
    scale = 2 * CFG.control_radius_m  # 150 m
    # row 0: itself, position relative to the next conflict point ahead (145 m)
    np.testing.assert_allclose(graph[0], [(130 - 145) / scale, (10 - 6) / 3.5 - 1, 1 / 3],
                               rtol=1e-6)
    # row 1: the projected southbound vehicle 5 m behind; row 2: the own-lane follower 30 m back
    np.testing.assert_allclose(graph[1], [-5 / scale, (11 - 6) / 3.5 - 1, -0.5], rtol=1e-6)
    np.testing.assert_allclose(graph[2], [-30 / scale, (12 - 6) / 3.5 - 1, 0.0], rtol=1e-6)
    assert np.all(graph[3:] == 0)  # fewer references than K - 1: zero padding
    assert np.all(g.obs[0, 0, :, 3:] == 0)  # padded columns
    assert g.slot[0, 0, col] == view.vehicle[0]
    assert np.all(g.slot[0, 0, 3:] == -1)


def test_cloud_graph_uses_the_whole_lane_and_highest_density_indicator(scene) -> None:
    sim, view, v, a = scene
    di = density_indicator(view, CFG.di_n)
    g = cloud_graphs(sim.network, view, di, v, a, 1, CFG)
    assert g.obs.shape == (1, 1, 60, 60, 3)
    assert g.mask[0, 0].sum() == 3
    di_of_cols = di[g.view_index[0, 0, :3]]
    assert np.all(np.diff(di_of_cols) <= 0)  # highest DI first
    col = column_of(g, 0)
    scale = 300.0  # the longest lane of the 1x1 grid
    graph = g.obs[0, 0, :, col]
    np.testing.assert_allclose(graph[1, 0], -5 / scale, rtol=1e-6)
    np.testing.assert_allclose(graph[2, 0], -30 / scale, rtol=1e-6)


def test_references_outside_the_control_area_are_ignored() -> None:
    sim = hand_sim(CFG)
    # Eastbound vehicles at 80 m (inside the area [75, 225)) and 60 m (outside).
    place(sim, [(EAST, 80.0, 10.0), (EAST, 60.0, 10.0)])
    view = sim.view
    v = sim.v.ravel()[view.vehicle]
    g = edge_graphs(sim.network, view, sim.safety.sv, v, np.zeros_like(v), 1, CFG)
    np.testing.assert_array_equal(g.mask[0, 0, :2], [1, 0])
    assert np.all(g.obs[0, 0, 1:, 0] == 0)  # its follower at 60 m is outside the area


def test_at_most_k_decisions_per_node() -> None:
    sim = hand_sim(CFG.replace(k_edge=4))
    place(sim, [(EAST, 80.0 + 12.0 * i, 10.0) for i in range(8)])
    view = sim.view
    v = sim.v.ravel()[view.vehicle]
    g = edge_graphs(sim.network, view, sim.safety.sv, v, np.zeros_like(v), 1, sim.config)
    assert g.obs.shape == (1, 1, 4, 4, 3)
    assert g.mask.sum() == 4
    chosen = g.view_index[0, 0]
    others = np.setdiff1d(np.arange(8), chosen)
    assert sim.safety.sv[chosen].max() <= sim.safety.sv[others].min()  # the 4 lowest SV
