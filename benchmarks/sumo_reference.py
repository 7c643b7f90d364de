"""Outside reference: Eclipse SUMO speed on the same grid and demand as ``mivecc``.

Network (``netgenerate``, in a temporary directory): ``rows`` x ``cols`` junctions,
150 m apart, with 150 m approach/exit links on every side, one lane per direction,
no U-turns. Junction types (``junction_type``):

* ``unregulated`` (default, the like-for-like peer of mivecc's free-flowing unsignalized
  grid): SUMO lets vehicles cross without any right-of-way rule, so the grid never jams and
  SUMO does only its car-following and movement work;
* ``right_before_left`` (SUMO's uncontrolled equal-priority junction: each approach yields to
  the one on its right) and ``priority`` (netconvert ranks the approaches): gap acceptance
  that saturates early, from roughly 900 veh/lane/h the grid jams (vehicle count and
  insertion backlog keep growing);
* ``traffic_light``: SUMO's default static two-phase fixed-time programme at every junction
  (42 s green, 3 s yellow per phase), which also jams at high demand.

Demand: one Poisson flow per entry lane (``period="exp(rate)"``, rate = density / 3600 veh/s,
departSpeed 10 m/s), 2*rows + 2*cols straight routes from each fringe node to the opposite
one (fringe nodes are found as the nodes with a single neighbour: with ``unregulated`` they
are not ``dead_end`` junctions). Vehicle: length 2 m, maxSpeed 13 m/s, accel/decel 3 m/s^2,
minGap 1 m, Krauss ``sigma=0``. Simulation: 0.1 s steps, ``--seed``, ``--time-to-teleport -1``
(teleporting off, so jams stay jams; ``teleports`` in the result should be 0). A run in which
SUMO inserted no vehicle raises RuntimeError (it would time an empty network).

Timing: ``warmup_steps`` untimed steps, then ``steps`` calls of
``libsumo.simulationStep()`` timed with ``time.perf_counter()``. The per-step
``libsumo.vehicle.getIDCount()`` is inside the timed interval and not subtracted; its
cost (``count_call_us``) is measured separately: it grows with the vehicle count
(~1 us at 60 vehicles, ~18 us at 600) but stays near 1 % of a step. libsumo restarts
cleanly in one process (``close()`` then ``start()``), so repeated calls run in-process.

Usage: ``python benchmarks/sumo_reference.py --rows 3 --cols 3 --density 900``
"""

from __future__ import annotations

import json
import math
import numbers
import os
import shutil
import subprocess
import sys
import tempfile
import time
from typing import Any

from mivecc_env import cli_args

JUNCTION_TYPES = ("unregulated", "right_before_left", "priority", "traffic_light")
STEP_LENGTH_S = 0.1
SPACING_M = 150.0
_INSTALL_HINT = "Eclipse SUMO is not installed; install it with `pip install mivecc[sumo]`."


def sumo_available() -> bool:
    """Tell whether libsumo and the ``netgenerate`` binary can be used.

    Returns:
        True if ``import libsumo`` works and ``netgenerate`` is found.
    """
    try:
        import libsumo  # noqa: F401

        _netgenerate()
    except ImportError:
        return False
    return True


def _netgenerate() -> str:
    """Locate ``netgenerate`` (eclipse-sumo package, then $SUMO_HOME, then $PATH)."""
    homes = [os.environ.get("SUMO_HOME", "")]
    try:
        import sumo

        homes.insert(0, sumo.SUMO_HOME)
    except ImportError:
        pass
    for home in filter(None, homes):
        cand = os.path.join(home, "bin", "netgenerate")
        if os.access(cand, os.X_OK):
            return cand
    found = shutil.which("netgenerate")
    if found is None:
        raise ImportError(_INSTALL_HINT)
    return found


def _validate(
    rows: int, cols: int, density: float, steps: int, warmup_steps: int, junction_type: str
) -> None:
    """Raise ValueError naming the first out-of-range argument."""
    for name, val, low in (("rows", rows, 1), ("cols", cols, 1), ("steps", steps, 1),
                           ("warmup_steps", warmup_steps, 0)):  # fmt: skip
        if isinstance(val, bool) or not isinstance(val, numbers.Integral) or val < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {val!r}")
    if not isinstance(density, numbers.Real) or not math.isfinite(density) or density <= 0:
        raise ValueError(f"density must be a finite number > 0 (veh/lane/h), got {density!r}")
    if junction_type not in JUNCTION_TYPES:
        raise ValueError(f"junction_type must be one of {JUNCTION_TYPES}, got {junction_type!r}")


def _build_net(workdir: str, rows: int, cols: int, junction_type: str) -> str:
    """Run ``netgenerate`` for the grid and return the ``.net.xml`` path."""
    net = os.path.join(workdir, "grid.net.xml")
    cmd = [
        _netgenerate(), "--grid",
        "--grid.x-number", str(cols), "--grid.y-number", str(rows),
        "--grid.length", str(SPACING_M), "--grid.attach-length", str(SPACING_M),
        "--default.lanenumber", "1", "--no-turnarounds",
        "--default.junctions.type", junction_type, "--tls.guess", "false",
        "--output-file", net,
    ]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    return net


def _through_routes(net: str) -> list[tuple[str, str]]:
    """Return (entry edge, exit edge) of every straight boundary-to-boundary route."""
    import xml.etree.ElementTree as ET

    root = ET.parse(net).getroot()
    xy: dict[str, tuple[int, int]] = {}
    for j in root.iter("junction"):
        if j.get("type") != "internal":
            xy[j.get("id", "")] = (round(float(j.get("x", 0))), round(float(j.get("y", 0))))
    neighbours: dict[str, set[str]] = {node: set() for node in xy}
    for e in root.iter("edge"):
        if e.get("function") != "internal":
            a, b = e.get("from", ""), e.get("to", "")
            neighbours[a].add(b)
            neighbours[b].add(a)
    # Fringe nodes have one neighbour (their junction type is dead_end, or e.g. unregulated
    # when every junction is made unregulated).
    fringe = {node: xy[node] for node, nb in neighbours.items() if len(nb) == 1}
    inner_x = {xy[node][0] for node in xy if node not in fringe}
    entry: dict[str, str] = {}
    exit_: dict[str, str] = {}
    for e in root.iter("edge"):
        if e.get("function") == "internal":
            continue
        if e.get("from") in fringe:
            entry[e.get("from", "")] = e.get("id", "")
        if e.get("to") in fringe:
            exit_[e.get("to", "")] = e.get("id", "")
    routes = []
    for node, (x, y) in sorted(fringe.items()):
        horizontal = x not in inner_x  # node sits on the left or right boundary
        opposite = [
            n for n, (x2, y2) in fringe.items()
            if n != node and ((y2 == y and x2 != x) if horizontal else (x2 == x and y2 != y))
        ]  # fmt: skip
        if len(opposite) != 1:
            raise RuntimeError(f"cannot find the exit opposite fringe node {node!r}")
        routes.append((entry[node], exit_[opposite[0]]))
    return routes


def _write_routes(workdir: str, routes: list[tuple[str, str]], density: float, end_s: float) -> str:
    """Write one exponential-headway flow per entry lane; return the route-file path."""
    rate = density / 3600.0  # veh/s per lane
    lines = [
        "<routes>",
        '  <vType id="car" length="2" maxSpeed="13" accel="3" decel="3" minGap="1" sigma="0"/>',
    ]
    for i, (src, dst) in enumerate(routes):
        lines.append(
            f'  <flow id="f{i}" type="car" from="{src}" to="{dst}" begin="0" end="{end_s:.1f}"'
            f' period="exp({rate:.10g})" departSpeed="10"/>'
        )
    lines.append("</routes>")
    path = os.path.join(workdir, "grid.rou.xml")
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    return path


class SumoSession:
    """One running libsumo simulation of the grid: started on ``with``, closed on exit.

    ``run_steps(n)`` and ``run_for(seconds)`` step it and return the wall time and the
    vehicle-steps (the sum of ``getIDCount()`` after each step, called inside the timed loop as
    in :func:`run_sumo`). The route file's flows last ``horizon_s`` simulated seconds; stepping
    past them raises RuntimeError (the network would drain and time an emptying grid).
    libsumo runs one simulation per process at a time.
    """

    def __init__(self, rows: int, cols: int, density: float, seed: int = 0,
                 junction_type: str = "unregulated", horizon_s: float = 3600.0) -> None:
        _validate(rows, cols, density, 1, 0, junction_type)
        if not (math.isfinite(horizon_s) and horizon_s > 0):
            raise ValueError(f"horizon_s must be a finite number > 0, got {horizon_s!r}")
        try:
            import libsumo
        except ImportError as exc:
            raise ImportError(_INSTALL_HINT) from exc
        self._sumo = libsumo
        self.rows, self.cols, self.density, self.seed = rows, cols, float(density), int(seed)
        self.junction_type, self.horizon_s = junction_type, float(horizon_s)
        self.max_steps = round(self.horizon_s / STEP_LENGTH_S)  # steps the demand covers
        self.steps_done = 0
        self._workdir: tempfile.TemporaryDirectory[str] | None = None

    def __enter__(self) -> SumoSession:
        self._workdir = tempfile.TemporaryDirectory(prefix="mivecc_sumo_")
        try:
            wd = self._workdir.name
            net = _build_net(wd, self.rows, self.cols, self.junction_type)
            rou = _write_routes(wd, _through_routes(net), self.density, self.horizon_s + 10.0)
            self._sumo.start([
                "sumo", "-n", net, "-r", rou, "--no-step-log", "--no-warnings",
                "--step-length", str(STEP_LENGTH_S), "--seed", str(self.seed),
                "--time-to-teleport", "-1",
            ])  # fmt: skip
        except BaseException:
            self._workdir.cleanup()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            self._sumo.close()
        finally:
            if self._workdir is not None:
                self._workdir.cleanup()

    def _check_horizon(self, more: int) -> None:
        if self.steps_done + more > self.max_steps:
            raise RuntimeError(
                f"SUMO session: {self.steps_done + more} steps pass the demand horizon of "
                f"{self.horizon_s:g} s; start it with a larger horizon_s")

    def run_steps(self, steps: int) -> tuple[float, int]:
        """Wall seconds of ``steps`` steps and the vehicle-steps they carried."""
        self._check_horizon(steps)
        step, count = self._sumo.simulationStep, self._sumo.vehicle.getIDCount
        total = 0
        t0 = time.perf_counter()
        for _ in range(steps):
            step()
            total += count()
        elapsed = time.perf_counter() - t0
        self.steps_done += steps
        return elapsed, total

    def run_for(self, seconds: float) -> tuple[int, float, int]:
        """Step until at least ``seconds`` of wall time have passed: (steps, wall seconds,
        vehicle-steps)."""
        step, count = self._sumo.simulationStep, self._sumo.vehicle.getIDCount
        clock = time.perf_counter
        left = self.max_steps - self.steps_done  # steps the demand still covers
        steps = total = 0
        t0 = clock()
        while True:
            if steps == left:
                self._check_horizon(steps + 1)  # raises: the demand would end
            step()
            total += count()
            steps += 1
            elapsed = clock() - t0
            if elapsed >= seconds:
                break
        self.steps_done += steps
        return steps, elapsed, total

    def vehicles(self) -> int:
        """Vehicles in the network now."""
        return int(self._sumo.vehicle.getIDCount())

    def backlog(self) -> int:
        """Vehicles waiting to be inserted now."""
        return int(self._sumo.simulation.getMinExpectedNumber()) - self.vehicles()

    def stats(self) -> dict[str, Any]:
        """SUMO version, teleports and vehicles inserted so far."""

        def stat(key: str) -> int:
            return int(self._sumo.simulation.getParameter("", key))

        return {"sumo_version": self._sumo.getVersion()[1],
                "teleports": stat("stats.teleports.total"),
                "inserted": stat("stats.vehicles.inserted")}

    def count_call_us(self, calls: int = 1000) -> float:
        """Cost of one ``getIDCount`` call [us]."""
        count = self._sumo.vehicle.getIDCount
        t1 = time.perf_counter()
        for _ in range(calls):
            count()
        return (time.perf_counter() - t1) / calls * 1e6


def run_sumo(
    rows: int,
    cols: int,
    density: float,
    steps: int,
    seed: int = 0,
    warmup_steps: int = 600,
    junction_type: str = "unregulated",
) -> dict[str, Any]:
    """Time SUMO (libsumo) on the straight-through unsignalized grid.

    Args:
        rows: Number of intersection rows (>= 1).
        cols: Number of intersection columns (>= 1).
        density: Poisson arrival rate per entry lane, in vehicles/lane/hour (> 0).
        steps: Number of timed 0.1 s steps (>= 1).
        seed: SUMO ``--seed`` for the arrival streams.
        warmup_steps: Untimed 0.1 s steps run first so that the network fills (>= 0).
        junction_type: one of :data:`JUNCTION_TYPES` (default ``"unregulated"``).

    Returns:
        Dict with ``steps_per_s`` (timed steps per wall-clock second),
        ``vehicle_steps_per_s`` (sum of per-step vehicle counts / elapsed s),
        ``mean_vehicles`` (vehicles in the network per timed step), ``steps``,
        ``elapsed_s`` (wall-clock s), ``rows``, ``cols``, ``density`` (veh/lane/h),
        ``sumo_version``, ``junction_type``, plus diagnostics ``seed``,
        ``warmup_steps``, ``teleports`` (0 expected: teleporting is disabled),
        ``inserted`` (vehicles inserted so far), ``insertion_backlog`` (vehicles
        waiting to enter at the end), ``queue_start`` (the backlog after the warm-up),
        and ``count_call_us`` (cost of one
        ``getIDCount`` call, in microseconds, included in ``elapsed_s``).

    Raises:
        ValueError: If an argument is out of range.
        ImportError: If SUMO / libsumo is not installed.
        RuntimeError: If SUMO inserted no vehicle (the routes did not load).
    """
    _validate(rows, cols, density, steps, warmup_steps, junction_type)
    horizon_s = (warmup_steps + steps) * STEP_LENGTH_S
    with SumoSession(rows, cols, density, seed, junction_type, horizon_s) as sumo:
        sumo.run_steps(warmup_steps)
        queue_start = sumo.backlog()
        elapsed, total = sumo.run_steps(steps)
        count_us = sumo.count_call_us()
        stats = sumo.stats()
        backlog = sumo.backlog()
    if stats["inserted"] == 0 or total == 0:
        raise RuntimeError(
            f"SUMO carried no vehicles on the {rows}x{cols} {junction_type} grid "
            f"(inserted {stats['inserted']}): the routes or the demand did not load"
        )
    return {
        "steps_per_s": steps / elapsed,
        "vehicle_steps_per_s": total / elapsed,
        "mean_vehicles": total / steps,
        "steps": steps,
        "elapsed_s": elapsed,
        "rows": rows,
        "cols": cols,
        "density": float(density),
        "sumo_version": stats["sumo_version"],
        "junction_type": junction_type,
        "seed": int(seed),
        "warmup_steps": warmup_steps,
        "teleports": stats["teleports"],
        "inserted": stats["inserted"],
        "insertion_backlog": backlog,
        "queue_start": queue_start,
        "count_call_us": count_us,
    }


def main(argv: list[str] | None = None) -> None:
    """Command-line entry: run one measurement and print it as JSON."""
    p = cli_args.Parser(description=__doc__.splitlines()[0])
    p.add_argument("--rows", type=cli_args.count(1), default=3, help="intersection rows")
    p.add_argument("--cols", type=cli_args.count(1), default=3, help="intersection columns")
    p.add_argument("--density", type=cli_args.density, default=900.0,
                   help="veh/lane/h per entry lane")
    p.add_argument("--steps", type=cli_args.count(1), default=2000, help="timed 0.1 s steps")
    p.add_argument("--warmup-steps", type=cli_args.count(0), default=600,
                   help="untimed 0.1 s steps")
    p.add_argument("--seed", type=cli_args.seed, default=0, help="SUMO --seed")
    p.add_argument("--junction-type", choices=JUNCTION_TYPES, default=JUNCTION_TYPES[0])
    a = p.parse_args(argv)
    res = run_sumo(a.rows, a.cols, a.density, a.steps, a.seed, a.warmup_steps, a.junction_type)
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
