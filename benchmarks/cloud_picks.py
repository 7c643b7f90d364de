"""Where the cloud's decision vehicles sit under each ``cloud_pick_population``.

Runs MiVeCC-E dynamics (the cloud graphs do not act back) on a grid and, every ``--every``
steps after ``--start``, builds the cloud graph under each population and counts the picks
that are past their lane's last conflict point (on an exit link, where nothing conflicts).

Usage:
    python benchmarks/cloud_picks.py --density 2100 --steps 1000 --start 600 --every 20
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import numpy as np

from mivecc_env import cli_args
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.core import Simulator
from mivecc_env.sim.state_graph import cloud_graphs
from mivecc_env.sim.virtual_lane import density_indicator

POPULATIONS = ("network", "conflict_ahead", "before_last_centre")


def main(argv: Sequence[str] | None = None) -> dict[str, float]:
    parser = cli_args.Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=cli_args.count(1), default=3)
    parser.add_argument("--cols", type=cli_args.count(1), default=3)
    parser.add_argument("--density", type=cli_args.density, default=2100.0)
    parser.add_argument("--seed", type=cli_args.seed, default=0)
    parser.add_argument("--steps", type=cli_args.count(1), default=1000)
    parser.add_argument("--start", type=cli_args.count(0), default=600)
    parser.add_argument("--every", type=cli_args.count(1), default=20)
    args = parser.parse_args(argv)
    cfg = MiVeCCConfig(rows=args.rows, cols=args.cols, density_vplh=args.density)
    sim = Simulator(cfg, seed=args.seed)
    net = sim.network
    last_cp = np.where(np.isfinite(net.lane_cp_s), net.lane_cp_s, -np.inf).max(axis=1)
    past, picks = dict.fromkeys(POPULATIONS, 0), dict.fromkeys(POPULATIONS, 0)
    for t in range(args.steps):
        sim.step()
        if t < args.start or t % args.every:
            continue
        view = sim.view
        v, a = sim.v.ravel()[view.vehicle], sim.a.ravel()[view.vehicle]
        di = density_indicator(view, cfg.di_n)
        for p in POPULATIONS:
            g = cloud_graphs(net, view, di, v, a, 1, cfg.replace(cloud_pick_population=p))
            idx = g.view_index[0, 0][g.mask[0, 0] > 0]
            past[p] += int((view.s[idx] >= last_cp[view.lane[idx]]).sum())
            picks[p] += int(idx.size)
    shares = {p: 100.0 * past[p] / max(picks[p], 1) for p in POPULATIONS}
    for p in POPULATIONS:
        print(f"{p}: {picks[p]} picks, {shares[p]:.1f} % past their lane's last conflict point")
    return shares


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
