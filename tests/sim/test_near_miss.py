"""Near-miss measures on constructed encounters with hand-computed values.

Vehicles move at constant speeds through hand-built virtual-lane views, so the measures are
checked independently of the driving rules.
"""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim._numba import HAVE_NUMBA
from mivecc_env.sim.core import Simulator
from mivecc_env.sim.near_miss import (
    TTC_BIN_S,
    NearMissStats,
    ttc_percentile,
    ttc_percentile_of,
)
from mivecc_env.sim.network import GridNetwork
from mivecc_env.sim.virtual_lane import build_view
from tests.sim._scenario import EAST, NORTH, WEST

DT = 0.1
KERNEL = [True]


@pytest.fixture(autouse=True, params=["kernel", "numpy"])
def _path(request: pytest.FixtureRequest) -> None:
    """Run every hand-computed case through the compiled kernel and the numpy reference."""
    if request.param == "kernel" and not HAVE_NUMBA:
        pytest.skip("numba is not installed")
    KERNEL[0] = request.param == "kernel"


def drive(config: MiVeCCConfig, vehicles: list[tuple[int, float, float]], steps: int,
          batch: int = 1) -> NearMissStats:
    """Move ``(lane, s, v)`` vehicles at constant speed for ``steps`` steps in every env."""
    net = GridNetwork.from_config(config)
    stats = NearMissStats(net, batch, config.vehicle_length_m)
    stats.use_kernel = KERNEL[0]
    n = len(vehicles)
    active = np.ones((batch, n), dtype=bool)
    lane = np.tile(np.array([x[0] for x in vehicles], dtype=np.int64), (batch, 1))
    s = np.tile(np.array([x[1] for x in vehicles]), (batch, 1))
    v = np.tile(np.array([x[2] for x in vehicles]), (batch, 1))
    for k in range(steps):
        view = build_view(net, config.projection_window_m, config.projection_clear_m,
                          active, lane, s)
        v_view = v.ravel()[view.vehicle]
        s_new = view.s + v_view * DT
        stats.record_step(view, v_view, s_new, np.zeros(view.n_vehicles, bool), k * DT, DT)
        s.ravel()[view.vehicle] = s_new
    return stats


ONE = MiVeCCConfig(rows=1, cols=1)


def test_ttc_of_a_closing_follower() -> None:
    # follower 21 m behind its leader, closing at 13 - 8 = 5 m/s: TTC 4.2 s at the first step;
    # one step later 20.5 m -> 4.1 s (the minimum); the leader has nothing ahead
    stats = drive(ONE, [(EAST, 20.0, 13.0), (EAST, 41.0, 8.0)], steps=2)
    assert stats.min_ttc_s[0] == pytest.approx(4.1)
    assert stats.ttc_hist[0].sum() == 2
    # the 1st percentile is the lower sample's bin, rounded up to the bin edge
    assert 4.1 - 1e-9 <= ttc_percentile(stats.ttc_hist)[0] <= 4.1 + TTC_BIN_S + 1e-9
    assert stats.summary(0)["min_ttc_s"] == pytest.approx(4.1)


def test_no_ttc_sample_without_closing() -> None:
    stats = drive(ONE, [(EAST, 20.0, 8.0), (EAST, 41.0, 13.0)], steps=5)
    assert stats.ttc_hist.sum() == 0
    assert stats.summary(0)["min_ttc_s"] == np.inf
    assert stats.summary(0)["ttc_p1_s"] == np.inf


def test_ttc_is_never_negative_with_a_coincident_projection() -> None:
    # A crossing vehicle waiting at 0 m/s (as at a red light) exactly as far from its conflict
    # point as the ego (39 m) minus 0.02 mm: the view sorts points within 0.1 mm in input order
    # (own point first), so the projection, 0.02 mm *behind* the ego, is its nearest point
    # ahead at d_front = -2e-5 m. The two are level on the virtual lane: TTC 0, not -2e-6 s.
    view = build_view(GridNetwork.from_config(ONE), ONE.projection_window_m,
                      ONE.projection_clear_m, np.ones((1, 2), dtype=bool),
                      np.array([[EAST, NORTH]]), np.array([[116.00005, 106.00003]]))
    assert view.front_point[0] >= 0 and -1e-4 < view.d_front[0] < 0.0  # the constructed case
    stats = drive(ONE, [(EAST, 116.00005, 10.0), (NORTH, 106.00003, 0.0)], steps=1)
    assert stats.min_ttc_s[0] == 0.0 and not np.signbit(stats.min_ttc_s[0])
    assert stats.ttc_hist[0, 0] == 1 and stats.ttc_hist[0].sum() == 1
    assert f"{stats.summary(0)['min_ttc_s']:.3f}" == "0.000"


def test_ttc_percentile_of_a_histogram() -> None:
    hist = np.zeros((2, 2001), dtype=np.int64)
    hist[0, 5] = hist[0, 7] = 1
    hist[0, 100] = 198  # 200 samples: the 1st percentile is the 2nd smallest, bin 7
    hist[1, 2000] = 3  # only overflow
    p = ttc_percentile(hist)
    assert p[0] == pytest.approx(8 * TTC_BIN_S)
    assert p[1] == np.inf
    assert ttc_percentile(np.zeros((1, 2001), dtype=np.int64))[0] == np.inf  # no sample


def test_one_histogram_percentile_matches_the_batch_one() -> None:
    """The scalar form (the per-step summary of one environment) is bit-identical, also when
    the percentile bin lies beyond the prefix it accumulates first, or in the overflow bin."""
    rng = np.random.default_rng(0)
    hists = [np.zeros(2001, dtype=np.int64)]
    for _ in range(300):
        h = np.zeros(2001, dtype=np.int64)
        lo = int(rng.integers(0, 2001))
        n = int(rng.integers(1, 400))
        np.add.at(h, rng.integers(lo, 2001, size=n), 1)
        hists.append(h)
    late = np.zeros(2001, dtype=np.int64)
    late[1500], late[3] = 500, 1  # 501 samples: need 6, reached only at bin 1500
    over = np.zeros(2001, dtype=np.int64)
    over[[0, 2000]] = 1, 1000
    hists += [late, over]
    batch = ttc_percentile(np.stack(hists))
    for h, p in zip(hists, batch.tolist(), strict=True):
        got = ttc_percentile_of(h)
        assert isinstance(got, float) and got == p
    assert ttc_percentile_of(late) == 1501 * TTC_BIN_S and ttc_percentile_of(over) == np.inf


def test_post_encroachment_time() -> None:
    # 1x1: the eastbound and northbound lanes cross at s = 155 m (east) and 145 m (north).
    # A (east, 100 m, 10 m/s) leaves the point (centre 1 m past it, 156 m) at 5.6 s;
    # B (north, 80.5 m) reaches it (centre 1 m before it, 144 m) at 6.35 s: PET 0.75 s.
    # B leaves at 6.55 s. D follows B (north, 60.5 m): it reaches at 8.35 s, after its own
    # lane's B left last: no sample. C follows A (east, 70 m): reaches at 8.4 s; the last to
    # leave was B (D leaves at 8.55 s): PET 8.4 - 6.55 = 1.85 s.
    stats = drive(ONE, [(EAST, 100.0, 10.0), (NORTH, 80.5, 10.0), (EAST, 70.0, 10.0),
                        (NORTH, 60.5, 10.0)], steps=100)
    assert stats.pet_samples.tolist() == [2]
    assert stats.pet_under.tolist() == [1]
    assert stats.min_pet_s[0] == pytest.approx(0.75, abs=1e-9)
    summary = stats.summary(0)
    assert summary["min_pet_s"] == pytest.approx(0.75, abs=1e-9)
    assert summary["pet_under_1s"] == 1.0 and summary["pet_samples"] == 2.0


def test_pet_within_one_step() -> None:
    # A (east) leaves 156 m at 0.05 s and B (north) reaches 144 m at 0.08 s, both in the
    # first step (20 m/s: 2 m per step): PET 0.03 s
    stats = drive(ONE, [(EAST, 155.0, 20.0), (NORTH, 142.4, 20.0)], steps=3)
    assert stats.pet_samples.tolist() == [1]
    assert stats.min_pet_s[0] == pytest.approx(0.03, abs=1e-9)


def test_min_distance_of_a_crossing_pair() -> None:
    # A 5 m before the point on the east lane, B 4 m before it on the north lane: hypot(5, 4);
    # an own-lane pair 10 m apart and a vehicle on the west lane are farther
    stats = drive(ONE, [(EAST, 150.0, 0.0), (NORTH, 141.0, 0.0), (EAST, 20.0, 0.0),
                        (EAST, 30.0, 0.0), (WEST, 30.0, 0.0)], steps=1)
    assert stats.min_distance_m[0] == pytest.approx(np.hypot(5.0, 4.0))


def test_min_distance_of_an_own_lane_pair() -> None:
    stats = drive(ONE, [(EAST, 20.0, 0.0), (EAST, 23.5, 0.0), (NORTH, 141.0, 0.0)], steps=1)
    assert stats.min_distance_m[0] == pytest.approx(3.5)


def test_min_distance_of_opposite_lanes() -> None:
    # east at x = 100, y = 145; west (from x = 300) at s = 195: x = 105, y = 155
    stats = drive(ONE, [(EAST, 100.0, 0.0), (WEST, 195.0, 0.0)], steps=1)
    assert stats.min_distance_m[0] == pytest.approx(np.hypot(5.0, 10.0))


def test_min_distance_of_parallel_roads() -> None:
    # 2x1: eastbound rows 0 and 1 (lanes 0, 1) run at y = 145 and 295: 150 m apart
    stats = drive(MiVeCCConfig(rows=2, cols=1), [(0, 100.0, 0.0), (1, 100.0, 0.0)], steps=1)
    assert stats.min_distance_m[0] == pytest.approx(150.0)


def test_min_distance_matches_brute_force() -> None:
    # many random vehicles in a 3x3 grid: the fast path equals the all-pairs minimum
    cfg = MiVeCCConfig()
    net = GridNetwork.from_config(cfg)
    rng = np.random.default_rng(0)
    for _ in range(20):
        n = 40
        lane = rng.integers(0, net.n_lanes, n)
        s = rng.uniform(0.0, 590.0, n)
        stats = drive(cfg, [(int(a), float(b), 0.0) for a, b in zip(lane, s, strict=True)], 1)
        xy = net.xy(lane, s)
        d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        assert stats.min_distance_m[0] == pytest.approx(d.min())


def test_reset_at_clears_one_environment() -> None:
    stats = drive(ONE, [(EAST, 100.0, 10.0), (NORTH, 80.5, 10.0), (EAST, 20.0, 13.0),
                        (EAST, 41.0, 8.0)], steps=80, batch=2)
    assert stats.pet_samples.tolist() == [1, 1]
    stats.reset_at(np.array([1]))
    assert stats.pet_samples.tolist() == [1, 0]
    batch = stats.batch_summary()
    for env in range(2):
        assert {k: float(v[env]) for k, v in batch.items()} == stats.summary(env)
    assert np.isfinite(stats.min_ttc_s[0]) and stats.min_ttc_s[1] == np.inf
    assert stats.ttc_hist[1].sum() == 0 and stats.ttc_hist[0].sum() > 0
    assert np.isinf(stats.last_leave_s.reshape(2, -1)[1]).all()
    assert stats.summary(1)["min_distance_m"] == np.inf


@pytest.mark.parametrize(("rows", "batch", "steps"), [(1, 1, 400), (3, 2, 300)])
def test_kernel_matches_the_numpy_reference(rows: int, batch: int, steps: int) -> None:
    # both paths fed the same steps of a busy simulation give bit-identical accumulators
    if not KERNEL[0]:
        pytest.skip("compares both paths once")
    cfg = MiVeCCConfig(rows=rows, cols=rows, density_vplh=2100)
    sim = Simulator(cfg, batch_size=batch, seed=0)
    ref = NearMissStats(sim.network, batch, cfg.vehicle_length_m)
    ref.use_kernel = False
    record = sim.near_miss.record_step

    def both(*args: object) -> None:
        record(*args)
        ref.record_step(*args)

    sim.near_miss.record_step = both
    for _ in range(steps):
        sim.step()
    ker = sim.near_miss
    assert ker.pet_samples.sum() > 0 and ker.ttc_hist.sum() > 0
    for name in ("min_ttc_s", "ttc_hist", "min_pet_s", "pet_samples", "pet_under",
                 "min_distance_m", "last_leave_s", "last_leave_side"):
        np.testing.assert_array_equal(getattr(ker, name), getattr(ref, name), err_msg=name)
