"""The released code's collision count, per flagged vehicle (``released_check_collisions``).

1x1 grid: the centre at 150 m; eastbound and northbound cross at (east 155, north 145). A
vehicle is controlled (on a section virtual lane) while less than 5 m past the centre.
"""

from __future__ import annotations

import pytest

from mivecc_env.config import MiVeCCConfig
from mivecc_env.metrics import batch_summary, episode_summary
from mivecc_env.sim import released_check
from mivecc_env.sim.core import Simulator
from tests.sim._scenario import EAST, NORTH, hand_sim, place


def _flagged(vehicles, config: MiVeCCConfig | None = None) -> int:
    sim = hand_sim(config)
    place(sim, vehicles)
    return int(released_check.flagged_count(sim.network, sim.config, sim.active, sim.lane,
                                            sim.s, None)[0])


@pytest.mark.parametrize("model", ["paper", "released"])
def test_pairs_that_flag_each_other_count_twice(model: str) -> None:
    cfg = MiVeCCConfig(rows=1, cols=1, model=model)
    # a rear-end 1 m apart inside the section: each is the other's nearest
    assert _flagged([(EAST, 100.0, 10.0), (EAST, 101.0, 10.0)], cfg) == 2
    # a crossing pair 1.1 m apart (1 m and 0.5 m before their point): projected 0.5 m apart
    assert _flagged([(EAST, 154.0, 10.0), (NORTH, 144.5, 10.0)], cfg) == 2


def test_a_pair_only_one_vehicle_looks_at_counts_once() -> None:
    # 0 and 1 are 1.5 m apart; a northbound vehicle far from both is projected 0.5 m behind 0
    # (at 155 + 89.5 - 145 = 99.5), so 0 looks at it (55 m away in the plane) and only 1
    # looks at 0
    assert _flagged([(EAST, 100.0, 10.0), (EAST, 101.5, 10.0), (NORTH, 89.5, 10.0)]) == 1


def test_pairs_off_the_section_virtual_lanes_count_zero() -> None:
    # the eastbound vehicle is 6 m past the centre (uncontrolled), the northbound one 0.7 m
    # before the point: 1.2 m apart, neither sees the other
    assert _flagged([(EAST, 156.0, 10.0), (NORTH, 144.3, 10.0)]) == 0
    # a rear-end on the exit link
    assert _flagged([(EAST, 200.0, 10.0), (EAST, 201.0, 10.0)]) == 0
    # no pair closer than 2 m: nothing flagged
    assert _flagged([(EAST, 100.0, 10.0), (EAST, 103.0, 10.0)]) == 0


def test_summary_reports_it_next_to_the_strict_count() -> None:
    sim = hand_sim(MiVeCCConfig(rows=1, cols=1, density_vplh=1.0))
    # after the move: one strict event the released check flags twice, and a crossing pair
    # 1.5 m apart it does not look at (the eastbound vehicle then 6.5 m past the centre)
    place(sim, [(EAST, 100.0, 10.0), (EAST, 101.0, 10.0), (EAST, 155.5, 10.0),
                (NORTH, 144.0, 10.0)])
    sim.step()
    assert sim.collision_events[0] == 2 and sim.collided[0] == 4
    assert sim.released_flagged[0] == 2
    summary = episode_summary(sim)
    assert summary["collisions"] == 2.0 and summary["collided_vehicles"] == 4.0
    assert summary["released_check_collisions"] == 2.0
    assert batch_summary(sim)["released_check_collisions"].tolist() == [2.0]
    sim.reset_at([0], [1])
    assert sim.released_flagged[0] == 0


def test_flagged_vehicles_are_among_the_strictly_collided() -> None:
    # the paper model collides at 2100 veh/lane/h (2x2, 8 seeds, 150 s); every flagged
    # vehicle is in a strict pair
    sim = Simulator(MiVeCCConfig(rows=2, cols=2, density_vplh=2100.0), batch_size=8,
                    seed=list(range(8)))
    for _ in range(1500):
        sim.step()
    assert sim.collided.sum() > 0 and sim.released_flagged.sum() > 0
    assert (sim.released_flagged <= sim.collided).all()
