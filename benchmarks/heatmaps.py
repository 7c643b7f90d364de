"""The paper's heat maps: velocity and density over the network at one instant.

Runs MiVeCC-E (unsignalized, rules only) and the fixed-time signalized baseline with the same
seed and demand, and saves for each, at the final instant, ``<name>_velocity.png``,
``<name>_density.png`` and an RGB frame ``<name>_frame.png`` under ``--out``.

Usage:
    python benchmarks/heatmaps.py --rows 3 --cols 3 --density 2100 --steps 1500 --seed 0
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from mivecc_env.config import MiVeCCConfig
from mivecc_env.render import render_rgb, save_heatmaps
from mivecc_env.sim.core import Simulator


def main(argv: Sequence[str] | None = None) -> list[Path]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=3)
    parser.add_argument("--cols", type=int, default=3)
    parser.add_argument("--density", type=float, default=2100.0)
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/heatmaps"))
    args = parser.parse_args(argv)

    from matplotlib.image import imsave

    written: list[Path] = []
    for name, control in (("unsignalized_E", "unsignalized"), ("signalized", "signalized")):
        cfg = MiVeCCConfig(rows=args.rows, cols=args.cols, density_vplh=args.density,
                           control=control)
        sim = Simulator(cfg, seed=args.seed)
        for _ in tqdm(range(args.steps), desc=name):
            sim.step()
        title = f"{name}, {args.rows}x{args.cols}, {args.density:g} veh/lane/h"
        written += save_heatmaps(sim, args.out / name, title=title)
        frame_path = args.out / f"{name}_frame.png"
        imsave(frame_path, render_rgb(sim, px_per_m=2.0))
        written.append(frame_path)
    for path in written:
        print(path)
    return written


if __name__ == "__main__":
    main()
