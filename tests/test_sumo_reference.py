"""Tests for the Eclipse SUMO reference benchmark (``benchmarks/sumo_reference.py``)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

from tests.scripts import load_benchmark

sumo_reference = load_benchmark("sumo_reference", "sumo_reference")
needs_sumo = pytest.mark.skipif(
    not sumo_reference.sumo_available(), reason="eclipse-sumo / libsumo not installed"
)

KEYS = {
    "steps_per_s", "vehicle_steps_per_s", "mean_vehicles", "steps", "elapsed_s",
    "rows", "cols", "density", "sumo_version", "junction_type",
}  # fmt: skip


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"rows": 0}, "rows"),
        ({"cols": -1}, "cols"),
        ({"cols": 1.5}, "cols"),
        ({"density": 0.0}, "density"),
        ({"density": float("nan")}, "density"),
        ({"steps": 0}, "steps"),
        ({"warmup_steps": -1}, "warmup_steps"),
        ({"junction_type": "zipper_roundabout"}, "junction_type"),
    ],
)
def test_bad_args_raise_value_error(kwargs: dict, field: str) -> None:
    args = {"rows": 1, "cols": 1, "density": 900.0, "steps": 10, **kwargs}
    with pytest.raises(ValueError, match=field):
        sumo_reference.run_sumo(**args)


@pytest.mark.sumo
@needs_sumo
def test_run_1x1_and_determinism() -> None:
    runs = [
        sumo_reference.run_sumo(1, 1, 900.0, steps=200, seed=3, warmup_steps=300) for _ in range(2)
    ]  # two runs in one process also checks that libsumo restarts cleanly
    res = runs[0]
    assert res.keys() >= KEYS
    assert res["mean_vehicles"] > 0
    assert res["steps"] == 200 and res["rows"] == 1 and res["cols"] == 1
    assert res["junction_type"] == "unregulated"
    assert res["inserted"] > 0
    assert res["sumo_version"].startswith("SUMO")
    for key in ("steps_per_s", "vehicle_steps_per_s", "elapsed_s"):
        assert math.isfinite(res[key]) and res[key] > 0, key
    assert res["teleports"] == 0
    assert runs[1]["mean_vehicles"] == res["mean_vehicles"]
    assert runs[1]["inserted"] == res["inserted"]


@pytest.mark.sumo
@needs_sumo
def test_seed_changes_arrivals() -> None:
    a = sumo_reference.run_sumo(1, 1, 900.0, steps=50, seed=1, warmup_steps=300)
    b = sumo_reference.run_sumo(1, 1, 900.0, steps=50, seed=2, warmup_steps=300)
    assert (a["inserted"], a["mean_vehicles"]) != (b["inserted"], b["mean_vehicles"])


def test_missing_sumo_gives_install_hint(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "libsumo", None)  # makes ``import libsumo`` fail
    assert sumo_reference.sumo_available() is False
    with pytest.raises(ImportError, match=r"mivecc\[sumo\]"):
        sumo_reference.run_sumo(1, 1, 900.0, steps=10)


@pytest.mark.sumo
@needs_sumo
@pytest.mark.parametrize("junction_type", sumo_reference.JUNCTION_TYPES)
def test_every_junction_type_has_all_through_routes(tmp_path: Path, junction_type: str) -> None:
    # With unregulated junctions the fringe nodes are not dead_end junctions: the routes must
    # still be found (they were not, and SUMO ran an empty network).
    net = sumo_reference._build_net(str(tmp_path), 2, 3, junction_type)
    routes = sumo_reference._through_routes(net)
    assert len(routes) == 2 * 2 + 2 * 3
    assert len({src for src, _ in routes}) == len(routes)


@pytest.mark.sumo
@needs_sumo
def test_unregulated_grid_carries_vehicles() -> None:
    res = sumo_reference.run_sumo(2, 2, 1500.0, steps=100, seed=0, warmup_steps=400,
                                  junction_type="unregulated")
    assert res["inserted"] > 20 and res["mean_vehicles"] > 10
    assert res["teleports"] == 0


@pytest.mark.sumo
@needs_sumo
def test_empty_run_raises(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sumo_reference, "_through_routes", lambda net: [])
    with pytest.raises(RuntimeError, match="no vehicles"):
        sumo_reference.run_sumo(1, 1, 900.0, steps=20, warmup_steps=20)
