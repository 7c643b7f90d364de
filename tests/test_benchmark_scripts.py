"""Smoke runs of the experiment scripts in benchmarks/ (tiny settings, real work)."""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import ceiling_resolution
import cloud_critic_check
import cloud_pick_counts
import cloud_reward_check
import comparison
import critic_check
import edge_reward_check
import headroom_search
import keep_clear
import learned_policies
import machine_info
import near_miss_cost
import paper_table
import released_reference
import released_study
import rules_study
import shield_stress
import signal_sweep
import stacking_audit
import table_diff
import trace_collisions
import validated_actors
import validated_networks
import validation_size

from mivecc_agents.policies import pretrained_policies
from mivecc_env import mivecc_v0
from mivecc_env.config import ConfigError


def test_rules_study_writes_its_table(tmp_path: Path) -> None:
    rows = rules_study.main(["--rows", "1", "--cols", "1", "--densities", "900", "--seeds", "0",
                             "--steps", "300", "--readings", "sensible/acc=ego",
                             "literal/acc=ego", "--out", str(tmp_path)])
    assert [r["reading"] for r in rows] == ["sensible/acc=ego", "literal/acc=ego"]
    assert all(r["arrived_total"] > 0 for r in rows)
    assert (tmp_path / "rules_study.md").read_text().count("| ") > 4
    assert all(r["released_velocity_mps"] > 0 and r["min_distance_m"] > 0 for r in rows)


def test_near_miss_cost_times_the_hooks_as_the_step_calls_them(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The hooks alone are timed with the arguments ``Simulator.step`` gives them (the (B,)
    per-environment clocks), and without the passing-time path the compiled step no longer
    calls (session 21's audit: a scalar clock compiled another specialisation inside the
    timed loop, and the numpy passing path was counted)."""
    from mivecc_env.sim._numba import HAVE_NUMBA
    from mivecc_env.sim.near_miss import NearMissStats
    from mivecc_env.sim.passing import PassingTimes

    clocks: list[object] = []
    record_step = NearMissStats.record_step

    def spy(self, view, v, s_new, out, t0, dt):  # type: ignore[no-untyped-def]
        clocks.append(t0)
        return record_step(self, view, v, s_new, out, t0, dt)

    passing_calls = []
    record = PassingTimes.record
    monkeypatch.setattr(NearMissStats, "record_step", spy)
    monkeypatch.setattr(PassingTimes, "record",
                        lambda self, *a: passing_calls.append(a) or record(self, *a))
    (row,) = near_miss_cost.main(["--batch", "3", "--density", "2100", "--warmup", "20",
                                  "--rounds", "1", "--block", "2"])
    assert row["batch"] == 3 and row["vehicles"] > 0 and row["hooks_ms"] > 0
    assert all(isinstance(t0, np.ndarray) and t0.shape == (3,) for t0 in clocks)
    assert len(clocks) >= 205  # 22 + 2 steps of the "with" simulator, 5 untimed + 200 timed
    if HAVE_NUMBA:  # the compiled move records the passing times: no separate hook
        assert passing_calls == []


def test_paper_table_runs_and_merges(tmp_path: Path) -> None:
    out = paper_table.main(["--grids", "1x1", "--densities", "1500", "--schemes", "E", "EE",
                            "--seeds", "0", "--steps", "400", "--workers", "1",
                            "--out", str(tmp_path / "a")])
    with open(out / "paper_table.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["scheme"] for r in rows} == {"E", "EE"}
    assert (out / "velocity_vs_density_1x1.png").stat().st_size > 5000
    assert (out / "gains_1x1.png").stat().st_size > 5000
    # the machine is recorded beside the runs (learned policies' runs depend on the CPU)
    machine = json.loads((out / "machine.json").read_text())
    assert machine["cpu_count"] >= 1 and machine["torch"] and machine["numpy"]
    assert machine["policy_digests"] == machine_info.policy_digests()  # a pure function
    assert set(machine["policy_digests"]) == {  # the shield edges too (no shield cloud)
        f"{model}/{kind}" for model in ("paper", "released", "paper/shield", "released/shield")
        for kind in ("edge", "cloud") if not (kind == "cloud" and "shield" in model)}
    assert "Machine: " in (out / "paper_table.md").read_text()
    merged = paper_table.main(["--grids", "1x1", "--out", str(tmp_path / "b"), "--from-csv",
                               str(out / "paper_table.csv")])
    text = (merged / "paper_table.md").read_text()
    assert "EE vs E [%]" in text and "| 1500 |" in text
    assert "E released-style v [m/s]" in text and "| EE | 1500 |" in text
    assert "Machine: " not in text and not (merged / "machine.json").exists()


def test_paper_table_later_csv_replaces_the_same_runs() -> None:
    def run(scheme: str, seed: int, v: float) -> dict:
        return {"rows": 3, "cols": 3, "scheme": scheme, "density": 900, "seed": seed,
                "avg_travel_velocity_mps": v}

    old = [run("E", 0, 12.0), run("EEC", 0, 12.1), run("EEC", 1, 12.2)]
    new = [run("EEC", 0, 12.5)]
    merged = paper_table.merge_runs([old, new])
    assert [(r["scheme"], r["seed"], r["avg_travel_velocity_mps"]) for r in merged] == [
        ("E", 0, 12.0), ("EEC", 0, 12.5), ("EEC", 1, 12.2)]
    # one file's repeated runs are all kept (nothing to replace within a file)
    assert len(paper_table.merge_runs([old + old])) == 6


def test_cloud_reward_check_ranks_constant_clouds(tmp_path: Path) -> None:
    rows = cloud_reward_check.main(["--model", "released", "--rows", "1", "--cols", "1",
                                    "--densities", "1500", "--seeds", "0", "--steps", "400",
                                    "--skip", "100", "--out", str(tmp_path)])
    by_name = {r["cloud"]: r for r in rows}
    for a in cloud_reward_check.CONSTANTS_MPS2:
        assert by_name[f"constant {a:+g}"]["mean_cloud_action_mps2"] == pytest.approx(a)
    assert -3.0 <= by_name["shipped cloud"]["mean_cloud_action_mps2"] <= 3.0
    assert by_name["constant -3"]["cloud_reward"] < by_name["constant +3"]["cloud_reward"]
    text = (tmp_path / "cloud_reward_check_released.md").read_text()
    # the constant clouds decide every step, the learned one at its training period
    period = pretrained_policies("released")["cloud"].config["cloud_period"]
    assert text.count("| constant") == 4 and f"| shipped cloud | {period} |" in text
    assert [r["cloud_period"] for r in rows] == [1, 1, 1, 1, period]


def test_paper_table_cloud_period_sets_both_clouds(tmp_path: Path) -> None:
    out = paper_table.main(["--grids", "1x1", "--densities", "1500", "--schemes", "EEC",
                            "EEC+3", "--seeds", "0", "--steps", "200", "--workers", "1",
                            "--cloud-period", "10", "--out", str(tmp_path)])
    with open(out / "paper_table.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert sorted(r["scheme"] for r in rows) == ["EEC", "EEC+3"]
    assert all(r["cloud_period"] == "10" for r in rows)
    with pytest.raises(SystemExit) as exc:
        paper_table.main(["--cloud-period", "0", "--out", str(tmp_path)])
    assert exc.value.code == 2


def test_paper_table_set_reaches_every_run_and_its_row(tmp_path: Path) -> None:
    argv = ["--grids", "3x3", "--densities", "2100", "--schemes", "EEC+3", "--seeds", "0",
            "--steps", "300", "--workers", "1"]
    rows = {}
    for graphs in ("network", "per_lane"):
        out = paper_table.main([*argv, "--set", f"cloud_graphs={graphs}", "--out",
                                str(tmp_path / graphs)])
        with open(out / "paper_table.csv") as fh:
            (rows[graphs],) = list(csv.DictReader(fh))
        assert rows[graphs]["cloud_graphs"] == graphs
        assert "--set cloud_graphs=" in (out / "paper_table.md").read_text().splitlines()[0]
    # the per-lane constant cloud commands every vehicle: the runs differ
    assert rows["network"]["mean_speed_mps"] != rows["per_lane"]["mean_speed_mps"]


def test_cloud_pick_counts_per_lane_picks_the_whole_population(
    capsys: pytest.CaptureFixture[str],
) -> None:
    result = cloud_pick_counts.main(["--densities", "600", "2100", "--seeds", "0",
                                     "--steps", "700", "--warmup", "500", "--every", "50"])
    assert "| 2100 |" in capsys.readouterr().out
    for r in result.values():
        assert r["per_lane"] == r["population"] > 0
        assert r["network"] <= min(60.0, r["population"])
        assert r["lane_max"] <= 60
    assert result[2100.0]["network"] == 60.0 < result[2100.0]["population"]


def test_shield_stress_counts_the_unshielded_collisions_only(
    capsys: pytest.CaptureFixture[str],
) -> None:
    result = shield_stress.main(["--densities", "2100", "--seeds", "0", "--steps", "1200",
                                 "--models", "released", "--actions", "plus3"])
    assert "| released | plus3 | on |" in capsys.readouterr().out
    (off,), (on,) = ([r for m, a, s, r in result if s is shield] for shield in (False, True))
    assert off["collisions"] > 0 == on["collisions"]
    assert on["min_distance_m"] > 2.0 > off["min_distance_m"]
    assert on["vehicle_steps"] > 0


def test_shield_stress_raw_actions_collide_only_without_the_shield() -> None:
    # the released trainer's exploration: random edge actions executed unmodified every other step
    result = shield_stress.main(["--grid", "1x1", "--densities", "2100", "--seeds", "0",
                                 "--steps", "1500", "--actions", "raw"])
    for model in ("paper", "released"):
        (off,), (on,) = ([r for m, a, s, r in result if m == model and s is shield]
                         for shield in (False, True))
        assert off["collisions"] > 0 == on["collisions"], model


def test_cloud_critic_check_probes_the_shipped_critic(tmp_path: Path) -> None:
    rows = cloud_critic_check.main(["--model", "released", "--rows", "1", "--cols", "1",
                                    "--densities", "1500", "--seeds", "0", "1", "--steps", "300",
                                    "--skip", "100", "--every", "20", "--out", str(tmp_path)])
    by_probe = {r["probe"]: r for r in rows}
    assert {"a + 1", "a - 1", "constant -3", "constant +0", "constant +3"} <= set(by_probe)
    assert all(0.0 <= r["share_positive"] <= 1.0 for r in rows)
    up = by_probe["actor: share of actions within 0.01 of +3"]["mean_gap"]
    down = by_probe["actor: share of actions within 0.01 of -3"]["mean_gap"]
    positive = by_probe["actor: mean action [m/s^2]"]["share_positive"]
    assert up <= positive and down <= 1.0 - positive  # at +3 is positive, at -3 is not
    text = (tmp_path / "cloud_critic_check_released.md").read_text()
    assert "saturated pre-activations" in text and "always_minus3" in text
    # 2 environments x (300 - 100) / 20 kept steps
    period = pretrained_policies("released")["cloud"].config["cloud_period"]
    assert f"20 cloud states (cloud_period {period}) of the shipped released-model cloud" in text
    # the gaps are real critic differences: a tiny shift moves Q by about slope x shift
    from mivecc_agents.policies import pretrained_path

    obs, mask, period = critic_check.collect_states(
        "cloud", "released", 1, 1, [1500.0], [0], 200, 100, 25,
        pretrained_path("cloud", "released"))
    assert period == pretrained_policies("released")["cloud"].config["cloud_period"]
    assert obs.shape[1:] == (60, 60, 3) and len(obs) == len(mask) == 4
    h = 1e-3
    fine = {r["probe"]: r["mean_gap"] for r in critic_check.critic_gaps(
        "cloud", pretrained_path("cloud", "released"), obs, mask, h, [])}
    cols = critic_check.actor_columns("cloud", pretrained_path("cloud", "released"), obs, mask)
    listed = cols["always_plus3"] + cols["always_minus3"] + cols["state_dependent"]
    assert sorted(listed) == list(np.flatnonzero(mask.any(axis=0)))  # a partition of the columns
    assert 0.0 <= cols["saturated_share"] <= 1.0
    slope = fine["slope dQ/dc of a + c*1 [1/(m/s^2)]"]
    # (downwards: the actor's action may sit at the +3 bound, where "a + h" is clamped)
    assert fine[f"a - {h:g}"] == pytest.approx(-slope * h, rel=0.2, abs=1e-6)
    assert abs(slope * h) > 1e-6


def test_critic_check_probes_an_edge_critic(tmp_path: Path) -> None:
    from mivecc_agents.policies import pretrained_path

    rows = critic_check.main(["--kind", "edge", "--model", "released", "--rows", "1", "--cols",
                              "1", "--densities", "1500", "--seeds", "0", "--steps", "300",
                              "--skip", "100", "--every", "20", "--out", str(tmp_path)])
    by_probe = {r["probe"]: r for r in rows}
    assert {"a + 1", "a - 1", "constant -3", "constant +0", "constant +3"} <= set(by_probe)
    text = (tmp_path / "edge_critic_check_released.md").read_text()
    assert text.startswith("Command: `python benchmarks/critic_check.py --kind edge --model "
                           "released --rows 1")
    assert "of the shipped released-model edge" in text and "decision slot" in text
    # the edge's states are its graphs under MiVeCC-EE: one row per node with a decision
    obs, mask, period = critic_check.collect_states(
        "edge", "released", 1, 1, [1500.0], [0], 200, 100, 25,
        pretrained_path("edge", "released"))
    assert period is None
    assert obs.shape[1:] == (15, 15, 3) and 0 < len(obs) == len(mask) <= 4
    assert (mask.sum(axis=1) > 0).all()
    cols = critic_check.actor_columns("edge", pretrained_path("edge", "released"), obs, mask)
    listed = cols["always_plus3"] + cols["always_minus3"] + cols["state_dependent"]
    assert sorted(listed) == list(np.flatnonzero(mask.any(axis=0)))
    # a checkpoint of the other kind is refused with one line (exit 2)
    for argv in (["--kind", "edge", "--cloud", "x.pt"], ["--model", "paper"]):
        with pytest.raises(SystemExit) as exc:
            critic_check.main([*argv, "--out", str(tmp_path)])
        assert exc.value.code == 2


def test_critic_check_passes_set_fields_to_the_env(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen: list[dict] = []
    real = critic_check.evaluate_batch

    def spy(*args: object, **kwargs: object) -> list[dict]:
        seen.append(dict(kwargs))
        return real(*args, **kwargs)

    monkeypatch.setattr(critic_check, "evaluate_batch", spy)
    critic_check.main(["--kind", "edge", "--model", "released", "--rows", "1", "--cols", "1",
                       "--densities", "1500", "--seeds", "0", "--steps", "200", "--skip", "100",
                       "--every", "25", "--set", "safety_shield=true", "--out", str(tmp_path)])
    assert seen and seen[0]["safety_shield"] is True
    text = (tmp_path / "edge_critic_check_released.md").read_text()
    assert "--constants -3 0 3 --set safety_shield=true`" in text.splitlines()[0]


def test_edge_reward_check_ranks_constant_edges(tmp_path: Path) -> None:
    rows = edge_reward_check.main([
        "--model", "released", "--densities", "1500", "--seeds", "0", "--steps", "400",
        "--skip", "100", "--constants", "0", "3", "--set", "reward_sv_weight=0",
        "edge_reward_scope=decisions", "collision_penalty=0", "--out", str(tmp_path)])
    by_name = {r["edge"]: r for r in rows}
    zero, plus3 = by_name["constant +0 m/s^2"], by_name["constant +3 m/s^2"]
    # with the velocity term alone, the reward and the velocity both prefer +3 to 0
    assert plus3["edge_reward"] > zero["edge_reward"]
    assert plus3["released_velocity_mps"] > zero["released_velocity_mps"]
    assert len(rows) == 3 and rows[-1]["edge"].startswith("learned (")
    text = (tmp_path / "edge_reward_check_released.md").read_text()
    assert text.startswith("Command: `python benchmarks/edge_reward_check.py --model released")
    assert text.count("| constant") == 2 and "| learned (" in text


def test_table_diff_counts_identical_runs_and_compares_gains(tmp_path: Path) -> None:
    def run(scheme: str, seed: int, v: float, events: int = 0, out: int = 5,
            wall_s: float = 1.0) -> dict:
        return {"rows": 1, "cols": 1, "scheme": scheme, "density": 900, "seed": seed,
                "avg_travel_velocity_mps": v, "released_velocity_mps": v + 1.0,
                "collisions": events, "throughput": out, "min_pet_s": math.nan,
                "wall_s": wall_s}

    a = [run("E", 0, 10.0), run("E", 1, 10.0), run("EE", 0, 11.0), run("EE", 1, 11.0, 1)]
    # b: E seed 1 moves another vehicle out, every run took another time, and b has a column
    # a lacks (a config field added since): neither of the last two is compared
    b = [{**r, "safety_shield": False} for r in (
        run("E", 0, 10.0, wall_s=2.0), run("E", 1, 10.0, out=6), run("EE", 0, 11.0),
        run("EE", 1, 12.0, 2))]
    a[2]["throughput"] = ""  # a merged table's run made before its column existed: skipped
    assert table_diff.identical_runs(a, b) == {"E": (2, 2), "EE": (1, 2)}
    columns = table_diff.shared_columns(a, b)
    assert columns == ["avg_travel_velocity_mps", "released_velocity_mps", "collisions",
                       "throughput", "min_pet_s"]
    assert table_diff.identical_runs(a, b, columns) == {"E": (1, 2), "EE": (1, 2)}
    assert table_diff.differing_columns(a, b, columns) == {
        "avg_travel_velocity_mps": 1, "released_velocity_mps": 1, "collisions": 1,
        "throughput": 1}
    assert table_diff.gains(a, (1, 1), [900], "avg_travel_velocity_mps")["EE vs E"] == [10.0]
    assert table_diff.gains(b, (1, 1), [900], "avg_travel_velocity_mps")["EE vs E"] == [15.0]
    assert table_diff.events(b, "EE", (1, 1), [900]) == [2]
    for name, rows in (("a.csv", a), ("b.csv", b)):
        with open(tmp_path / name, "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    text = table_diff.main([str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), "--names", "X",
                            "Y", "--out", str(tmp_path / "diff.md")])
    assert "| E | 2 / 2 | 1 / 2 |" in text and "| EE | 1 / 2 | 1 / 2 |" in text
    assert "in all 5 columns both tables have but the timings" in text
    assert ("Columns that differ (runs in both that differ in each): avg_travel_velocity_mps 1, "
            "released_velocity_mps 1, collisions 1, throughput 1.") in text
    assert "| EE vs E, Y | +15.00 | 5.00 |" in text
    assert "| EE, Y | 2 | 2 |" in text and "| EEC, " not in text  # no EEC runs: no EEC rows
    assert (tmp_path / "diff.md").read_text().startswith("Command: `python benchmarks/table_diff")
    (tmp_path / "bad.csv").write_text("x,y\n1,2\n")
    for argv in ([str(tmp_path / "a.csv"), str(tmp_path / "missing.csv")],
                 [str(tmp_path / "bad.csv"), str(tmp_path / "a.csv")]):
        with pytest.raises(SystemExit) as exc:
            table_diff.main(argv)
        assert exc.value.code == 2


@pytest.mark.parametrize("new, old, expected", [(11.0, 10.0, 10.0), (9.0, 10.0, -10.0)])
def test_improvement_rate(new: float, old: float, expected: float) -> None:
    assert paper_table.improvement(new, old) == pytest.approx(expected)


def test_comparison_runs_reuses_and_tabulates(tmp_path: Path) -> None:
    args = ["--grids", "1x1", "--densities", "1500", "--schemes", "fixed-time", "max-pressure",
            "reservation", "--seeds", "0", "--steps", "300", "--out", str(tmp_path / "a")]
    assert comparison.main(args) == 0
    with open(tmp_path / "a" / "comparison.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert sorted(r["scheme"] for r in rows) == ["fixed-time", "max-pressure", "reservation"]
    assert all(float(r["arrived"]) == float(rows[0]["arrived"]) for r in rows)  # same demand
    md = (tmp_path / "a" / "comparison.md").read_text()
    assert "| 1500 |" in md and "max-pressure vs fixed-time" in md
    assert (tmp_path / "a" / "comparison_1x1.png").stat().st_size > 1000
    # a second call reuses every run of the first CSV
    again = ["--from-csv", str(tmp_path / "a" / "comparison.csv"),
             *[a if a != str(tmp_path / "a") else str(tmp_path / "b") for a in args]]
    assert comparison.main(again) == 0
    with open(tmp_path / "b" / "comparison.csv") as fh:
        assert [r["avg_travel_velocity_mps"] for r in csv.DictReader(fh)] == [
            r["avg_travel_velocity_mps"] for r in rows]
    assert {r["signal_keep_clear"] for r in rows if r["scheme"] != "reservation"} == {"True"}
    # without the keep-clear rule: the signal runs are made again (reservation's reused)
    off = [*again[:-2], "--signal-keep-clear", "false", "--out", str(tmp_path / "c")]
    assert comparison.main(off) == 0
    with open(tmp_path / "c" / "comparison.csv") as fh:
        made = {r["scheme"]: r for r in csv.DictReader(fh)}
    first = {r["scheme"]: r for r in rows}
    assert made["fixed-time"]["signal_keep_clear"] == made["max-pressure"][
        "signal_keep_clear"] == "False"
    assert made["reservation"]["wall_s"] == first["reservation"]["wall_s"]  # reused
    assert made["fixed-time"]["wall_s"] != first["fixed-time"]["wall_s"]  # simulated again
    assert "without the keep-clear rule" in (tmp_path / "c" / "comparison.md").read_text()



def test_released_study_reports_both_collision_counts(tmp_path: Path) -> None:
    released_study.main(["--steps", "200", "--parts", "released", "--densities", "2100",
                         "--out", str(tmp_path)])
    with open(tmp_path / "released_study.csv") as fh:
        (row,) = list(csv.DictReader(fh))
    assert int(row["released_check"]) <= int(row["collided_vehicles"])
    text = (tmp_path / "released_study.md").read_text()
    assert "| collisions | released check |" in text and "| released | released | 2100 |" in text


def test_trace_collisions_finds_the_documented_event(capsys: pytest.CaptureFixture[str]) -> None:
    # docs/results/released_study.md, "Traced collisions": E, released, 2100, seed 2, step 2378
    # (the released simulator has one strict event on this stream too).
    records = trace_collisions.main(["--density", "2100", "--seed", "2", "--steps", "2379",
                                     "--history", "2"])
    out = capsys.readouterr().out
    assert [r["step"] for r in records] == [2378]
    assert sorted(records[0]["vehicles"]) == [1389, 1392] and 8 in records[0]["areas"]
    assert "v1389 lane 5 s= 152.32" in out and "collision events: 1" in out
    # both were controlled, at most 5 m from their centres (their lanes 5 m off the centre)
    assert all(abs(d) <= 10.0 for d in records[0]["past_centre_m"])


def test_past_centre_is_signed_to_the_nearest_centre() -> None:
    centres = np.array([[150.0, 300.0, np.inf], [150.0, np.inf, np.inf]])
    got = trace_collisions.past_centre_m(centres, np.array([0, 0, 1, 0]),
                                         np.array([154.0, 292.0, 400.0, 10.0]))
    assert got.tolist() == [4.0, -8.0, 250.0, -140.0]


def test_trace_collisions_takes_config_fields() -> None:
    records = trace_collisions.main(["--scheme", "E", "--density", "2100", "--seed", "2",
                                     "--steps", "2379", "--history", "0", "--set",
                                     "section_control_end_m=10"])
    assert [r["step"] for r in records] != [2378]  # another rule, another trajectory
    with pytest.raises(ConfigError, match="density: use --density instead of --set"):
        trace_collisions.main(["--set", "density=900"])


def test_trace_collisions_refuses_a_checkpoint_for_the_rules_alone() -> None:
    with pytest.raises(SystemExit) as exc:
        trace_collisions.main(["--scheme", "E", "--edge", "edge.pt"])
    assert exc.value.code == 2


def test_trace_collisions_runs_the_policies_on_one_thread_like_the_table() -> None:
    # another thread count rounds the networks differently and the traced episode drifts
    # from the paper table's (measured: EEC, default model, 1200 veh/lane/h, seed 2)
    import torch

    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        trace_collisions.main(["--scheme", "EE", "--model", "paper", "--steps", "3",
                               "--history", "0"])
        assert torch.get_num_threads() == 1
        trace_collisions.main(["--scheme", "EE", "--model", "paper", "--steps", "3",
                               "--history", "0", "--threads", "2"])
        assert torch.get_num_threads() == 2
        with pytest.raises(SystemExit) as exc:
            trace_collisions.main(["--scheme", "EE", "--threads", "0"])
        assert exc.value.code == 2
    finally:
        torch.set_num_threads(before)


@pytest.mark.slow
def test_trace_collisions_eec_finds_the_documented_event(
        capsys: pytest.CaptureFixture[str]) -> None:
    # docs/training.md, "The released model's EEC events, traced": EEC with the released
    # model's shipped policies (session 15), 2100, seed 2, step 603: a crossing pair, one of
    # them more than 5 m past its last centre (on no control area, -1)
    records = trace_collisions.main(["--scheme", "EEC", "--density", "2100", "--seed", "2",
                                     "--steps", "604", "--history", "2"])
    out = capsys.readouterr().out
    assert [r["step"] for r in records] == [603]
    assert sorted(records[0]["vehicles"]) == [209, 294] and -1 in records[0]["areas"]
    assert "v294 lane 4 s= 155.05" in out and "collision events: 1" in out


def test_released_reference_geometry_and_streams() -> None:
    # released lanes by group of 3: southbound, westbound, northbound, eastbound (x = -155,
    # -5, 145 for the southbound ones); this grid shifted by (-300, -300) m
    assert released_reference.lane_map(2100.0).tolist() == [9, 10, 11, 5, 4, 3, 8, 7, 6, 0, 1, 2]
    xy = released_reference.released_xy(np.array([0, 4, 7, 11]),
                                        np.array([450.0, 153.82, 146.55, 300.0]))
    np.testing.assert_allclose(xy, [[-155, 300], [3.82, 5], [5, 3.45], [-150, 145]], atol=1e-9)
    table = released_reference.env_arrivals(2100.0, 1, 30.0)
    env = mivecc_v0.parallel_env(rows=3, cols=3, density=2100.0, scheme="E", model="released")
    env.reset(seed=1)
    zero = {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.possible_agents}
    for _ in range(40):
        env.step(zero)
    sim, lanes = env.sim, released_reference.lane_map(2100.0)
    entered = sim.active[0]
    assert entered.sum() > 3
    for slot in np.flatnonzero(entered):  # every entered vehicle's arrival is in the table
        assert sim.t_arrive[0, slot] in table[:, lanes[sim.lane[0, slot]]]
    assert (np.diff(released_reference.poisson_arrivals(2100.0, 0, 60.0)[:-1], axis=0)
            >= 1.0 - 1e-9).all()  # the 1 s gap floor


def test_released_reference_counts_each_close_pair_once() -> None:
    class Scene:  # two vehicles crossing at (5, 5), closer than 2 m for two steps
        def __init__(self, arrivals: np.ndarray, args: object, m_thr: float) -> None:
            self.current_time, self.passed_veh, self.passed_veh_step_total = 0.0, 0, 0
            self.veh_info = [[] for _ in range(12)]
            self.veh_info[4] = [{"p": 160.0, "id_info": [0, 0]}]  # westbound, y = 5
            self.veh_info[7] = [{"p": 149.2, "id_info": [1, 0]}]  # northbound, x = 5

        def step(self, *args: object) -> None:
            for lane in (4, 7):
                self.veh_info[lane][0]["p"] -= 1.0

        def scene_update(self) -> tuple[float, int, list]:
            self.current_time += 0.1
            return 0.0, 0, []

        def delete_vehicle(self) -> None:
            pass

    out = released_reference.run(SimpleNamespace(MultiTrafficInteraction=Scene),
                                 np.zeros((1, 12)), 10)
    assert out["events"] == 1  # close for several steps: one pair, one event
    (_, lane_a, p_a, lane_b, p_b, dist), = out["pairs"].values()
    assert (lane_a, lane_b) == (4, 7) and (p_a, p_b) == (156.0, 145.2) and dist == 1.02


def test_headroom_search_family_contains_the_ceiling() -> None:
    """The searched family's ceiling member acts exactly +3 in real columns, and run as one
    candidate among others gives the EE+3 scheme's velocity, and each candidate's trajectory
    does not depend on the others in its batch."""
    from mivecc_agents.evaluation import evaluate_batch
    from mivecc_agents.policies import constant_policy

    rng = np.random.default_rng(0)
    obs = rng.uniform(-1, 1, (2, 4, 15, 15, 3)).astype(np.float32)
    mask = (rng.uniform(size=(2, 4, 15)) < 0.7).astype(np.float32)
    thetas = np.vstack([headroom_search.ceiling_theta(), np.zeros(7)])
    a = headroom_search.linear_actions(obs, mask, thetas)
    assert np.array_equal(a[0], 3.0 * mask[0]) and np.array_equal(a[1], 0.0 * mask[1])
    x = headroom_search.column_features(obs)
    assert x.shape == (2, 4, 15, 7) and np.array_equal(x[..., 1, 3:6], obs[..., 1, 1, :])

    setting = headroom_search.Setting("edge", 1, 1, (900.0, 2100.0), (0,), 300,
                                      {"model": "released", "safety_shield": True}, None)
    other = np.array([0.5, -0.5, 0.2, 0.1, 0.0, 0.3, 1.0])
    v, events = headroom_search.run_batch(setting, np.vstack([other, thetas[0]]))
    alone, _ = headroom_search.run_batch(setting, thetas[:1])
    ee3 = evaluate_batch("EE", 1, 1, [900.0, 2100.0], 300, [0], progress=False,
                         policies={"edge": constant_policy("edge", 3.0, 15)}, model="released",
                         safety_shield=True)
    assert v.shape == events.shape == (2, 2, 1)
    assert np.array_equal(v[1], alone[0])
    assert v[1, :, 0].tolist() == [r["released_velocity_mps"] for r in ee3]
    assert not np.array_equal(v[0], v[1])  # another policy, another trajectory
    base, _ = headroom_search.run_batch(setting, None)
    share = headroom_search.ceiling_shares(v, base, alone)
    assert np.allclose(share[1], 100.0)


def test_headroom_search_writes_its_report(tmp_path: Path) -> None:
    result = headroom_search.main([
        "--kind", "cloud", "--grid", "1x1", "--densities", "2100", "--seeds", "1000",
        "--steps", "400", "--population", "3", "--elite", "2", "--iterations", "2",
        "--table-seeds", "0", "--table-steps", "100", "--out", str(tmp_path)])
    assert [h["iteration"] for h in result["history"]] == [1, 2]
    assert all(h["best_share_pct"] >= h["median_share_pct"] for h in result["history"])
    assert [r["density"] for r in result["table"]] == list(paper_table.DENSITIES)
    for name in ("md", "csv", "json", "png"):
        assert (tmp_path / f"headroom_cloud_released.{name}").stat().st_size > 0
    text = (tmp_path / "headroom_cloud_released.md").read_text()
    assert "share of the constant +3 cloud's gain over MiVeCC-EE (shipped edge)" in text


def test_ceiling_resolution_compares_constants_below_the_ceiling(tmp_path: Path) -> None:
    out = ceiling_resolution.main(["--kind", "edge", "--grid", "1x1", "--densities", "900",
                                   "--seeds", "0", "--steps", "400", "--deltas", "ulp", "0.5",
                                   "--workers", "1", "--out", str(tmp_path)])
    with open(tmp_path / "ceiling_resolution.csv") as fh:
        rows = {r["variant"]: r for r in csv.DictReader(fh)}
    assert set(rows) == {"shipped", "3.0", "2.999999761581421", "2.5"}
    assert float(rows["3.0"]["minus_ceiling_points"]) == 0.0
    assert len({r["baseline_mps"] for r in rows.values()}) == 1  # one baseline for all
    gains = {v: float(r["gain_pct"]) for v, r in rows.items()}
    assert all(np.isfinite(list(gains.values()))) and gains["2.5"] != gains["3.0"]
    for r in rows.values():  # the difference as paper_targets.py rounds the gains
        assert float(r["minus_ceiling_points"]) == pytest.approx(
            round(float(r["gain_pct"]), 2) - round(gains["3.0"], 2), abs=1e-12)
    text = out.read_text()
    assert "| edge, " not in text and "minus the +3 ceiling's gain [points]" in text
    assert "fall short of +3 by at most" in text


def test_stacking_audit_counts_every_environment_step(tmp_path: Path) -> None:
    out = stacking_audit.main(["--model", "released", "--densities", "300", "2100", "--seeds",
                               "0", "--steps", "60", "--out", str(tmp_path)])
    report = json.loads(out.read_text())
    assert (report["environments"], report["environment_steps"]) == (2, 120)
    assert len(report["first"]) == min(5, report["environment_steps_that_differ"])
    assert all(0 <= f["step"] < 60 and 0 <= f["env"] < 2 for f in report["first"])
    assert isinstance(report["random_graph_check_says_exact"], bool)


def test_stacking_audit_of_the_cloud_counts_its_decision_steps(tmp_path: Path) -> None:
    out = stacking_audit.main(["--kind", "cloud", "--model", "released", "--densities", "300",
                               "2100", "--seeds", "0", "--steps", "25", "--out", str(tmp_path)])
    report = json.loads(out.read_text())
    # the shipped released cloud decides every 10 steps: steps 0, 10 and 20, in 2 environments
    assert (report["kind"], report["environment_steps"]) == ("cloud", 6)
    assert report["policy"] == "mivecc_agents/pretrained/released/cloud.pt"
    assert isinstance(report["random_graph_check_says_exact"], bool)


def test_keep_clear_pairs_every_signal_scheme(tmp_path: Path) -> None:
    text = keep_clear.main(["--grids", "1x1", "--densities", "1500", "--seeds", "0",
                            "--steps", "300", "--workers", "1", "--out", str(tmp_path)])
    with open(tmp_path / "keep_clear.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    # Coder needs a 2x2 grid: four schemes on 1x1, each with the rule off and on
    assert sorted((r["scheme"], r["signal_keep_clear"]) for r in rows) == sorted(
        (s, rule) for s in ("fixed-time", "actuated", "max-pressure", "pa-dqn")
        for rule in ("False", "True"))
    assert "| 1500 | 0 -> 0 / " in text and "coder" not in text
    assert (tmp_path / "keep_clear.md").read_text().startswith(
        "Written by `python benchmarks/keep_clear.py --grids 1x1")


def test_learned_policies_puts_policies_beside_the_committed_runs(tmp_path: Path) -> None:
    from mivecc_agents.comaddpg import SHIPPED_PATH

    args = ["--grids", "1x1", "--densities", "900", "--seeds", "0", "--steps", "3000",
            "--out", str(tmp_path)]
    text = learned_policies.main(["--policies", f"a={SHIPPED_PATH}", "b=shipped", *args])
    with open(tmp_path / "learned_policies.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["policy"] for r in rows] == ["a", "b"]
    assert (tmp_path / "learned_policies.png").stat().st_size > 10_000
    assert rows[0]["avg_travel_velocity_mps"] == rows[1]["avg_travel_velocity_mps"]
    # the shipped policy's committed comparison run, and MiVeCC-EEC's beside it
    with open(Path(comparison.__file__).parents[1] / "docs/results/comparison/comparison.csv",
              newline="", encoding="utf-8") as fh:
        committed = {r["scheme"]: r for r in csv.DictReader(fh) if (
            r["rows"], float(r["density"]), r["seed"]) == ("1", 900.0, "0")}
    assert float(rows[0]["avg_travel_velocity_mps"]) == float(
        committed["comaddpg"]["avg_travel_velocity_mps"])
    eec = committed["EEC"]
    assert "| density [veh/lane/h] | a | b | MiVeCC-EEC |" in text
    assert (f" | {float(eec['avg_travel_velocity_mps']):.3f} / 0 / "
            f"{float(eec['throughput']):.0f} |") in text
    # runs of another length have no reference column
    short = learned_policies.main(["--policies", f"a={SHIPPED_PATH}", *args[:-4],
                                   "--steps", "50", "--out", str(tmp_path)])
    assert "MiVeCC-EEC" not in short
    # a signal comparator: its shipped policy of the grid, the committed runs beside it
    text = learned_policies.main(["--scheme", "pa-dqn", "--reference-schemes", "pa-dqn",
                                  *args])
    pa = committed["pa-dqn"]
    cell = f"{float(pa['avg_travel_velocity_mps']):.3f} / 0 / {float(pa['throughput']):.0f}"
    assert f"| 900 | {cell} | {cell} |" in text
    # without the keep-clear rule: the committed runs (made with it) are not shown beside the
    # policy, those of a CSV made without it are
    off = ["--scheme", "pa-dqn", "--reference-schemes", "pa-dqn", "--set",
           "signal_keep_clear=false", *args]
    assert "pa-dqn (committed)" not in learned_policies.main(off)
    text = learned_policies.main([*off, "--reference", str(
        Path(comparison.__file__).parents[1] / "docs/results/keep_clear/keep_clear.csv")])
    assert f"| 900 | {cell} | {cell} |" in text  # 1x1 at 900: the rule changes nothing
    for bad, message in ((["--policies", f"a={SHIPPED_PATH}", f"a={SHIPPED_PATH}"],
                          "--policies"),
                         (["--scheme", "coder"], "--grids: scheme coder runs on none")):
        with pytest.raises(ConfigError, match=message):
            learned_policies.main([*bad, *args])


def test_validated_actors_evaluates_every_validated_actor_and_each_rules_pick(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from mivecc_agents import cli
    from mivecc_agents.comaddpg import CoMADDPGPolicy, validation_key
    from mivecc_env import cli_args

    train = tmp_path / "tiny"
    assert cli.main(["train-comaddpg", "--out", str(train), "--episodes", "3", "--batch", "2",
                     "--episode-steps", "150", "--warmup", "64", "--minibatch", "32",
                     "--densities", "900", "2100", "--noise-decay-fraction", "0.5",
                     "--save-validated", "--validation-steps", "300",
                     "--validation-envs", "2", "--rows", "1", "--cols", "1"]) == 0
    capsys.readouterr()
    out = tmp_path / "out"
    text = validated_actors.main(["--trainings", str(train), "--grids", "1x1", "--densities",
                                  "2100", "--seeds", "0", "1", "--steps", "400", "--out",
                                  str(out)])
    with open(out / "validated_actors.csv", newline="", encoding="utf-8") as fh:
        runs = list(csv.DictReader(fh))
    with open(train / "train_log.csv", newline="", encoding="utf-8") as fh:
        log = [r for r in csv.DictReader(fh) if r["validation_collisions"] != "nan"]
    assert [int(float(r["episode"])) for r in log] == [2, 3]  # validated once decayed
    assert [(r["episode"], r["seed"]) for r in runs] == [("2", "0"), ("2", "1"), ("3", "0"),
                                                       ("3", "1")]
    # each actor's runs are the evaluation of its file
    from mivecc_agents.evaluation import evaluate_scheme

    actor = CoMADDPGPolicy.load(train / "validated" / "episode_03.pt")
    again = evaluate_scheme("comaddpg", 1, 1, 2100, 400, 1, policies={"vehicle": actor},
                            progress=False)
    assert float(runs[3]["avg_travel_velocity_mps"]) == again["avg_travel_velocity_mps"]
    assert float(runs[3]["collisions"]) == again["collisions"]
    # the keep_network=best column names the actor the training kept
    kept = max(log, key=lambda r: validation_key({k: float(v) for k, v in r.items()}))
    line = next(x for x in text.splitlines() if x.startswith("| tiny | "))  # the rules' table
    cells = line.strip("| ").split(" | ")[1:]  # last, best, best by reward
    assert cells[0].startswith("3 / ") and cells[1].startswith(f"{float(kept['episode']):.0f} / ")
    assert (out / "validated_actors.png").stat().st_size > 10_000
    assert "Written by `python benchmarks/validated_actors.py --trainings" in (
        out / "validated_actors.md").read_text()
    with pytest.raises(cli_args.InputError, match=r"has no train_log\.csv"):
        validated_actors.main(["--trainings", str(tmp_path), "--out", str(out)])
    # validation_size: the first 2 of 5 environments are the training's own validation
    size_out = tmp_path / "size"
    size_text = validation_size.main(["--trainings", str(train), "--evaluation",
                                      str(out / "validated_actors.csv"), "--envs", "1", "2", "5",
                                      "--out", str(size_out)])
    with open(size_out / "validation_size.csv", newline="", encoding="utf-8") as fh:
        envs = list(csv.DictReader(fh))
    assert [(r["episode"], r["env"], r["density"]) for r in envs[:5]] == [
        ("2", str(i), d) for i, d in enumerate(["900.0", "2100.0"] * 2 + ["900.0"])]
    assert len(envs) == 10
    for row in log:
        own = [r for r in envs if r["episode"] == row["episode"].split(".")[0]]
        again = validation_size.measures(own, 2)
        assert again == {c: float(row[c]) for c in again}  # the training's validation run
        assert math.isfinite(again["validation_velocity"])
    size_rows = [x for x in size_text.splitlines() if x.startswith("| ")][1:]
    assert [x.split(" | ")[0] for x in size_rows] == ["| last", "| 1", "| 2", "| 5"]
    assert size_rows[2].split(" | ")[1].startswith(f"{float(kept['episode']):.0f} / ")
    assert (size_out / "validation_size.png").stat().st_size > 10_000
    with pytest.raises(cli_args.InputError, match=r"--evaluation: .* is not a file"):
        validation_size.main(["--trainings", str(train), "--evaluation", str(tmp_path / "x"),
                              "--out", str(size_out)])
    (train / "validated" / "episode_02.pt").unlink()
    with pytest.raises(cli_args.InputError, match=r"episode_02\.pt is missing"):
        validated_actors.main(["--trainings", str(train), "--out", str(out)])


def test_validated_networks_evaluates_every_validated_pa_dqn_network_and_the_picks(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from mivecc_agents import cli
    from mivecc_agents.evaluation import evaluate_scheme
    from mivecc_agents.signal_dqn import SignalDQNPolicy, kept_episodes
    from mivecc_env import cli_args

    train = tmp_path / "tiny"
    assert cli.main(["train-signal", "--out", str(train), "--episodes", "3", "--batch", "2",
                     "--episode-steps", "300", "--warmup", "1", "--densities", "900", "2100",
                     "--eps-decay-fraction", "0.3", "--save-validated"]) == 0
    capsys.readouterr()
    out = tmp_path / "out"
    text = validated_networks.main(["--trainings", str(train), "--grids", "1x1", "--densities",
                                    "900", "2100", "--seeds", "0", "--steps", "300", "--out",
                                    str(out)])
    with open(out / "validated_networks.csv", newline="", encoding="utf-8") as fh:
        runs = list(csv.DictReader(fh))
    with open(train / "train_log.csv", newline="", encoding="utf-8") as fh:
        log = list(csv.DictReader(fh))
    validated = [r for r in log if r["validation_throughput"] != "nan"]
    episodes = [int(float(r["episode"])) for r in validated]
    assert len(episodes) >= 2 and episodes[-1] == 3
    assert [(int(r["episode"]), r["density"]) for r in runs] == [
        (e, d) for e in episodes for d in ("900", "2100")]
    # each network's runs are the evaluation of its file, with the comparison's keep-clear rule
    policy = SignalDQNPolicy.load(train / "validated" / "episode_03.pt")
    again = evaluate_scheme("pa-dqn", 1, 1, 2100, 300, 0, policies={"signal": policy},
                            progress=False)
    assert float(runs[-1]["throughput"]) == again["throughput"]
    assert float(runs[-1]["avg_travel_velocity_mps"]) == again["avg_travel_velocity_mps"]
    # the keep_network=best column names the network the training kept, the last column the last
    kept = kept_episodes([{k: float(v) for k, v in r.items()} for r in log])[0][1]
    line = next(x for x in text.splitlines() if x.startswith("| tiny | "))
    cells = line.strip("| ").split(" | ")[1:]  # last, best, hindsight: most out, fastest
    assert cells[0].startswith("3 / ") and cells[1].startswith(f"{kept} / ")
    out_by_episode = {e: np.mean([float(r["throughput"]) for r in runs
                                  if int(r["episode"]) == e]) for e in episodes}
    assert cells[2].startswith(f"{max(out_by_episode, key=out_by_episode.get)} / ")
    assert (out / "validated_networks.png").stat().st_size > 10_000
    assert "Written by `python benchmarks/validated_networks.py --trainings" in (
        out / "validated_networks.md").read_text()
    with pytest.raises(cli_args.InputError, match="has no validation runs"):
        comaddpg_like = tmp_path / "other"
        comaddpg_like.mkdir()
        (comaddpg_like / "train_log.csv").write_text("episode,validation_collisions\n1,0\n")
        validated_networks.main(["--trainings", str(comaddpg_like), "--out", str(out)])


def test_signal_sweep_trains_every_variant_and_seed_and_ranks_the_kept_scores(
        tmp_path: Path) -> None:
    import torch

    from mivecc_agents.signal_dqn import kept_episodes
    from mivecc_env import cli_args

    common = "--episodes 2 --batch 2 --episode-steps 600 --warmup 1 --densities 900 2100"
    out = tmp_path / "sweep"
    text = signal_sweep.main(["--variant", "default=", "lr=--lr 3e-3", "--options", common,
                              "--seeds", "0", "1", "--workers", "2", "--out", str(out)])
    with open(out / "signal_sweep.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["variant"], r["seed"], r["options"]) for r in rows] == [
        ("default", "0", ""), ("default", "1", ""), ("lr", "0", "--lr 3e-3"),
        ("lr", "1", "--lr 3e-3")]
    for r in rows:  # each row is its training's kept network, as the trainer logged it
        folder = out / f"{r['variant']}_seed{r['seed']}"
        with open(folder / "train_log.csv", newline="", encoding="utf-8") as fh:
            log = [{k: float(v) for k, v in x.items()} for x in csv.DictReader(fh)]
        (_, episode, kept, _), = kept_episodes(log)
        assert (int(r["kept_episode"]), float(r["kept_validation_throughput"])) == (episode,
                                                                                    kept)
        settings = torch.load(folder / "signal_dqn.pt", weights_only=False)["settings"]
        assert settings["seed"] == int(r["seed"]) and settings["keep_network"] == "best"
        assert settings["lr"] == (3e-3 if r["variant"] == "lr" else 1e-3)
        assert settings["densities"] in ([900.0, 2100.0], (900.0, 2100.0))
        assert "kept the network" in (folder / "output.txt").read_text()
    means = {v: np.mean([float(r["kept_validation_throughput"]) for r in rows
                         if r["variant"] == v]) for v in ("default", "lr")}
    table = [x for x in text.splitlines() if x.startswith("| ")][1:]  # after the header
    assert [x.split(" | ")[0] for x in table] == [
        f"| {v}" for v in sorted(means, key=lambda v: -means[v])]
    assert f"| {means['lr']:.1f} | {means['lr'] - means['default']:+.1f} |" in text
    assert f"Options of every variant: `{common}`." in text
    assert (out / "signal_sweep.png").stat().st_size > 10_000
    for bad, message in ((["--variant", "x=--lr -1"], r"--variant x: lr: must be"),
                         (["--variant", "x=--bogus 1"], "--variant x: .*unrecognized"),
                         (["--variant", "a=", "a=--lr 0.1"], "--variant")):
        with pytest.raises(cli_args.InputError, match=message):
            signal_sweep.main([*bad, "--out", str(tmp_path / "bad")])
    with pytest.raises(SystemExit):  # a usage error: one line, exit 2
        signal_sweep.main(["--variant", "x=--out y", "--out", str(tmp_path / "bad")])
