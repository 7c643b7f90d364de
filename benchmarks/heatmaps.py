"""The paper's heat maps: velocity and density over the network at one instant.

Runs the unsignalized scheme (``--scheme``, default MiVeCC-E: end-node rules only) and the
fixed-time signalized baseline with the same seed and demand, and saves for each, at the final
instant, ``<name>_velocity.png``, ``<name>_density.png`` and an RGB frame ``<name>_frame.png``
under ``--out``. The paper compares the two on a 3x3 grid at 2100 veh/lane/h.

No policy is loaded: ``EE`` / ``EEC`` without edge / cloud actions behave like ``E`` (the
fusion only uses actions that are given), so ``--scheme`` only changes the labels here.

Usage:
    python benchmarks/heatmaps.py --rows 3 --cols 3 --density 2100 --steps 1500 --seed 0
    python benchmarks/heatmaps.py --control signalized --steps 3000
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from mivecc_env import cli_args
from mivecc_env.config import MiVeCCConfig
from mivecc_env.render import render_rgb, save_heatmaps
from mivecc_env.sim.core import Simulator


def main(argv: Sequence[str] | None = None) -> list[Path]:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=cli_args.count(1), default=3)
    parser.add_argument("--cols", type=cli_args.count(1), default=3)
    parser.add_argument("--density", type=cli_args.density, default=2100.0)
    parser.add_argument("--steps", type=cli_args.count(1), default=1500)
    parser.add_argument("--seed", type=cli_args.seed, default=0)
    parser.add_argument("--scheme", choices=("E", "EE", "EEC"), default="E",
                        help="scheme of the unsignalized run (default: E)")
    parser.add_argument("--control", choices=("unsignalized", "signalized", "both"),
                        default="both", help="which runs to make (default: both)")
    parser.add_argument("--cell", type=cli_args.number(0.0, low_ok=False), default=10.0,
                        help="heat-map cell side [m]")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/heatmaps"))
    args = parser.parse_args(argv)
    cli_args.writable_dir("--out", args.out)

    from matplotlib.image import imsave

    written: list[Path] = []
    runs = [(f"unsignalized_{args.scheme}", "unsignalized"), ("signalized", "signalized")]
    if args.control != "both":
        runs = [run for run in runs if run[1] == args.control]
    for name, control in runs:
        cfg = MiVeCCConfig(rows=args.rows, cols=args.cols, density_vplh=args.density,
                           control=control, scheme=args.scheme)
        sim = Simulator(cfg, seed=args.seed)
        for _ in tqdm(range(args.steps), desc=name):
            sim.step()
        label = f"MiVeCC-{args.scheme}" if control == "unsignalized" else "signalized"
        title = (f"{label}, {args.rows}x{args.cols}, {args.density:g} veh/lane/h, "
                 f"seed {args.seed} (exited {int(sim.exited[0])}, "
                 f"collided {int(sim.collided[0])}, queued {int(sim.queued[0])})")
        written += save_heatmaps(sim, args.out / name, cell_m=args.cell, title=title)
        frame_path = args.out / f"{name}_frame.png"
        imsave(frame_path, render_rgb(sim, px_per_m=2.0))
        written.append(frame_path)
    for path in written:
        print(path)
    return written


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
