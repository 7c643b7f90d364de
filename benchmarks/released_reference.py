"""Run the authors' released simulator as MiVeCC-E and count strict collision events.

A diagnostic beside ``released_study.py``: it does not use this project's model at all. It
loads ``traffic_interaction_scene.py`` from a local clone of the authors' repository
(github.com/Mingtzge/MiVeCC_with_DRL; nothing of it is copied here, the path is an argument),
drives it as MiVeCC-E (zero edge actions, no cloud fusion, its same-lane rule "priori
knowledge" on, test-time settings) and checks after every move whether two vehicles are closer
than 2 m (Euclidean distance of their centres, any pair: this project's strict check). Each
pair counts once (the released code removes only the vehicles its own lenient check flags).

Arrival streams (``--streams``):

* ``env``: exactly the arrival times of this project's environment reset with ``--seeds``
  (``mivecc_v0.parallel_env(...).reset(seed=s)``, the streams of ``mivecc evaluate --seed`` and
  of ``evaluate_scheme``), each project lane fed to the released lane with the same position
  and direction (the released grid is this one shifted by (-300, -300) m);
* ``batch``: environment ``seed`` (0, 1 or 2) of the batch of ``released_study.py``
  (``Simulator(config, batch_size=3, seed=[0, 1, 2])``);
* ``poisson``: Poisson streams with the 1 s gap floor of the authors' MATLAB generator
  (``gen_multi_arvTime.m``), drawn from ``numpy.random.default_rng(seed)``.

Example (the commands of ``docs/results/released_study.md``):
    python benchmarks/released_reference.py \\
        --scene ~/MiVeCC_with_DRL/traffic_interaction_scene.py \\
        --streams env --density 1500 2100 --seeds 0 1 2

Needs numpy only (the released file's matplotlib import is stubbed; its ``np.float`` /
``np.int`` aliases are restored for numpy >= 1.24). About 80 s per 3000-step run on one core.
"""

from __future__ import annotations

import copy
import sys
import time
import types
from pathlib import Path

import numpy as np

from mivecc_env import cli_args, mivecc_v0
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.arrivals import ArrivalProcess
from mivecc_env.sim.core import Simulator

#: Released geometry: lane ``i``'s position from its distance ``p`` to the last centre [m].
LANE_OFFSET_M = 5.0
SEGMENT_M = 150.0
VALID_LEN_M = 450.0  # p at entry (3 intersections x 150 m)
STRICT_M = 2.0
DT_S = 0.1
#: ``--same-entry-step``: arrival times fed this much earlier [s] (see :func:`lockstep`).
ENTRY_NUDGE_S = 1e-9


def load_scene(path: Path) -> types.ModuleType:
    """The released scene module, imported from ``path`` without matplotlib."""
    for name in ("matplotlib", "matplotlib.pyplot"):
        sys.modules.setdefault(name, types.ModuleType(name))
    np.float = float  # type: ignore[attr-defined]  # removed aliases the released code uses
    np.int = int  # type: ignore[attr-defined]
    mod = types.ModuleType("released_scene")
    exec(compile(path.read_text(), str(path), "exec"), mod.__dict__)
    return mod


def released_xy(lane: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(n, 2) centre positions [m] of released lanes ``lane`` at distance ``p`` to their last
    centre (groups of 3 lanes: southbound, westbound, northbound, eastbound)."""
    g, k = lane // 3, (lane % 3).astype(float)
    across = SEGMENT_M * (1 - k) + LANE_OFFSET_M  # |coordinate| of the lane across the grid
    x = np.select([g == 0, g == 1, g == 2], [-across, p - SEGMENT_M, across], SEGMENT_M - p)
    y = np.select([g == 0, g == 1, g == 2], [p - SEGMENT_M, across, SEGMENT_M - p], -across)
    return np.stack([x, y], axis=1)


def lane_map(density: float) -> np.ndarray:
    """(12,) released lane of each project lane (same entry point and direction)."""
    env = mivecc_v0.parallel_env(rows=3, cols=3, density=density, scheme="E")
    net = env.sim.network
    lanes = np.arange(net.n_lanes)
    own = np.concatenate([net.xy(lanes, np.zeros(12)), net.xy(lanes, np.full(12, 10.0))], 1)
    own -= 2 * SEGMENT_M
    rel = np.concatenate([released_xy(lanes, np.full(12, VALID_LEN_M)),
                          released_xy(lanes, np.full(12, VALID_LEN_M - 10.0))], 1)
    dist = np.abs(own[:, None, :] - rel[None, :, :]).max(axis=2)
    match = dist.argmin(axis=1)
    if not (dist.min(axis=1) < 1e-9).all() or np.unique(match).size != 12:
        raise RuntimeError("lane_map: the two grids do not match lane by lane")
    return match


def env_arrivals(density: float, seed: int, horizon_s: float) -> np.ndarray:
    """(N + 1, 12) arrival times [s] of the project's environment reset with ``seed``, in
    released lane order, ``inf`` after a lane's last arrival before ``horizon_s``; the last row
    is zeros (the released files end that way)."""
    env = mivecc_v0.parallel_env(rows=3, cols=3, density=density, scheme="E", model="released")
    env.reset(seed=seed)
    return _table(env.sim.arrivals, 0, density, horizon_s)


def batch_arrivals(density: float, seed: int, horizon_s: float) -> np.ndarray:
    """As :func:`env_arrivals` for environment ``seed`` of the batch of
    ``benchmarks/released_study.py`` (``Simulator(config, batch_size=3, seed=[0, 1, 2])``)."""
    cfg = MiVeCCConfig(rows=3, cols=3, density_vplh=density, scheme="E", model="released")
    return _table(Simulator(cfg, batch_size=3, seed=[0, 1, 2]).arrivals, seed, density,
                  horizon_s)


def _table(arrivals: ArrivalProcess, b: int, density: float, horizon_s: float) -> np.ndarray:
    proc = copy.deepcopy(arrivals)  # streams at time 0; nothing has entered
    proc.advance(horizon_s)
    count = proc.arrived[b]
    # Each lane's own arrivals up to the horizon, then +inf (never due); the buffer never
    # wraps here: nothing entered, so it grows instead.
    out = np.full((int(count.max()) + 1, 12), np.inf)
    for lane, rel in enumerate(lane_map(density).tolist()):
        out[: count[lane], rel] = proc.times[b, lane, : count[lane]]
    out[-1] = 0.0
    return out


def poisson_arrivals(density: float, seed: int, horizon_s: float) -> np.ndarray:
    """(N + 1, 12) Poisson arrival times [s] with a 1 s gap floor (the authors' generator)."""
    rng = np.random.default_rng(seed)
    n = int(density * horizon_s / 3600 * 1.5) + 20
    gaps = np.maximum(-np.log(rng.random((n, 12))) * 3600.0 / density, 1.0)
    return np.vstack([np.cumsum(gaps, axis=0), np.zeros((1, 12))])


def run(scene: types.ModuleType, arrivals: np.ndarray, steps: int) -> dict:
    """One MiVeCC-E run of the released simulator; strict events after every move."""
    args = types.SimpleNamespace(collision_thr=STRICT_M, c_mode="closer", s_agent_num=15,
                                 m_agent_num=60, type="s_test", priori_knowledge=True)
    env = scene.MultiTrafficInteraction(arrivals, args, m_thr=0.0)  # m_thr 0: no cloud
    pairs: dict[tuple[int, int], tuple] = {}
    flagged = 0
    # The constructor runs until the first vehicle exists: count steps on the same clock.
    for _ in range(steps - round(env.current_time / DT_S)):
        env.step(np.zeros((9, 15)), np.zeros(60), 0)
        lane = np.array([i for i in range(12) for _ in env.veh_info[i]], dtype=np.int64)
        p = np.array([it["p"] for i in range(12) for it in env.veh_info[i]])
        vid = np.array([it["id_info"][0] for i in range(12) for it in env.veh_info[i]])
        if vid.size > 1:
            xy = released_xy(lane, p)
            d2 = ((xy[:, None, :] - xy[None, :, :]) ** 2).sum(axis=2)
            a, b = np.nonzero(np.triu(d2 < STRICT_M**2, 1))
            for i, j in zip(a.tolist(), b.tolist(), strict=True):
                key = (int(min(vid[i], vid[j])), int(max(vid[i], vid[j])))
                pairs.setdefault(key, (round(env.current_time, 1), int(lane[i]),
                                       round(float(p[i]), 2), int(lane[j]),
                                       round(float(p[j]), 2), round(float(np.sqrt(d2[i, j])), 2)))
        flagged += env.scene_update()[1]
        env.delete_vehicle()
    mean_s = env.passed_veh_step_total / max(env.passed_veh, 1) * DT_S
    return {"events": len(pairs), "flagged": flagged, "passed": env.passed_veh,
            "v455": (VALID_LEN_M + LANE_OFFSET_M) / mean_s if mean_s else 0.0,
            "pairs": pairs}


def lockstep(scene: types.ModuleType, density: float, seed: int, steps: int,
             overrides: dict | None = None,
             flags: list[tuple[int, int, int]] | None = None) -> list[tuple[int, float]]:
    """Step the released simulator and ``model="released"`` (MiVeCC-E, the environment's
    streams of ``seed``) side by side; returns (step, largest position difference [m] over the
    vehicles both have) for every step. Vehicles are matched by lane and arrival time.

    ``flags``: if given, gets (step, vehicles the released code's check flagged, this
    project's ``released_flagged`` increment) for every step where either is nonzero."""
    env = mivecc_v0.parallel_env(rows=3, cols=3, density=density, scheme="E", model="released",
                                 max_steps=steps + 10, **(overrides or {}))
    env.reset(seed=seed)
    sim = env.sim
    table = _table(sim.arrivals, 0, density, steps * DT_S + 60.0)
    lanes = lane_map(density)
    # Its clock adds 0.1 s per step, so it runs a hair behind k * 0.1 and lets an arrival at
    # exactly a step boundary (the 1 s floor makes first arrivals of 1.0 s common) enter one
    # step later than here; 1 ns earlier times remove that difference for the comparison.
    feed = table - ENTRY_NUDGE_S
    args = types.SimpleNamespace(collision_thr=STRICT_M, c_mode="closer", s_agent_num=15,
                                 m_agent_num=60, type="s_test", priori_knowledge=True)
    rel = scene.MultiTrafficInteraction(feed, args, m_thr=0.0)
    zero = {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.possible_agents}
    start = round(rel.current_time / DT_S)
    for _ in range(start):
        env.step(zero)
    out = []
    for k in range(start, steps):
        if k > start:
            rel.step(np.zeros((9, 15)), np.zeros(60), 0)
            theirs_flagged = rel.scene_update()[1]
            rel.delete_vehicle()
            before = int(sim.released_flagged[0])
            env.step(zero)
            ours_flagged = int(sim.released_flagged[0]) - before
            if flags is not None and (theirs_flagged or ours_flagged):
                flags.append((k, int(theirs_flagged), ours_flagged))
        theirs = {(i, table[it["seq_in_lane"], i]): VALID_LEN_M - it["p"]
                  for i in range(12) for it in rel.veh_info[i]}
        m = sim.active[0]
        ours = {(int(lanes[ln]), ta): s for ln, ta, s in
                zip(sim.lane[0, m].tolist(), sim.t_arrive[0, m].tolist(), sim.s[0, m].tolist(),
                    strict=True)}
        both = theirs.keys() & ours.keys()
        dev = max((abs(theirs[x] - ours[x]) for x in both), default=0.0)
        out.append((k, dev if len(both) == len(theirs) == len(ours) else np.inf))
    return out


def check_cloud_view(scene: types.ModuleType, states: int, vehicles: int = 120) -> int:
    """Compare ``sim/cloud_view.released_cloud_view`` with the released code's cloud virtual
    lanes (``virtual_lane_all`` after one ``scene_update``) on ``states`` random 3x3 states of
    ``vehicles`` vehicles (uniform lanes and positions, seeds 0, 1, ...); returns the number of
    lanes whose sets of (position, vehicle) differ (printed per state)."""
    from mivecc_env.sim import cloud_view

    rmap = lane_map(2100.0)
    args = types.SimpleNamespace(collision_thr=STRICT_M, c_mode="closer", s_agent_num=15,
                                 m_agent_num=60, type="s_test", priori_knowledge=True)
    cfg = MiVeCCConfig(rows=3, cols=3, density_vplh=1.0, model="released")
    bad = 0
    for seed in range(states):
        rng = np.random.default_rng(seed)
        lane = rng.integers(0, 12, vehicles)
        s = rng.uniform(0.0, 599.0, vehicles)
        sim = Simulator(cfg, seed=0)
        sim.active[0, :vehicles] = True
        sim.lane[0, :vehicles], sim.s[0, :vehicles] = lane, s
        ours = cloud_view.released_cloud_view(sim.network, sim.active, sim.lane, sim.s)
        first = np.full((3, 12), 1e9)
        first[0, 0] = first[-1] = 0.0  # one vehicle at time 0 ends the constructor's loop
        rel = scene.MultiTrafficInteraction(first, args)
        rel.veh_info = [[] for _ in range(12)]
        index = {}
        for r in range(12):
            mine = sorted((i for i in range(vehicles) if rmap[lane[i]] == r), key=lambda i: -s[i])
            for j, i in enumerate(mine):  # the released lists hold the front vehicle first
                rel.veh_info[r].append({
                    "p": VALID_LEN_M - s[i], "v": 10.0, "a": 0.0, "control": True,
                    "finish": False, "collision": 0, "section": -1, "vir_p": 150,
                    "step": 0, "header": False, "closer_p": 150, "reward": 10,
                    "seq_p": [-1, -1], "m_seq": -1})
                index[(r, j)] = i
        rel.veh_num = np.array([len(x) for x in rel.veh_info])
        rel.arrive_time = np.full((3, 12), 1e9)  # nothing enters
        rel.virtual_lane = [[] for _ in range(9)]
        rel.scene_update()
        diff = 0
        for ln in range(12):
            sel = ours.point_group == ln
            got = sorted(zip(np.round(ours.point_pos[sel], 5).tolist(),
                             ours.point_vehicle[sel].tolist(), strict=True))
            ref = sorted((round(VALID_LEN_M - it[0], 5), index[(it[1], it[2])])
                         for it in rel.virtual_lane_all[rmap[ln]])
            diff += got != ref
        print(f"cloud view, state {seed}: {int((~ours.point_own).sum())} projections, "
              f"{diff} of 12 lanes differ", flush=True)
        bad += diff
    return bad


def main(argv: list[str] | None = None) -> list[dict]:
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", type=Path, required=True,
                   help="traffic_interaction_scene.py of a clone of the authors' repository")
    p.add_argument("--streams", choices=["env", "batch", "poisson"], default="env")
    p.add_argument("--density", type=cli_args.density, nargs="+", default=[2100.0],
                   help="veh/lane/h")
    p.add_argument("--seeds", type=cli_args.seed, nargs="+", default=[0, 1, 2])
    p.add_argument("--steps", type=cli_args.count(1), default=3000)
    p.add_argument("--same-entry-step", action="store_true",
                   help="feed arrival times 1 ns earlier, so that an arrival at exactly a step "
                   "boundary enters on the same step as here (the released clock sums 0.1 s "
                   "steps and runs a hair behind)")
    p.add_argument("--lockstep", action="store_true",
                   help="env streams only: step both simulators side by side and print the "
                   "first step where a position differs by more than 1e-6 m")
    p.add_argument("--without-corner-reset", action="store_true",
                   help="lockstep with stale_corner_reset=False (the preset before it)")
    p.add_argument("--check-cloud-view", type=cli_args.count(0), metavar="STATES", default=0,
                   help="only compare the released cloud view (sim/cloud_view.py) with the "
                   "released code's on this many random 3x3 states")
    args = p.parse_args(argv)
    scene = load_scene(args.scene)
    if args.check_cloud_view:
        bad = check_cloud_view(scene, args.check_cloud_view)
        print(f"cloud view: {bad} lanes differ in {args.check_cloud_view} states")
        return [{"cloud_view_lanes_differing": bad}]
    if args.lockstep:
        rows = []
        for density in args.density:
            for seed in args.seeds:
                flags: list[tuple[int, int, int]] = []
                res = lockstep(scene, density, seed, args.steps,
                               {"stale_corner_reset": False} if args.without_corner_reset
                               else None, flags)
                first = next(((k, d) for k, d in res if d > 1e-6), None)
                print(f"lockstep density {density:.0f} seed {seed}: "
                      + ("identical (< 1e-6 m) for all steps" if first is None else
                         f"first difference at step {first[0]}: {first[1]:.3g} m (inf: the "
                         "vehicle sets differ)"), flush=True)
                for k, theirs, ours in flags:
                    print(f"    step {k}: flagged by the released check {theirs}, "
                          f"released_check_collisions here +{ours}", flush=True)
                rows.append({"density": density, "seed": seed, "first": first, "flags": flags})
        return rows
    make = {"env": env_arrivals, "batch": batch_arrivals, "poisson": poisson_arrivals}[
        args.streams]
    rows = []
    for density in args.density:
        for seed in args.seeds:
            t0 = time.perf_counter()
            table = make(density, seed, args.steps * DT_S + 60.0)
            if args.same_entry_step:
                table = table - ENTRY_NUDGE_S
            out = run(scene, table, args.steps)
            out |= {"density": density, "seed": seed, "streams": args.streams}
            rows.append(out)
            print(f"{args.streams} density {density:.0f} seed {seed}: strict events "
                  f"{out['events']}, released-flagged {out['flagged']}, passed {out['passed']}, "
                  f"v455 {out['v455']:.3f} m/s ({time.perf_counter() - t0:.0f} s)", flush=True)
            for (va, vb), ev in out["pairs"].items():
                print(f"    vehicles {va}, {vb}: t = {ev[0]} s, lane {ev[1]} p = {ev[2]} m, "
                      f"lane {ev[3]} p = {ev[4]} m, distance {ev[5]} m", flush=True)
    return rows


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
