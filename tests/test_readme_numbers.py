"""The README's results are the committed tables' numbers.

The README quotes the 3x3 rows of both models' paper tables
(``docs/results/paper_table*/paper_table.csv``, written by ``benchmarks/paper_table.py``). When
a table is regenerated, these tests fail until the README is brought up to date: they recompute
every quoted figure from the committed runs (means over seeds, gains of the means, strict
events summed over seeds) and look for it in the README's text.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from paper_table import (  # noqa: E402
    DENSITIES,
    PAPER_3X3,
    improvement,
    read_runs_csv,
    summarise,
)

README = (ROOT / "README.md").read_text(encoding="utf-8")
RESULTS = README[README.index("## Results"):README.index("## Documentation")]


def _table(model: str) -> dict[tuple[str, int], dict[str, float]]:
    """(scheme, density) -> seed means of the 3x3 runs of one model's committed table, as
    ``paper_table.summarise`` computes them, plus the released-style velocity ``rv``."""
    name = "paper_table" if model == "default" else "paper_table_released"
    return _cells(ROOT / "docs" / "results" / name / "paper_table.csv")


def _cells(path: Path) -> dict[tuple[str, int], dict[str, float]]:
    """:func:`_table` of any paper_table CSV."""
    rows = read_runs_csv(path)
    cells = summarise(rows, "3x3")[1]
    for (scheme, d), cell in cells.items():
        cell["rv"] = float(np.mean([x["released_velocity_mps"] for x in rows if (
            x["rows"], x["cols"], x["scheme"], x["density"]) == (3, 3, scheme, d)]))
        cell["events"] = int(cell["collisions"])
    return cells


def _gains(cells: dict, a: str, b: str, key: str) -> list[float]:
    return [improvement(cells[(a, d)][key], cells[(b, d)][key]) for d in DENSITIES]


def _span(gains: list[float]) -> str:
    return f"{min(gains):+.2f} % to {max(gains):+.2f} %"


def _events(cells: dict, scheme: str) -> str:
    return " / ".join(str(cells[(scheme, d)]["events"]) for d in DENSITIES)


@pytest.fixture(scope="module")
def default() -> dict:
    return _table("default")


@pytest.fixture(scope="module")
def released() -> dict:
    return _table("released")


def test_both_tables_hold_three_seeds_per_cell(default, released):
    for cells in (default, released):
        assert {c["n"] for c in cells.values()} == {3}


def test_default_model_velocity_rows(default):
    for d in (300, 1200, 2100):
        cells = [f"{d}", f"{default[('E', d)]['ub']:.3f}"] + [
            f"{default[(s, d)]['v']:.3f} ({default[(s, d)]['events']})"
            for s in ("signalized", "E", "EE", "EEC", "EE+3")]
        assert "| " + " | ".join(cells) + " |" in RESULTS, d


def test_default_model_gains_and_events(default):
    edge = _gains(default, "EE", "E", "v")
    assert _span(edge) in RESULTS
    share = [g / c for g, c in zip(edge, _gains(default, "EE+3", "E", "v"), strict=True)]
    assert f"{100 * min(share):.0f}-{100 * max(share):.0f} % of what an edge" in RESULTS
    assert f"Strict events {_events(default, 'EE')} (E: " in RESULTS.replace("\n  ", " ")
    assert f"(E: {_events(default, 'E')})" in RESULTS.replace("\n  ", " ")
    cloud = _gains(default, "EEC", "EE", "v")
    assert f"{_span(cloud)} over EE" in RESULTS
    assert f"+{min(_gains(default, 'EEC', 'EE', 'rv')):.2f} % to" in RESULTS
    assert f"strict events {_events(default, 'EEC')}." in RESULTS.replace("\n  ", " ")


def test_released_model_gain_rows(released):
    for (a, b), name in ((("EE", "E"), "EE vs E"), (("EEC", "E"), "EEC vs E"),
                         (("EEC", "EE"), "EEC vs EE")):
        gains = _gains(released, a, b, "rv")
        cells = [f"{g:+.2f} ({PAPER_3X3[name][d]:.2f})"
                 for g, d in zip(gains, DENSITIES, strict=True)]
        assert f"| {name} [%] | " + " | ".join(cells) + " |" in RESULTS, name
    events = [" / ".join(str(released[(s, d)]["events"]) for s in ("E", "EE", "EEC"))
              for d in DENSITIES]
    assert "| events E / EE / EEC | " + " | ".join(events) + " |" in RESULTS


def test_released_model_cloud_span(released):
    assert f"{_span(_gains(released, 'EEC', 'EE', 'rv'))} over EE" in RESULTS


def test_released_model_edge_against_its_ceiling(released):
    edge = _gains(released, "EE", "E", "rv")
    ceiling = _gains(released, "EE+3", "E", "rv")
    share = [g / c for g, c, d in zip(edge, ceiling, DENSITIES, strict=True) if d >= 1500]
    text = RESULTS.replace("\n  ", " ")
    assert f"{100 * min(share):.0f}-{100 * max(share):.0f} % of the constant +3 edge" in text
    events = [released[("EE+3", d)]["events"] for d in DENSITIES]
    assert f"collides {min(events)}-{max(events)} times per cell" in text


SHIELD = ROOT / "docs" / "results" / "training" / "session26"


def test_shield_paragraph(default, released):
    """The README's safety-shield paragraph: no strict event in any shielded cell, and the
    velocity each scheme loses at 2100 veh/lane/h against the committed tables."""
    text = README.replace("\n", " ")
    for name in ("released", "released_s3to7", "default", "default_s3to7"):
        cells = _cells(SHIELD / f"pt_shield_{name}" / "paper_table.csv")
        assert {s for s, _ in cells} == {"E", "EE", "EEC", "EE+3", "EEC+3"}
        assert sum(c["events"] for c in cells.values()) == 0, name
    for model, base, key in (("released", released, "rv"), ("default", default, "v")):
        cells = _cells(SHIELD / f"pt_shield_{model}" / "paper_table.csv")
        loss = {s: 100 * (1 - cells[(s, 2100)][key] / base[(s, 2100)][key]) for s in ("E", "EEC")}
        assert f"{model} model's E loses {loss['E']:.1f} %, EEC {loss['EEC']:.1f} %" in text


def test_shield_figures_in_the_docs(default, released):
    """docs/training.md and docs/model.md quote the shielded tables' smallest distance and how
    far the velocities move at 300-900 veh/lane/h: recomputed from the committed runs."""
    training, model = (" ".join((ROOT / "docs" / f).read_text(encoding="utf-8").split())
                       for f in ("training.md", "model.md"))
    closest = min(
        x["min_distance_m"]
        for name in ("released", "released_s3to7", "default", "default_s3to7",
                     "released_per_lane")
        for x in read_runs_csv(SHIELD / f"pt_shield_{name}" / "paper_table.csv"))
    assert f"smallest centre distance in these runs is {closest:.2f} m" in training
    assert f"smallest centre distance {closest:.2f} m" in model
    moved = {}
    for model_name, base, key in (("released", released, "rv"), ("default", default, "v")):
        cells = _cells(SHIELD / f"pt_shield_{model_name}" / "paper_table.csv")
        moved[model_name] = max(abs(cells[(s, d)][key] - base[(s, d)][key])
                                for s in ("E", "EE", "EEC") for d in (300, 600, 900))
    assert (f"by at most {moved['released']:.3f} m/s (released model) and "
            f"{moved['default']:.3f} m/s") in training
    assert moved["released"] < 0.02 and moved["default"] < 0.09
    assert "under 0.02 m/s (released) and 0.09 m/s (default) at 300-900" in model


def test_shield_edge_figures(default, released):
    """The README's shield-edge sentence: the share of the +3 edge's gain each edge realises
    under the shield (seeds 0-2), and the released model's EEC-vs-E span with either edge,
    recomputed from the committed runs (the shares as paper_targets.py prints them)."""
    text = " ".join(README.split())
    s27 = ROOT / "docs" / "results" / "training" / "session27"

    def share(cells: dict, key: str) -> str:
        ours, ceiling = (_gains(cells, s, "E", key) for s in ("EE", "EE+3"))
        ratio = [100 * o / c for o, c in zip(ours, ceiling, strict=True) if round(c, 2) > 0]
        return f"{min(ratio):.0f}-{max(ratio):.0f} %"

    shield_edge = {m: _cells(s27 / f"pt_shield_pair_{m}" / "paper_table.csv")
                   for m in ("released", "default")}
    trained_without = {m: _cells(SHIELD / f"pt_shield_{m}" / "paper_table.csv")
                       for m in ("released", "default")}
    assert (f"realises {share(shield_edge['released'], 'rv')} (released model) and "
            f"{share(shield_edge['default'], 'v')} (default model)") in text
    assert (f"realise {share(trained_without['released'], 'rv')} and "
            f"{share(trained_without['default'], 'v')}") in text
    new, old = (_gains(c, "EEC", "E", "rv") for c in (shield_edge["released"],
                                                     trained_without["released"]))
    assert f"gains {_span(new)} over E in released-style velocity" in text
    assert f"against {_span(old)} with the pair trained without the shield" in text
    cloud_share = _gains(shield_edge["released"], "EEC", "EE", "rv")
    assert f"EEC vs EE {_span(cloud_share)}, under half the paper's at 300-1200" in text
    half = [PAPER_3X3["EEC vs EE"][d] / 2 for d in DENSITIES]
    assert [d for d, g, h in zip(DENSITIES, cloud_share, half, strict=True)
            if round(g, 2) < h] == [300, 600, 900, 1200]
    paper = PAPER_3X3["EEC vs E"]
    assert f"(the paper: {min(paper.values()):.2f}-{max(paper.values()):.2f} %)" in text
    assert all(g > paper[d] for g, d in zip(new, DENSITIES, strict=True))


def test_td3_edge_table_in_training_doc():
    """docs/training.md's TD3 table (session 28): EE vs E of the shipped shield edge, the TD3
    edge and the +3 edge, and the share of the +3 edge's gain, from the committed runs."""
    training = (ROOT / "docs" / "training.md").read_text(encoding="utf-8")
    results = ROOT / "docs" / "results" / "training"
    for model, base, key in (("released", "pt_area", "rv"), ("default", "pt_paper_area", "v")):
        s27 = _cells(results / "session27" / base / "paper_table.csv")
        td3_ee = _cells(results / "session28" / f"pt_td3_{'paper' if model == 'default' else model}"
                        / "paper_table.csv")
        td3 = {**s27, **{k: v for k, v in td3_ee.items() if k[0] == "EE"}}
        ceiling = _gains(s27, "EE+3", "E", key)
        for label, cells in (("the shipped shield edge (DDPG)", s27), ("TD3", td3)):
            gains = _gains(cells, "EE", "E", key)
            share = [100 * g / c for g, c in zip(gains, ceiling, strict=True)]
            row = (f"| {model}, {label} | " + " | ".join(f"{g:+.2f}" for g in gains)
                   + f" | {min(share):.0f}-{max(share):.0f} % |")
            assert row in training, row
        row = f"| {model}, constant +3 edge | " + " | ".join(f"{g:+.2f}" for g in ceiling)
        assert row in training, row
