"""The signals' keep-clear rule (``signal_keep_clear``, on by default): no vehicle waits inside a
box and the two traced box-blocking collisions of the rule's absence are gone
(docs/comparators.md, "Keeping the box clear")."""

from __future__ import annotations

import numpy as np

from mivecc_agents.evaluation import evaluate_scheme
from mivecc_env.config import MiVeCCConfig, from_overrides
from mivecc_env.sim import signals
from mivecc_env.sim.core import Simulator


def test_on_by_default() -> None:
    assert MiVeCCConfig().signal_keep_clear is True
    assert evaluate_scheme("fixed-time", 1, 1, 300, 5, 0, progress=False)["signal_keep_clear"]


def test_the_actuated_box_blocking_collision_is_gone() -> None:
    # 3x3, 1500 veh/lane/h, seed 1: the traced actuated collision (2 events) of the comparison
    runs = {rule: evaluate_scheme("actuated", 3, 3, 1500, 3000, 1, progress=False,
                                  signal_keep_clear=rule) for rule in (False, True)}
    assert runs[False]["collisions"] == 2.0
    assert runs[True]["collisions"] == 0.0


def test_the_slowed_entry_pa_dqn_collision_is_gone_and_the_flow_kept() -> None:
    # 3x3, 2100 veh/lane/h, seed 0, comparator_entry="slowed": the traced PA-DQN event
    from mivecc_agents.signal_policy_files import load_signal_policy, shipped_signal_policy_path

    policies = {"signal": load_signal_policy(shipped_signal_policy_path("pa-dqn", 3, 3))}
    runs = {rule: evaluate_scheme("pa-dqn", 3, 3, 2100, 3000, 0, progress=False,
                                  policies=policies, comparator_entry="slowed",
                                  signal_keep_clear=rule) for rule in (False, True)}
    assert (runs[False]["collisions"], runs[True]["collisions"]) == (1.0, 0.0)
    assert runs[True]["throughput"] >= runs[False]["throughput"]


def _box_standstills(rule: bool) -> int:
    """Vehicle-steps standing (< 0.5 m/s) inside an intersection box (between the stop line
    and its mirror past the centre): 3x3 actuated signals at 1500 veh/lane/h, 3000 steps."""
    c = from_overrides(None, rows=3, cols=3, density_vplh=1500, control="signalized",
                       signal_controller="actuated", signal_keep_clear=rule)
    sim = Simulator(c, seed=1)
    off = signals.stop_line_offset_m(c)
    count = 0
    for _ in range(3000):
        sim.step()
        view = sim.view
        centres = sim.network.lane_centres_s[view.lane]
        inside = (np.abs(view.s[:, None] - centres) < off).any(axis=1)
        count += int((inside & (sim.v.ravel()[view.vehicle] < 0.5)).sum())
    return count


def test_no_vehicle_stands_inside_a_box() -> None:
    assert _box_standstills(False) > 20  # the rule off: vehicles wait inside boxes
    assert _box_standstills(True) == 0


def test_the_1x1_pa_dqn_policy_blocks_boxes_on_3x3_only_without_the_rule() -> None:
    # docs/comparators.md, PA-DQN: the 1x1 policy on 3x3 at 2100 veh/lane/h, seed 0 (9 strict
    # events without the rule; the docs give the three seeds' 9, 11, 7)
    from mivecc_agents.signal_policy_files import load_signal_policy, shipped_signal_policy_path

    policies = {"signal": load_signal_policy(shipped_signal_policy_path("pa-dqn", 1, 1))}
    runs = {rule: evaluate_scheme("pa-dqn", 3, 3, 2100, 3000, 0, progress=False,
                                  policies=policies, signal_keep_clear=rule)
            for rule in (False, True)}
    assert (runs[False]["collisions"], runs[True]["collisions"]) == (9.0, 0.0)


def test_a_batch_with_the_rule_acting_gives_each_runs_single_result() -> None:
    # 3x3 actuated signals: at 1500 veh/lane/h, seed 1 the rule holds vehicles back (the traced
    # box blocking); a batch with another demand and seed gives each run as alone, bit for bit
    from mivecc_agents.evaluation import evaluate_batch

    keys = ("avg_travel_velocity_mps", "mean_speed_mps", "throughput", "backlog",
            "collisions", "min_pet_s")
    batch = evaluate_batch("actuated", 3, 3, [900.0, 1500.0], 1500, [2, 1], progress=False)
    by_run = {(r["density"], r["seed"]): r for r in batch}  # every density with every seed
    assert len(by_run) == 4
    alone = [evaluate_scheme("actuated", 3, 3, d, 1500, s, progress=False)
             for d, s in ((900.0, 2), (1500.0, 1))]
    assert [[by_run[r["density"], r["seed"]][k] for k in keys] for r in alone] == [
        [r[k] for k in keys] for r in alone]
    without = evaluate_scheme("actuated", 3, 3, 1500.0, 1500, 1, progress=False,
                              signal_keep_clear=False)
    assert without["mean_speed_mps"] != alone[1]["mean_speed_mps"]  # the rule acted there
