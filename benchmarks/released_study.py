"""The released model (``model="released"``) and its behaviours, measured one by one.

Runs MiVeCC-E on the 3x3 grid, seeds as one batch (``Simulator(config, batch_size=3,
seed=[0, 1, 2])``), and reports strict collision events (any two vehicles closer than 2 m) and
the released-style velocity (``released_velocity_mps`` of ``sim/passing.py``: 455 m on 3x3,
from entry to 5 m past the last intersection centre, no entry wait, 455 m / mean passing time)
beside this project's 600 m travel velocity, and near-miss figures (``sim/near_miss.py``).

Parts:
    released   -- the released variant at 300, 900, 1500, 2100 veh/lane/h;
    schemes    -- E, EE and EEC with the shipped policies under the released variant (one env
                  per seed, ``mivecc_agents.evaluation.evaluate_scheme``; slow);
    divergence -- at 2100: each released behaviour switched off alone from the released preset
                  and switched on alone over the paper preset;
    consistent -- candidate physically consistent defaults (no speed reset, entry clearance
                  kept: every vehicle within its velocity and acceleration bounds) at the four
                  densities.

Usage (one command; progress on stderr; CSV + markdown under
benchmarks/results/released_study/, the markdown also copied to docs/results/)::

    python benchmarks/released_study.py [--steps 3000] [--parts released divergence consistent]
        [--schemes E EE EEC] [--densities ...] [--set FIELD=VALUE ...]
"""

from __future__ import annotations

import argparse
import csv
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from mivecc_env import cli_args, metrics
from mivecc_env.config import MiVeCCConfig
from mivecc_env.model_presets import PAPER, RELEASED
from mivecc_env.sim.core import Simulator

ROOT = Path(__file__).resolve().parent
OUT = ROOT / "results" / "released_study"
DOCS = ROOT.parent / "docs" / "results"
DENSITIES = (300, 900, 1500, 2100)
SEEDS = (0, 1, 2)

#: Released behaviours as groups of fields (docs/model.md, divergence table). Behaviour 8
#: (edge gate, random edge selection) does not act under MiVeCC-E.
BEHAVIOURS: dict[str, tuple[str, ...]] = {
    "1 speed reset": ("speed_reset",),
    "1b stale action off the virtual lanes": ("stale_action",),
    "1c stale record reset entering the corner section": ("stale_corner_reset",),
    "2 sections": ("sections",),
    "3 section virtual lanes (+ entry lag)": ("section_virtual_lanes", "section_entry_lag"),
    "4 header rule": ("header_rule",),
    "5 SV epsilons, TTC offset, a record": (
        "sv_d_epsilon", "sv_acc_epsilon", "sv_no_front_distance_m", "ttc_closing_offset_mps",
        "accel_record",
    ),
    "6 same-lane rule (released form)": ("same_lane_rule", "same_lane_rule_form"),
    "7a v_min 5": ("v_min_mps",),
    "7b entry: a_max, no clearance": ("entry_accel_mps2", "entry_clearance_m"),
}

#: Candidate physically consistent defaults: no speed reset, entry clearance kept, so every
#: vehicle stays within its velocity and acceleration bounds at every step.
_NO_RESET = {**RELEASED, "model": "paper", "speed_reset": False,
             "entry_clearance_m": PAPER["entry_clearance_m"]}
CONSISTENT: dict[str, dict[str, Any]] = {
    "paper (today's default)": {},
    "released without reset, with clearance": _NO_RESET,
    "... and without stale action": {**_NO_RESET, "stale_action": False},
    "same-lane (released) + SV eps + v_min 5": {
        "same_lane_rule": True, "same_lane_rule_form": "released", "sv_d_epsilon": 1e-4,
        "sv_acc_epsilon": 1e-7, "sv_no_front_distance_m": 100.0,
        "ttc_closing_offset_mps": 0.1, "v_min_mps": 5.0,
    },
}


def _near_miss(summaries: list[dict[str, float]]) -> dict[str, float]:
    return {
        "min_ttc_s": min(s["min_ttc_s"] for s in summaries),
        "min_pet_s": min(s["min_pet_s"] for s in summaries),
        "pet_under_1s": sum(s["pet_under_1s"] for s in summaries),
        "min_distance_m": min(s["min_distance_m"] for s in summaries),
    }


def run(config: MiVeCCConfig, steps: int) -> dict[str, float]:
    """Run the 3 seeds as one batch: strict collisions, both velocities, near-miss figures."""
    sim = Simulator(config, batch_size=len(SEEDS), seed=list(SEEDS))
    for _ in range(steps):
        sim.step()
    exited = sim.exited.sum()
    summaries = [metrics.episode_summary(sim, b) for b in range(len(SEEDS))]
    return {
        "collisions": int(sim.collision_events.sum()),
        "collided_vehicles": int(sim.collided.sum()),
        "released_check": int(sim.released_flagged.sum()),
        "arrived": int(sim.arrived.sum()),
        # pooled over the seeds: sum of path lengths / sum of passing times (455 m / mean time)
        "released_velocity_mps": float(
            sim.passing.sum_length_m.sum() / max(sim.passing.sum_time_s.sum(), 1e-12)
        ),
        "travel_velocity_mps": float(sim.sum_travel_velocity.sum() / max(exited, 1)),
        **_near_miss(summaries),
    }


def run_scheme(scheme: str, density: int, steps: int,
               overrides: dict[str, Any] | None = None) -> dict[str, float]:
    """One scheme with the shipped released-model policies under ``model="released"`` (then
    ``overrides``), one env per seed."""
    from mivecc_agents.evaluation import evaluate_scheme
    from mivecc_agents.policies import pretrained_policies

    policies = pretrained_policies("released")
    res = [
        evaluate_scheme(scheme, 3, 3, density, steps, seed, policies=policies, progress=False,
                        model="released", **(overrides or {}))
        for seed in SEEDS
    ]
    passed = sum(r["released_passed"] for r in res)
    # pooled 455 m / mean passing time (every lane's mark is 455 m on 3x3)
    mean_time = sum(r["released_passed"] * 455.0 / r["released_velocity_mps"]
                    for r in res if r["released_passed"]) / max(passed, 1)
    thr = sum(r["throughput"] for r in res)
    return {
        "collisions": int(sum(r["collisions"] for r in res)),
        "collided_vehicles": int(sum(r["collided_vehicles"] for r in res)),
        "released_check": int(sum(r["released_check_collisions"] for r in res)),
        "arrived": int(sum(r["arrived"] for r in res)),
        "released_velocity_mps": 455.0 / mean_time if passed else float("nan"),
        "travel_velocity_mps": sum(r["avg_travel_velocity_mps"] * r["throughput"]
                                   for r in res) / max(thr, 1),
        **_near_miss(res),
    }


def cell(label: str, part: str, density: int, overrides: dict[str, Any], steps: int,
         rows: list[dict[str, Any]], scheme: str = "E") -> None:
    t = time.time()
    if part == "schemes":
        res = run_scheme(scheme, density, steps, overrides)
    else:
        cfg = MiVeCCConfig(rows=3, cols=3, density_vplh=float(density), scheme="E", **overrides)
        res = run(cfg, steps)
    rows.append({"part": part, "variant": label, "density": density, **res})
    print(f"[{part}] {label} @ {density}: {res['collisions']} collisions "
          f"({res['released_check']} flagged by the released check), "
          f"v455 {res['released_velocity_mps']:.3f} m/s, v600 {res['travel_velocity_mps']:.3f}, "
          f"min TTC {res['min_ttc_s']:.2f} s, min PET {res['min_pet_s']:.2f} s, "
          f"min dist {res['min_distance_m']:.2f} m ({time.time() - t:.0f} s)",
          file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> None:
    ap = cli_args.Parser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=cli_args.count(1), default=3000)
    ap.add_argument("--parts", nargs="+", default=["released", "divergence", "consistent"],
                    choices=["released", "schemes", "divergence", "consistent"])
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--densities", type=cli_args.whole_density, nargs="+", default=list(DENSITIES),
                    help="densities of the released, schemes and consistent parts [veh/lane/h]")
    ap.add_argument("--schemes", nargs="+", default=["E", "EE", "EEC"],
                    choices=["E", "EE", "EEC"], help="schemes of the schemes part")
    ap.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE",
                    help="config fields for the schemes part, after model='released' (e.g. "
                    "cloud_view=window: the cloud view the shipped cloud was trained on)")
    args = ap.parse_args(argv)
    cli_args.writable_dir("--out", args.out)
    from mivecc_agents.cli import parse_set_items

    scheme_over = parse_set_items(args.set)
    suffix = "".join(f", {k}={v}" for k, v in scheme_over.items())
    rows: list[dict[str, Any]] = []
    if "released" in args.parts:
        for d in args.densities:
            cell("released", "released", d, {"model": "released"}, args.steps, rows)
    if "schemes" in args.parts:
        for scheme in args.schemes:
            for d in args.densities:
                cell(f"released {scheme} (shipped policies{suffix})", "schemes", d, scheme_over,
                     args.steps, rows, scheme)
    if "divergence" in args.parts:
        cell("released", "divergence", 2100, {"model": "released"}, args.steps, rows)
        cell("paper", "divergence", 2100, {}, args.steps, rows)
        for name, fields in BEHAVIOURS.items():
            off = {"model": "released", **{f: PAPER[f] for f in fields}}
            on = {f: RELEASED[f] for f in fields}
            cell(f"released without {name}", "divergence", 2100, off, args.steps, rows)
            cell(f"paper with {name}", "divergence", 2100, on, args.steps, rows)
    if "consistent" in args.parts:
        for name, over in CONSISTENT.items():
            for d in args.densities:
                cell(name, "consistent", d, over, args.steps, rows)
    write(rows, args)


def write(rows: list[dict[str, Any]], args: argparse.Namespace) -> None:
    with open(args.out / "released_study.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    cmd = "python benchmarks/released_study.py " + " ".join(
        ["--steps", str(args.steps), "--parts", *args.parts,
         "--densities", *map(str, args.densities)]
        + (["--schemes", *args.schemes] if "schemes" in args.parts else [])
        + (["--set", *args.set] if args.set else []))
    lines = [
        "# Released model study (MiVeCC-E, 3x3, seeds 0-2 as one batch)", "",
        f"Command: `{cmd}`. {args.steps} steps per cell. Collisions: strict events (any two "
        "vehicles closer than 2 m), summed over the 3 seeds. v455: released-style velocity "
        "(455 m / mean passing time from entry to 5 m past the last centre, no entry wait); "
        "v600: this project's average travel velocity (600 m lane, entry wait included). "
        "Released check: the released code's own collision count, per flagged vehicle "
        "(`released_check_collisions`).", "",
        "Near misses over the 3 seeds: minimum TTC on the virtual lanes, minimum PET at the "
        "conflict points and its count under 1 s, minimum centre distance of any two vehicles.",
        "",
        "| part | variant | density | collisions | released check | v455 [m/s] | v600 [m/s] | "
        "min TTC [s] | min PET [s] | PET < 1 s | min distance [m] | arrived |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['part']} | {r['variant']} | {r['density']} | {r['collisions']} | "
            f"{r['released_check']} | "
            f"{r['released_velocity_mps']:.3f} | {r['travel_velocity_mps']:.3f} | "
            f"{r['min_ttc_s']:.2f} | {r['min_pet_s']:.2f} | {int(r['pet_under_1s'])} | "
            f"{r['min_distance_m']:.2f} | {r['arrived']} |"
        )
    md = args.out / "released_study.md"
    md.write_text("\n".join(lines) + "\n")
    if args.out == OUT:
        DOCS.mkdir(parents=True, exist_ok=True)
        shutil.copy(md, DOCS / "released_study.md")
    print(f"wrote {md}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
