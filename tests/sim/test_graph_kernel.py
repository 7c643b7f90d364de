"""The compiled reference-row fill of the state graphs equals the numpy path, bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim import graph_kernel
from mivecc_env.sim.core import Simulator
from mivecc_env.sim.state_graph import (
    build_graphs,
    cloud_graphs,
    cloud_population,
    population_limit_s,
    select_cloud_decisions,
    select_edge_decisions,
)
from mivecc_env.sim.virtual_lane import density_indicator, density_indicator_reference

pytestmark = pytest.mark.skipif(not graph_kernel.HAVE_NUMBA, reason="numba not available")


def both_paths(sim: Simulator, view, config: MiVeCCConfig) -> int:
    """Build edge and cloud graphs with the kernel and with numpy; assert equal; return the
    number of reference cells filled."""
    net, b = sim.network, sim.batch_size
    v = sim.v.ravel()[view.vehicle]
    a = sim.a.ravel()[view.vehicle]
    sv = np.linspace(-1.0, 1.0, view.vehicle.size)  # any SVs: only the selection uses them
    area = net.control_area(view.lane, view.s)
    dec, node, col = select_edge_decisions(net, view, sv, config.k_edge, config, area)
    lane = view.lane[dec]
    where = np.argmax(net.lane_intersections[lane] == (node % net.n_intersections)[:, None], 1)
    centre = net.lane_centres_s[lane, where]
    longest = float(net.lane_length.max())
    cdec, cenv, ccol = select_cloud_decisions(view, density_indicator(view, config.di_n),
                                              config.k_cloud, longest)
    filled = 0
    for args, kw in (
        ((dec, node, col, net.n_intersections, b, config.k_edge, 2 * config.control_radius_m),
         {"area_centre_s": centre, "area_radius_m": config.control_radius_m}),
        ((cdec, cenv, ccol, 1, b, config.k_cloud, longest), {}),
    ):
        fast = build_graphs(net, view, v, a, *args, config, use_kernel=True, **kw)
        ref = build_graphs(net, view, v, a, *args, config, use_kernel=False, **kw)
        for f in ("obs", "mask", "slot", "view_index"):
            x, y = getattr(fast, f), getattr(ref, f)
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), f
        filled += int(np.count_nonzero(ref.obs[..., 1:, :, :].any(axis=-1)))
    return filled


def test_kernel_matches_numpy_on_running_traffic() -> None:
    cfg = MiVeCCConfig(rows=2, cols=2, scheme="EEC")
    sim = Simulator(cfg, batch_size=3, seed=[1, 2, 3], densities=[900.0, 1800.0, 2700.0])
    filled = 0
    for t in range(240):
        sim.step()
        if t % 40 == 39:
            filled += both_paths(sim, sim.view, cfg)
    assert filled > 1000


def _congested() -> tuple[Simulator, MiVeCCConfig]:
    """A 2x2 EEC simulator after 200 steps at 2700 veh/lane/h (dense virtual lanes)."""
    cfg = MiVeCCConfig(rows=2, cols=2, scheme="EEC")
    sim = Simulator(cfg, batch_size=2, seed=[5, 6], densities=[2700.0, 2700.0])
    for _ in range(200):
        sim.step()
    return sim, cfg


def test_kernel_matches_numpy_with_tied_distances() -> None:
    # Positions rounded to a 4 m grid: many points share a position, so the tie order of the
    # stable sort (lower point index first) is what decides the row order.
    sim, cfg = _congested()
    view = sim.view
    pos = np.round(view.point_pos / 4.0) * 4.0  # monotone: the points stay sorted
    tied = dataclasses.replace(view, point_pos=pos, s=pos[view.own_point])
    assert np.unique(pos).size < pos.size / 2
    assert both_paths(sim, tied, cfg) > 100


def test_kernel_matches_numpy_with_near_ties_out_of_position_order() -> None:
    # The view sorts points by position quantised to 0.1 mm, so two points closer than that
    # keep their input order and may sit out of position order (two queued vehicles whose
    # positions differ by float noise; batch_fuzz found such runs). The kernel takes each side
    # in the view's order; the numpy path sorted by exact distance and picked other references
    # there (18 of 696 fuzz cases); it now takes the kernel's order (reference_order).
    sim, cfg = _congested()
    view = sim.view
    pos = view.point_pos.copy()
    # positions on a 4 m grid (many points share one), then every other point 20 um ahead:
    # within the resolution, and ahead of its successor wherever the two shared a position
    pos = np.round(pos / 4.0) * 4.0
    pos[::2] += 2e-5
    swapped = np.flatnonzero((np.diff(pos) < 0) & (np.diff(view.point_group) == 0))
    assert swapped.size > 3  # points out of position order within a lane's run
    jittered = dataclasses.replace(view, point_pos=pos, s=pos[view.own_point])
    assert both_paths(sim, jittered, cfg) > 100


def _assert_stable_top_k(group: np.ndarray, key: np.ndarray, n_groups: int, k: int) -> None:
    """``select_per_group`` equals the first k of each group of the stable (group, key) sort."""
    idx, grp, col = graph_kernel.select_per_group(group, key, n_groups, k)
    inside = np.flatnonzero(group >= 0)
    order = inside[np.lexsort((key[inside], group[inside]))]
    ref_group = group[order]
    rank = np.arange(order.size) - np.searchsorted(ref_group, ref_group)
    keep = rank < k
    np.testing.assert_array_equal(idx, order[keep])
    np.testing.assert_array_equal(grp, ref_group[keep])
    np.testing.assert_array_equal(col, rank[keep])


def test_select_per_group_is_the_stable_two_key_sort() -> None:
    rng = np.random.default_rng(0)
    n, n_groups, k = 5000, 40, 7
    group = rng.integers(-1, n_groups, n)
    key = np.round(rng.normal(size=n), 1)  # many ties
    _assert_stable_top_k(group, key, n_groups, k)


def _random_groups(
    rng: np.random.Generator, n_range: tuple[int, int], groups_range: tuple[int, int],
    k_range: tuple[int, int],
) -> tuple[int, int, int, np.ndarray]:
    """(n, n_groups, k, group): sizes drawn from the half-open ranges, in that order, then n
    group ids in [-1, n_groups) (-1: left out)."""
    n, n_groups, k = (int(rng.integers(*r)) for r in (n_range, groups_range, k_range))
    return n, n_groups, k, rng.integers(-1, n_groups, n)


def test_select_per_group_with_nan_and_signed_zero_keys() -> None:
    # NaN sorts last (as in numpy's sorts), -0.0 ties with 0.0; every k from 1 to past n.
    rng = np.random.default_rng(1)
    for _ in range(100):
        n, n_groups, k, group = _random_groups(rng, (0, 300), (1, 12), (1, 70))
        key = np.round(rng.normal(size=n), 1)
        key[rng.random(n) < 0.05] = np.nan
        key[rng.random(n) < 0.05] = -0.0
        _assert_stable_top_k(group, key, n_groups, k)


def test_fused_selections_match_select_per_group() -> None:
    # select_nodes / select_capped_desc compute the group and key inside the kernel: the same
    # selection as select_per_group on the numpy-built group and key (NaN, caps, -1 areas).
    rng = np.random.default_rng(2)
    for _ in range(100):
        n, n_per, k = (int(x) for x in (rng.integers(0, 300), rng.integers(1, 6),
                                         rng.integers(1, 40)))
        env = np.sort(rng.integers(0, 9, n))
        area = rng.integers(-1, n_per, n)
        value = np.round(rng.normal(size=n), 1)
        value[rng.random(n) < 0.05] = np.nan
        n_groups = (int(env.max()) + 1) * n_per if n else 0
        ref = graph_kernel.select_per_group(np.where(area >= 0, env * n_per + area, -1),
                                            value, n_groups, k)
        got = graph_kernel.select_nodes(env, area, n_per, value, k)
        for x, y in zip(got, ref, strict=True):
            np.testing.assert_array_equal(x, y)
        cap = 0.5
        for eligible in (None, rng.random(n) < 0.7):
            group = env if eligible is None else np.where(eligible, env, -1)
            ref = graph_kernel.select_per_group(group, -np.minimum(value, cap),
                                                int(env.max()) + 1 if n else 0, k)
            got = graph_kernel.select_capped_desc(env, eligible, value, cap, k)
            for x, y in zip(got, ref, strict=True):
                np.testing.assert_array_equal(x, y)


def test_density_indicator_and_area_centres_match_numpy() -> None:
    cfg = MiVeCCConfig(rows=3, cols=3, scheme="EEC")
    sim = Simulator(cfg, batch_size=4, seed=[1, 2, 3, 4], densities=[300.0, 900.0, 2100.0, 2700.0])
    checked = 0
    for t in range(300):
        sim.step()
        if t % 50 == 49:
            view, net = sim.view, sim.network
            for n in (1, 5, 40):
                fast = density_indicator(view, n)
                ref = density_indicator_reference(view, n)
                assert fast.tobytes() == ref.tobytes()
            area = net.control_area(view.lane, view.s)
            inside = area >= 0
            lane, node = view.lane[inside], area[inside]
            which = np.argmax(net.lane_intersections[lane] == node[:, None], axis=1)
            ref = net.lane_centres_s[lane, which]
            fast = graph_kernel.area_centres(lane, node, net.lane_intersections,
                                             net.lane_centres_s)
            assert fast.tobytes() == ref.tobytes()
            checked += int(inside.sum())
    assert checked > 1000


def test_fused_density_selection_matches_numpy_indicator() -> None:
    # select_cloud_di computes the density indicator inside the selection (eligible vehicles
    # only): the same picks as the numpy indicator + select_per_group, and cloud_graphs with
    # di=None builds the same graphs as with the indicator given.
    cfg = MiVeCCConfig(rows=3, cols=3, scheme="EEC")
    sim = Simulator(cfg, batch_size=4, seed=[5, 6, 7, 8], densities=[300.0, 900.0, 2100.0, 2700.0])
    rng = np.random.default_rng(0)
    picked = 0
    for t in range(300):
        sim.step()
        if t % 50 != 49:
            continue
        view, net = sim.view, sim.network
        n_env = int(view.env.max()) + 1
        v = sim.v.ravel()[view.vehicle]
        a = sim.a.ravel()[view.vehicle]
        for n, cap, k in ((1, 1e9, 7), (5, float(net.lane_length.max()), cfg.k_cloud),
                          (5, 3.0, 20), (40, 1e9, 2)):
            di = density_indicator_reference(view, n)
            for eligible in (None, rng.random(view.n_vehicles) < 0.6,
                             cloud_population(net, view, "conflict_ahead")):
                group = view.env if eligible is None else np.where(eligible, view.env, -1)
                ref = graph_kernel.select_per_group(group, -np.minimum(di, cap), n_env, k)
                got = graph_kernel.select_cloud_di(
                    view.env, eligible, view.own_point, view.point_run_start,
                    view.point_run_end, view.point_pos, n, cap, k)
                for x, y in zip(got, ref, strict=True):
                    assert x.dtype == y.dtype and x.tobytes() == y.tobytes()
                picked += ref[0].size
        pop = cloud_population(net, view, cfg.cloud_pick_population)
        fused = cloud_graphs(net, view, None, v, a, sim.batch_size, cfg, pop)
        given = cloud_graphs(net, view, density_indicator_reference(view, cfg.di_n), v, a,
                             sim.batch_size, cfg, pop)
        for f in ("obs", "mask", "slot", "view_index"):
            assert getattr(fused, f).tobytes() == getattr(given, f).tobytes(), f
    assert picked > 1000


def test_control_area_before_matches_the_two_calls() -> None:
    # one pass for the control area and the cloud's pick population (BatchedMiVeCCEnv)
    cfg = MiVeCCConfig(rows=1, cols=2, scheme="EEC")
    sim = Simulator(cfg, batch_size=3, seed=[1, 2, 3], densities=[300.0, 1500.0, 2700.0])
    checked = past = 0
    for t in range(400):
        sim.step()
        if t % 100 != 99:
            continue
        view, net = sim.view, sim.network
        for population in ("conflict_ahead", "before_last_centre"):
            limit = population_limit_s(net, population)
            area, before = graph_kernel.control_area_before(
                view.lane, view.s, net.lane_centres_s, net.lane_intersections,
                net.control_radius_m, net.segment_length_m, limit)
            ref_area = net.control_area(view.lane, view.s)
            ref_pop = cloud_population(net, view, population)
            assert area.tobytes() == ref_area.tobytes()
            assert before.dtype == ref_pop.dtype and before.tobytes() == ref_pop.tobytes()
            checked += int((area >= 0).sum())
            past += int((~before).sum())
    assert checked > 500 and past > 100


def _edge_selection(cfg: MiVeCCConfig, seeds: list[int], densities: list[float],
                    steps: int) -> tuple:
    """A seeded batch after ``steps`` steps and its edge decisions: (sim, view, v, a, area,
    decision, node, column, centre of each decision's area)."""
    sim = Simulator(cfg, batch_size=len(seeds), seed=seeds, densities=densities)
    for _ in range(steps):
        sim.step()
    net, view = sim.network, sim.view
    v = sim.v.ravel()[view.vehicle]
    a = sim.a.ravel()[view.vehicle]
    area = net.control_area(view.lane, view.s)
    dec, node, col = select_edge_decisions(net, view, sim.safety.sv, cfg.k_edge, cfg, area)
    centre = graph_kernel.area_centres(view.lane[dec], node % net.n_intersections,
                                       net.lane_intersections, net.lane_centres_s)
    return sim, view, v, a, area, dec, node, col, centre


def test_kernel_overwrites_every_output_element() -> None:
    # The kernel path allocates its outputs uninitialised: buffers full of NaN / garbage come
    # out equal to the numpy path (zero padding written by the kernel), and a repeated
    # (node, column) is refused.
    cfg = MiVeCCConfig(rows=2, cols=2, scheme="EEC")
    sim, view, v, a, _, dec, node, col, centre = _edge_selection(
        cfg, [7, 8, 9], [300.0, 1500.0, 2700.0], 150)
    net, b, k = sim.network, sim.batch_size, cfg.k_edge
    assert 0 < dec.size < b * net.n_intersections * k  # some padded columns
    ref = build_graphs(net, view, v, a, dec, node, col, net.n_intersections, b, k,
                       2 * cfg.control_radius_m, cfg, centre, cfg.control_radius_m,
                       use_kernel=False)
    shape = ref.mask.shape
    cells = np.full(ref.obs.shape, np.nan, np.float32)
    mask = np.full(shape, 7.0, np.float32)
    slot = np.full(shape, 123, np.int64)
    view_index = np.full(shape, 456, np.int64)
    args = (k, dec, node, col, view, v, a, cfg.velocity_floor_mps,
            2.0 / (cfg.v_max_mps - cfg.velocity_floor_mps), 1.0 / cfg.a_max_mps2,
            net.lane_cp_s, net.lane_length, centre, cfg.control_radius_m,
            1.0 / (2 * cfg.control_radius_m))
    graph_kernel.build(cells.reshape(-1, 3), mask.reshape(-1), slot.reshape(-1),
                       view_index.reshape(-1), *args)
    for got, want in ((cells, ref.obs), (mask, ref.mask), (slot, ref.slot),
                      (view_index, ref.view_index)):
        assert got.tobytes() == want.tobytes()
    def twice(x: np.ndarray) -> np.ndarray:
        return np.concatenate([x[:1], x])

    with pytest.raises(ValueError, match="two decisions"):
        graph_kernel.build(cells.reshape(-1, 3), mask.reshape(-1), slot.reshape(-1),
                           view_index.reshape(-1), k, twice(dec), twice(node), twice(col),
                           *args[4:12], twice(centre), *args[13:])


def test_area_centres_looked_up_from_the_node() -> None:
    # area_centre_s=_CENTRE_OF_NODE (edge_graphs' kernel path: the centres looked up in the
    # kernel) gives the graphs of the explicit centres, on both paths.
    from mivecc_env.sim.state_graph import _CENTRE_OF_NODE, edge_graphs

    cfg = MiVeCCConfig(rows=2, cols=3, scheme="EEC")
    sim, view, v, a, area, dec, node, col, centre = _edge_selection(
        cfg, [3, 4], [1200.0, 2700.0], 160)
    net, b, k = sim.network, sim.batch_size, cfg.k_edge
    args = (net, view, v, a, dec, node, col, net.n_intersections, b, k,
            2 * cfg.control_radius_m, cfg)
    want = build_graphs(*args, centre, cfg.control_radius_m, use_kernel=False)
    for got in (build_graphs(*args, _CENTRE_OF_NODE, cfg.control_radius_m, use_kernel=True),
                build_graphs(*args, _CENTRE_OF_NODE, cfg.control_radius_m, use_kernel=False),
                edge_graphs(net, view, sim.safety.sv, v, a, b, cfg, area)):
        for f in ("obs", "mask", "slot", "view_index"):
            assert getattr(got, f).tobytes() == getattr(want, f).tobytes(), f


def test_select_per_group_large_groups_with_infinities_and_one_value() -> None:
    # Groups larger than 2k go through the bucket prefilter: infinite keys (the prefilter
    # steps aside), one repeated value, huge and tiny ranges, NaN all give the stable sort.
    rng = np.random.default_rng(3)
    for trial in range(60):
        n, n_groups, k, group = _random_groups(rng, (50, 900), (1, 5), (1, 25))
        scale = [1e-300, 1.0, 1e300][trial % 3]
        key = np.round(rng.normal(size=n), 2) * scale
        if trial % 4 == 0:
            key[rng.random(n) < 0.02] = np.inf
            key[rng.random(n) < 0.02] = -np.inf
        if trial % 5 == 0:
            key[:] = 0.5
        key[rng.random(n) < 0.03] = np.nan
        _assert_stable_top_k(group, key, n_groups, k)
