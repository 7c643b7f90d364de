"""benchmarks/paper_table.py figures: gains paired by density and seed, in both metrics."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import paper_table


def _row(scheme: str, density: float, seed: int, v: float, released: float | str = "") -> dict:
    return {"scheme": scheme, "density": density, "seed": seed, "rows": 3, "cols": 3,
            "avg_travel_velocity_mps": v, "released_velocity_mps": released, "collisions": 0,
            "upper_bound_mps": 13.0, "coordinator_actions": "unused"}


ROWS = [
    _row("E", 900.0, 0, 12.0, 10.0), _row("E", 900.0, 1, 10.0, 10.0),
    _row("EE", 900.0, 0, 12.12, 10.5), _row("EE", 900.0, 1, 10.2, 11.0),
    _row("EEC", 900.0, 0, math.nan, 10.5), _row("EEC", 900.0, 1, 10.0, 12.1),
    _row("EE", 900.0, 2, 11.0),  # no E run with seed 2: not paired, left out
    _row("E", 900.0, 0, 5.0) | {"rows": 1, "cols": 1},  # another grid
]


def test_gains_are_paired_by_density_and_seed() -> None:
    gains = paper_table._paired_gains(ROWS, "3x3")
    assert gains["EE"][900.0] == pytest.approx([1.0, 2.0])
    assert math.isnan(gains["EEC"][900.0][0]) and gains["EEC"][900.0][1] == 0.0
    assert set(gains) == {"EE", "EEC"}


def test_gains_over_another_base_and_metric() -> None:
    gains = paper_table._paired_gains(ROWS, "3x3", "released_velocity_mps", "EE", ("EEC",))
    assert set(gains) == {"EEC"}
    assert gains["EEC"][900.0] == pytest.approx([0.0, 10.0])
    # runs without the metric (an old CSV's) are left out
    old = [r | {"released_velocity_mps": ""} for r in ROWS]
    assert paper_table._paired_gains(old, "3x3", "released_velocity_mps") == {}


def test_gains_figure_has_a_row_per_metric(tmp_path: Path) -> None:
    from matplotlib.image import imread

    both, one, none = tmp_path / "a.png", tmp_path / "b.png", tmp_path / "c.png"
    assert paper_table.plot_gains(ROWS, "3x3", both)
    assert paper_table.plot_gains([r | {"released_velocity_mps": ""} for r in ROWS], "3x3", one)
    assert imread(both).shape[0] > imread(one).shape[0]  # the released-style row below
    assert not paper_table.plot_gains([r for r in ROWS if r["scheme"] == "E"], "3x3", none)
    assert not none.exists()


def test_velocity_figure(tmp_path: Path) -> None:
    _, mean = paper_table.summarise(ROWS, "3x3")
    paper_table.plot(mean, "3x3", tmp_path / "v.png")
    assert (tmp_path / "v.png").stat().st_size > 5000
