"""The compiled view build (``view_kernel``) equals the numpy reference element for element.

The kernel sorts each environment's points with a counting sort by bucket and an insertion
sort within the buckets; these states stress it: many points in one bucket (exact ties and
piles of vehicles within centimetres), empty environments between full ones, batches of 1, 7
and 64 environments, both projection modes (the one intersection in range, or every conflict
point where the windows overlap) and the reused buffers of ``ViewWorkspace``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mivecc_env.sim import view_kernel
from mivecc_env.sim.network import GridNetwork, build_grid
from mivecc_env.sim.view_kernel import ViewWorkspace
from mivecc_env.sim.virtual_lane import (
    POSITION_RESOLUTION_M,
    build_view,
    build_view_reference,
)

pytestmark = pytest.mark.skipif(not view_kernel.HAVE_NUMBA, reason="numba not installed")


def _assert_same_view(a, b) -> None:
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        assert x.dtype == y.dtype, f.name
        np.testing.assert_array_equal(x, y, err_msg=f.name)


def _grid(rows: int, cols: int) -> GridNetwork:
    return build_grid(rows, cols, segment_length_m=150.0, lane_offset_m=5.0,
                      control_radius_m=100.0)


def _state(net: GridNetwork, batch: int, cap: int, rng: np.random.Generator, kind: str):
    """(active, lane, s) of a random batch; ``kind`` picks how crowded and tied it is."""
    active = rng.random((batch, cap)) < 0.7
    lane = rng.integers(0, net.n_lanes, (batch, cap))
    length = net.lane_length[lane]
    s = rng.uniform(0.0, 1.0, (batch, cap)) * length
    if kind == "ties":  # exact ties of positions: between vehicles and with projections
        s = np.round(s / 5.0) * 5.0
    elif kind == "piles":  # many vehicles within centimetres near the conflict points
        centre = net.lane_cp_s[lane, rng.integers(0, 2, (batch, cap))]
        s = centre + rng.uniform(-0.05, 0.05, (batch, cap))
    elif kind == "gaps":  # every other environment empty, the first and the last full
        active[1::2] = False
        active[0] = active[-1] = True
    s = np.clip(s, 0.0, length - 1e-9)
    s[~np.isfinite(s)] = 0.0
    return active, lane, s


@pytest.mark.parametrize("kind", ["random", "ties", "piles", "gaps"])
@pytest.mark.parametrize("batch", [1, 7, 64])
def test_compiled_view_equals_reference(kind: str, batch: int) -> None:
    net = _grid(2, 2)
    rng = np.random.default_rng(batch * 31 + len(kind))
    for window, clear in ((75.0, 10.0), (140.0, 10.0)):  # one intersection / overlapping
        active, lane, s = _state(net, batch, 40, rng, kind)
        view = build_view(net, window, clear, active, lane, s)
        _assert_same_view(view, build_view_reference(net, window, clear, active, lane, s))
        assert view.n_vehicles == active.sum()
        if view_kernel.HAVE_NUMBA:  # the compiled path ran, not the reference fallback
            candidate = window + clear + 2.0 * net.lane_offset_m < net.segment_length_m
            assert view_kernel.build_view_fast(net, window, clear, active, lane, s,
                                               1.0 / POSITION_RESOLUTION_M,
                                               candidate) is not None


def test_whole_lane_in_one_bucket() -> None:
    """A hundred vehicles of one lane at the same position (one bucket, all tied): the
    reference's tie order (slot order, own points before projections) is kept."""
    net = _grid(1, 1)
    active = np.ones((3, 100), dtype=bool)
    lane = np.zeros((3, 100), dtype=np.int64)
    lane[:, 50:] = 1  # a crossing lane: its projections land among the own points
    s = np.full((3, 100), float(net.lane_cp_s[0, 0]))
    s[:, 50:] = float(net.lane_cp_s[1, 0])
    s[1] += np.repeat(np.arange(10), 10) * 1e-5  # ten tied groups, closer than 0.1 mm
    view = build_view(net, 75.0, 10.0, active, lane, s)
    _assert_same_view(view, build_view_reference(net, 75.0, 10.0, active, lane, s))
    assert (~view.point_own).sum() > 0


def test_empty_batch_and_workspace_growth() -> None:
    """No vehicle at all, then batches that grow and shrink through one workspace: every
    view equals the reference and the previous view stays intact."""
    net = _grid(3, 3)
    ws = ViewWorkspace()
    rng = np.random.default_rng(3)
    empty = np.zeros((4, 16), dtype=bool)
    zeros = np.zeros((4, 16))
    view = build_view(net, 75.0, 10.0, empty, zeros.astype(np.int64), zeros, ws)
    assert view.n_vehicles == 0 and view.point_pos.size == 0
    previous = None
    for batch, cap in ((2, 8), (9, 64), (3, 16), (9, 200)):
        active, lane, s = _state(net, batch, cap, rng, "random")
        view = build_view(net, 75.0, 10.0, active, lane, s, ws)
        _assert_same_view(view, build_view_reference(net, 75.0, 10.0, active, lane, s))
        if previous is not None:
            _assert_same_view(previous[0], build_view_reference(net, 75.0, 10.0, *previous[1]))
        previous = (view, (active, lane, s))


@pytest.mark.parametrize(("seg", "off", "clear", "n_on"),
                         [(150.0, 5.0, 10.0, 3), (100.0, 3.5, 7.25, 5), (0.3, 0.1, 0.05, 4)])
def test_centre_thresholds_give_the_reference_index(seg, off, clear, n_on) -> None:
    """The kernel's candidate centre index (thresholds found once per layout) equals the
    reference's ceil-division index at and next to every threshold and at random positions."""
    at = view_kernel._centre_thresholds(seg, off, clear, n_on)
    assert at.size == n_on - 1 and np.all(np.diff(at) > 0)
    rng = np.random.default_rng(0)
    xs = [*rng.uniform(-seg, (n_on + 1) * seg, 2000), 0.0, -0.0]
    for t in at:
        xs += [t, np.nextafter(t, -np.inf), np.nextafter(t, np.inf)]
    for x in xs:
        assert int(np.sum(x >= at)) == view_kernel._centre_index(x, seg, off, clear, n_on), x


def test_centre_index_is_the_reference_formula() -> None:
    from mivecc_env.sim.virtual_lane import _candidate_conflict_columns

    net = _grid(3, 3)
    xs = np.random.default_rng(1).uniform(0.0, 600.0, 5000)
    cols = _candidate_conflict_columns(net, 75.0, 10.0, xs)
    n_on = net.lane_centres_s.shape[1]
    got = [view_kernel._centre_index(x, net.segment_length_m, net.lane_offset_m, 10.0, n_on)
           for x in xs]
    np.testing.assert_array_equal(cols[:, 0] // 2, got)


def test_block_rows_are_the_dataclass_fields_in_order() -> None:
    """The compiled view is built positionally from ``_FIELDS``: same names, same order."""
    from mivecc_env.sim.virtual_lane import VirtualLaneView

    assert [f.name for f in dataclasses.fields(VirtualLaneView)] == [
        name for name, _block, _row in view_kernel._FIELDS]
