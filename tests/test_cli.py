"""Tests of the ``mivecc`` command line and :func:`mivecc_agents.evaluation.evaluate_scheme`."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mivecc_agents.cli import build_parser, main, parse_set_value
from mivecc_agents.evaluation import RESULT_KEYS, Policy, evaluate_scheme
from mivecc_env.config import ConfigError

BASE = ["evaluate", "--rows", "1", "--cols", "1", "--density", "900", "--steps", "200",
        "--seed", "0", "--no-progress"]  # fmt: skip


def _run_json(capsys: pytest.CaptureFixture[str], *extra: str) -> tuple[dict, str]:
    code = main([*BASE, "--json", *extra])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out), err


def test_evaluate_json_has_required_keys(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["evaluate", "--scheme", "E", "--rows", "1", "--cols", "1", "--density", "900",
                 "--steps", "300", "--seed", "0", "--json"])
    out, _ = capsys.readouterr()
    assert code == 0
    result = json.loads(out)
    missing = set(RESULT_KEYS) - set(result)
    assert not missing, missing
    assert result["scheme"] == "E" and result["steps"] == 300
    assert (result["rows"], result["cols"], result["density"], result["seed"]) == (1, 1, 900, 0)
    assert result["end_rule"] == "sensible" and result["same_lane_rule"] is False
    assert result["steps_per_s"] > 0
    assert 0 < result["mean_speed_mps"] <= result["upper_bound_mps"] + 1.0
    assert 0 <= result["avg_travel_velocity_mps"] <= result["upper_bound_mps"] + 1e-9
    assert result["coordinator_actions"] == "unused"


@pytest.mark.parametrize(("extra", "rc"), [
    ((), 0),  # the README's first command
    (("--scheme", "EE", "--no-pretrained"), 0),  # no policy at all
    (("--edge-checkpoint", "no/such.pt"), 2),  # a missing file fails before torch loads
    (("--scheme", "EEC", "--cloud-checkpoint", "no/such.pt"), 2),
])
def test_evaluation_without_a_policy_does_not_import_torch(extra: tuple[str, ...],
                                                           rc: int) -> None:
    """Evaluations that load no policy stay torch-free: torch's import alone takes longer than
    the evaluation (a regression of 088b042, fixed; a missing checkpoint used to cost 6 s)."""
    args = ["evaluate", "--scheme", "E", "--rows", "1", "--cols", "1", "--density", "900",
            "--steps", "20", "--seed", "0", "--json", *extra]
    code = (
        "import sys\n"
        "from mivecc_agents.cli import main\n"
        f"rc = main({args!r})\n"
        "print('torch imported:', 'torch' in sys.modules, 'rc:', rc)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=False, timeout=300).stdout
    assert out.strip().endswith(f"torch imported: False rc: {rc}")


def test_same_seed_is_deterministic(capsys: pytest.CaptureFixture[str]) -> None:
    first, _ = _run_json(capsys)
    second, _ = _run_json(capsys)
    for r in (first, second):
        r.pop("steps_per_s")
        r.pop("wall_s")
    assert first == second
    other, _ = _run_json(capsys, "--seed", "1")
    other.pop("steps_per_s")
    other.pop("wall_s")
    assert other != first


def test_ee_without_policy_warns_zero_actions(capsys: pytest.CaptureFixture[str]) -> None:
    result, err = _run_json(capsys, "--scheme", "EE", "--no-pretrained")
    assert result["coordinator_actions"] == "zero"
    assert "zero coordinator actions" in err and "no trained policy" in err


def test_ee_uses_the_shipped_edge_policy(capsys: pytest.CaptureFixture[str]) -> None:
    from mivecc_agents.policies import pretrained_path

    if pretrained_path("edge") is None:
        pytest.skip("no shipped edge policy")
    result, _ = _run_json(capsys, "--scheme", "EE")
    assert result["coordinator_actions"] == "policy"
    assert result["edge_checkpoint"].endswith("edge.pt")


def test_rule_options_reach_the_config(capsys: pytest.CaptureFixture[str]) -> None:
    result, _ = _run_json(capsys, "--end-rule", "literal", "--same-lane-rule",
                          "--set", "omega=0.3")
    assert result["end_rule"] == "literal"
    assert result["same_lane_rule"] is True
    assert result["omega"] == pytest.approx(0.3)


def test_released_model_from_the_command_line(capsys: pytest.CaptureFixture[str]) -> None:
    result, _ = _run_json(capsys, "--set", "model=released", "--set", "edge_sv_gate=none")
    assert result["model"] == "released"
    assert result["cloud_pick_population"] == "before_last_centre"  # set by the preset
    assert result["edge_sv_gate"] is None  # an explicit field wins over the preset (-2 there)
    assert result["released_velocity_mps"] > 0.0
    for key in ("min_ttc_s", "ttc_p1_s", "min_pet_s", "min_distance_m"):
        assert result[key] >= 0.0, key


def test_signalized_baseline(capsys: pytest.CaptureFixture[str]) -> None:
    result, err = _run_json(capsys, "--scheme", "signalized")
    assert result["scheme"] == "signalized" and result["control"] == "signalized"
    assert "zero coordinator actions" not in err


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        (["--density", "0"], "density_vplh"),
        (["--set", "v_max_mps=100"], "v_max_mps"),
        (["--set", "unknown=1"], "unknown"),
        (["--set", "rows=2"], "rows"),
        (["--set", "omega"], "--set"),
        (["--steps", "0"], "steps"),
    ],
)
def test_bad_values_exit_2_naming_the_field(
    capsys: pytest.CaptureFixture[str], extra: list[str], field: str
) -> None:
    code = main([*BASE, "--json", *extra])
    out, err = capsys.readouterr()
    assert code == 2
    assert out == ""
    assert field in err
    assert "Traceback" not in err


def test_several_seeds_give_runs_and_mean(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    out_file = tmp_path / "res.json"
    code = main([*BASE, "--steps", "300", "--seeds", "0", "1", "--json", "--out", str(out_file)])
    out, _ = capsys.readouterr()
    assert code == 0
    doc = json.loads(out)
    assert json.loads(out_file.read_text()) == doc
    assert [r["seed"] for r in doc["runs"]] == [0, 1]
    assert doc["mean"]["seed"] == [0, 1]
    v = [r["avg_travel_velocity_mps"] for r in doc["runs"]]
    assert doc["mean"]["avg_travel_velocity_mps"] == pytest.approx(np.mean(v))
    assert doc["mean"]["rows"] == 1


def test_table_output(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([*BASE, "--steps", "50"]) == 0
    out, _ = capsys.readouterr()
    assert "avg_travel_velocity_mps" in out and "seed 0" in out


def test_version_and_no_command(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--version"]) == 0
    assert "mivecc" in capsys.readouterr().out
    assert main([]) == 2
    assert main(["evaluate", "--scheme", "X"]) == 2


def test_fields_command(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fields"]) == 0
    assert "density_vplh" in capsys.readouterr().out


def test_parser_has_one_subparser_per_command() -> None:
    parser = build_parser()
    args = parser.parse_args(["evaluate", "--scheme", "EEC"])
    assert callable(args.func) and args.scheme == "EEC"


def test_parse_set_value() -> None:
    assert parse_set_value("true") is True
    assert parse_set_value("none") is None
    assert parse_set_value("3") == 3
    assert parse_set_value("-2.5") == -2.5
    assert parse_set_value("literal") == "literal"


def test_evaluate_scheme_uses_policies() -> None:
    calls: dict[str, list] = {"edge": [], "cloud": []}

    def policy(kind: str, value: float) -> Policy:
        def act(obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
            calls[kind].append((obs.shape, mask.shape))
            return np.full(mask.shape, value)  # out of the box: clipped to +-a_max

        return act

    kw = {"progress": False, "omega": 0.9}  # the cloud action dominates the fused one
    zero = evaluate_scheme("EEC", 1, 1, 900, 60, 0, warn=False, **kw)
    res = evaluate_scheme("EEC", 1, 1, 900, 60, 0, **kw,
                          policies={"edge": policy("edge", 10.0), "cloud": policy("cloud", -10.0)})
    assert zero["coordinator_actions"] == "zero"
    assert res["coordinator_actions"] == "policy"
    assert len(calls["edge"]) == len(calls["cloud"]) == 60
    assert calls["edge"][0] == ((1, 15, 15, 3), (1, 15))
    assert calls["cloud"][0] == ((1, 60, 60, 3), (1, 60))
    assert res["mean_speed_mps"] < zero["mean_speed_mps"]


def test_evaluate_scheme_step_hook_sees_every_state() -> None:
    # called after the reset (t = 0) and after each step, on the env being evaluated
    seen: list[tuple[int, int]] = []
    res = evaluate_scheme("E", 1, 1, 900, 40, 0, progress=False,
                          step_hook=lambda env, t: seen.append((t, env.sim.step_count)))
    assert seen == [(t, t) for t in range(41)]
    assert res["steps"] == 40


def test_evaluate_scheme_rejects_bad_arguments() -> None:
    with pytest.raises(ConfigError, match="scheme"):
        evaluate_scheme("EEE", 1, 1, 900, 10, 0, progress=False)
    with pytest.raises(ConfigError, match="policies"):
        evaluate_scheme("EE", 1, 1, 900, 10, 0, progress=False, policies={"edges": print})
    with pytest.raises(ConfigError, match="density_vplh"):
        evaluate_scheme("E", 1, 1, 900, 10, 0, progress=False, density_vplh=300)


def test_evaluate_rejects_a_corrupt_checkpoint(tmp_path, capsys) -> None:
    bad = tmp_path / "edge.pt"
    bad.write_bytes(b"not a checkpoint")
    code = main(["evaluate", "--scheme", "EE", "--rows", "1", "--cols", "1", "--steps", "5",
                 "--edge-checkpoint", str(bad), "--no-progress"])
    assert code == 2
    err = capsys.readouterr().err
    assert "--edge-checkpoint" in err and "Traceback" not in err
