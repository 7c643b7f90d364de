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
    coder = [f"{g:+.1f} ({PAPER_3X3['EEC vs Coder'][d]:.1f})"
             for g, d in zip(_gains(released, "EEC", "coder", "rv"), DENSITIES, strict=True)]
    assert "| EEC vs Coder [%] | " + " | ".join(coder) + " |" in RESULTS


def test_coder_runs_do_not_depend_on_the_model() -> None:
    """The released table's Coder runs equal the default table's, run for run."""
    runs = {}
    for name in ("paper_table", "paper_table_released"):
        rows = read_runs_csv(ROOT / "docs" / "results" / name / "paper_table.csv")
        runs[name] = {(x["density"], x["seed"]): (x["avg_travel_velocity_mps"],
                                                   x["released_velocity_mps"], x["collisions"],
                                                   x["throughput"])
                      for x in rows if x["scheme"] == "coder"}
    assert len(runs["paper_table"]) == 21 and runs["paper_table"] == runs["paper_table_released"]


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

    def share(cells: dict, key: str) -> str:
        ours, ceiling = (_gains(cells, s, "E", key) for s in ("EE", "EE+3"))
        ratio = [100 * o / c for o, c in zip(ours, ceiling, strict=True) if round(c, 2) > 0]
        return f"{min(ratio):.0f}-{max(ratio):.0f} %"

    s32 = ROOT / "docs" / "results" / "training" / "session32"  # both since then
    shield_edge = {m: _cells(s32 / f"pt_shield_pair_{m}" / "paper_table.csv")
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
    """docs/training.md's TD3 table (session 28): EE vs E of session 27's shield edge, the TD3
    edge and the +3 edge, and the share of the +3 edge's gain, from the committed runs."""
    training = (ROOT / "docs" / "training.md").read_text(encoding="utf-8")
    results = ROOT / "docs" / "results" / "training"
    for model, base, key in (("released", "pt_area", "rv"), ("default", "pt_paper_area", "v")):
        s27 = _cells(results / "session27" / base / "paper_table.csv")
        td3_ee = _cells(results / "session28" / f"pt_td3_{'paper' if model == 'default' else model}"
                        / "paper_table.csv")
        td3 = {**s27, **{k: v for k, v in td3_ee.items() if k[0] == "EE"}}
        ceiling = _gains(s27, "EE+3", "E", key)
        for label, cells in (("session 27's shield edge (DDPG)", s27), ("TD3", td3)):
            gains = _gains(cells, "EE", "E", key)
            share = [100 * g / c for g, c in zip(gains, ceiling, strict=True)]
            row = (f"| {model}, {label} | " + " | ".join(f"{g:+.2f}" for g in gains)
                   + f" | {min(share):.0f}-{max(share):.0f} % |")
            assert row in training, row
        row = f"| {model}, constant +3 edge | " + " | ".join(f"{g:+.2f}" for g in ceiling)
        assert row in training, row


def test_exploration_table_in_training_doc():
    """docs/training.md's 1x1 table of session 28's edge variants: the gains of each run's
    deterministic evaluation and of the constant +3 edge, from the committed eval_log.csv files."""
    import csv

    training = (ROOT / "docs" / "training.md").read_text(encoding="utf-8")
    results = ROOT / "docs" / "results" / "training"

    def gains(run: str, frames: int, column: str = "gain_pct") -> list[str]:
        with (results / run / "eval_log.csv").open() as fh:
            rows = [r for r in csv.DictReader(fh) if int(r["frames"]) == frames]
        assert [float(r["density"]) for r in rows] == [900.0, 1500.0, 2100.0]
        return [f"{float(r[column]):+.2f}" for r in rows]

    runs = [
        ("released, session 27's shield edge (scalar noise 0.1), 60 000 frames",
         "session27/edge_released_shield_sv0_area", 60_000),
        ("released, TD3, 60 000 frames", "session28/edge_released_shield_td3", 60_000),
        ("released, `actor_preact_bound=3`, 60 000 frames",
         "session28/edge_released_shield_area_bound3", 60_000),
        ("released, session 27's run continued, 120 000 frames",
         "session28/edge_released_shield_area_150k", 120_000),
        ("released, session 27's run continued, 150 000 frames",
         "session28/edge_released_shield_area_150k", 150_000),
        ("released, per-column noise 1.0 -> 0.3, seed 0, 60 000 frames",
         "session28/edge_released_shield_area_percol", 60_000),
        ("released, per-column noise 1.0 -> 0.3, seed 1, 60 000 frames",
         "session28/edge_released_shield_area_percol_seed1", 60_000),
        ("released, per-column noise 1.0 -> 0.3, seed 2, 60 000 frames",
         "session28/edge_released_shield_area_percol_seed2", 60_000),
        ("released, per-column noise 1.0 -> 0.3, seed 1 continued, 120 000 frames",
         "session28/edge_released_shield_area_percol_seed1_120k", 120_000),
        ("released, per-column noise 1.0 -> 0.5, seed 1, 60 000 frames",
         "session28/edge_released_shield_area_percol05_seed1", 60_000),
        ("released, per-column noise 1.0 -> 0.5, seed 2, 60 000 frames",
         "session28/edge_released_shield_area_percol05_seed2", 60_000),
        ("default, session 27's shield edge, 60 000 frames",
         "session27/edge_paper_shield_sv0_area", 60_000),
        ("default, per-column noise 1.0 -> 0.3, seed 0, 60 000 frames",
         "session28/edge_paper_shield_area_percol", 60_000),
        ("default, per-column noise 1.0 -> 0.3, seed 1, 60 000 frames",
         "session28/edge_paper_shield_area_percol_seed1", 60_000),
    ]
    ceilings = {m: " / ".join(gains(f"session28/edge_{m}_shield_area_percol", 60_000,
                                     "ceiling_gain_pct")) for m in ("released", "paper")}
    for i, (label, run, frames) in enumerate(runs):
        model = "released" if label.startswith("released") else "paper"
        first = i == 0 or label.split(",")[0] != runs[i - 1][0].split(",")[0]
        row = f"| {label} | " + " | ".join(gains(run, frames)) + " | " + (
            ceilings[model] if first else "same") + " |"
        assert row in training, row
    # every run of a model was evaluated on the same seeds: one ceiling per model
    for run in ("edge_released_shield_area_bound3", "edge_released_shield_area_percol_seed1",
                "edge_released_shield_area_150k"):
        assert " / ".join(gains(f"session28/{run}", 60_000 if "150k" not in run else 120_000,
                                "ceiling_gain_pct")) == ceilings["released"]


def _merged_cells(*paths: Path) -> dict:
    """:func:`_cells` of several paper_table CSVs, a later file's run replacing an earlier
    one's (as ``paper_targets.py`` merges them)."""
    runs = {}
    for row in (row for p in paths for row in read_runs_csv(p)):
        runs[(row["scheme"], row["density"], row["seed"])] = row
    rows = list(runs.values())
    out = summarise(rows, "3x3")[1]
    for (scheme, d), cell in out.items():
        cell["rv"] = float(np.mean([x["released_velocity_mps"] for x in rows
                                    if (x["scheme"], x["density"]) == (scheme, d)]))
    return out


def _ceiling_share(c: dict, key: str) -> list[float]:
    """The share of the +3 edge's gain over E that EE realises, per density [%]."""
    return [100 * a / b for a, b in zip(_gains(c, "EE", "E", key), _gains(c, "EE+3", "E", key),
                                        strict=True)]


def _assert_row(text: str, label: str, values: list[float], fmt: str) -> None:
    line = f"| {label} | " + " | ".join(format(v, fmt) for v in values) + " |"
    assert line in text, line


def test_shipped_shield_edge_table_in_training_doc():
    """docs/training.md's 3x3 table of the session-28 shield edges, from the committed runs."""
    training = (ROOT / "docs" / "training.md").read_text(encoding="utf-8")
    s27, s28 = (ROOT / "docs" / "results" / "training" / f"session{n}" for n in (27, 28))
    cells, share = _merged_cells, _ceiling_share

    def row(label: str, values: list[float], fmt: str) -> None:
        _assert_row(training, label, values, fmt)

    pair = lambda m, suffix="": s28 / f"pt_shield_pair_{m}{suffix}" / "paper_table.csv"  # noqa: E731
    rel, rel37 = cells(pair("released")), cells(pair("released", "_s3to7"))
    row("released, seeds 0-2: EE vs E", _gains(rel, "EE", "E", "rv"), "+.2f")
    row("released, seeds 0-2: EE+3 vs E", _gains(rel, "EE+3", "E", "rv"), "+.2f")
    row("released, seeds 0-2: share of EE+3 [%]", share(rel, "rv"), ".0f")
    row("released, seeds 0-2, session 27's edge: share of EE+3 [%]",
        share(cells(s27 / "pt_area" / "paper_table.csv"), "rv"), ".0f")
    # other edges' EE runs over the shipped pair's E and EE+3 (folder under session28/)
    for label, folder in (("the seed-1 edge", "pt_percol_released_seed1"),
                          ("the seed-2 edge", "pt_percol_released_seed2"),
                          ("the seed-1 edge at 120 000 frames", "pt_percol_released_seed1_120k"),
                          ("the seed-1 edge, noise 1.0 -> 0.5", "pt_percol05_released_seed1"),
                          ("the seed-2 edge, noise 1.0 -> 0.5", "pt_percol05_released_seed2")):
        row(f"released, seeds 0-2, {label}: share of EE+3 [%]",
            share(cells(pair("released"), s28 / folder / "paper_table.csv"), "rv"), ".0f")
    row("released, seeds 3-7: share of EE+3 [%]", share(rel37, "rv"), ".0f")
    row("released, seeds 0-2: EEC vs E", _gains(rel, "EEC", "E", "rv"), "+.2f")
    row("released, seeds 0-2: EEC vs EE", _gains(rel, "EEC", "EE", "rv"), "+.2f")
    default, default37 = cells(pair("default")), cells(pair("default", "_s3to7"))
    row("default, seeds 0-2: EE vs E", _gains(default, "EE", "E", "v"), "+.2f")
    row("default, seeds 0-2: share of EE+3 [%]", share(default, "v"), ".0f")
    row("default, seeds 0-2, session 27's edge: share of EE+3 [%]",
        share(cells(s27 / "pt_paper_area" / "paper_table.csv"), "v"), ".0f")
    row("default, seeds 0-2, the seed-1 edge: share of EE+3 [%]",
        share(cells(pair("default"), s28 / "pt_percol_paper_seed1" / "paper_table.csv"), "v"),
        ".0f")
    row("default, seeds 3-7: share of EE+3 [%]", share(default37, "v"), ".0f")
    row("default, seeds 0-2: EEC vs EE", _gains(default, "EEC", "EE", "v"), "+.2f")


def test_td3_learner_cost_in_training_doc():
    """docs/training.md's TD3 cost: the median fps_optim of the committed session-28 logs."""
    import csv
    import statistics

    training = " ".join((ROOT / "docs" / "training.md").read_text(encoding="utf-8").split())
    s28 = ROOT / "docs" / "results" / "training" / "session28"

    def median_fps(run: str) -> str:
        with (s28 / run / "train_log.csv").open() as fh:
            values = [float(r["fps_optim"]) for r in csv.DictReader(fh)
                      if r["fps_optim"] not in ("", "nan") and float(r["fps_optim"]) > 0]
        return f"{statistics.median(values):.0f}"

    td3 = [median_fps(f"edge_{m}_shield_td3") for m in ("released", "paper")]
    ddpg = [median_fps(f"edge_{m}_shield_area_percol") for m in ("released", "paper")]
    assert (f"was {td3[0]} / {td3[1]} with TD3 (released / default model) against "
            f"{ddpg[0]} / {ddpg[1]} with DDPG") in training


#: docs/training.md's session-29 share table: label -> (session, paper_table folder); each
#: EE run is merged over the shipped pair's E and EE+3 runs (session 28).
SESSION29_EDGES = {
    "session 28, seed 0 (shipped)": ("session28", "pt_shield_pair_released"),
    "session 28, seed 1": ("session28", "pt_percol_released_seed1"),
    "session 28, seed 2": ("session28", "pt_percol_released_seed2"),
    "1. four densities, seed 0 (60 000 frames)": ("session29", "pt_lowd_seed0_edge"),
    "1. four densities, seed 1, best (30 000 frames)": ("session29", "pt_lowd_seed1_edge_best"),
    "1. four densities, seed 1, final (60 000 frames)": ("session29", "pt_lowd_seed1_edge"),
    "2. picked on 3x3, seed 1 (40 800 frames)": ("session29", "pt_sel3x3_seed1_best"),
    "2. picked on 3x3, seed 2 (60 000 frames)": ("session29", "pt_sel3x3_seed2_best"),
    "2. picked on 3x3, seed 3 (10 200 frames)": ("session29", "pt_sel3x3_seed3_best"),
    "2. picked on 3x3, seed 4 (30 600 frames)": ("session29", "pt_sel3x3_seed4_best"),
    "3. linear learning rates, seed 1 (60 000 frames)": ("session29", "pt_linlr_seed1_best"),
    "3. linear learning rates, seed 2 (30 600 frames)": ("session29", "pt_linlr_seed2_best"),
    "4. four times the updates, seed 1 (60 000 frames)": ("session29", "pt_upf1_seed1_best"),
    "4. four times the updates, seed 2 (30 600 frames)": ("session29", "pt_upf1_seed2_best"),
}


def session29_share_rows() -> list[tuple[str, list[float]]]:
    """(label, share per density [%]) of :data:`SESSION29_EDGES`."""
    training = ROOT / "docs" / "results" / "training"
    pair = training / "session28" / "pt_shield_pair_released" / "paper_table.csv"
    return [(label, _ceiling_share(_merged_cells(pair, training / s / f / "paper_table.csv"),
                                   "rv"))
            for label, (s, f) in SESSION29_EDGES.items()]


def test_session29_edge_table_in_training_doc():
    training = (ROOT / "docs" / "training.md").read_text(encoding="utf-8")
    rows = session29_share_rows()
    for label, shares in rows:
        _assert_row(training, label, shares, ".0f")
    # the README's summary of the other training seeds (session 28's seed-1 and seed-2 edges)
    others = [round(x) for label, shares in rows if label in ("session 28, seed 1",
                                                              "session 28, seed 2")
              for x in shares]
    assert (f"Seeds 1 and 2 realise {min(others)}-{max(others)} % of its gain"
            in " ".join(README.split()))


def test_session29_figures_in_training_doc():
    """The critic check, the evaluation cost and the per-column cloud of session 29."""
    import csv
    import statistics

    training = " ".join((ROOT / "docs" / "training.md").read_text(encoding="utf-8").split())
    s29 = ROOT / "docs" / "results" / "training" / "session29"
    check = (s29 / "edge_critic_check_percol_seed2.md").read_text(encoding="utf-8")

    def probe(name: str, column: int) -> str:
        line = next(x for x in check.splitlines() if x.startswith(f"| {name} |"))
        return line.split("|")[column].strip()

    assert probe("actor: share of actions within 0.01 of +3", 3) == "51 %"
    assert probe("actor: mean action [m/s^2]", 2) == "+2.20060"
    assert probe("constant +3", 3) == "24 %"
    assert "state_dependent (15 columns)" in check
    assert ("51 % of its actions are within 0.01 of +3 (seed 0: 93 %), its mean action is "
            "+2.20 m/s^2, and it rates +3 above its own action in 24 % of 3600 states") in training
    # the evaluation cost on 3x3: the iteration after each evaluation against the median one
    extra, medians = [], []
    for seed in (1, 2):
        run = s29 / f"edge_released_shield_sel3x3_seed{seed}"
        with (run / "train_log.csv").open() as fh:
            rows = [(int(r["frames"]), float(r["wall_s"])) for r in csv.DictReader(fh)]
        with (run / "eval_log.csv").open() as fh:
            evaluated = {int(r["frames"]) for r in csv.DictReader(fh)}
        step = {rows[i][0]: rows[i][1] - rows[i - 1][1] for i in range(1, len(rows))}
        median = statistics.median(step.values())
        medians.append(median)
        extra += [step[rows[i + 1][0]] - median for i in range(len(rows) - 1)
                  if rows[i][0] in evaluated]
    assert (f"took {min(extra):.0f}-{max(extra):.0f} s longer than the median iteration "
            f"({min(medians):.1f}-{max(medians):.1f} s)") in training
    # the per-column cloud: its evaluations, and its verdict against the +3 cloud
    with (s29 / "cloud_released_shield_percol" / "eval_log.csv").open() as fh:
        log = list(csv.DictReader(fh))
    for frames in (30000, 60000, 90000):
        gains = " / ".join(f"{float(r['gain_pct']):+.2f}" for r in log
                           if int(r["frames"]) == frames)
        assert f"{gains} %" in training, gains
    ceiling = " / ".join(f"{float(r['ceiling_gain_pct']):+.2f}" for r in log
                         if int(r["frames"]) == 0)
    assert f"(the +3 cloud: {ceiling} %)" in training
    from tests.scripts import load_benchmark

    targets = load_benchmark("paper_targets")
    table = targets.main(["--column", "per-column cloud",
                          str(ROOT / "docs/results/training/session28/pt_shield_pair_released"
                                     "/paper_table.csv"),
                          str(s29 / "pt_cloud_percol_best" / "paper_table.csv")])
    line = next(x for x in table.splitlines() if "constant +3 cloud" in x)
    cloud = line.split("|")[2].strip()
    assert cloud in training, cloud


def _shares_by_frames(run: Path) -> dict[int, list[float]]:
    """A training run's evaluations (``eval_log.csv``): frames -> the shares of the +3 edge's
    gain at its densities [%]."""
    import csv

    by_frames: dict[int, list[float]] = {}
    with (run / "eval_log.csv").open() as fh:
        for r in csv.DictReader(fh):
            by_frames.setdefault(int(r["frames"]), []).append(float(r["ceiling_share_pct"]))
    return by_frames


def _curve_spans(run: Path) -> tuple[list[float], list[float], list[float]]:
    """A run's training curve as shares of the +3 edge's gain [%]: at 0 frames, at its first
    evaluation (10 200 frames), and at that one and every later one."""
    by_frames = _shares_by_frames(run)
    start, first = by_frames.pop(0), by_frames.pop(10_200)
    return start, first, [x for v in by_frames.values() for x in v] + first


def _assert_same_ee_runs(shipped_table: Path, edge_table: Path) -> None:
    """The EE runs of a table made with the shipped files equal, field for field, those of a
    table made with ``--edge`` and the checkpoint the file was exported from."""
    def ee_runs(table: Path) -> dict:
        return {(r["density"], r["seed"]): r for r in read_runs_csv(table / "paper_table.csv")
                if r["scheme"] == "EE"}

    shipped, explicit = ee_runs(shipped_table), ee_runs(edge_table)
    assert shipped and shipped.keys() == explicit.keys()
    for key, row in shipped.items():
        assert all(row[k] == explicit[key][k] for k in (
            "avg_travel_velocity_mps", "released_velocity_mps", "collisions", "min_ttc_s",
            "in_network")), key


def _picking(run: Path) -> tuple[int, float]:
    """(frames, score) of the policy a run's ``min_ceiling_share`` picking kept: the first
    evaluation with the largest smallest share over its densities."""
    by_frames = _shares_by_frames(run)
    best = max(by_frames, key=lambda f: min(by_frames[f]))
    return best, min(by_frames[best])


def _assert_picked_row(raw: str, pair: Path, table: Path, run: Path,
                       label: str) -> tuple[list[float], float]:
    """Assert the doc's row ``| <label> (<frames> frames) | shares | score |`` of a run's kept
    policy (its EE table ``table`` merged over ``pair``'s E and EE+3 runs) and return
    (its shares of the +3 edge's gain per density [%], its picking score)."""
    share = _ceiling_share(_merged_cells(pair, table / "paper_table.csv"), "rv")
    frames, score = _picking(run)
    full = f"{label} ({frames:_} frames)".replace("_", " ")
    assert (f"| {full} | " + " | ".join(f"{x:.0f}" for x in share)
            + f" | {score:.1f} |") in raw, full
    return share, score


def _picking_shares(table: Path) -> list[float]:
    """The share of the +3 edge's gain EE realises at 900 / 1500 / 2100 veh/lane/h in a
    paper_table CSV with E, EE and EE+3 runs (the picking evaluation's densities) [%]."""
    cells = _merged_cells(table)
    return [100 * (cells[("EE", d)]["rv"] / cells[("E", d)]["rv"] - 1)
            / (cells[("EE+3", d)]["rv"] / cells[("E", d)]["rv"] - 1) for d in (900, 1500, 2100)]


def test_session29_picking_scores_in_training_doc():
    """The picking evaluation's score (smallest ceiling share over 900 / 1500 / 2100 veh/lane/h
    on 3x3 seeds 1000-1002) of the shipped seed-0 edge and of the seed 1-4 runs' picks."""

    training = " ".join((ROOT / "docs" / "training.md").read_text(encoding="utf-8").split())
    s29 = ROOT / "docs" / "results" / "training" / "session29"
    shares = _picking_shares(s29 / "pt_pick_seed0" / "paper_table.csv")
    picks = [_picking(s29 / f"edge_released_shield_sel3x3_seed{seed}")[1]
             for seed in (1, 2, 3, 4)]
    others = " / ".join(f"{x:.1f}" for x in picks)
    assert (f"is {min(shares):.1f} % for the shipped seed-0 edge and {others} % for the best "
            "policies of seeds 1 / 2 / 3 / 4") in training
    assert min(shares) > max(picks)


#: The headroom searches of session 30: table label -> report stem under session30/.
SESSION30_SEARCHES = {
    "edge, released model": "headroom_edge/headroom_edge_released",
    "edge, default model": "headroom_edge_paper/headroom_edge_paper",
    "cloud, released model": "headroom_cloud/headroom_cloud_released",
    "cloud, default model": "headroom_cloud_paper/headroom_cloud_paper",
    "cloud, released model, seeds 1000-1003 x 3000 steps":
        "headroom_cloud_4seeds/headroom_cloud_released",
}


def test_session30_headroom_figures_in_training_doc():
    """The headroom table and its bullets, from the searches' committed reports."""
    import json

    training = " ".join((ROOT / "docs" / "training.md").read_text(encoding="utf-8").split())
    s30 = ROOT / "docs" / "results" / "training" / "session30"
    runs = {label: json.loads((s30 / f"{stem}.json").read_text())
            for label, stem in SESSION30_SEARCHES.items()}

    def shares(run: dict, policy: str) -> list[float]:
        return [row[f"{policy}_share_pct"] for row in run["table"]]

    for label, run in runs.items():
        best = [h["best_share_pct"] for h in run["history"]]
        events = sum(r["search_mean_events"] + r["search_best_events"] for r in run["table"])
        row = (f"| {label} | {min(best):.1f}-{max(best):.1f} | "
               + " / ".join(f"{x:.0f}" for x in shares(run, "search_mean")) + " | "
               + " / ".join(f"{x:.0f}" for x in shares(run, "search_best")) + f" | {events} |")
        assert row in training, row
        assert events == 0 and all(h["best_events"] == 0 for h in run["history"])
    edges = [runs["edge, released model"], runs["edge, default model"]]
    top = max(h["best_share_pct"] for run in edges for h in run["history"])
    assert f"realises more than {top:.1f} % of its gain" in training
    on_table = [x for run in edges for p in ("search_mean", "search_best") for x in shares(run, p)]
    assert f"realise {min(on_table):.0f}-{max(on_table):.0f} % of its gain" in training
    biases = [run["mean"][-1] for run in edges]
    assert f"its bias ends at {min(biases):.1f}-{max(biases):.1f}" in training
    cloud = runs["cloud, released model"]
    own = [h["best_share_pct"] for h in cloud["history"]]
    table = shares(cloud, "search_mean") + shares(cloud, "search_best")
    assert f"finds clouds at {min(own):.0f}-{max(own):.0f} % of the +3 cloud's gain" in training
    assert f"the same clouds realise {min(table):.0f}-{max(table):.0f} %" in training
    default = shares(runs["cloud, default model"], "search_mean") + shares(
        runs["cloud, default model"], "search_best")
    assert f"clouds realise {min(default):.0f}-{max(default):.0f} % on the table" in training
    gains = " / ".join(f"{r['search_best_gain_pct']:+.2f}" for r in cloud["table"][:4])
    assert f"EEC vs EE is {gains} % at 300-1200 veh/lane/h" in training
    half = [PAPER_3X3["EEC vs EE"][d] / 2 for d in DENSITIES]
    assert all(r["search_best_gain_pct"] < h
               for r, h in zip(cloud["table"][:4], half[:4], strict=True))
    longer = runs["cloud, released model, seeds 1000-1003 x 3000 steps"]
    longer_table = shares(longer, "search_mean") + shares(longer, "search_best")
    assert (f"finds no cloud above {max(h['best_share_pct'] for h in longer['history']):.1f} % "
            f"on its own seeds, and its two policies realise {min(longer_table):.0f}-"
            f"{max(longer_table):.0f} % on the table's") in training
    clouds = table + default + longer_table
    readme = " ".join(README.split())
    assert (f"Its edges realise {min(on_table):.0f}-{max(on_table):.0f} % of the +3 edge's gain "
            f"on the table's seeds and its clouds {min(clouds):.0f}-{max(clouds):.0f} % of the "
            "+3 cloud's") in readme
    default = runs["cloud, default model"]["table"]
    assert all(r["search_best_gain_pct"] < h for r, h in zip(default[:6], half[:6], strict=True))
    at_2100 = (f"(+{default[6]['search_best_gain_pct']:.2f} % against {half[6]:.2f} %), where "
               f"the constant cloud does too (+{default[6]['ceiling_gain_pct']:.2f} %)")
    assert default[6]["ceiling_gain_pct"] >= half[6] and at_2100 in training, at_2100


#: docs/training.md's session-31 table: seed -> (one-critic table, five-critic table), each EE
#: run merged over the shipped pair's E and EE+3 runs (session 28).
SESSION31_ONE_CRITIC = {0: ("session28", "pt_shield_pair_released"),
                        **{s: ("session29", f"pt_sel3x3_seed{s}_best") for s in (1, 2, 3, 4)}}


def test_session31_critic_ensemble_in_training_doc():
    """The five-critic edges of session 31 against the one-critic ones, from the committed
    tables, evaluation logs, critic checks and training logs."""
    import csv
    import re
    import statistics

    raw = (ROOT / "docs" / "training.md").read_text(encoding="utf-8")
    training = " ".join(raw.split())
    results = ROOT / "docs" / "results" / "training"
    s31 = results / "session31"
    pair = results / "session28" / "pt_shield_pair_released" / "paper_table.csv"
    one, five = {}, {}
    for seed, (session, folder) in SESSION31_ONE_CRITIC.items():
        one[seed] = _ceiling_share(_merged_cells(pair, results / session / folder /
                                                 "paper_table.csv"), "rv")
        five[seed] = _ceiling_share(_merged_cells(pair, s31 / f"pt_ens5_seed{seed}_best" /
                                                  "paper_table.csv"), "rv")
    # the picking scores: seed 0's from session 29's evaluation of the shipped edge
    shipped_score = min(_picking_shares(results / "session29" / "pt_pick_seed0" /
                                        "paper_table.csv"))
    for seed in range(5):
        frames, score = _picking(s31 / f"edge_released_shield_ens5_seed{seed}")
        label = f"seed {seed}, five critics ({frames:_} frames)".replace("_", " ")
        assert (f"| {label} | " + " | ".join(f"{x:.0f}" for x in five[seed])
                + f" | {score:.1f} |") in raw, label
        if seed == 0:
            label, score = "seed 0, one critic (shipped)", shipped_score
        else:
            frames, score = _picking(results / "session29" /
                                     f"edge_released_shield_sel3x3_seed{seed}")
            label = f"seed {seed}, one critic ({frames:_} frames)".replace("_", " ")
        assert (f"| {label} | " + " | ".join(f"{x:.0f}" for x in one[seed])
                + f" | {score:.1f} |") in raw, label
    # two more one-critic seeds (5, 6): only the shipped edge reaches the +3 edge
    scores = {}
    for seed in (5, 6):
        share, scores[seed] = _assert_picked_row(
            raw, pair, s31 / f"pt_sel3x3_seed{seed}_best",
            s31 / f"edge_released_shield_sel3x3_seed{seed}", f"seed {seed}, one critic")
        assert max(share) < 100
        if seed == 5:
            assert all(99 <= share[i] < 100 for i in (3, 4))  # within 1 point at 1200, 1500
    assert all(max(v) < 100 for s, v in one.items() if s != 0)
    others = [_picking(results / "session29" / f"edge_released_shield_sel3x3_seed{s}")[1]
              for s in (1, 2, 3, 4)]
    assert max(others) < scores[5] == max(scores.values())
    assert f"scores above {scores[5]:.1f} on the picking seeds" in training
    # recipe 2 with the actor's pre-activations bounded by 4 (seeds 1, 2): worse
    for seed in (1, 2):
        share, _ = _assert_picked_row(raw, pair, s31 / f"pt_bound4_seed{seed}_best",
                                      s31 / f"edge_released_shield_bound4_seed{seed}",
                                      f"seed {seed}, one critic, bound 4")
        assert min(share) < min(one[seed])
    bounded = [min(_ceiling_share(_merged_cells(pair, s31 / f"pt_bound4_seed{seed}_best" /
                                                "paper_table.csv"), "rv")) for seed in (1, 2)]
    assert (f"(weakest density {bounded[0]:.0f} and {bounded[1]:.0f} % against "
            f"{min(one[1]):.0f} and {min(one[2]):.0f} % without the bound)") in training
    # recipe 2 with uniform draws in the exploration (seeds 1, 2)
    uniform = {}
    for seed in (0, 1, 2, 3):
        uniform[seed], _ = _assert_picked_row(raw, pair, s31 / f"pt_unif05_seed{seed}_best",
                                              s31 / f"edge_released_shield_unif05_seed{seed}",
                                              f"seed {seed}, one critic, uniform 0.05")
        assert max(uniform[seed]) < 100
    assert (f"realises {min(uniform[2]):.1f}-{max(uniform[2]):.1f} % of the +3 edge's gain at "
            "every density") in training
    mean_uniform = statistics.mean(x for v in uniform.values() for x in v)
    mean_without = statistics.mean(x for s, v in one.items() if s < 4 for x in v)
    assert (f"the mean share is {mean_uniform:.1f} % with the draws and {mean_without:.1f} % "
            "without") in training
    assert [min(uniform[s]) > min(one[s]) for s in range(4)] == [False, False, True, True]
    assert (f"(weakest density {min(uniform[3]):.0f} % against {min(one[3]):.0f} %)"
            in training)
    assert (f"and {min(uniform[0]):.0f} % against the shipped edge's {min(one[0]):.0f} %"
            in training)
    assert f"(the shipped one: {min(one[0]):.0f}-{max(one[0]):.0f} %)" in training
    top = _picking(s31 / "edge_released_shield_unif05_seed2")[1]
    assert top > shipped_score and f"its picking score, {top:.1f}, is the first" in training
    assert f"seeds 1 and 0 lose ({min(uniform[1]):.0f} % against {min(one[1]):.0f} %," in training
    mean_one = statistics.mean(x for v in one.values() for x in v)
    mean_five = statistics.mean(x for v in five.values() for x in v)
    assert (f"the mean share is {mean_five:.1f} % with five critics and {mean_one:.1f} % with "
            "one") in training
    assert (f"over training seeds 0-4 they realise {mean_five:.1f} % of its gain on average, "
            f"one critic {mean_one:.1f} %") in " ".join(README.split())
    raised = {s: [b - a for a, b in zip(one[s], five[s], strict=True)] for s in range(5)}
    assert all(sum(d > 0 for d in raised[s]) >= 4 for s in (2, 3))  # "at most densities"
    assert f"(by up to {max(max(raised[2]), max(raised[3])):.0f} points)" in training
    assert all(d < 0 for d in raised[4]) and raised[0][0] > 0 > max(raised[0][1:])
    best = max((x, s, i) for s in range(5) for i, x in enumerate(five[s]))
    assert best[0] < 100 and (best[1], best[2]) == (2, 0)  # seed 2 at 300 veh/lane/h
    assert f"(the closest: {best[0]:.1f} %, seed 2 at 300 veh/lane/h)" in training
    assert f"scores above the shipped edge's {shipped_score:.1f}" in training
    assert max(_picking(s31 / f"edge_released_shield_ens5_seed{s}")[1]
               for s in range(5)) < shipped_score

    # the critic checks: the members' mean against the constant +3; the actor's columns
    def check(seed: int) -> str:
        return (s31 / f"edge_critic_check_ens5_seed{seed}.md").read_text(encoding="utf-8")

    def probe(text: str, name: str) -> str:
        line = next(x for x in text.splitlines() if x.startswith(f"| {name} |"))
        return line.split("|")[3].strip()

    above = " / ".join(probe(check(s), "constant +3").removesuffix(" %") for s in range(5))
    assert f"in {above} % of 3600 states (seeds 0-4)" in training
    columns = {s: re.search(r"always_plus3 \((\d+) columns\)", check(s)).group(1)
               for s in range(5)}
    assert (columns[2], columns[4]) == ("14", "1")
    assert "always_minus3 (1 columns): 9" in check(2)
    assert probe(check(2), "actor: share of actions within 0.01 of +3") == "93 %"
    assert probe(check(4), "actor: share of actions within 0.01 of +3") == "52 %"

    # the learner's cost: median fps_optim, five critics (seeds 1, 2) and one (seeds 3, 4)
    def median_fps(run: Path) -> int:
        with (run / "train_log.csv").open() as fh:
            values = [float(r["fps_optim"]) for r in csv.DictReader(fh)
                      if r["fps_optim"] not in ("", "nan")]
        return round(statistics.median(values))

    ens = sorted(median_fps(s31 / f"edge_released_shield_ens5_seed{s}") for s in (1, 2))
    ones = sorted(median_fps(results / "session29" / f"edge_released_shield_sel3x3_seed{s}")
                  for s in (3, 4))
    assert (f"was {ens[0]}-{ens[1]} with five critics, two runs side by side, against "
            f"{ones[0]}-{ones[1]} with one critic") in training
    ratio = f"{statistics.mean(ones) / statistics.mean(ens):.1f}x"
    assert f"about {ratio} the update time" in training
    assert f"with five critics the updates took about {ratio} as long as with one" in training


def _one_critic_and_uniform_shares() -> tuple[dict, dict, dict, dict]:
    """Recipe 2's edges on training seeds 0-8 without and with uniform draws (p = 0.05): the
    shares of the +3 edge's gain on 3x3 seeds 0-2 per training seed and the picking scores
    per training seed, for each; every EE run merged over session 28's pair (its E and EE+3
    runs)."""
    results = ROOT / "docs" / "results" / "training"
    pair = results / "session28" / "pt_shield_pair_released" / "paper_table.csv"

    def folder(seed: int) -> Path:  # where the one-critic run of a seed is
        return results / ("session29" if seed < 5 else "session31" if seed < 7 else "session32")

    tables = {0: results / "session28" / "pt_shield_pair_released",
              **{s: folder(s) / f"pt_sel3x3_seed{s}_best" for s in range(1, 9)}}
    one = {s: _ceiling_share(_merged_cells(pair, t / "paper_table.csv"), "rv")
           for s, t in tables.items()}
    one_scores = {0: min(_picking_shares(results / "session29" / "pt_pick_seed0" /
                                         "paper_table.csv")),
                  **{s: _picking(folder(s) / f"edge_released_shield_sel3x3_seed{s}")[1]
                     for s in range(1, 9)}}
    session = {s: results / ("session31" if s < 4 else "session32") for s in range(9)}
    uniform = {s: _ceiling_share(_merged_cells(pair, session[s] / f"pt_unif05_seed{s}_best" /
                                               "paper_table.csv"), "rv") for s in range(9)}
    uniform_scores = {s: _picking(session[s] / f"edge_released_shield_unif05_seed{s}")[1]
                      for s in range(9)}
    return one, one_scores, uniform, uniform_scores


def test_session32_uniform_draws_and_shipped_edge():
    """Session 32: uniform draws on training seeds 4-8 (and p = 0.2 on seed 0), recipe 2
    without them on seeds 7-8, the seed-8 edge that learned the +3 edge and replaced the
    released shield edge, and the regenerated shipped-pair tables, from the committed files."""
    import re
    import statistics

    raw = (ROOT / "docs" / "training.md").read_text(encoding="utf-8")
    training = " ".join(raw.split())
    readme = " ".join(README.split())
    results = ROOT / "docs" / "results" / "training"
    s28, s31, s32 = (results / f"session{n}" for n in (28, 31, 32))
    pair = s28 / "pt_shield_pair_released" / "paper_table.csv"
    one, one_scores, uniform, uniform_scores = _one_critic_and_uniform_shares()
    # the new rows
    for seed, tag, label in (*((s, "unif05", f"seed {s}, one critic, uniform 0.05")
                               for s in (4, 5, 6, 7, 8)),
                             (7, "sel3x3", "seed 7, one critic"),
                             (8, "sel3x3", "seed 8, one critic"),
                             (0, "unif20", "seed 0, one critic, uniform 0.2")):
        share, score = _assert_picked_row(raw, pair, s32 / f"pt_{tag}_seed{seed}_best",
                                          s32 / f"edge_released_shield_{tag}_seed{seed}", label)
        if tag == "unif20":
            assert (f"(weakest density {min(share):.0f} % against {min(uniform[0]):.0f} %, "
                    f"picking score {score:.1f} against {uniform_scores[0]:.1f}; both far from "
                    f"seed 0's {one_scores[0]:.1f} without draws)") in training
    # over nine seeds: means, weakest densities, picking scores, which seeds gain
    means = {k: statistics.mean(x for v in d.values() for x in v)
             for k, d in (("uniform", uniform), ("one", one))}
    weakest = {k: statistics.mean(min(v) for v in d.values())
               for k, d in (("uniform", uniform), ("one", one))}
    picks = {k: statistics.mean(d.values())
             for k, d in (("uniform", uniform_scores), ("one", one_scores))}
    assert (f"realise on average {means['uniform']:.1f} % of the +3 edge's gain (seven "
            f"densities each), without them {means['one']:.1f} %; at each edge's weakest "
            f"density {weakest['uniform']:.1f} % against {weakest['one']:.1f} % on average, and "
            f"the mean picking score is {picks['uniform']:.1f} against {picks['one']:.1f}") \
        in training
    gains = [s for s in range(9) if min(uniform[s]) > min(one[s])]
    assert gains == [2, 3, 4, 6, 8]
    assert ("Five seeds of nine gain at their weakest density (2, 3, 4, 6, 8), four lose "
            "(0, 1, 5, 7)") in training
    assert [s for s, x in one_scores.items() if x > 94] == [0]
    assert [s for s, x in uniform_scores.items() if x > 94] == [2, 3, 4, 8]
    assert (f"(mean share {means['uniform']:.1f} % against {means['one']:.1f} %; at each edge's "
            f"weakest density {weakest['uniform']:.1f} % against {weakest['one']:.1f} %; five "
            "seeds gain, four lose)") in readme
    # the shipped edge: the best picking score of every run picked on 3x3 (sessions 29-32)
    picked = [_picking(run)[1] for n in (29, 31, 32)
              for run in (results / f"session{n}").glob("edge_released_shield_*")
              if (run / "eval_log.csv").exists() and "ceiling_share_pct" in
              (run / "eval_log.csv").read_text(encoding="utf-8").splitlines()[0]]
    assert len(picked) >= 25 and max(picked) == uniform_scores[8] > one_scores[0]
    assert (f"Its picking score, {uniform_scores[8]:.1f}, is the best of every run picked on "
            f"3x3 in sessions 29-32 (the replaced edge: {one_scores[0]:.1f})") in training
    assert _picking(s32 / "edge_released_shield_unif05_seed8")[0] == 30_600
    # the regenerated shipped-pair tables against session 28's, and the seed-2 edge
    new, old = ({name: _merged_cells(s / f"pt_shield_pair_released{name}" / "paper_table.csv")
                 for name in ("", "_s3to7")} for s in (s32, s28))
    seed2 = {"": _merged_cells(pair, s31 / "pt_unif05_seed2_best" / "paper_table.csv"),
             "_s3to7": _merged_cells(s28 / "pt_shield_pair_released_s3to7" / "paper_table.csv",
                                     s32 / "pt_unif05_seed2_best_s3to7" / "paper_table.csv")}

    def span(cells: dict) -> str:
        share = _ceiling_share(cells, "rv")
        return f"{min(share):.1f}-{max(share):.1f} %"

    assert (f"on seeds 0-2 it realises {span(new[''])} of the +3 edge's gain (the replaced "
            f"edge: {span(old[''])}), on seeds 3-7 {span(new['_s3to7'])} "
            f"({span(old['_s3to7'])})") in training
    assert (f"{span(new[''])} of the +3 edge's gain on seeds 0-2 and {span(new['_s3to7'])} on "
            f"seeds 3-7 (the seed-0 edge: {span(old[''])} and {span(old['_s3to7'])})") in readme
    assert (f"(picking score {uniform_scores[2]:.1f}; {span(seed2[''])} of the +3 edge's gain on "
            f"seeds 0-2, {span(seed2['_s3to7'])} on seeds 3-7,") in training
    # the shipped table's EE runs are the --edge runs of the kept policy (bit for bit)
    _assert_same_ee_runs(s32 / "pt_shield_pair_released", s32 / "pt_unif05_seed8_best")

    # where the shipped edge is at the +3 edge (gains as printed): all but 900, 0.01 short
    def short(cells: dict) -> list[float]:
        return [round(round(c, 2) - round(e, 2), 2) for e, c in zip(
            _gains(cells, "EE", "E", "rv"), _gains(cells, "EE+3", "E", "rv"), strict=True)]

    for name in ("", "_s3to7"):
        assert [(d, x) for d, x in zip(DENSITIES, short(new[name]), strict=True) if x > 0] == [
            (900, 0.01)]
    assert ("it is at or above the +3 edge at every density but 900 veh/lane/h on both seed "
            "sets, where it is 0.01 points short") in training
    # the table of the shipped pair, and its cloud
    new37 = new["_s3to7"]
    rows = (("seeds 0-2: EE vs E", _gains(new[""], "EE", "E", "rv"), "+.2f"),
            ("seeds 0-2: EE+3 vs E", _gains(new[""], "EE+3", "E", "rv"), "+.2f"),
            ("seeds 0-2: share of EE+3 [%]", _ceiling_share(new[""], "rv"), ".0f"),
            ("seeds 3-7: EE vs E", _gains(new37, "EE", "E", "rv"), "+.2f"),
            ("seeds 3-7: EE+3 vs E", _gains(new37, "EE+3", "E", "rv"), "+.2f"),
            ("seeds 3-7: share of EE+3 [%]", _ceiling_share(new37, "rv"), ".0f"),
            ("seeds 0-2: EEC vs E", _gains(new[""], "EEC", "E", "rv"), "+.2f"),
            ("seeds 0-2: EEC vs EE", _gains(new[""], "EEC", "EE", "rv"), "+.2f"),
            ("seeds 0-2: EEC+3 vs EE", _gains(new[""], "EEC+3", "EE", "rv"), "+.2f"))
    for label, values, fmt in rows:
        _assert_row(raw, label, values, fmt)
    eec = _gains(new[""], "EEC", "E", "rv")
    cloud = _gains(new[""], "EEC", "EE", "rv")
    assert (f"EEC gains {min(eec):+.2f} to {max(eec):+.2f} % over E (the paper: 0.37-2.96 %) "
            f"and {min(cloud):+.2f} to {max(cloud):+.2f} % over EE") in training
    lead = [round(a, 2) - round(b, 2) for a, b in zip(
        cloud, _gains(new[""], "EEC+3", "EE", "rv"), strict=True)]
    assert f"within {min(lead):+.2f} to {max(lead):+.2f} points of the constant" in training
    events = sum(r["collisions"] for name in ("", "_s3to7", "_per_lane", "_6000")
                 for r in read_runs_csv(s32 / f"pt_shield_pair_released{name}" /
                                        "paper_table.csv"))
    assert events == 0

    # the critic checks: the seed-8 edge is the +3 edge; seed 2 and session 28's seed 0 less so
    def check(path: Path) -> tuple[dict[str, tuple[str, str]], int]:
        text = path.read_text(encoding="utf-8")
        probes = {x.split("|")[1].strip(): (x.split("|")[2].strip(), x.split("|")[3].strip())
                  for x in text.splitlines() if x.startswith("| ") and x.count("|") == 4}
        return probes, int(re.search(r"always_plus3 \((\d+) columns\)", text).group(1))

    near = "actor: share of actions within 0.01 of +3"
    (p8, c8), (p2, c2), (p0, c0) = (check(f) for f in (
        s32 / "edge_critic_check_unif05_seed8.md", s32 / "edge_critic_check_unif05_seed2.md",
        s28 / "edge_critic_check_percol.md"))
    assert (p8[near][1], c8) == ("100 %", 15)
    assert (f"(mean difference {p8['constant +3'][0]} over 3600 states)") in training
    assert abs(float(p8["constant +3"][0])) < 1e-4
    assert (f"is within 0.01 of +3 in {p2[near][1]} of its actions ({c2} columns always +3), and "
            f"session 28's seed-0 edge in {p0[near][1]} ({c0} columns)") in training
    # the shipped edge's training curve: from near nothing to the ceiling, and settled
    start, first, later = _curve_spans(s32 / "edge_released_shield_unif05_seed8")
    assert (f"it realises {min(start):.0f}-{max(start):.0f} % of the +3 edge's gain at 0 frames, "
            f"{min(first):.0f}-{max(first):.0f} % at 10 200 frames, and "
            f"{min(later):.0f}-{max(later):.0f} % at every evaluation from there") in training


def test_session32_default_shield_edge():
    """Session 32: the default model's shield edge trained with uniform draws (seeds 0, 1),
    the seed-1 edge that replaced session 28's, and the default shipped pair's regenerated
    tables (average travel velocity), from the committed files."""
    import re

    raw = (ROOT / "docs" / "training.md").read_text(encoding="utf-8")
    training = " ".join(raw.split())
    results = ROOT / "docs" / "results" / "training"
    s28, s32 = results / "session28", results / "session32"
    pair = s28 / "pt_shield_pair_default" / "paper_table.csv"

    def shares(*tables: Path) -> list[float]:
        return _ceiling_share(_merged_cells(pair, *tables), "v")

    # the replaced edge: its shares and its picking score on the picking seeds
    picks = _merged_cells(s32 / "pt_pick_paper_shipped" / "paper_table.csv")
    old_score = min(100 * (picks[("EE", d)]["v"] / picks[("E", d)]["v"] - 1)
                    / (picks[("EE+3", d)]["v"] / picks[("E", d)]["v"] - 1)
                    for d in (900, 1500, 2100))
    assert ("| session 28's seed 0 (shipped until session 32) | "
            + " | ".join(f"{x:.0f}" for x in shares()) + f" | {old_score:.1f} |") in raw
    scores = {}
    for seed in (0, 1):
        table = s32 / f"pt_paper_unif05_seed{seed}_best" / "paper_table.csv"
        frames, scores[seed] = _picking(s32 / f"edge_paper_shield_unif05_seed{seed}")
        label = f"seed {seed}, uniform 0.05 ({frames:_} frames)".replace("_", " ")
        assert (f"| {label} | " + " | ".join(f"{x:.0f}" for x in shares(table))
                + f" | {scores[seed]:.1f} |") in raw, label
    assert scores[1] > max(scores[0], old_score)
    assert _picking(s32 / "edge_paper_shield_unif05_seed1")[0] == 40_800
    # the shipped pair's tables, new against session 28's
    new, old = ({n: _merged_cells(s / f"pt_shield_pair_default{n}" / "paper_table.csv")
                 for n in ("", "_s3to7")} for s in (s32, s28))

    def span(cells: dict) -> str:
        share = _ceiling_share(cells, "v")
        return f"{min(share):.1f}-{max(share):.1f} %"

    def at(cells: dict) -> str:
        ds = [str(d) for d, e, c in zip(DENSITIES, _gains(cells, "EE", "E", "v"),
                                        _gains(cells, "EE+3", "E", "v"), strict=True)
              if round(e, 2) >= round(c, 2)]
        return ", ".join(ds[:-1]) + " and " + ds[-1] if len(ds) > 1 else ds[0]

    assert (f"on seeds 0-2 it realises {span(new[''])} of the +3 edge's gain (the replaced "
            f"edge: {span(old[''])}), on seeds 3-7 {span(new['_s3to7'])} "
            f"({span(old['_s3to7'])})") in training
    assert all(min(_ceiling_share(new[n], "v")) > min(_ceiling_share(old[n], "v")) for n in new)
    assert (f"at or above the +3 edge at {at(new[''])} veh/lane/h on seeds 0-2 and "
            f"{at(new['_s3to7'])} on seeds 3-7; the replaced edge at {at(old[''])} (seeds 0-2) "
            f"and {at(old['_s3to7'])} (seeds 3-7)") in training
    _assert_same_ee_runs(s32 / "pt_shield_pair_default", s32 / "pt_paper_unif05_seed1_best")
    assert sum(r["collisions"] for n in ("", "_s3to7", "_6000") for r in read_runs_csv(
        s32 / f"pt_shield_pair_default{n}" / "paper_table.csv")) == 0
    n = new[""]
    for label, values, fmt in (
            ("seeds 0-2: EE vs E", _gains(n, "EE", "E", "v"), "+.2f"),
            ("seeds 0-2: EE+3 vs E", _gains(n, "EE+3", "E", "v"), "+.2f"),
            ("seeds 0-2: share of EE+3 [%]", _ceiling_share(n, "v"), ".0f"),
            ("seeds 3-7: share of EE+3 [%]", _ceiling_share(new["_s3to7"], "v"), ".0f"),
            ("seeds 0-2: EEC vs E", _gains(n, "EEC", "E", "v"), "+.2f"),
            ("seeds 0-2: EEC vs EE", _gains(n, "EEC", "EE", "v"), "+.2f"),
            ("seeds 0-2: EEC+3 vs EE", _gains(n, "EEC+3", "EE", "v"), "+.2f")):
        _assert_row(raw, label, values, fmt)
    cloud = _gains(n, "EEC", "EE", "v")
    half = PAPER_3X3["EEC vs EE"][2100] / 2
    assert round(cloud[-1], 2) >= half and all(
        round(g, 2) < PAPER_3X3["EEC vs EE"][d] / 2
        for g, d in zip(cloud[:-1], DENSITIES[:-1], strict=True))
    assert (f"EE is {min(cloud):+.2f} to {max(cloud):+.2f} % on seeds 0-2, half the paper's value "
            f"at 2100 veh/lane/h ({cloud[-1]:+.2f} % against {half:.2f} %)") in training
    lead = [round(a, 2) - round(b, 2) for a, b in zip(
        cloud, _gains(n, "EEC+3", "EE", "v"), strict=True)]
    assert f"within {min(lead):+.2f} to {max(lead):+.2f} points of the constant" in training
    # critic check and training curve of the shipped edge
    check = (s32 / "edge_critic_check_paper_unif05_seed1.md").read_text(encoding="utf-8")
    near = next(x for x in check.splitlines()
                if x.startswith("| actor: share of actions within 0.01 of +3 |")).split("|")[3]
    columns = re.search(r"always_plus3 \((\d+) columns\)", check).group(1)
    assert (f"Its actions are within 0.01 of +3 in {near.strip()} of 3600 states, {columns} of its "
            "15 columns +3 in every state probed") in training
    start, first, later = _curve_spans(s32 / "edge_paper_shield_unif05_seed1")
    assert (f"{min(start):.0f}-{max(start):.0f} % of the +3 edge's gain at 0 frames, "
            f"{min(first):.0f}-{max(first):.0f} % at 10 200 frames, "
            f"{min(later):.0f}-{max(later):.0f} % from there to 60 000 frames") in training
    assert min(later) > max(start)


#: Session 33's constant coordinators below +3, by rank (largest action first), as labelled.
_BELOW_3 = ("+3 - 2.4e-7", "+3 - 1e-4", "+3 - 0.01")


def _resolution_rows(kind: str) -> dict[str, list[float]]:
    """``ceiling_resolution.csv`` of session 33's ``kind`` run: label -> the differences from
    the +3 ceiling's gain per density [points] (the shipped policy and each constant below +3)."""
    import csv

    path = (ROOT / "docs" / "results" / "training" / "session33" / f"resolution_{kind}_released"
            / "ceiling_resolution.csv")
    by_variant: dict[str, list[float]] = {}
    with path.open() as fh:
        for r in csv.DictReader(fh):
            by_variant.setdefault(r["variant"], []).append(float(r["minus_ceiling_points"]))
    constants = sorted((v for v in by_variant if v not in ("shipped", "3.0")), key=float,
                       reverse=True)
    assert len(constants) == len(_BELOW_3) and float(constants[0]) == pytest.approx(3 - 2.4e-7)
    rows = {f"{kind}, shipped": by_variant["shipped"]}
    rows.update({f"{kind}, {label}": by_variant[v]
                 for label, v in zip(_BELOW_3, constants, strict=True)})
    return rows


def _span_points(values: list[float]) -> str:
    return f"{min(values):+.2f} to {max(values):+.2f}"


def _picking_row(run: Path, label: str) -> str:
    """A doc row: each evaluation's smallest share of the ceiling's gain [%], and the pick."""
    by_frames = _shares_by_frames(run)
    frames, score = _picking(run)
    cells = [f"{min(by_frames[f]):.0f}" if f in by_frames else "-"
             for f in range(0, 120_001, 15_000)]
    return (f"| {label} | " + " | ".join(cells)
            + f" | {score:.1f} ({frames:_} frames) |".replace("_", " "))


def test_session33_ceiling_resolution_and_stacking_audit():
    """Session 33: constant coordinators a hair below +3 against the +3 ceiling (the table's
    resolution), the stacking audits, and the clouds retrained with uniform draws, from the
    committed files."""
    import json
    import re

    raw = (ROOT / "docs" / "training.md").read_text(encoding="utf-8")
    training = " ".join(raw.split())
    s33 = ROOT / "docs" / "results" / "training" / "session33"
    rows = {**_resolution_rows("cloud"), **_resolution_rows("edge")}
    for label, values in rows.items():
        _assert_row(raw, label, values, "+.2f")
    cloud_ulp, edge_ulp = rows["cloud, +3 - 2.4e-7"], rows["edge, +3 - 2.4e-7"]
    assert f"is {_span_points(cloud_ulp)} points from the +3 cloud" in training
    readme = " ".join(README.split())
    assert (f"below +3 land {_span_points(edge_ulp)} points (edge) and "
            f"{_span_points(cloud_ulp)} points (cloud) from the +3 ceilings") in readme
    assert f"the edge's is {_span_points(edge_ulp)}" in training
    constants = [x for k, v in rows.items() if "+3 -" in k for x in v]
    shipped = rows["cloud, shipped"] + rows["edge, shipped"]
    assert min(constants) <= min(shipped) and max(shipped) <= max(constants)
    assert (f"their cells here are {_span_points(rows['cloud, shipped'])} (cloud) and "
            f"{_span_points(rows['edge, shipped'])} (edge) points") in training
    for kind in ("cloud", "edge"):
        md = (s33 / f"resolution_{kind}_released" / "ceiling_resolution.md").read_text()
        short = float(re.search(r"fall short of \+3 by at most (\S+) m/s", md).group(1))
        assert f"{short:.2g}".replace("e-07", "e-7") in training, (kind, short)
        assert f"{short:.2g}".replace("e-07", "e-7").replace("0.00012", "1.2e-4") in readme
    check = (s33 / "cloud_critic_check_shipped_shield.md").read_text(encoding="utf-8")
    assert "400 cloud states" in check and "always_plus3 (60 columns)" in check
    assert "state_dependent (0 columns)" in check
    # the committed table's cloud cells the section quotes (session 32, Intel Xeon)
    pair = _merged_cells(s33.parent / "session32" / "pt_shield_pair_released" / "paper_table.csv")
    lead = [round(a, 2) - round(b, 2) for a, b in zip(
        _gains(pair, "EEC", "EE", "rv"), _gains(pair, "EEC+3", "EE", "rv"), strict=True)]
    assert "(-0.03 to +0.02 in the committed table)" in training
    assert _span_points(lead) == "-0.03 to +0.02"
    # the stacking audits
    t2, t1, b21 = (json.loads((s33 / f"stacking_audit_{n}.json").read_text())
                   for n in ("t2", "t1", "t1_b21"))
    assert (t2["environment_steps_that_differ"], t2["environment_steps"]) == (14, 9000)
    assert t2["random_graph_check_says_exact"] and t2["nodes"] == [8]
    assert t2["all_in_real_columns"] and t2["largest_difference_mps2"] == pytest.approx(2.4e-7,
                                                                                        rel=0.01)
    assert t2["first"][0] == {"step": 77, "env": 5}  # (2100 veh/lane/h, seed 2) of 2 x 3
    assert t1["environment_steps_that_differ"] == 0 == b21["environment_steps_that_differ"]
    assert (t1["environment_steps"], b21["environment_steps"]) == (9000, 31_500)
    assert "in 14 of 9000 environment-steps" in training
    assert "nor in 31 500 environment-steps" in training
    # the clouds retrained with uniform draws, against the shipped cloud on the picking seeds
    scores = {}
    for seed in (0, 1):
        run = s33 / f"cloud_released_shield_unif05_seed{seed}"
        assert _picking_row(run, f"seed {seed}") in raw
        scores[seed] = _picking(run)[1]
    picks = _merged_cells(s33 / "pt_pick_cloud_shipped" / "paper_table.csv")
    shipped_score = min(100 * (picks[("EEC", d)]["rv"] / picks[("EE", d)]["rv"] - 1)
                        / (picks[("EEC+3", d)]["rv"] / picks[("EE", d)]["rv"] - 1)
                        for d in (900, 1500, 2100))
    assert f"The shipped cloud scores {shipped_score:.1f} on the same seeds" in training
    assert shipped_score > max(scores.values())


def test_session34_stacking_audits_of_every_shipped_policy():
    """Session 34: the one-thread stacking audits of every shipped policy (the table's rows and
    the 1x1 exception), from the committed files."""
    import json

    raw = (ROOT / "docs" / "training.md").read_text(encoding="utf-8")
    training = " ".join(raw.split())
    audits = {path.stem: json.loads(path.read_text(encoding="utf-8")) for path in
              sorted((ROOT / "docs" / "results" / "training" / "session34").glob("*.json"))}
    assert len(audits) == 11
    for name, audit in audits.items():
        assert audit["threads"] == 1 and audit["environments"] == 21, name
        assert audit["steps"] == 3000 and audit["random_graph_check_says_exact"], name
        assert ("--grid 1x1" in audit["command"]) == name.endswith("_1x1"), name
        # an edge acts on every step, a cloud every 10 steps (its training period)
        assert audit["environment_steps"] == 21 * (3000 if audit["kind"] == "edge" else 300)
    rows = {
        "edge, released model": ["edge_released"],
        "edge, default model": ["edge_paper"],
        "shield edge, released model": ["edge_released_shield"],
        "shield edge, default model": ["edge_paper_shield"],
        "cloud, released model (one graph; with the shield; per-lane graphs)":
            ["cloud_released", "cloud_released_shield", "cloud_released_per_lane"],
        "cloud, default model (one graph; with the shield; per-lane graphs)":
            ["cloud_paper", "cloud_paper_shield", "cloud_paper_per_lane"],
        "**shield edge, released model, 1x1**": ["edge_released_shield_1x1"],
    }
    assert sorted(n for names in rows.values() for n in names) == sorted(audits)
    for label, names in rows.items():
        compared = {audits[n]["environment_steps"] for n in names}
        differ = {audits[n]["environment_steps_that_differ"] for n in names}
        assert len(compared) == len(differ) == 1, label
        steps = f"{compared.pop():,}".replace(",", " ")
        steps = f"{steps} each" if len(names) > 1 else steps
        n_differ = differ.pop()
        shown = f"**{n_differ}**" if n_differ else "0"
        assert f"| {label} | {steps} | {shown} |" in raw, label
    one = audits["edge_released_shield_1x1"]
    assert one["policy"] == "mivecc_agents/pretrained/released/shield/edge.pt"
    assert one["first"][0] == {"step": 85, "env": 14} and one["all_in_real_columns"]
    assert one["largest_difference_mps2"] == pytest.approx(2.4e-7, rel=0.01)
    assert (f"{one['environment_steps_that_differ']} of its 63 000 environment-steps "
            f"({100 * one['environment_steps_that_differ'] / 63_000:.1f} %)") in training
    assert "the first at step 85 (environment 14)" in training
    later = {path.stem: json.loads(path.read_text(encoding="utf-8")) for path in sorted(
        (ROOT / "docs" / "results" / "training" / "session34" / "seeds3to7").glob("*.json"))}
    assert sorted(later) == ["cloud_released_shield", "edge_released_shield"]
    for name, audit in later.items():
        assert "--seeds 3 4 5 6 7" in audit["command"] and audit["environments"] == 35, name
        assert audit["threads"] == 1 and audit["environment_steps_that_differ"] == 0, name
    assert (later["edge_released_shield"]["environment_steps"],
            later["cloud_released_shield"]["environment_steps"]) == (105_000, 10_500)
    assert ("the released shield edge in 0 of 105 000 environment-steps, the released cloud "
            "over it (with the shield) in 0 of 10 500") in training


def test_session34_rules_only_runs_on_a_cpu_without_avx512():
    """The README tables rerun on an AVX2 CPU against the committed (AVX-512) ones."""
    import csv

    training = " ".join((ROOT / "docs" / "training.md").read_text(encoding="utf-8").split())
    here = ROOT / "docs" / "results" / "reproducibility" / "session34_avx2"

    def runs(path):
        with path.open(newline="") as fh:
            return {(r["rows"], r["scheme"], r["density"], r["seed"]): r
                    for r in csv.DictReader(fh)}

    differ: dict[tuple[str, str], int] = {}
    largest_rules_only = 0.0
    for model, published in (("released", "paper_table_released"), ("default", "paper_table")):
        # (the Coder runs, added to the default table in session 43, were not rerun then)
        a = {k: r for k, r in runs(ROOT / "docs" / "results" / published /
                                     "paper_table.csv").items() if k[1] != "coder"}
        b = runs(here / model / "paper_table.csv")
        assert a.keys() == b.keys() and len(a) == 252
        assert '"avx512f"' not in (here / model / "machine.json").read_text()
        for key in a:
            fields = ("avg_travel_velocity_mps", "released_velocity_mps")
            if any(a[key][f] != b[key][f] for f in (*fields, "collisions")):
                differ[model, key[1]] = differ.get((model, key[1]), 0) + 1
            if key[1] in ("E", "signalized", "EE+3", "EEC+3"):
                assert a[key]["collisions"] == b[key]["collisions"]
                largest_rules_only = max(largest_rules_only, *(
                    abs(float(a[key][f]) - float(b[key][f])) for f in fields))
    assert differ == {("released", "E"): 12, ("released", "signalized"): 3,
                      ("released", "EE+3"): 1, ("released", "EEC+3"): 1,
                      ("released", "EE"): 2, ("released", "EEC"): 2,
                      ("default", "signalized"): 3, ("default", "EE"): 3,
                      ("default", "EEC"): 1}
    assert f"at most {largest_rules_only:.1e} m/s in either velocity metric" in training
    assert (f"at most {largest_rules_only:.1e} m/s, and no printed figure moves"
            in " ".join(README.split()))
    assert ("Released model: E 12, signalized 3, `EE+3` 1 and `EEC+3` 1 of 42 runs each "
            "differ; default model: signalized 3 of 42") in training
    assert "released EE and EEC differ in 2 of 42 each" in training
    assert "default EE in 3 of 42" in training and "and EEC in 1 of 42" in training


def test_session46_rerun_on_the_xeon_equals_session21_in_every_column():
    """Both tables rerun in session 46 on an Intel Xeon whose policy digests equal session
    21's: every run identical to session 21's rerun in every shared column (timings aside)."""
    import json

    import table_diff

    training = " ".join((ROOT / "docs" / "training.md").read_text(encoding="utf-8").split())
    here = ROOT / "docs" / "results" / "reproducibility"
    digests = json.loads((here / "machine_session21.json").read_text())["policy_digests"]
    for model, before in (("default", "paper_table_session21.csv"),
                          ("released", "paper_table_released_session21.csv")):
        machine = json.loads((here / "session46_xeon" / model / "machine.json").read_text())
        assert machine["cpu"].startswith("Intel(R) Xeon") and not machine["git_dirty"]
        assert {k: machine["policy_digests"][k] for k in digests} == digests
        a = read_runs_csv(here / before)
        b = read_runs_csv(here / "session46_xeon" / model / "paper_table.csv")
        columns = table_diff.shared_columns(a, b)
        assert len(columns) == 36 and "min_pet_s" in columns and "throughput" in columns
        assert set(b[0]) - set(a[0]) == {"comparator_entry", "signal_keep_clear",
                                          "cloud_graphs", "safety_shield"}
        counts = table_diff.identical_runs(a, b, columns)
        assert counts == {s: (42, 42) for s in ("E", "EE", "EE+3", "EEC", "EEC+3",
                                                "signalized")}, model
        assert table_diff.differing_columns(a, b, columns) == {}
        # against the committed (AMD EPYC) table: the rules-only runs identical in every column
        published = [r for r in read_runs_csv(ROOT / "docs" / "results" / (
            "paper_table" if model == "default" else "paper_table_released") / "paper_table.csv")
            if r["scheme"] != "coder"]
        every = table_diff.identical_runs(published, b, table_diff.shared_columns(published, b))
        assert all(every[s] == (42, 42) for s in ("E", "EE+3", "signalized")), model
    assert "252 of 252 per model, learned policies included, in every one of the 36 columns" in (
        training)
    assert "equal session 21's reruns there in every column of all 504 runs" in " ".join(
        README.split())


def test_session35_stacking_audits_on_other_seeds_and_lengths():
    """Session 35's stacking audits: every row of the table in docs/training.md, and the
    times in its command block, from the committed audit files."""
    import json

    raw = (ROOT / "docs" / "training.md").read_text(encoding="utf-8")
    audits = ROOT / "docs" / "results" / "training" / "session35" / "audits"
    reports = {path.stem: json.loads(path.read_text(encoding="utf-8"))
               for path in audits.glob("*.json")}
    assert len(reports) == 10
    for name, report in reports.items():
        kind, model = name.split("_")[:2]
        assert report["kind"] == kind and report["threads"] == 1
        assert ("released" in report["policy"]) == (model == "released")
        assert ("shield" in report["command"]) == ("shield" in name)
        assert report["environment_steps_that_differ"] == 0, name
        steps, envs = (6000, 21) if name.endswith("6000") else (3000, 35)
        assert (report["steps"], report["environments"]) == (steps, envs), name
        per_env = steps if kind == "edge" else steps // 10  # the cloud decides every 10 steps
        assert report["environment_steps"] == envs * per_env, name
    for row, names in {
        "| edge, released model, seeds 3-7 | 105 000 | 0 |": ["edge_released_s3to7"],
        "| edge, default model, seeds 3-7 | 105 000 | 0 |": ["edge_paper_s3to7"],
        "| cloud, released model, seeds 3-7 | 10 500 | 0 |": ["cloud_released_s3to7"],
        "| cloud, default model, seeds 3-7 | 10 500 | 0 |": ["cloud_paper_s3to7"],
        "| edge, released model, 6000 steps | 126 000 | 0 |": ["edge_released_6000"],
        "| shield edge, released model, 6000 steps | 126 000 | 0 |":
            ["edge_released_shield_6000"],
        "| shield edge, default model, 6000 steps | 126 000 | 0 |": ["edge_paper_shield_6000"],
        "| cloud, released model, 6000 steps (one graph; with the shield) | 12 600 each | 0 |":
            ["cloud_released_6000", "cloud_released_shield_6000"],
        "| cloud, default model, 6000 steps, with the shield | 12 600 | 0 |":
            ["cloud_paper_shield_6000"],
    }.items():
        assert row in raw
        count = int(row.split("|")[2].replace("each", "").replace(" ", ""))
        assert all(reports[n]["environment_steps"] == count for n in names), row
    times = dict(line.rsplit(" ", 2)[:2] for line in (audits / "times.txt").read_text(
        encoding="utf-8").splitlines() if line.endswith(" s"))

    def span(name: str) -> str:
        minutes, seconds = divmod(round(float(times[name])), 60)
        return f"{minutes} min {seconds} s"

    block = " ".join(raw.split())
    assert f"--out runs/s35/audit/edge_released_s3to7 # {span('edge_released_s3to7')}" in block
    assert (f"--kind cloud ({span('cloud_released_s3to7')}), --model paper (edge "
            f"{span('edge_paper_s3to7')}, cloud {span('cloud_paper_s3to7')})") in block
    assert (f"--model released ({span('edge_released_6000')}, "
            f"{span('cloud_released_6000')})") in block
    assert (f"--model released ({span('edge_released_shield_6000')}, "
            f"{span('cloud_released_shield_6000')}) and --model paper "
            f"({span('edge_paper_shield_6000')}, {span('cloud_paper_shield_6000')})") in block


def test_eec_vs_coder_is_the_committed_comparison() -> None:
    """The paper's first row as the README quotes it: MiVeCC-EEC's velocity gain over Coder
    per density, from the committed comparison runs (``benchmarks/comparison.py``)."""
    import comparison

    rows = list(comparison.load_rows([ROOT / "docs" / "results" / "comparison" /
                                      "comparison.csv"]).values())
    gains = [comparison.gain(rows, (3, 3), d, "EEC", "coder") for d in DENSITIES]
    quoted = ", ".join(f"{g:+.1f} %" for g in gains)
    assert quoted in " ".join(RESULTS.split())


def test_comaddpg_paragraph_is_the_committed_comparison() -> None:
    """README's CoMADDPG figures: its velocities and EEC's at 300 and 2100 on both grids, its
    strict events (none on 1x1, 3 on 3x3; EEC 13) and its place above EEC everywhere, from
    the committed comparison; the 1x1-trained policy's events from its kept runs."""
    import comparison

    results = ROOT / "docs" / "results"
    rows = list(comparison.load_rows([results / "comparison" / "comparison.csv"]).values())
    text = " ".join(RESULTS.split())
    table = comparison.summarise(rows, [(1, 1), (3, 3)], ["EEC", "comaddpg"], DENSITIES)
    cell = {(t["grid"], t["scheme"], t["density"]): t for t in table}

    def v(grid: str, scheme: str, density: int) -> str:
        return f"{cell[grid, scheme, density]['velocity_mean_mps']:.2f}"

    assert (f"(1x1: {v('1x1', 'comaddpg', 300)} to {v('1x1', 'comaddpg', 2100)} m/s from 300 "
            f"to 2100 veh/lane/h; EEC {v('1x1', 'EEC', 300)} to {v('1x1', 'EEC', 2100)}; 3x3: "
            f"{v('3x3', 'comaddpg', 300)} to {v('3x3', 'comaddpg', 2100)}; EEC "
            f"{v('3x3', 'EEC', 300)} to {v('3x3', 'EEC', 2100)})") in text
    events = {g: sum(cell[g, "comaddpg", d]["collisions"] for d in DENSITIES) for g in ("1x1",
                                                                                    "3x3")}
    eec = sum(cell["3x3", "EEC", d]["collisions"] for d in DENSITIES)
    assert (events["1x1"], events["3x3"], eec) == (0, 3, 13)
    assert "collision-free on 1x1 and with 3 strict events over the 21 runs on 3x3 (EEC 13)" in text
    assert all(cell[g, "comaddpg", d]["velocity_mean_mps"] > cell[g, "EEC", d]["velocity_mean_mps"]
               for g in ("1x1", "3x3") for d in DENSITIES)
    first = list(comparison.load_rows(
        [results / "comaddpg" / "train_1x1" / "comparison_with_this_policy.csv"]).values())
    events_first = [t["collisions"] for t in comparison.summarise(first, [(1, 1)], ["comaddpg"],
                                                                   DENSITIES)]
    assert events_first == [0, 0, 0, 0, 3, 2, 1]
    assert "(3, 2, 1 events at 1500, 1800, 2100)" in text


def test_headroom_outside_the_fusion_is_the_committed_runs() -> None:
    """README's "Headroom outside the fusion": CoMADDPG's and EEC's gains over E on 3x3 from
    the comparison, their share of the paper's EEC vs E, and the EEC+3 ceiling's range."""
    import comparison
    import paper_table

    rows = list(comparison.load_rows([ROOT / "docs" / "results" / "comparison" /
                                      "comparison.csv"]).values())
    text = " ".join(RESULTS.split())
    mine = [comparison.gain(rows, (3, 3), d, "comaddpg", "E") for d in DENSITIES]
    assert ("gain " + " / ".join(f"{g:+.2f}" for g in mine) + " % over MiVeCC-E") in text
    paper = [paper_table.PAPER_3X3["EEC vs E"][d] for d in DENSITIES]
    shares = [round(100 * round(g, 2) / p) for g, p in zip(mine, paper, strict=True)]
    assert f"{min(shares)}-{max(shares)} % of the paper's EEC vs E" in text
    eec = [comparison.gain(rows, (3, 3), d, "EEC", "E") for d in DENSITIES]
    assert f"MiVeCC-EEC gains {eec[0]:+.2f} ... {eec[-1]:+.2f} %" in text
    cells = paper_table.cell_runs(paper_table.read_runs_csv(
        ROOT / "docs" / "results" / "paper_table" / "paper_table.csv"), "3x3")
    ceiling = [100 * (np.mean([x["avg_travel_velocity_mps"] for x in cells["EEC+3", d]])
                      / np.mean([x["avg_travel_velocity_mps"] for x in cells["E", d]]) - 1)
               for d in DENSITIES]
    assert f"(EEC+3) {min(ceiling):+.2f} ... {max(ceiling):+.2f} %" in text


def _comaddpg_seed_runs() -> tuple[dict, dict]:
    """Mean velocity and summed strict events per (policy, grid, density) of the committed
    training-seed runs, and MiVeCC-EEC's and E's mean velocity per (grid, density)."""
    import csv

    import comparison

    folder = ROOT / "docs" / "results" / "comaddpg" / "training_seeds"
    with open(folder / "learned_policies.csv", newline="", encoding="utf-8") as fh:
        runs = list(csv.DictReader(fh))
    cell: dict = {}
    for r in runs:
        key = (r["policy"], f"{r['rows']}x{r['cols']}", int(r["density"]))
        v, e = cell.get(key, ([], 0))
        cell[key] = ([*v, float(r["avg_travel_velocity_mps"])], e + float(r["collisions"]))
    cell = {k: (float(np.mean(v)), int(e)) for k, (v, e) in cell.items()}
    rows = list(comparison.load_rows([ROOT / "docs" / "results" / "comparison" /
                                      "comparison.csv"]).values())
    table = comparison.summarise(rows, [(1, 1), (3, 3)], ["E", "EEC"], DENSITIES)
    ref = {(t["scheme"], t["grid"], t["density"]): t["velocity_mean_mps"] for t in table}
    return cell, ref


def test_comaddpg_training_seeds_and_fuller_critic_are_the_committed_runs() -> None:
    """README and docs/comparators.md on CoMADDPG's training seeds and the observations critic:
    who is above MiVeCC-EEC where, the strict events, the gains over E, the training logs'
    last ten episodes; and the shipped policy's runs equal the committed comparison's."""
    import comparison

    cell, ref = _comaddpg_seed_runs()
    text = " ".join(RESULTS.split())
    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())

    def above(policy: str, grid: str) -> list[bool]:
        return [cell[policy, grid, d][0] > ref["EEC", grid, d] for d in DENSITIES]

    def events(policy: str, grid: str) -> int:
        return sum(cell[policy, grid, d][1] for d in DENSITIES)

    rows = list(comparison.load_rows([ROOT / "docs" / "results" / "comparison" /
                                      "comparison.csv"]).values())
    shipped = {(t["grid"], t["density"]): t for t in comparison.summarise(
        rows, [(1, 1), (3, 3)], ["comaddpg"], DENSITIES)}
    for (grid, d), t in shipped.items():
        assert cell["actions_seed0", grid, d] == (t["velocity_mean_mps"], t["collisions"])
    assert all(above("actions_seed0", "1x1") + above("actions_seed0", "3x3"))
    assert not any(above("actions_seed1", "1x1"))
    assert above("actions_seed1", "3x3") == [False] * 5 + [True] * 2
    assert (events("actions_seed1", "1x1"), events("actions_seed1", "3x3")) == (0, 1)
    assert above("actions_seed2", "1x1") == [True, True] + [False] * 5
    assert all(above("actions_seed2", "3x3"))
    assert (events("actions_seed2", "3x3"), cell["actions_seed2", "3x3", 2100][1],
            events("actions_seed2", "1x1")) == (58, 31, 6)
    assert "with `--seed 2` it has 58 strict events on 3x3 (31 at 2100 veh/lane/h)" in text
    assert [cell["actions_seed2", "1x1", d][1] for d in DENSITIES] == [0, 1, 0, 0, 2, 1, 2]
    assert "(on 1x1 5 of its 6 events fall at 1500 veh/lane/h and above, one at 600)" in docs
    obs = [f"observations_seed{s}" for s in range(3)]
    assert all(all(above(p, "3x3")) for p in obs)
    assert [events(p, "3x3") for p in obs] == [39, 67, 24]
    assert [events(p, "1x1") for p in obs] == [3, 5, 3]
    assert "39, 67 and 24 strict events over the 21 runs (seeds 0, 1, 2)" in docs
    assert "with 24-67 strict events there" in text
    seed1 = [cell["actions_seed1", "1x1", d][0] - ref["EEC", "1x1", d] for d in DENSITIES]
    assert f"({max(seed1):.3f} to {min(seed1):.3f} m/s)" in docs
    fastest = [cell["observations_seed1", "3x3", d][0] - ref["EEC", "3x3", d] for d in DENSITIES]
    assert f"(seed 1: {fastest[0]:+.3f} to {fastest[-1]:+.3f} m/s" in docs

    def gains(policy: str) -> str:
        g = [100 * (cell[policy, "3x3", d][0] / ref["E", "3x3", d] - 1) for d in DENSITIES]
        return f"{g[0]:+.2f} ... {g[-1]:+.2f} %"

    assert f"seed 1: {gains('actions_seed1')}; seed 2: {gains('actions_seed2')}" in text
    assert f"seed 1 gains {gains('observations_seed1')}, above the paper's EEC vs E from" in text
    g = [100 * (cell["observations_seed1", "3x3", d][0] / ref["E", "3x3", d] - 1)
         for d in DENSITIES]
    paper = PAPER_3X3["EEC vs E"]
    assert [round(x, 2) > paper[d] for x, d in zip(g, DENSITIES, strict=True)] == [
        False] * 3 + [True] * 4

    def last_ten(folder: Path) -> str:
        import csv

        with open(folder / "train_log.csv", newline="", encoding="utf-8") as fh:
            counts = [int(float(r["collisions"])) for r in list(csv.DictReader(fh))[-10:]]
        return f"{min(counts)}-{max(counts)}"

    base = ROOT / "docs" / "results" / "comaddpg"
    obs_ten = [last_ten(base / "training_seeds" / p) for p in obs]
    act_ten = [last_ten(base / "train_3x3"), *(last_ten(base / "training_seeds" /
                                                        f"actions_seed{s}") for s in (1, 2))]
    assert (f"are {obs_ten[0]}, {obs_ten[1]} and {obs_ten[2]}, against {act_ten[0]}, "
            f"{act_ten[1]} and {act_ten[2]} with the shipped critic") in docs


def _policy_cells(path: Path) -> dict:
    """(policy, density) -> (mean velocity, summed strict events, mean vehicles out) of a
    ``benchmarks/learned_policies.py`` CSV."""
    import csv

    runs: dict = {}
    with open(path, newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            runs.setdefault((r["policy"], int(r["density"])), []).append(r)
    return {k: (float(np.mean([float(x["avg_travel_velocity_mps"]) for x in v])),
                int(sum(float(x["collisions"]) for x in v)),
                float(np.mean([float(x["throughput"]) for x in v]))) for k, v in runs.items()}


def test_signal_comparators_training_seeds_are_the_committed_runs() -> None:
    """docs/comparators.md, "Training seeds of the learned signal comparators": the places of
    PA-DQN's and Coder's seeds among the signal controllers with the keep-clear rule (the
    default), EEC's lead, and the runs without the rule (Coder's collisions); the shipped
    policies' runs equal the committed comparison's."""
    import comparison

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    results = ROOT / "docs" / "results"
    rows = list(comparison.load_rows([results / "comparison" / "comparison.csv"]).values())
    signals = ["fixed-time", "actuated", "max-pressure"]
    table = comparison.summarise(rows, [(1, 1), (3, 3)], [*signals, "pa-dqn", "coder", "EEC"],
                                 DENSITIES)
    ref = {(t["grid"], t["scheme"], t["density"]): t for t in table}
    seeds = ("seed0", "seed1", "seed2")
    pa1 = _policy_cells(results / "pa_dqn" / "training_seeds" / "1x1" / "learned_policies.csv")
    pa3 = _policy_cells(results / "pa_dqn" / "training_seeds" / "3x3" / "learned_policies.csv")
    coder = _policy_cells(results / "coder" / "training_seeds" / "learned_policies.csv")
    for cells, grid, scheme in ((pa1, "1x1", "pa-dqn"), (pa3, "3x3", "pa-dqn"),
                                (coder, "3x3", "coder")):
        for d in DENSITIES:
            t = ref[grid, scheme, d]
            assert cells["seed0", d][1] == t["collisions"]  # means: to the last place or so
            assert cells["seed0", d][0] == pytest.approx(t["velocity_mean_mps"], abs=1e-12)

    def best(grid: str, d: int, key: str) -> float:
        return max(ref[grid, s, d][key] for s in signals)

    # PA-DQN 1x1: every seed first in velocity from 900 on, in throughput from 600 on
    spread = max(max(pa1[s, d][0] for s in seeds) - min(pa1[s, d][0] for s in seeds)
                 for d in DENSITIES)
    assert f"the three are within {spread:.2f} m/s of each other" in docs
    assert all(pa1[s, d][0] > best("1x1", d, "velocity_mean_mps") for s in seeds
               for d in DENSITIES[2:])
    assert all(12 * pa1[s, d][2] > best("1x1", d, "throughput_vph_mean") for s in seeds
               for d in DENSITIES[1:])
    assert all(pa1[s, d][1] == 0 for s in seeds for d in DENSITIES)
    # PA-DQN 3x3
    fixed = {d: ref["3x3", "fixed-time", d] for d in DENSITIES}
    assert all(12 * pa3["seed0", d][2] > best("3x3", d, "throughput_vph_mean")
               for d in DENSITIES[3:])
    assert all(12 * pa3[s, d][2] < fixed[d]["throughput_vph_mean"] for s in seeds[1:]
               for d in DENSITIES[3:])
    assert (f"({pa3['seed1', 2100][2]:.0f} and {pa3['seed2', 2100][2]:.0f} vehicles out at 2100 "
            f"against {fixed[2100]['throughput_vph_mean'] / 12:.0f})") in docs
    assert all(pa3[s, d][0] > fixed[d]["velocity_mean_mps"] for s in seeds for d in DENSITIES)
    above_mp = [(s, d) for s in seeds for d in DENSITIES
                if pa3[s, d][0] > ref["3x3", "max-pressure", d]["velocity_mean_mps"]]
    assert above_mp == [("seed2", 1500)]
    assert (f"seed 2 at 1500: {pa3['seed2', 1500][0]:.3f} against "
            f"{ref['3x3', 'max-pressure', 1500]['velocity_mean_mps']:.3f} m/s") in docs
    # with the rule no policy collides
    assert all(c[s, d][1] == 0 for c in (pa1, pa3, coder) for s in seeds for d in DENSITIES)
    out = [round(coder[("seed1", d)][2]) for d in DENSITIES[3:]]
    assert f"seed 1 has the fewest vehicles out from 1200 on ({min(out)}-{max(out)})" in docs

    def lead_of(cells: dict, policy: str) -> str:
        g = [100 * (ref["3x3", "EEC", d]["velocity_mean_mps"] / cells[policy, d][0] - 1)
             for d in DENSITIES]
        return f"{min(g):.0f}-{max(g):.0f} %"

    def lead(policy: str) -> str:
        return lead_of(coder, policy)

    assert (f"{lead('seed0')} with the shipped seed, {lead('seed1')} with seed 1 and "
            f"{lead('seed2')} with seed 2") in docs
    text = " ".join(RESULTS.split())
    assert (f"with seeds 1 and 2 EEC leads by {lead('seed1')[:-2]} % and "
            f"{lead('seed2')[:-2]} %;") in text
    # without the rule: Coder's seed 1 and PA-DQN's seed 2 collide, the others' runs unchanged
    pa1_off, pa3_off, coder_off = (_policy_cells(results / folder / "learned_policies.csv")
                                   for folder in ("pa_dqn/training_seeds/1x1_without_keep_clear",
                                                  "pa_dqn/training_seeds/3x3_without_keep_clear",
                                                  "coder/training_seeds/without_keep_clear"))
    assert [coder_off["seed1", d][1] for d in DENSITIES] == [0, 0, 8, 27, 26, 28, 23]
    assert "112 strict events at 900-2100 veh/lane/h (8, 27, 26, 28, 23)" in docs
    assert "without the keep-clear rule (`--set signal_keep_clear=false`) seed 1 collides, 112" \
        in text
    assert [(s, d) for s in seeds for d in DENSITIES if pa3_off[s, d][1]] == [("seed2", 1500)]
    assert pa1_off == pa1
    assert all(coder_off[s, d] == coder[s, d] for s in ("seed0", "seed2") for d in DENSITIES)
    assert all(pa3_off[s, d] == pa3[s, d] for s in ("seed0", "seed1") for d in DENSITIES)
    moved = max(abs(pa3_off["seed2", d][0] - pa3["seed2", d][0]) for d in DENSITIES)
    assert f"(its mean velocity moves by at most {moved:.3f} m/s)" in docs
    out_off = [round(coder_off[("seed1", d)][2]) for d in DENSITIES[3:]]
    assert (f"from {min(out_off)}-{max(out_off)} vehicles out at 1200-2100 instead of "
            f"{min(out)}-{max(out)} (EEC's lead {lead_of(coder_off, 'seed1')})") in docs


def test_signal_policies_trained_with_keep_clear_and_on_another_cpu() -> None:
    """docs/comparators.md, "Signal policies trained with the keep-clear rule, and on another
    CPU": the four retrained policies beside the shipped ones, their logs against the shipped
    logs, EEC's lead over each Coder."""
    import csv

    import comparison

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    results = ROOT / "docs" / "results"
    rows = list(comparison.load_rows([results / "comparison" / "comparison.csv"]).values())
    table = comparison.summarise(rows, [(3, 3)], ["EEC", "fixed-time", "actuated",
                                                  "max-pressure", "pa-dqn", "coder"], DENSITIES)
    ref = {(t["scheme"], t["density"]): t for t in table}
    pa = _policy_cells(results / "pa_dqn" / "trained_with_keep_clear_3x3" / "learned_policies.csv")
    coder = _policy_cells(results / "coder" / "trained_with_keep_clear" / "learned_policies.csv")
    names = ("shipped", "xeon_without_rule", "xeon_with_rule")
    for scheme, cells in (("pa-dqn", pa), ("coder", coder)):  # the shipped files' runs
        assert all(cells["shipped", d][0] == pytest.approx(ref[scheme, d]["velocity_mean_mps"],
                                                           abs=1e-12) for d in DENSITIES)
    assert all(c[n, d][1] == 0 for c in (pa, coder) for n in names for d in DENSITIES)

    def log(path: Path) -> list[dict]:
        with open(path, newline="", encoding="utf-8") as fh:
            return list(csv.DictReader(fh))

    def last_ten(rows: list[dict], key: str, digits: int) -> str:
        values = [float(r[key]) for r in rows[-10:]]
        return f"{min(values):.{digits}f}-{max(values):.{digits}f}"

    for folder, shipped in (("pa_dqn/trained_with_keep_clear_3x3", "pa_dqn/train_3x3"),
                            ("coder/trained_with_keep_clear", "coder/train_3x3")):
        off, on, ref_log = (log(results / f / "train_log.csv") for f in (
            f"{folder}/without_rule", f"{folder}/with_rule", shipped))
        first = {k for k in off[0] if off[0][k] != ref_log[0][k]}
        assert first == {"loss", "wall_s"}  # the first episode: only the loss (and the clock)
        assert off[0]["throughput"] != on[0]["throughput"]
        assert f"{float(on[0]['throughput']):.1f} against {float(off[0]['throughput']):.1f}" \
            in docs
    pa_off, pa_ref = (log(results / f / "train_log.csv") for f in (
        "pa_dqn/trained_with_keep_clear_3x3/without_rule", "pa_dqn/train_3x3"))
    assert (f"reward per decision {last_ten(pa_off, 'reward_per_decision', 2)}, throughput "
            f"{last_ten(pa_off, 'throughput', 0)} vehicles per environment, against "
            f"{last_ten(pa_ref, 'reward_per_decision', 2)} and "
            f"{last_ten(pa_ref, 'throughput', 0)}") in docs
    coder_off, coder_ref = (log(results / f / "train_log.csv") for f in (
        "coder/trained_with_keep_clear/without_rule", "coder/train_3x3"))
    assert (f"throughput {last_ten(coder_off, 'throughput', 0)} against "
            f"{last_ten(coder_ref, 'throughput', 0)} over the last ten episodes") in docs
    # Coder without the rule: the regional stage ends like the shipped one, the aggregation
    # stage (acting with the final regional network) far lower
    def stage_span(rows: list[dict], stage: str, last: int | None = None) -> str:
        values = [float(r["throughput"]) for r in rows if r["stage"] == stage][-(last or 99):]
        return f"{min(values):.0f}-{max(values):.0f}"

    assert (f"{stage_span(coder_off, '1', 5)} vehicles per environment over its last five "
            f"episodes against {stage_span(coder_ref, '1', 5)}, then the aggregation stage's 15 "
            f"episodes stay at {stage_span(coder_off, '2')} from the first, against "
            f"{stage_span(coder_ref, '2')})") in docs
    # PA-DQN without the rule: faster from 1200 on, fewer vehicles out at 2100
    assert all(pa["xeon_without_rule", d][0] > pa["shipped", d][0] for d in DENSITIES[3:])
    assert (f"({pa['xeon_without_rule', 2100][0]:.2f} against {pa['shipped', 2100][0]:.2f} m/s "
            f"at 2100) with fewer vehicles out ({pa['xeon_without_rule', 2100][2]:.0f} against "
            f"{pa['shipped', 2100][2]:.0f})") in docs
    # PA-DQN with the rule: fastest signal controller at 1500 and 2100, fewer out from 1200
    others = ("fixed-time", "actuated", "max-pressure")
    for d in (1500, 2100):
        assert pa["xeon_with_rule", d][0] == max(
            [pa[n, d][0] for n in names] + [ref[s, d]["velocity_mean_mps"] for s in others])
    assert all(pa["xeon_with_rule", d][2] < min(pa["shipped", d][2], pa["xeon_without_rule", d][2])
               for d in DENSITIES[3:])
    # Coder: vehicles out, EEC's lead
    def out_span(name: str) -> str:
        out = [coder[name, d][2] for d in DENSITIES]
        return f"{min(out):.0f}-{max(out):.0f}"

    assert f"({out_span('xeon_without_rule')} against {out_span('shipped')})" in docs
    assert f"control at every density ({out_span('xeon_with_rule')})" in docs
    assert all(coder["xeon_with_rule", d][2] > coder["xeon_without_rule", d][2]
               for d in DENSITIES)
    assert all(coder["xeon_with_rule", d][0] < coder["shipped", d][0] for d in DENSITIES[3:])

    def lead(name: str) -> str:
        g = [100 * (ref["EEC", d]["velocity_mean_mps"] / coder[name, d][0] - 1)
             for d in DENSITIES]
        return f"{min(g):.0f}-{max(g):.0f} %"

    assert (f"lead over it is {lead('xeon_without_rule')} (the shipped policy: "
            f"{lead('shipped')})") in docs
    assert f"EEC leads it by {lead('xeon_with_rule')}" in docs
    assert f"(EEC's lead {lead('xeon_without_rule')};" in " ".join(RESULTS.split())


def test_comaddpg_wide_critic_is_the_committed_runs() -> None:
    """docs/comparators.md: the wider fuller critic's lead over MiVeCC-EEC on 3x3, its strict
    events on both grids and its training logs' last ten episodes."""
    import csv

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    folder = ROOT / "docs" / "results" / "comaddpg" / "training_seeds"
    cells = _policy_cells(folder / "wide_critic" / "learned_policies.csv")  # 3x3 and 1x1 mixed
    with open(folder / "wide_critic" / "learned_policies.csv", newline="", encoding="utf-8") as fh:
        runs = list(csv.DictReader(fh))
    _, ref = _comaddpg_seed_runs()

    def v(policy: str, d: int) -> float:
        return float(np.mean([float(r["avg_travel_velocity_mps"]) for r in runs
                              if (r["policy"], r["rows"], int(r["density"])) == (policy, "3", d)]))

    def events(policy: str, rows: str) -> int:
        return int(sum(float(r["collisions"]) for r in runs if (r["policy"], r["rows"])
                       == (policy, rows)))

    wide = [f"observations_wide_seed{s}" for s in (0, 1)]
    lead = [v(wide[0], d) - ref["EEC", "3x3", d] for d in DENSITIES]
    assert all(v(p, d) > ref["EEC", "3x3", d] for p in wide for d in DENSITIES)
    assert f"(seed 0: {lead[0]:+.3f} to {lead[-1]:+.3f} m/s, now the fastest" in docs
    assert f"with {events(wide[0], '3')} and {events(wide[1], '3')} strict events there" in docs
    assert f"39 and 67) and {events(wide[0], '1')} and {events(wide[1], '1')} on 1x1" in docs
    assert cells  # the file parses as the benchmark writes it
    gains = [100 * (v(wide[0], d) / ref["E", "3x3", d] - 1) for d in DENSITIES]
    text = " ".join(RESULTS.split())
    assert (f"(its wider version's seed 0: up to {max(gains):+.2f} % with "
            f"{events(wide[0], '3')};") in text

    def last_ten(name: str) -> str:
        with open(folder / name / "train_log.csv", newline="", encoding="utf-8") as fh:
            counts = [int(float(r["collisions"])) for r in list(csv.DictReader(fh))[-10:]]
        return f"{min(counts)}-{max(counts)}"

    assert (f"the last ten training episodes have {last_ten(wide[0])} and {last_ten(wide[1])} "
            "collision events") in docs


def test_pa_dqn_rerun_on_another_cpu_is_the_committed_run() -> None:
    """docs/comparators.md, PA-DQN "On another CPU": the rerun's policy stays within 0.06 m/s
    of the shipped one and is the fastest signal controller from 900 veh/lane/h on; the rerun's
    log first differs in the second episode's loss and has the same summary figures."""
    import csv

    import comparison

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    folder = ROOT / "docs" / "results" / "pa_dqn"
    cells = _policy_cells(folder / "train_1x1_rerun_xeon" / "learned_policies.csv")
    gap = max(abs(cells["rerun_xeon", d][0] - cells["shipped", d][0]) for d in DENSITIES)
    assert gap < 0.06 and "stay within 0.06 m/s of the shipped policy's" in docs
    rows = list(comparison.load_rows([ROOT / "docs" / "results" / "comparison" /
                                      "comparison.csv"]).values())
    table = comparison.summarise(rows, [(1, 1)], ["fixed-time", "actuated", "max-pressure"],
                                 DENSITIES)
    best = {d: max(t["velocity_mean_mps"] for t in table if t["density"] == d)
            for d in DENSITIES}
    assert all(cells["rerun_xeon", d][0] > best[d] for d in DENSITIES[2:])
    assert all(cells["rerun_xeon", d][1] == 0 for d in DENSITIES)
    logs = []
    for path in (folder / "train_1x1_rerun_xeon" / "train_log.csv",
                 folder / "train_1x1" / "train_log.csv"):
        with open(path, newline="", encoding="utf-8") as fh:
            logs.append(list(csv.DictReader(fh)))
    differs = [i for i, (a, b) in enumerate(zip(*logs, strict=True)) if any(
        a[k] != b[k] for k in a if k != "wall_s")]
    assert differs[0] == 1 and [k for k in logs[0][1] if k != "wall_s"
                                and logs[0][1][k] != logs[1][1][k]] == ["loss"]

    def summary(log: list[dict]) -> tuple:  # as the docs round them
        last = log[-10:]
        return tuple(f"{f(float(r[key]) for r in last):.{places}f}" for key, places in (
            ("reward_per_decision", 2), ("throughput", 0)) for f in (min, max))

    assert summary(logs[0]) == summary(logs[1])


def test_keep_clear_cost_workload_is_the_committed_runs() -> None:
    """docs/comparators.md, "What the rule costs": the timed command's traffic (fixed-time,
    3x3, 2100 veh/lane/h, seeds 0-2), the same with and without the rule."""
    import csv

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    results = ROOT / "docs" / "results"
    with open(results / "comparison" / "comparison.csv", newline="", encoding="utf-8") as fh:
        runs = [r for r in csv.DictReader(fh) if (r["scheme"], r["rows"], r["density"]) == (
            "fixed-time", "3", "2100.0") and r["seed"] in ("0", "1", "2")]
    assert len(runs) == 3

    def mean(key: str) -> float:
        return float(np.mean([float(r[key]) for r in runs]))

    assert (f"per run {mean('throughput'):.1f} vehicles out, {mean('in_network'):.1f} in the "
            f"network and {mean('backlog'):.1f} waiting to enter at the end") in docs
    with open(results / "keep_clear" / "keep_clear.csv", newline="", encoding="utf-8") as fh:
        pairs = {}
        for r in csv.DictReader(fh):
            if (r["scheme"], r["rows"], r["density"]) == ("fixed-time", "3", "2100"):
                pairs.setdefault(r["seed"], set()).add(
                    (r["avg_travel_velocity_mps"], r["throughput"], r["backlog"]))
    assert len(pairs) == 3 and all(len(v) == 1 for v in pairs.values())  # rule on = off


def test_keeping_the_best_validated_network() -> None:
    """docs/comparators.md, "Keeping the best-validated network": session 46's trainings
    against session 45's (the same training, another network kept), their evaluation."""
    import csv

    import comparison

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    results = ROOT / "docs" / "results"

    def log(folder: str) -> list[dict]:
        with open(results / folder / "train_log.csv", newline="", encoding="utf-8") as fh:
            return list(csv.DictReader(fh))

    def validated(rows: list[dict], stage: str | None = None) -> list[tuple[int, float]]:
        return [(int(r["episode"]), float(r["validation_throughput"])) for r in rows
                if r["validation_throughput"] != "nan" and stage in (None, r.get("stage"))]

    # the same training as session 45's up to the end of the stage where the kept network
    # first differs: PA-DQN's whole log, Coder's regional stage
    for best, last, same_rows in (
            ("pa_dqn/keep_best_3x3/without_rule",
             "pa_dqn/trained_with_keep_clear_3x3/without_rule", 40),
            ("coder/keep_best/without_rule", "coder/trained_with_keep_clear/without_rule", 30),
            ("coder/keep_best/with_rule", "coder/trained_with_keep_clear/with_rule", 30)):
        a, b = log(best), log(last)
        columns = [c for c in b[0] if c != "wall_s"]
        equal = [all(x[c] == y[c] for c in columns) for x, y in zip(a, b, strict=True)]
        assert equal == [True] * same_rows + [False] * (len(a) - same_rows), best
    off, on, pa = (log(f) for f in ("coder/keep_best/without_rule", "coder/keep_best/with_rule",
                                    "pa_dqn/keep_best_3x3/without_rule"))
    stage1 = validated(off, "1")
    best1 = max(stage1, key=lambda v: v[1])
    assert len(stage1) == 15 and len(validated(off, "2")) == 8 and len(validated(pa)) == 20
    assert (f"moved {min(v for _, v in stage1):.1f}-{best1[1]:.1f} vehicles out over the "
            f"stage's 15 validated episodes; the last one, the network session 45 kept, "
            f"{stage1[-1][1]:.1f}, the best (episode {best1[0]}) {best1[1]:.1f}") in docs
    agg = [float(r["throughput"]) for r in off if r["stage"] == "2"][-5:]
    assert f"move {min(agg):.0f}-{max(agg):.0f} vehicles per environment over their last five" \
        in docs
    from mivecc_agents.coder import training_shortfall
    assert training_shortfall(off) is None and training_shortfall(on) is None
    with_rule = validated(on, "1")
    assert (f"its last validation {with_rule[-1][1]:.1f} against the best "
            f"{max(v for _, v in with_rule):.1f}") in docs
    pa_val = validated(pa)
    pa_best = max(pa_val, key=lambda v: v[1])
    assert (f"moved {min(v for _, v in pa_val):.1f}-{pa_best[1]:.1f} vehicles out (episodes "
            f"{pa_val[0][0]}-{pa_val[-1][0]}); it kept episode {pa_best[0]} ({pa_best[1]:.1f}; "
            f"the last network {pa_val[-1][1]:.1f})") in docs

    # the evaluation: vehicles out, EEC's lead, who is faster
    coder = _policy_cells(results / "coder" / "keep_best" / "learned_policies.csv")
    pa_cells = _policy_cells(results / "pa_dqn" / "keep_best_3x3" / "learned_policies.csv")
    rows = list(comparison.load_rows([results / "comparison" / "comparison.csv"]).values())
    ref = {(t["scheme"], t["density"]): t
           for t in comparison.summarise(rows, [(3, 3)], ["EEC"], DENSITIES)}

    def out(cells: dict, name: str) -> str:
        values = [cells[name, d][2] for d in DENSITIES]
        return f"{min(values):.0f}-{max(values):.0f}"

    def lead(name: str) -> str:
        g = [100 * (ref["EEC", d]["velocity_mean_mps"] / coder[name, d][0] - 1)
             for d in DENSITIES]
        return f"{min(g):.0f}-{max(g):.0f} %"

    assert all(c[1] == 0 for c in (*coder.values(), *pa_cells.values()))
    assert (f"lets out {out(coder, 'best_without_rule')} vehicles on seeds 0-2 against session "
            f"45's {out(coder, 'last_without_rule')} and the shipped policy's "
            f"{out(coder, 'shipped')}") in docs
    more = [coder["best_without_rule", d][2] > coder["shipped", d][2] for d in DENSITIES]
    faster = [coder["best_without_rule", d][0] > coder["shipped", d][0] for d in DENSITIES]
    assert more == [True] * 5 + [False] * 2 and faster == [True] * 3 + [False] * 4
    assert (f"leads it by {lead('best_without_rule')} (session 45's policy: "
            f"{lead('last_without_rule')}; the shipped one: {lead('shipped')})") in docs
    more = [coder["best_with_rule", d][2] > coder["last_with_rule", d][2] for d in DENSITIES]
    assert more == [False] * 3 + [True] * 4
    assert (f"lets out {out(coder, 'best_with_rule')} vehicles against "
            f"{out(coder, 'last_with_rule')} (more from 1200 veh/lane/h on, fewer below), and "
            f"EEC leads it by {lead('best_with_rule')}") in docs
    assert all(pa_cells["best_without_rule", d][2] > pa_cells["last_without_rule", d][2]
               for d in DENSITIES)
    assert [pa_cells["best_without_rule", d][0] < pa_cells["last_without_rule", d][0]
            for d in DENSITIES] == [False] * 3 + [True] * 4
    assert [pa_cells["best_without_rule", d][0] > pa_cells["shipped", d][0]
            for d in DENSITIES] == [False] + [True] * 6
    assert (f"({out(pa_cells, 'best_without_rule')} against "
            f"{out(pa_cells, 'last_without_rule')}; the shipped policy "
            f"{out(pa_cells, 'shipped')})") in docs
    assert (f"lets out {out(coder, 'best_without_rule')} vehicles against the shipped one's "
            f"{out(coder, 'shipped')} (EEC's lead {lead('best_without_rule')};") in " ".join(
        RESULTS.split())


def test_keeping_the_best_validated_network_over_training_seeds() -> None:
    """docs/comparators.md, "Three training seeds, with the keep-clear rule (the defaults), both
    ways": the same trainings, and what the kept networks change."""
    import csv

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    results = ROOT / "docs" / "results"
    pa_dir = results / "pa_dqn" / "keep_best_3x3" / "training_seeds"
    coder_dir = results / "coder" / "keep_best" / "training_seeds"

    def log(path: Path) -> list[dict]:
        with open(path / "train_log.csv", newline="", encoding="utf-8") as fh:
            return list(csv.DictReader(fh))

    for best, last, same_rows in (
            (pa_dir / "best_seed0", results / "pa_dqn" / "trained_with_keep_clear_3x3" /
             "with_rule", 40),
            (pa_dir / "best_seed1", pa_dir / "last_seed1", 40),
            (pa_dir / "best_seed2", pa_dir / "last_seed2", 40),
            (results / "coder" / "keep_best" / "with_rule",
             results / "coder" / "trained_with_keep_clear" / "with_rule", 30),
            (coder_dir / "best_seed1", coder_dir / "last_seed1", 30),
            (coder_dir / "best_seed2", coder_dir / "last_seed2", 30)):
        a, b = log(best), log(last)
        columns = [c for c in b[0] if c != "wall_s"]
        equal = [all(x[c] == y[c] for c in columns) for x, y in zip(a, b, strict=True)]
        assert equal == [True] * same_rows + [False] * (len(a) - same_rows), best
    cells = {name: _policy_cells(folder / "learned_policies.csv")
             for name, folder in (("pa", pa_dir), ("coder", coder_dir))}

    def count(name: str, index: int, better) -> int:
        c = cells[name]
        return sum(better(c[f"best_seed{s}", d][index], c[f"last_seed{s}", d][index])
                   for s in range(3) for d in DENSITIES)

    def sums(name: str) -> str:
        c = cells[name]
        return ", ".join(f"{sum(c[f'best_seed{s}', d][2] for d in DENSITIES):.0f} against "
                         f"{sum(c[f'last_seed{s}', d][2] for d in DENSITIES):.0f}"
                         for s in range(3))

    assert all(v[1] == 0 for c in cells.values() for v in c.values())  # no collision
    assert (f"(means over evaluation seeds 0-2) {sums('pa')} (PA-DQN, seeds 0, 1, 2) and "
            f"{sums('coder')} (Coder), and in {count('pa', 2, float.__gt__)} of 21 cells for "
            f"PA-DQN and {count('coder', 2, float.__gt__)} of 21 for Coder") in docs
    assert all(sum(cells[n][f"best_seed{s}", d][2] for d in DENSITIES)
               > sum(cells[n][f"last_seed{s}", d][2] for d in DENSITIES)
               for n in cells for s in range(3))
    coder, pa = cells["coder"], cells["pa"]
    assert f"(faster in {count('coder', 0, float.__gt__)} of 21 cells;" in docs
    assert all(coder[f"best_seed{s}", d][0] > coder[f"last_seed{s}", d][0]
               for s in (1, 2) for d in DENSITIES)
    assert f"which is faster in only {count('pa', 0, float.__gt__)} of 21 cells" in docs
    slower_high = sum(pa[f"best_seed{s}", d][0] < pa[f"last_seed{s}", d][0]
                      for s in range(3) for d in DENSITIES[3:])
    assert f"(slower in {slower_high} of the 12 cells from 1200 veh/lane/h on)" in docs


def test_keeping_the_best_validated_network_on_the_single_intersection() -> None:
    """docs/comparators.md, "On the single intersection it changes little"."""
    import csv

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    here = ROOT / "docs" / "results" / "pa_dqn" / "keep_best_1x1" / "training_seeds"

    def log(path: Path) -> list[dict]:
        with open(path / "train_log.csv", newline="", encoding="utf-8") as fh:
            return list(csv.DictReader(fh))

    validated = []
    for seed in range(3):
        best, last = log(here / f"best_seed{seed}"), log(here / f"last_seed{seed}")
        columns = [c for c in last[0] if c != "wall_s"]
        assert all(all(x[c] == y[c] for c in columns) for x, y in zip(best, last, strict=True))
        validated += [float(r["validation_throughput"]) for r in best
                      if r["validation_throughput"] != "nan"]
    rerun = log(ROOT / "docs" / "results" / "pa_dqn" / "train_1x1_rerun_xeon")
    columns = [c for c in rerun[0] if c != "wall_s"]
    assert all(all(x[c] == y[c] for c in columns)
               for x, y in zip(log(here / "last_seed0"), rerun, strict=True))
    c = _policy_cells(here / "learned_policies.csv")
    pairs = [(c[f"best_seed{s}", d], c[f"last_seed{s}", d]) for s in range(3) for d in DENSITIES]
    assert all(b[1] == 0 == a[1] for b, a in pairs)
    largest = max(abs(b[0] - a[0]) for b, a in pairs)
    assert (f"stay within {min(validated):.1f}-{max(validated):.1f} vehicles out, so the kept "
            f"network is about as good as the last one; over the 21 cells it lets out more in "
            f"{sum(b[2] > a[2] for b, a in pairs)}, fewer in {sum(b[2] < a[2] for b, a in pairs)}, "
            f"and is faster in {sum(b[0] > a[0] for b, a in pairs)}, by at most {largest:.2f} m/s"
            ) in docs



def test_keeping_the_best_validated_network_costs() -> None:
    """docs/comparators.md, "Keeping the best-validated network": the training times next to
    the commands are the logs' last ``wall_s``; the cost per validated episode and in all."""
    import csv

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    results = ROOT / "docs" / "results"

    def log(folder: str) -> list[dict]:
        with open(results / folder / "train_log.csv", newline="", encoding="utf-8") as fh:
            return list(csv.DictReader(fh))

    def clock(folder: str) -> str:
        seconds = round(float(log(folder)[-1]["wall_s"]))
        return f"{seconds // 60} min {seconds % 60} s"

    pa, co = "pa_dqn/keep_best_3x3", "coder/keep_best"
    ps, cs = f"{pa}/training_seeds", f"{co}/training_seeds"
    for runs, text in (
            ([f"{co}/without_rule"], "coder_off_best # {} of training"),
            ([f"{co}/with_rule"], "coder_kc_best # {} of training"),
            ([f"{pa}/without_rule"], "pa_dqn_3x3_off_best # {} of training"),
            ([f"{ps}/best_seed1", f"{ps}/best_seed0", f"{ps}/best_seed2"],
             "pa_dqn_best_seed1 # {} of training; --seed 0, 2: {}, {}"),
            ([f"{ps}/last_seed1", f"{ps}/last_seed2"],
             "pa_dqn_last_seed1 # {} of training; --seed 2: {}"),
            ([f"{cs}/best_seed1", f"{cs}/best_seed2"],
             "coder_best_seed1 # {} of training; --seed 2: {}"),
            ([f"{cs}/last_seed1", f"{cs}/last_seed2"],
             "coder_last_seed1 # {} of training; --seed 2: {}")):
        assert text.format(*(clock(r) for r in runs)) in docs, text
    one = "pa_dqn/keep_best_1x1/training_seeds"
    best = sorted(float(log(f"{one}/best_seed{s}")[-1]["wall_s"]) for s in range(3))
    last = sorted(float(log(f"{one}/last_seed{s}")[-1]["wall_s"]) for s in range(3))

    def short(seconds: float) -> str:
        seconds = round(seconds)
        return f"{seconds // 60} min {seconds % 60} s"

    assert (f"{short(best[0])}-{short(best[-1])} of training keeping the best, "
            f"{short(last[0])}-{short(last[-1])} the last") in docs
    # per episode, in the three runs: validated against not validated
    validated, plain = [], []
    for folder in (f"{co}/without_rule", f"{co}/with_rule", f"{pa}/without_rule"):
        rows = log(folder)
        wall = np.diff([0.0] + [float(r["wall_s"]) for r in rows])
        checked = np.array([r["validation_throughput"] != "nan" for r in rows])
        validated.append(wall[checked].mean())
        plain.append(wall[~checked].mean())
    assert (f"a validated episode {min(validated):.1f}-{max(validated):.1f} s against "
            f"{min(plain):.1f}-{max(plain):.1f} s in the three runs below") in docs
    ratios = []
    for best_runs, last_runs in (([f"{ps}/best_seed{s}" for s in range(3)],
                                  [f"{ps}/last_seed{s}" for s in (1, 2)]),
                                 ([f"{cs}/best_seed{s}" for s in (1, 2)],
                                  [f"{cs}/last_seed{s}" for s in (1, 2)])):
        ratios.append(np.mean([float(log(r)[-1]["wall_s"]) for r in best_runs])
                      / np.mean([float(log(r)[-1]["wall_s"]) for r in last_runs]))
    share = sorted(round(100 * (r - 1)) for r in ratios)
    assert docs.count(f"{share[0]}-{share[-1]} % more training time at the defaults") == 2


COMADDPG_TRAININGS = [f"{view}_seed{s}" for view in ("actions", "observations") for s in range(3)]
COMADDPG_VALIDATION = ("validation_collisions", "validation_reward", "validation_velocity")


def _comaddpg_log(path: Path) -> list[dict]:
    import csv

    with open(path / "train_log.csv", newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _validated_actors(folder: Path) -> tuple[str, list[dict]]:
    """``validated_actors.md``'s rules table and one dict per actor of its CSV: validation
    measures, evaluation collision events (sum) and velocities."""
    import csv

    md = (folder / "validated_actors.md").read_text(encoding="utf-8")
    table = md[md.index("| training | last |"):md.index("Over the 72")].strip()
    actors: dict = {}
    with open(folder / "validated_actors.csv", newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            a = actors.setdefault((r["training"], r["episode"]), {
                **{c: float(r[c]) for c in COMADDPG_VALIDATION}, "collisions": 0.0,
                "velocity": []})
            a["collisions"] += float(r["collisions"])
            a["velocity"].append(float(r["avg_travel_velocity_mps"]))
    assert len(actors) == 72
    return table, list(actors.values())


def _rules_row(table: str, name: str) -> list[list[str]]:
    """The cells of a training's row of a rules table (``validated_actors.md``: episode,
    events, velocity of last, best, by reward; ``validated_networks.md``: episode, vehicles
    out, backlog, velocity of last, best and the two hindsight picks)."""
    line = next(x for x in table.splitlines() if x.startswith(f"| {name} | "))
    return [c.split(" / ") for c in line.strip("| ").split(" | ")[1:]]


def test_keeping_the_best_validated_comaddpg_actor_trains_the_same() -> None:
    """docs/comparators.md, "Keeping the best-validated actor": session 48's trainings against
    the shipped policy's and the seed tables' (the same training, another actor kept); their
    clocks and the validation's cost."""
    import math

    from mivecc_agents.comaddpg import validation_key

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    results = ROOT / "docs" / "results" / "comaddpg"
    last_dirs = {"actions_seed0": results / "train_3x3",
                 **{n: results / "training_seeds" / n for n in COMADDPG_TRAININGS[1:]}}
    folder = results / "keep_best"
    table, _ = _validated_actors(folder)
    clocks, costs = [], []
    for name in COMADDPG_TRAININGS:
        best, last = _comaddpg_log(folder / name), _comaddpg_log(last_dirs[name])
        assert [{k: v for k, v in r.items() if k not in ("wall_s", *COMADDPG_VALIDATION)}
                for r in best] == [{k: v for k, v in r.items() if k != "wall_s"}
                                   for r in last], name
        rows = [r for r in best if r["validation_collisions"] != "nan"]
        assert [int(r["episode"]) for r in rows] == list(range(19, 31))
        kept = max(rows, key=lambda r: validation_key(
            {c: float(r[c]) for c in COMADDPG_VALIDATION}))
        assert _rules_row(table, name)[1][0] == kept["episode"]
        note = (folder / name / "output.txt").read_text(encoding="utf-8")
        assert f"after episode {kept['episode']}: " in note
        clocks.append(float(best[-1]["wall_s"]))
        wall = np.diff([0.0] + [float(r["wall_s"]) for r in best])
        validated = np.array([r["validation_collisions"] != "nan" for r in best])
        costs.append((wall[validated].mean() - wall[5:18].mean(),
                      12 * (wall[validated].mean() - wall[5:18].mean()) / clocks[-1]))

    def clock(seconds: float) -> str:
        seconds = round(seconds)
        return f"{seconds // 60} min {seconds % 60} s"

    assert f"({clock(min(clocks))} to {clock(max(clocks))} of training each" in docs
    low, high = min(c for c, _ in costs), max(c for c, _ in costs)
    share = math.ceil(100 * max(x for _, x in costs))  # "at most": rounded up
    assert (f"a validation run costs {low:.1f}-{high:.1f} s, at most {share} % of "
            "the training") in docs


def test_keeping_the_best_validated_comaddpg_actor_study() -> None:
    """docs/comparators.md, "Which validated actor to keep": the rules' table, the
    correlations, the reward rule."""
    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    folder = ROOT / "docs" / "results" / "comaddpg" / "keep_best"
    table, actors = _validated_actors(folder)
    assert " ".join(table.split()) in docs

    def r(x: list[float], y: list[float]) -> float:
        return float(np.corrcoef(x, y)[0, 1])

    vel = r([a["validation_velocity"] for a in actors], [np.mean(a["velocity"]) for a in actors])
    col = r([a["validation_collisions"] for a in actors], [a["collisions"] for a in actors])
    rew = r([a["validation_reward"] for a in actors], [a["validation_velocity"] for a in actors])
    assert f"(Pearson r = {vel:.2f} over the 72 actors) and its collisions too " \
           f"(r = {col:.2f})" in docs
    assert f"reward and velocity correlate with r = {rew:.2f}" in docs
    zero = [a["collisions"] for a in actors if a["validation_collisions"] == 0]
    assert f"the {len(zero)} actors with no collision in it have {min(zero):.0f} to " \
           f"{max(zero):.0f} strict events in the evaluation" in docs
    totals = table.splitlines()[-1].strip("| ").split(" | ")[1:]
    assert f"keeps {totals[2]} strict events against the velocity rule's {totals[1]}" in docs
    gaps = [float(_rules_row(table, n)[1][2]) - float(_rules_row(table, n)[2][2])
            for n in COMADDPG_TRAININGS
            if _rules_row(table, n)[1][0] != _rules_row(table, n)[2][0]]
    assert len(gaps) == 1 and f"{gaps[0]:.3f} m/s slower than the velocity rule's in the " \
           "one training where the two rules differ" in docs


def _validation_size(folder: Path) -> tuple[str, dict[str, list[str]]]:
    """``validation_size.md``'s table and its rows' cells by their first cell (N or last)."""
    md = (folder / "validation_size.md").read_text(encoding="utf-8")
    table = md[md.index("| N |"):].strip()
    rows = {line.strip("| ").split(" | ")[0]: line.strip("| ").split(" | ")[1:]
            for line in table.splitlines()[2:]}
    return table, rows


def test_how_many_comaddpg_validation_environments() -> None:
    """docs/comparators.md, "How many validation environments": the table is the committed
    study's, whose first 21 environments are every training's logged validation run, and
    every figure of its bullets."""
    import csv

    import validation_size

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    keep_best = ROOT / "docs" / "results" / "comaddpg" / "keep_best"
    table, rows = _validation_size(keep_best / "validation_size")
    assert " ".join(table.split()) in docs
    with open(keep_best / "validation_size" / "validation_size.csv", newline="",
              encoding="utf-8") as fh:
        envs: dict = {}
        for r in csv.DictReader(fh):
            envs.setdefault((r["training"], r["episode"]), []).append(r)
    for name in COMADDPG_TRAININGS:
        for row in _comaddpg_log(keep_best / name):
            if row["validation_collisions"] == "nan":
                continue
            again = validation_size.measures(envs[name, row["episode"].split(".")[0]], 21)
            assert again == {c: float(row[c]) for c in again}, (name, row["episode"])

    def total(cells: list[str]) -> tuple[str, str]:
        return tuple(cells[len(COMADDPG_TRAININGS)].split(" / "))  # type: ignore[return-value]

    def clean(cells: list[str]) -> str:
        return cells[len(COMADDPG_TRAININGS) + 1].split(" / ")[1]

    assert rows["14"][:6] == rows["21"][:6] == rows["28"][:6] != rows["7"][:6]
    assert (f"With 7 (session 47's number) the kept actors have {total(rows['7'])[0]} strict "
            f"events in the evaluation; with 14, 21 or 28 the same actors are kept in every "
            f"training, with {total(rows['21'])[0]} events (the last actors: "
            f"{total(rows['last'])[0]})") in docs
    assert (f"have {clean(rows['7'])} events in the evaluation with 7 environments, "
            f"{clean(rows['14'])} with 14, {clean(rows['21'])} with 21") in docs
    changed = [i for i in range(6) if rows["42"][i] != rows["28"][i]]
    assert [COMADDPG_TRAININGS[i] for i in changed] == ["actions_seed1"]
    was, now = rows["28"][changed[0]].split(" / "), rows["42"][changed[0]].split(" / ")
    assert (f"(episode {now[0]}: no event in the evaluation against {was[1]}, but "
            f"{float(was[2]) - float(now[2]):.3f} m/s slower), {total(rows['42'])[0]} events "
            f"with a mean velocity of {total(rows['42'])[1]} m/s against "
            f"{total(rows['21'])[1]}") in docs and now[1] == "0"
    _, short = _validation_size(keep_best / "validation_size_1000_steps")
    assert (f"keeps actors with {total(short['7'])[0]} events with 7 environments, "
            f"{total(short['14'])[0]} with 14 and {total(short['21'])[0]} with 21 (as many "
            f"steps as 7 environments of 3000, which keep {total(rows['7'])[0]})") in docs
    assert int(total(short["21"])[0]) < int(total(rows["7"])[0])


def test_keeping_the_best_validated_comaddpg_actor_beside_the_last() -> None:
    """docs/comparators.md, "The kept actors beside the last ones", and the README's
    sentence: the kept actors' evaluation (learned_policies.csv) against the last ones' and
    MiVeCC-EEC's."""
    import csv

    import comparison
    import torch

    from mivecc_agents.comaddpg import SHIPPED_PATH, CoMADDPGPolicy

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    results = ROOT / "docs" / "results" / "comaddpg"
    kept_dir = results / "keep_best"
    names = COMADDPG_TRAININGS
    for name, last in (("actions_seed0", SHIPPED_PATH),
                       ("observations_seed0",
                        results / "training_seeds" / "observations_seed0" / "comaddpg.pt")):
        a = CoMADDPGPolicy.load(kept_dir / name / "comaddpg.pt").actor.state_dict()
        b = CoMADDPGPolicy.load(last).actor.state_dict()
        assert all(torch.equal(a[k], b[k]) for k in a), name  # kept its last actor
    cell: dict = {}
    with open(kept_dir / "learned_policies.csv", newline="", encoding="utf-8") as fh:
        for x in csv.DictReader(fh):
            cell.setdefault((x["policy"], int(x["rows"]), int(x["density"])), []).append(x)

    def velocity(policy: str, grid: int, density: int) -> float:
        return float(np.mean([float(x["avg_travel_velocity_mps"])
                              for x in cell[policy, grid, density]]))

    def events(policy: str, grid: int) -> int:
        return int(sum(float(x["collisions"]) for d in DENSITIES
                       for x in cell[policy, grid, d]))

    rows = list(comparison.load_rows([ROOT / "docs/results/comparison/comparison.csv"]).values())
    eec = {(g, t["density"]): t["velocity_mean_mps"] for g in (1, 3)
           for t in comparison.summarise(rows, [(g, g)], ["EEC"], DENSITIES)}
    above = {(n, g): [d for d in DENSITIES if velocity(f"best_{n}", g, d) > eec[g, d]]
             for n in names for g in (1, 3)}
    assert all(len(above[n, g]) == 7 for n in names[:2] for g in (1, 3))
    assert not [d for d in DENSITIES if velocity("last_actions_seed1", 1, d) > eec[1, d]]
    assert above["actions_seed2", 3] == [300, 600, 900] and above["actions_seed2", 1] == [300]
    assert "seed 2's (episode 20) only at 300-900 veh/lane/h on 3x3 and at 300 on 1x1" in docs
    assert "seed 2's safer actor only at 300-900 veh/lane/h on 3x3 and 300 on 1x1" in readme
    assert all(len(above[n, 3]) == 7 for n in names[3:])
    assert [len(above[n, 1]) for n in names[3:]] == [4, 7, 7]
    assert [d for d in DENSITIES if d not in above["observations_seed0", 1]] == [1200, 1500, 1800]
    assert "on 1x1 but for seed 0 at 1200-1800 veh/lane/h (its last actor)" in docs
    faster = {n: [sum(velocity(f"best_{n}", g, d) > velocity(f"last_{n}", g, d)
                      for d in DENSITIES) for g in (1, 3)]
              for n in ("actions_seed1", "actions_seed2", "observations_seed1",
                        "observations_seed2")}
    assert faster == {"actions_seed1": [7, 7], "actions_seed2": [0, 0],
                      "observations_seed1": [0, 0], "observations_seed2": [7, 7]}
    for g, text in ((1, "{} m/s on 1x1"), (3, "{} on 3x3")):
        for prefix in ("best", "last"):
            v = sorted(velocity(f"{prefix}_{n}", g, 2100) for n in names[:3])
            assert f"{v[0]:.3f}-{v[-1]:.3f}" in docs
        best = sorted(velocity(f"best_{n}", g, 2100) for n in names[:3])
        assert text.format(f"{best[0]:.3f}-{best[-1]:.3f}") in docs
    pairs = {g: [f"{events(f'last_{n}', g)} -> {events(f'best_{n}', g)}" for n in names]
             for g in (1, 3)}
    assert all(events(f"best_{n}", g) <= events(f"last_{n}", g) for n in names for g in (1, 3))
    assert (f"seed 0 {pairs[3][0]}, seed 1 {pairs[3][1]}, seed 2 {pairs[3][2]}; on 1x1 "
            f"{', '.join(pairs[1][:3])}. With the fuller critic: {', '.join(pairs[3][3:])} on "
            f"3x3 and {', '.join(pairs[1][3:])} on 1x1") in docs
    kept3, last3 = (sum(events(f"{p}_{n}", 3) for n in names) for p in ("best", "last"))
    kept1, last1 = (sum(events(f"{p}_{n}", 1) for n in names) for p in ("best", "last"))
    assert (f"the kept actors have {kept3} strict events on 3x3 against {last3}, {kept1} on "
            f"1x1 against {last1}") in docs
    assert ("strict events on 3x3 go from "
            f"{', '.join(str(events(f'last_{n}', 3)) for n in names[:3])} to "
            f"{', '.join(str(events(f'best_{n}', 3)) for n in names[:3])}") in readme


def test_every_validated_pa_dqn_network() -> None:
    """docs/comparators.md, "Every validated PA-DQN network": the committed study's table, its
    networks' validation figures are the seed table's logged validation runs (the trainings
    rerun with --save-validated), and every figure of its bullets."""
    import csv

    from mivecc_agents.signal_dqn import kept_episodes

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    seeds_dir = ROOT / "docs" / "results" / "pa_dqn" / "keep_best_3x3" / "training_seeds"
    folder = seeds_dir / "validated_networks"
    md = (folder / "validated_networks.md").read_text(encoding="utf-8")
    table = md[md.index("| training | last |"):md.index("Over the 60")].strip()
    assert " ".join(table.split()) in docs
    with open(folder / "validated_networks.csv", newline="", encoding="utf-8") as fh:
        runs = list(csv.DictReader(fh))
    trainings = [f"pa_dqn_seed{s}" for s in range(3)]
    networks: dict = {}
    for r in runs:
        n = networks.setdefault((r["training"], int(r["episode"])), {
            "validation": float(r["validation_throughput"]), "runs": []})
        n["runs"].append(r)
    assert sorted(networks) == [(t, e) for t in trainings for e in range(21, 41)]
    for s, t in enumerate(trainings):  # the trainings are the seed table's (same validation)
        with open(seeds_dir / f"best_seed{s}" / "train_log.csv", newline="",
                  encoding="utf-8") as fh:
            log = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(fh)]
        logged = {int(r["episode"]): r["validation_throughput"] for r in log
                  if r["validation_throughput"] == r["validation_throughput"]}
        assert logged == {e: networks[t, e]["validation"] for e in range(21, 41)}
        assert _rules_row(table, t)[1][0] == str(kept_episodes(log)[0][1])
    for n in networks.values():
        assert len(n["runs"]) == 21
        n["out"], n["backlog"], n["velocity"] = (float(np.mean([float(r[k]) for r in n["runs"]]))
                                                 for k in ("throughput", "backlog",
                                                           "avg_travel_velocity_mps"))

    def r(x: str, y: str) -> str:
        pairs = [(n[x], n[y]) for n in networks.values()]
        return f"{np.corrcoef(np.array(pairs).T)[0, 1]:.2f}"

    assert f"correlate with Pearson r = {r('validation', 'out')}." in docs
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    assert (f"predict the evaluation's (Pearson r = {r('validation', 'out')} over "
            f"{len(networks)} networks), and the evaluation's velocity falls as its vehicles "
            f"out rise (r = {r('out', 'velocity')})") in readme
    assert (f"correlate with r = {r('out', 'velocity')} over the networks (validation vehicles "
            f"out and evaluation velocity: r = {r('validation', 'velocity')})") in docs
    picks = {t: _rules_row(table, t) for t in trainings}

    def listed(values: list[float], digits: int) -> str:
        return f"{values[0]:.{digits}f}, {values[1]:.{digits}f} and {values[2]:.{digits}f}"

    gap = [float(picks[t][2][1]) - float(picks[t][1][1]) for t in trainings]
    gain = [float(picks[t][1][1]) - float(picks[t][0][1]) for t in trainings]
    loss = [float(picks[t][0][3]) - float(picks[t][1][3]) for t in trainings]
    assert min(loss) > 0
    assert (f"lets out {listed(gap, 1)} fewer vehicles per run than the best network in "
            f"hindsight (seeds 0, 1, 2) and {listed(gain, 1)} more than the last one") in docs
    assert f"slower than the last one at every seed (by {listed(loss, 3)} m/s)" in docs
    fast_out, fast_backlog = [], []
    for t in trainings:
        own = {e: n for (tt, e), n in networks.items() if tt == t}
        fast = max(own, key=lambda e: own[e]["velocity"])
        assert picks[t][3][0] == str(fast)
        assert sorted(own, key=lambda e: own[e]["out"]).index(fast) <= 1  # fewest or 2nd
        assert sorted(own, key=lambda e: -own[e]["backlog"]).index(fast) <= 1
        fast_out.append(own[fast]["out"])
        fast_backlog.append(own[fast]["backlog"])
    assert (f"({listed(fast_out, 1)} vehicles out; {listed(fast_backlog, 1)} waiting to "
            "enter)") in docs

    def run(episode: int) -> dict:
        return next(x for x in networks["pa_dqn_seed0", episode]["runs"]
                    if (x["density"], x["seed"]) == ("1500", "0"))

    fast, kept = run(30), run(26)
    assert picks["pa_dqn_seed0"][3][0] == "30" and picks["pa_dqn_seed0"][1][0] == "26"
    assert (f"episode 30) reaches {float(fast['avg_travel_velocity_mps']):.2f} m/s with "
            f"{float(fast['throughput']):.0f} vehicles out and {float(fast['backlog']):.0f} "
            f"waiting to enter, the one the training keeps (episode 26) "
            f"{float(kept['avg_travel_velocity_mps']):.2f} m/s with "
            f"{float(kept['throughput']):.0f} out and {float(kept['backlog']):.0f} waiting") in docs



def test_what_comaddpg_validation_leaves_is_in_the_actors() -> None:
    """docs/comparators.md, "What is left is in the actors, not in the pick": the kept actors
    with 21 validation environments against each training's best validated actor in
    hindsight, from the committed evaluation."""
    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    folder = ROOT / "docs" / "results" / "comaddpg" / "keep_best"
    _, rows = _validation_size(folder / "validation_size")
    kept_episodes = [cell.split(" / ")[0] for cell in rows["21"][:len(COMADDPG_TRAININGS)]]
    import csv

    events: dict = {}
    with open(folder / "validated_actors.csv", newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            key = (r["training"], r["episode"])
            events.setdefault(key, [float(r["validation_collisions"]), 0.0])[1] += float(
                r["collisions"])
    kept, best, colliding = [], [], []
    for name, episode in zip(COMADDPG_TRAININGS, kept_episodes, strict=True):
        own = [v for (t, _), v in events.items() if t == name]
        kept.append(events[name, episode][1])
        best.append(min(e for _, e in own))
        if min(v for v, _ in own) > 0:
            colliding.append((min(v for v, _ in own), kept[-1]))
    gaps = [k - b for k, b in zip(kept, best, strict=True)]
    assert min(gaps) >= 0
    assert (f"kept actor has at most {max(gaps):.0f} strict events more in the evaluation than "
            f"the best of its validated actors in hindsight (the fewest events any of them "
            f"has: {sum(best):.0f} over the six trainings against the kept actors' "
            f"{sum(kept):.0f},") in docs
    words = {1: "One", 2: "Two", 3: "Three", 4: "Four", 5: "Five", 6: "Six"}
    assert (f"{words[len(colliding)]} of the six trainings have no actor without a validation "
            f"collision ({min(v for v, _ in colliding):.0f} to "
            f"{max(v for v, _ in colliding):.0f} events at best), and they carry "
            f"{sum(k for _, k in colliding):.0f} of the {sum(kept):.0f} events") in docs


def test_a_recipe_sweep_of_pa_dqn() -> None:
    """docs/comparators.md, "A recipe sweep of PA-DQN": the committed sweep's table, its
    default trainings are the 1x1 training-seed trainings, and the bullets' figures."""
    import csv
    from collections import defaultdict

    from mivecc_agents.signal_dqn import kept_episodes

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    folder = ROOT / "docs" / "results" / "pa_dqn" / "recipe_sweep_1x1"
    md = (folder / "signal_sweep.md").read_text(encoding="utf-8")
    assert " ".join(md[md.index("| variant |"):].split()) in docs
    with open(folder / "signal_sweep.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    scores: dict = defaultdict(list)
    for r in rows:
        scores[r["variant"]].append(float(r["kept_validation_throughput"]))
    seeds_dir = ROOT / "docs" / "results" / "pa_dqn" / "keep_best_1x1" / "training_seeds"
    for r in (r for r in rows if r["variant"] == "default"):
        with open(seeds_dir / f"best_seed{r['seed']}" / "train_log.csv", newline="",
                  encoding="utf-8") as fh:
            log = [{k: float(v) for k, v in x.items()} for x in csv.DictReader(fh)]
        (_, episode, kept, _), = kept_episodes(log)
        assert (int(r["kept_episode"]), float(r["kept_validation_throughput"])) == (episode,
                                                                                    kept)
    base = np.mean(scores["default"])
    gain = {v: np.mean(x) - base for v, x in scores.items()}
    spread = max(scores["default"]) - min(scores["default"])
    best = max(gain, key=gain.get)
    assert best == "eps_0.25" and 0 < gain[best] <= spread
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    number_words = {8: "eight"}
    assert (f"none of {number_words[len(gain) - 1]} one-setting changes beats it beyond its "
            "own seed spread") in readme
    losers = sorted((v for v in gain if gain[v] < -spread), key=gain.get)
    assert losers == ["period_20", "gamma_0.99", "lr_3e-4"]
    assert (f"by more than the spread of the default's own seeds ({spread:.1f} vehicles): the "
            f"best, `eps_0.25` (the exploration decays over a quarter of the decisions instead "
            f"of half), by {gain[best]:.1f}. Three changes lose more than that: a 20 s decision "
            f"period ({gain['period_20']:.1f}), gamma 0.99 ({gain['gamma_0.99']:.1f}) and a "
            f"learning rate of 3e-4 ({gain['lr_3e-4']:.1f})") in docs
    out, velocity = _runs_by_policy(folder)

    def total(table: dict, policy: str) -> float:
        return sum(np.mean(v) for v in table[policy].values())

    more = [total(out, f"eps_0.25_seed{s}") - total(out, f"default_seed{s}") for s in range(3)]
    faster = [(total(velocity, f"eps_0.25_seed{s}") - total(velocity, f"default_seed{s}")) / 7
              for s in range(3)]
    words = [f"{abs(d):.1f} {'more' if d > 0 else 'fewer'}" for d in more]
    assert (f"`eps_0.25` lets out {words[0]}, {words[1]} and {words[2]} vehicles than the "
            f"default at training seeds 0, 1 and 2, with a mean velocity over the densities "
            f"higher by {faster[0]:.3f}, {faster[1]:.3f} and {faster[2]:.3f} m/s") in docs


def test_the_validated_pa_dqn_trainings_are_the_seed_tables() -> None:
    """docs/comparators.md, "Every validated PA-DQN network": the --save-validated reruns'
    logs equal the committed keep-best trainings' but for the clock; their training times and
    closing lines."""
    import csv

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    seeds_dir = ROOT / "docs" / "results" / "pa_dqn" / "keep_best_3x3" / "training_seeds"
    clocks = []
    for s in range(3):
        logs = []
        for path in (seeds_dir / "validated_networks" / f"pa_dqn_seed{s}",
                     seeds_dir / f"best_seed{s}"):
            with open(path / "train_log.csv", newline="", encoding="utf-8") as fh:
                logs.append(list(csv.DictReader(fh)))
        rerun, committed = logs
        assert [{k: v for k, v in r.items() if k != "wall_s"} for r in rerun] == [
            {k: v for k, v in r.items() if k != "wall_s"} for r in committed]
        clocks.append(round(float(rerun[-1]["wall_s"])))
        closing = (seeds_dir / "validated_networks" / f"pa_dqn_seed{s}" / "output.txt"
                   ).read_text(encoding="utf-8")
        assert "kept the network of the best greedy validation run" in closing

    def clock(seconds: int) -> str:
        return f"{seconds // 60} min {seconds % 60} s"

    assert f"({clock(min(clocks))} to {clock(max(clocks))} of training, seeds 0 and 1" in docs


def test_a_recipe_sweep_of_pa_dqn_on_3x3() -> None:
    """docs/comparators.md, "On 3x3 the recipe is not on a plateau": the committed sweep's
    table, its default trainings are the 3x3 seed table's, and the evaluation's figures."""
    import csv

    from mivecc_agents.signal_dqn import kept_episodes

    docs = " ".join((ROOT / "docs" / "comparators.md").read_text(encoding="utf-8").split())
    folder = ROOT / "docs" / "results" / "pa_dqn" / "recipe_sweep_3x3"
    md = (folder / "signal_sweep.md").read_text(encoding="utf-8")
    assert " ".join(md[md.index("| variant |"):].split()) in docs
    seeds_dir = ROOT / "docs" / "results" / "pa_dqn" / "keep_best_3x3" / "training_seeds"
    with open(folder / "signal_sweep.csv", newline="", encoding="utf-8") as fh:
        for r in (r for r in csv.DictReader(fh) if r["variant"] == "default"):
            with open(seeds_dir / f"best_seed{r['seed']}" / "train_log.csv", newline="",
                      encoding="utf-8") as log_fh:
                log = [{k: float(v) for k, v in x.items()} for x in csv.DictReader(log_fh)]
            (_, episode, kept, _), = kept_episodes(log)
            assert (int(r["kept_episode"]), float(r["kept_validation_throughput"])) == (
                episode, kept)
    out, velocity = _runs_by_policy(folder)
    texts = {}
    for variant in ("period_5", "eps_0.25"):
        more, faster = [], []
        for s in (0, 1):
            p, d = out[f"{variant}_seed{s}"], out[f"default_seed{s}"]
            assert all(np.mean(p[k]) > np.mean(d[k]) for k in d)  # at every density
            more.append(sum(np.mean(v) for v in p.values()) - sum(np.mean(v) for v in d.values()))
            pv, dv = velocity[f"{variant}_seed{s}"], velocity[f"default_seed{s}"]
            faster.append(np.mean([np.mean(v) for v in pv.values()])
                          - np.mean([np.mean(v) for v in dv.values()]))
        assert min(faster) > 0  # README: "at a higher mean velocity"
        texts[variant] = (f"{more[0]:.1f} and {more[1]:.1f}", f"{faster[0]:.3f} and "
                          f"{faster[1]:.3f}")
    assert (f"a 5 s decision period lets out {texts['period_5'][0]} more vehicles than the "
            f"default at training seeds 0 and 1 with a mean velocity higher by "
            f"{texts['period_5'][1]} m/s, `eps_0.25` {texts['eps_0.25'][0]} more at "
            f"{texts['eps_0.25'][1]} m/s higher") in docs
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    assert ("on 3x3 it does not: a 5 s decision period lets out more vehicles at every "
            "density, at a higher mean velocity") in readme
    at_2100 = [(np.mean(velocity[p][2100]), np.mean(out[p][2100])) for p in velocity]
    assert max(v for v, _ in at_2100) < 5.0 and max(o for _, o in at_2100) < 690


def _runs_by_policy(folder: Path) -> tuple[dict, dict]:
    """``learned_policies.csv`` of ``folder``: policy -> density -> the runs' vehicles out, and
    the same for their average travel velocities [m/s]."""
    import csv
    from collections import defaultdict

    out: dict = defaultdict(lambda: defaultdict(list))
    velocity: dict = defaultdict(lambda: defaultdict(list))
    with open(folder / "learned_policies.csv", newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            out[r["policy"]][int(r["density"])].append(float(r["throughput"]))
            velocity[r["policy"]][int(r["density"])].append(float(r["avg_travel_velocity_mps"]))
    return out, velocity
