"""One scheme switch: every scheme on the same seeded demand, with the same result keys."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_agents.evaluation import COMPARATORS, SCHEMES, evaluate_scheme
from mivecc_env.config import ConfigError, MiVeCCConfig
from mivecc_env.sim.core import Simulator

NAMES = ("E", "EE", "EEC", "fixed-time", "actuated", "max-pressure", "reservation",
         "optimisation")


def test_every_scheme_name_is_accepted() -> None:
    assert set(NAMES) <= set(SCHEMES)


def test_same_arrivals_per_lane_and_seed_under_every_control() -> None:
    controls = [{"control": "unsignalized"}, *COMPARATORS.values()]
    times = []
    for over in controls:
        sim = Simulator(MiVeCCConfig(rows=2, cols=2, density_vplh=1800, **over), seed=7)
        for _ in range(300):
            sim.step()
        arr = sim.arrivals
        # arrivals so far per lane, arrivals drawn ahead and the last drawn arrival time
        times.append((arr.arrived.copy(), arr.generated.copy(), arr._last.copy()))
    assert times[0][0].sum() > 40
    for other in times[1:]:
        for a, b in zip(times[0], other, strict=True):
            np.testing.assert_array_equal(a, b)


def test_every_scheme_prints_the_same_keys() -> None:
    keys = None
    arrived = set()
    for scheme in NAMES:
        r = evaluate_scheme(scheme, 1, 1, 900, steps=60, seed=3, progress=False, warn=False)
        assert r["scheme"] == scheme
        keys = keys or set(r)
        assert set(r) == keys, scheme
        arrived.add(r["arrived"])
    assert len(arrived) == 1  # the same demand


def test_scheme_sets_its_control() -> None:
    r = evaluate_scheme("max-pressure", 1, 1, 600, steps=20, seed=0, progress=False)
    assert r["control"] == "signalized" and r["signal_controller"] == "max-pressure"
    r = evaluate_scheme("reservation", 1, 1, 600, steps=20, seed=0, progress=False)
    assert r["control"] == "reservation"
    with pytest.raises(ConfigError, match="control: scheme 'reservation' needs"):
        evaluate_scheme("reservation", 1, 1, 600, steps=20, seed=0, control="signalized")
    with pytest.raises(ConfigError, match="control: scheme 'E' needs control='unsignalized'"):
        evaluate_scheme("E", 1, 1, 600, steps=20, seed=0, control="reservation")
