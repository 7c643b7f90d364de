"""benchmarks/paper_table.py figures: the gain-over-E panel, paired by seed."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import paper_table


def _row(scheme: str, density: float, seed: int, v: float) -> dict:
    return {"scheme": scheme, "density": density, "seed": seed, "rows": 3, "cols": 3,
            "avg_travel_velocity_mps": v, "collisions": 0, "upper_bound_mps": 13.0,
            "coordinator_actions": "unused"}


ROWS = [
    _row("E", 900.0, 0, 12.0), _row("E", 900.0, 1, 10.0),
    _row("EE", 900.0, 0, 12.12), _row("EE", 900.0, 1, 10.2),
    _row("EEC", 900.0, 0, math.nan), _row("EEC", 900.0, 1, 10.0),
    _row("EE", 900.0, 2, 11.0),  # no E run with seed 2: not paired, left out
    _row("E", 900.0, 0, 5.0) | {"rows": 1, "cols": 1},  # another grid
]


def test_gains_are_paired_by_density_and_seed() -> None:
    gains = paper_table._gains_over_e(ROWS, "3x3")
    assert gains["EE"][900.0] == pytest.approx([1.0, 2.0])
    assert math.isnan(gains["EEC"][900.0][0]) and gains["EEC"][900.0][1] == 0.0
    assert set(gains) == {"EE", "EEC"}


def test_plot_has_the_gain_panel(tmp_path: Path) -> None:
    _, mean = paper_table.summarise(ROWS, "3x3")
    with_gain, without = tmp_path / "a.png", tmp_path / "b.png"
    paper_table.plot(mean, "3x3", with_gain, ROWS)
    paper_table.plot(mean, "3x3", without)
    from matplotlib.image import imread

    assert imread(with_gain).shape[0] > imread(without).shape[0]  # a second panel below
