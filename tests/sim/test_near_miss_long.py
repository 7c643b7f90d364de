"""Compiled near-miss and collision-pair kernels against their numpy references on long runs.

Busy simulations (several seeds, batch sizes, a geometry whose conflict points are too far
apart for the kernel's "nearest centre only" shortcut) feed every step to both paths; the
accumulators and the pair lists must be bit-identical at every step, and the runs must contain
the events that exercise each branch (PET samples, crossing pairs, collisions).
"""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim._numba import HAVE_NUMBA
from mivecc_env.sim.core import Simulator, collision_pairs, collision_pairs_reference
from mivecc_env.sim.near_miss import NearMissStats

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="compares the compiled kernels")

FIELDS = ("min_ttc_s", "ttc_hist", "min_pet_s", "pet_samples", "pet_under", "min_distance_m",
          "last_leave_s", "last_leave_side")
WIDE = {"rows": 2, "cols": 2, "segment_length_m": 50.0, "lane_offset_m": 10.0,
        "control_radius_m": 25.0, "projection_window_m": 30.0}


@pytest.mark.parametrize(("fields", "batch", "seed", "steps"), [
    ({"rows": 3, "cols": 3}, 7, 1, 900),
    ({"rows": 2, "cols": 3}, 3, 2, 400),
    (WIDE, 4, 3, 300),
])
def test_kernels_match_references_every_step(fields: dict, batch: int, seed: int,
                                             steps: int) -> None:
    cfg = MiVeCCConfig(density_vplh=2100, **fields)
    sim = Simulator(cfg, batch_size=batch, seed=seed)
    ref = NearMissStats(sim.network, batch, cfg.vehicle_length_m)
    ref.use_kernel = False
    record = sim.near_miss.record_step
    seen = {"pairs": 0, "calls": 0}

    def both(view, v, s_new, gone, t0, dt):
        record(view, v, s_new, gone, t0, dt)
        ref.record_step(view, v, s_new, gone, t0, dt)
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(sim.near_miss, name), getattr(ref, name),
                                          err_msg=name)
        got = collision_pairs(sim.network, view, s_new, gone, cfg.vehicle_length_m)
        want = collision_pairs_reference(sim.network, view, s_new, gone, cfg.vehicle_length_m)
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)
        seen["pairs"] += want.shape[0]
        seen["calls"] += 1

    sim.near_miss.record_step = both
    for _ in range(steps):
        sim.step()
    assert seen["calls"] == steps
    assert (ref.pet_samples > 0).all() and (ref.ttc_hist.sum(axis=1) > 0).all()
    assert np.isfinite(ref.min_distance_m).all()
    if batch == 7:
        assert seen["pairs"] > 0  # collisions happened (the default model collides at 2100)


def test_local_shortcut_is_off_for_the_wide_geometry() -> None:
    # the WIDE case above runs the kernel's "every conflict point of every lane" branch
    cfg = MiVeCCConfig(density_vplh=2100, **WIDE)
    sim = Simulator(cfg, batch_size=1, seed=0)
    assert not sim.near_miss._local
