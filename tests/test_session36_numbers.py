"""Session 36's numbers in the docs, recomputed from the committed files.

Every timing the docs quote was measured again with ``benchmarks/time_commands.py`` (whole
processes, paired), its report, per-run figures and the commands' own output (the vehicles each
side carried) committed under ``docs/results/training/session36/timing/``; the last stacking
audits are under ``docs/results/training/session36/audits/``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
S36 = ROOT / "docs" / "results" / "training" / "session36"
TIMING = S36 / "timing"


def _flat(path: Path) -> str:
    """A Markdown file's text with every run of whitespace made one space."""
    return " ".join(path.read_text(encoding="utf-8").split())


TRAINING = _flat(ROOT / "docs" / "training.md")
README = _flat(ROOT / "README.md")
PERFORMANCE = _flat(ROOT / "docs" / "performance.md")


def wall_spreads(name: str) -> dict[str, tuple[float, float, float]]:
    """(min, median, max) of the wall seconds of A and B and of the paired ratios A/B of a
    timing report (its rows ``A wall s``, ``B wall s``, ``A/B wall``)."""
    out = {}
    for line in (TIMING / f"{name}.txt").read_text(encoding="utf-8").splitlines():
        if line.startswith(("A wall", "B wall", "A/B wall")):
            words = line.split()
            low, median, high = (float(x) for x in words[-3:])
            out[words[0]] = (low, median, high)
    return out


def medians(name: str) -> dict[str, float]:
    """Median wall seconds of A and B and the median paired ratio A/B of a timing report."""
    return {side: spread[1] for side, spread in wall_spreads(name).items()}


def ratio_cell(name: str) -> str:
    """``median (min-max)`` of a report's paired wall ratios, as the docs' tables write it."""
    low, median, high = wall_spreads(name)["A/B"]
    return f"{median:.2f} ({low:.2f}-{high:.2f})"


def commands(name: str) -> tuple[str, str | None]:
    """The commands A and B of a timing report."""
    lines = (TIMING / f"{name}.txt").read_text(encoding="utf-8").splitlines()
    b = lines[1][4:] if lines[1].startswith("B = ") else None
    return lines[0][4:], b


def log_json(name: str) -> list[dict]:
    """Every JSON object a timed command printed, in run order (A and B in turn, warm-up
    first)."""
    text = (TIMING / f"{name}.log").read_text(encoding="utf-8")
    decoder, objects, at = json.JSONDecoder(), [], 0
    while (start := text.find("{", at)) >= 0:
        obj, at = decoder.raw_decode(text, start)
        objects.append(obj)
    return objects


def log_tables(name: str, key: str) -> list[list[float]]:
    """The per-seed values of ``key`` in every ``mivecc evaluate`` table of a timing log."""
    rows = re.findall(rf"^{key}\s+(.+)$", (TIMING / f"{name}.log").read_text(encoding="utf-8"),
                      flags=re.MULTILINE)
    return [[float(x) for x in row.split()[:-1]] for row in rows]  # the last column: the mean


def seconds(value: float) -> str:
    """``value`` seconds written as the docs write a command's time (``52 s``, ``2 min 5 s``)."""
    minutes, rest = divmod(round(value), 60)
    return f"{minutes} min {rest} s" if minutes else f"{rest} s"


def test_shield_cost_table():
    """docs/performance.md, "The safety shield's cost": medians, ratios and the vehicles each
    side carried, from the reports and the commands' JSON."""
    for model in ("default", "released"):
        name = f"shield_cost_{model}"
        walls = medians(name)
        a, b = commands(name)
        assert a.endswith("safety_shield=true") and "safety_shield" not in b
        assert ("model=released" in b) == (model == "released")
        low, median, high = wall_spreads(name)["A/B"]
        runs = log_json(name)
        assert len(runs) == 16  # a warm-up pair and 7 counted pairs
        fields = ("arrived", "throughput", "in_network", "collided_vehicles")
        sides = [{tuple(int(r[f]) for f in fields) for r in runs[i::2]} for i in (0, 1)]
        assert all(len(side) == 1 for side in sides), name  # every run of a side the same
        workload = " / ".join(", ".join(map(str, side.pop())) for side in sides)
        row = (f"| {model} | {walls['A']:.3f} | {walls['B']:.3f} | {median:.3f} "
               f"({low:.3f}-{high:.3f}) | {workload} |")
        assert row in PERFORMANCE, row


def _per_env(name: str) -> dict[tuple[str, ...], dict[str, str]]:
    import csv

    with (TIMING / f"paper_table_per_env_{name}.csv").open(newline="") as fh:
        return {(r["rows"], r["scheme"], r["density"], r["seed"]): r for r in csv.DictReader(fh)}


def test_per_environment_call_timings_and_their_same_runs():
    """docs/training.md, "What the per-environment calls cost": each row's medians and paired
    ratio, the runs identical both ways (table_diff) and the vehicles carried."""
    rows = {
        "3x3 EE table, released shield edge, one worker": ("per_env_calls_ee_shield_released",
                                                           "ee_shield", 21),
        "the default model's README table": ("per_env_calls_default_table", "default", 252),
        "the released model's README table": ("per_env_calls_released_table", "released", 252),
    }
    for label, (name, diff, runs) in rows.items():
        walls = medians(name)
        a, b = commands(name)
        assert a == f"{b.rsplit(' --out ', 1)[0]} --per-env-calls --out {a.rsplit(' --out ', 1)[1]}"
        assert ("--model released" in a) == (diff != "default")
        table_diff = (TIMING / f"table_diff_{diff}.md").read_text(encoding="utf-8")
        schemes = re.findall(r"^\| ([\w+]+) \| (\d+) / (\d+) \|$", table_diff, flags=re.M)
        assert schemes and all(same == total for _, same, total in schemes), diff
        assert sum(int(total) for _, _, total in schemes) == runs == len(_per_env(diff))
        row = (f"| {label}: `--per-env-calls` against stacked | {walls['A']:.1f} | "
               f"{walls['B']:.1f} | {ratio_cell(name)} | {runs} of {runs} runs "
               f"(`table_diff_{diff}.md`) |")
        assert row in TRAINING, row

    def total(name: str, key: str) -> str:
        return f"{round(sum(float(r[key]) for r in _per_env(name).values())):,}".replace(",", " ")

    assert (f"{total('ee_shield', 'arrived')} arrived and {total('ee_shield', 'in_network')} in "
            "the network at the end, summed over the 21 EE runs") in TRAINING
    assert (f"{total('default', 'arrived')} / {total('default', 'in_network')} (default) and "
            f"{total('released', 'arrived')} / {total('released', 'in_network')} (released) over "
            f"the 252 runs of each README table, with {total('default', 'backlog')} waiting"
            ) in TRAINING
    assert total("default", "backlog") == total("released", "backlog")
    default, released = medians("per_env_calls_default_table"), medians(
        "per_env_calls_released_table")
    assert (f"stacking saves {100 * (1 - default['B'] / default['A']):.0f} % (default) and "
            f"{100 * (1 - released['B'] / released['A']):.0f} % (released)") in TRAINING


def test_evaluate_stacking_timings_and_the_readme():
    for scheme, name in (("EE", "evaluate_ee_stack"), ("EEC", "evaluate_eec_stack")):
        a, b = commands(name)
        assert b == f"{a} --stack-policies" and a.endswith(f"--scheme {scheme}")
        walls = medians(name)
        label = ("`mivecc evaluate --scheme EE` (README, 3 seeds)" if scheme == "EE"
                 else "`mivecc evaluate --scheme EEC` (3 seeds)")
        row = (f"| {label}: default against `--stack-policies` | {walls['A']:.1f} | "
               f"{walls['B']:.1f} | {ratio_cell(name)} | every printed figure of seeds 0-2, in "
               "all 8 runs |")
        assert row in TRAINING, row
        for key in ("arrived", "in_network", "avg_travel_velocity_mps",
                    "released_velocity_mps", "collisions"):
            values = log_tables(name, key)
            assert len(values) == 8 and all(v == values[0] for v in values), (name, key)
    ee, eec = medians("evaluate_ee_stack"), medians("evaluate_eec_stack")
    assert f"--seeds 0 1 2 # {ee['A']:.0f} s" in README
    assert f"--cloud-checkpoint runs/cloud/cloud.pt # {eec['A']:.0f} s" in README
    assert f"--stack-policies: {ee['B']:.0f} s and {eec['B']:.0f} s" in README
    arrived = [f"{a:.0f} / {n:.0f}" for a, n in zip(log_tables("evaluate_ee_stack", "arrived")[0],
                                                  log_tables("evaluate_ee_stack", "in_network")[0],
                                                  strict=True)]
    assert f"in the network at the end {arrived[0]}, {arrived[1]} (EEC: 235) and" in TRAINING
    assert log_tables("evaluate_eec_stack", "in_network")[0][1] == 235


def test_evaluate_workers_timings_and_the_readme():
    three, eight = medians("evaluate_workers_3seeds"), medians("evaluate_workers_8seeds")
    for n in (3, 8):
        a, b = commands(f"evaluate_workers_{n}seeds")
        seeds = " ".join(str(i) for i in range(n))
        assert a == f"{b} --workers 2" and b.endswith(f"--seeds {seeds}")
        runs = log_json(f"evaluate_workers_{n}seeds")
        assert len(runs) == (8 if n == 3 else 4)
        for output in runs:
            assert [r["seed"] for r in output["runs"]] == list(range(n))
            for r, first in zip(output["runs"], runs[0]["runs"], strict=True):
                assert {k for k in r if r[k] != first[k]} <= {"steps_per_s", "wall_s",
                                                               "batch_size"}
    assert (f"a median wall of {three['A']:.1f} s against {three['B']:.1f} s (ratio "
            f"{three['A/B']:.2f}, 3 pairs), with `--seeds 0 1 2 3 4 5 6 7` {eight['A']:.1f} s "
            f"against {eight['B']:.1f} s (ratio {eight['A/B']:.2f}, 2 pairs)") in TRAINING
    assert (f"8 seeds on 2 cores: {eight['A']:.0f} s against {eight['B']:.0f} s; 3 seeds: "
            f"{three['A']:.0f} s against {three['B']:.0f} s") in README
    counts = ", ".join(f"{r['arrived']:.0f} / {r['in_network']:.0f}"
                       for r in log_json("evaluate_workers_8seeds")[0]["runs"])
    assert f"seeds 0-7: {counts};" in TRAINING


def test_readme_command_times():
    """The README's times of its commands, each the wall of one timed run (or the median of
    the stacked side of a paired timing) on the idle machine of session 36."""
    one = {name: medians(name)["A"] for name in (
        "readme_rules_study", "readme_shield_stress", "readme_cloud_pick_counts_released",
        "readme_per_lane_released")}
    assert f"3000 --seeds 0 1 2`, {seconds(one['readme_rules_study'])})" in README
    assert f"shield_stress.py`, {round(one['readme_shield_stress'] / 60)} min;" in README
    assert f"cloud_pick_counts.py`, {seconds(one['readme_cloud_pick_counts_released'])})" in README
    assert f"--out runs/per_lane_released # {seconds(one['readme_per_lane_released'])}" in README
    default, released = (medians(f"per_env_calls_{m}_table")["B"] for m in ("default", "released"))
    assert f"--steps 3000 --workers 2 # {seconds(default)}" in README
    assert f"--out docs/results/paper_table_released # {seconds(released)}" in README
    assert f"that machine idle: {seconds(default)} and {seconds(released)}," in README
    command_1 = medians("shield_cost_default")["B"]  # README command 1 with --no-progress
    assert f"the evaluation takes about {command_1:.0f} s on an idle 2-core box" in README


#: Session 36's audits: the label of docs/training.md's table row each audit file backs.
AUDIT_ROWS = {
    "cloud_released_per_lane_s3to7": "cloud on per-lane graphs, released model, seeds 3-7",
    "cloud_paper_per_lane_s3to7": "cloud on per-lane graphs, default model, seeds 3-7",
    "cloud_released_per_lane_6000": "cloud on per-lane graphs, released model, 6000 steps",
    "edge_paper_6000": "edge, default model, 6000 steps",
    "cloud_paper_6000": "cloud, default model, 6000 steps",
    "edge_paper_shield_s3to7": "shield edge, default model, seeds 3-7",
    "cloud_paper_shield_s3to7": "cloud over it, default model, with the shield, seeds 3-7",
    "cloud_released_shield_per_lane": "cloud on per-lane graphs, released model, with the shield",
    "edge_released_shield_picking": "shield edge, released model, picking seeds",
    "edge_paper_shield_picking": "shield edge, default model, picking seeds",
    "cloud_released_shield_picking": "cloud, released model, with the shield, picking seeds",
}


def test_stacking_audits():
    """Every row of session 36's audit table and the times of its command block, from the
    committed audit files."""
    raw = (ROOT / "docs" / "training.md").read_text(encoding="utf-8")
    folder = S36 / "audits"
    reports = {p.stem: json.loads(p.read_text(encoding="utf-8")) for p in folder.glob("*.json")}
    assert sorted(reports) == sorted(AUDIT_ROWS)
    for name, label in AUDIT_ROWS.items():
        report = reports[name]
        kind, model = name.split("_")[:2]
        assert (report["kind"], report["threads"]) == (kind, 1), name
        assert ("released" in report["policy"]) == (model == "released"), name
        assert ("cloud_graphs=per_lane" in report["command"]) == ("per_lane" in name), name
        assert ("safety_shield=true" in report["command"]) == ("shield" in name), name
        assert ("shield" in report["policy"]) == ("shield" in name and kind == "edge"), name
        assert report["random_graph_check_says_exact"], name
        steps, envs = {"6000": (6000, 21), "s3to7": (3000, 35), "picking": (1500, 9)}.get(
            name.rsplit("_", 1)[1], (3000, 21))
        assert (report["steps"], report["environments"]) == (steps, envs), name
        compared = envs * (steps if kind == "edge" else steps // 10)  # the cloud: every 10 steps
        assert report["environment_steps"] == compared, name
        shown = f"{compared:,}".replace(",", " ")
        row = f"| {label} | {shown} | {report['environment_steps_that_differ']} |"
        assert row in raw, row
    times = {line.split()[0]: float(line.split()[1]) for line in (folder / "times.txt").read_text(
        encoding="utf-8").splitlines() if line.endswith(" s")}
    block = " ".join(raw.split())
    assert (f"--out runs/s36/audit/cloud_released_per_lane_s3to7 # "
            f"{seconds(times['cloud_released_per_lane_s3to7'])}") in block
    assert f"with --model paper ({seconds(times['cloud_paper_per_lane_s3to7'])})" in block
    assert f"cloud_graphs=per_lane ({seconds(times['cloud_released_per_lane_6000'])})" in block
    assert (f"--steps 6000 ({seconds(times['edge_paper_6000'])}, "
            f"{seconds(times['cloud_paper_6000'])})") in block
    assert (f"--seeds 3 4 5 6 7 ({seconds(times['edge_paper_shield_s3to7'])}, "
            f"{seconds(times['cloud_paper_shield_s3to7'])})") in block
    assert f"per_lane too ({seconds(times['cloud_released_shield_per_lane'])})" in block
    assert (f"--model {{released,paper}} ({seconds(times['edge_released_shield_picking'])}, "
            f"{seconds(times['edge_paper_shield_picking'])}), --kind cloud --model released "
            f"({seconds(times['cloud_released_shield_picking'])})") in block


def test_shield_stress_rerun_backs_the_quoted_figures():
    """The shield stress runs of today's shield (session 36): 0 events with the shield over
    1.3e8 vehicle-steps, up to 2607 without it, and the raw actions' velocity cost."""
    text = (S36 / "shield_stress.md").read_text(encoding="utf-8")
    rows = [line.split("|")[1:-1] for line in text.splitlines()
            if line.startswith("| paper") or line.startswith("| released")]
    assert len(rows) == 24  # 2 models x 3 action kinds x shield off / on, on 3x3 and on 1x1
    on = [r for r in rows if r[2].strip() == "on"]
    off = [r for r in rows if r[2].strip() == "off"]
    assert all(int(r[4]) == 0 for r in on)
    assert f"{sum(float(r[3]) for r in on):.1e}".replace("e+0", "e") == "1.3e8"
    most = max(int(r[4]) for r in off)
    assert f"collide up to {most} times per setting without it" in README
    assert f"in 1.3e8 vehicle-steps; without it: 0-{most} events per setting" in TRAINING
    costs = [float(a[6]) - float(b[6]) for a, b in zip(off, on, strict=True)
             if a[1].strip() == "raw"]
    assert f"the shield costs {min(costs):.1f}-{max(costs):.1f} m/s" in TRAINING
    assert "2 min; `docs/results/training/session36/shield_stress.md`" in README
