"""``mivecc train`` / ``evaluate`` on bad input: one line naming the option, exit 2, no
traceback; stdout holds only the result; evaluate's inference threads."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from mivecc_agents.cli import DEFAULT_DENSITY, build_parser, main
from mivecc_env.config import MiVeCCConfig


def _train_error(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    code = main(["train", "--no-progress", *argv])
    out, err = capsys.readouterr()
    assert code == 2, (out, err)
    assert out == ""
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err.strip()


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--frames", "0"], "--frames: must be an integer >= 100"),
        (["--frames", "-5"], "--frames: must be an integer >= 100"),
        (["--frames", "150", "--density", "900", "1500"], "--frames: must be an integer >= 200"),
        (["--rows", "0", "--cols", "0"], "--rows: must be an integer in [1, 16], got 0"),
        (["--cols", "0"], "--cols: must be an integer in [1, 16], got 0"),
        (["--buffer-size", "0"], "--buffer-size: must be an integer >= 192"),  # minibatch
        (["--workers", "0"], "--workers: must be an integer >= 1, got 0"),
        (["--threads", "0"], "--threads: must be an integer >= 1, got 0"),
        (["--device", "gpu"], "--device: must be cpu, cuda or cuda:N, got 'gpu'"),
        (["--device", "cuda:7"], "--device: 'cuda:7': torch sees"),  # none, or fewer
        (["--episode-steps", "0"], "--episode-steps: must be an integer >= 1"),
        (["--density", "0"], "--density: must be a number in [1.0, 3600.0], got 0.0"),
        (["--density", "nan"], "--density: must be finite"),
        (["--set", "omega=2"], "omega: must be a number in [0.0, 1.0]"),
        (["--set", "k_edge=10"], "k_edge: the edge network reads K=15 state graphs, got 10"),
        (["--preset-set", "actor_preact_bound=0"],
         "actor_preact_bound: must be a finite number > 0 or none, got 0.0"),
        (["--preset-set", "actor_preact_weight=-1"],
         "actor_preact_weight: must be a finite number >= 0, got -1.0"),
        (["--preset-set", "gamma=1.5"], "gamma: must be a number in [0, 1], got 1.5"),
        (["--preset-set", "batch_size=0"], "batch_size: must be an integer >= 1, got 0"),
        (["--preset-set", "tau=5"], "tau: must be a number in [0.0, 1.0], got 5.0"),
        (["--preset-set", "lr_critic=-0.1"], "lr_critic: must be a number >= 0.0, got -0.1"),
        (["--preset-set", "updates_per_frame=0"],
         "updates_per_frame: must be a number > 0.0, got 0.0"),
        (["--preset-set", "max_grad_norm=0"],
         "max_grad_norm: must be a number > 0.0 or None, got 0.0"),
        (["--preset-set", "warmup_frames=-1"], "warmup_frames: must be an integer >= 0, got -1"),
        (["--preset-set", "eval_steps=0"], "eval_steps: must be an integer >= 1, got 0"),
        (["--preset-set", "critic_members=17"],
         "critic_members: must be an integer in [1, 16], got 17"),
        (["--preset-set", "algorithm=td3", "critic_members=2"],
         "critic_members: must be 1 with algorithm 'td3' (it has its own pair of critics), got 2"),
        (["--preset-set", "reward_shaping=potential", "gamma=1"],
         "reward_shaping: 'potential' needs gamma < 1"),
    ],
)
def test_train_bad_option_is_one_line_exit_2(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, argv: list[str], expected: str
) -> None:
    err = _train_error(capsys, "--out", str(tmp_path / "run"), *argv)
    assert expected in err


def test_train_unwritable_out(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    err = _train_error(capsys, "--frames", "100", "--out", str(blocker / "run"))
    assert "--out: cannot write to folder" in err


def test_train_bad_checkpoints(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    from mivecc_agents.checkpoints import save_checkpoint
    from mivecc_agents.networks import make_actor_net, make_critic_net

    def ckpt(name: str, kind: str, actor_kind: str) -> str:
        return str(save_checkpoint(tmp_path / name, {
            "stage": kind, "kind": kind, "grid_size": 15 if kind == "edge" else 60,
            "actor": make_actor_net(actor_kind).state_dict(),
            "critic": make_critic_net(kind).state_dict(), "frames": 0, "updates": 0,
            "metrics": {}, "config": {}, "preset": {},
        }))

    out = str(tmp_path / "run")
    wrong_shape = ckpt("wrong.pt", "edge", "cloud")  # a K=60 actor in an edge checkpoint
    err = _train_error(capsys, "--stage", "cloud", "--edge-checkpoint", wrong_shape, "--out", out)
    assert "--edge-checkpoint:" in err and "do not fit the edge network (K=15)" in err
    cloud = ckpt("cloud.pt", "cloud", "cloud")
    err = _train_error(capsys, "--stage", "cloud", "--edge-checkpoint", cloud, "--out", out)
    assert "--edge-checkpoint:" in err and "'edge' policy is needed" in err
    err = _train_error(capsys, "--stage", "edge", "--resume", cloud, "--out", out)
    assert "--resume:" in err
    err = _train_error(capsys, "--stage", "cloud", "--edge-checkpoint", str(tmp_path / "no.pt"),
                       "--out", out)
    assert "no such checkpoint file" in err


def test_one_density_default_everywhere() -> None:
    parser = build_parser()
    default = MiVeCCConfig().density_vplh
    assert default == DEFAULT_DENSITY
    assert parser.parse_args(["evaluate"]).density == default
    assert parser.parse_args(["train"]).density == [default]

    import inspect

    from mivecc_agents.training import train

    assert inspect.signature(train).parameters["densities"].default == default


def test_evaluate_sets_inference_threads(capsys: pytest.CaptureFixture[str]) -> None:
    torch = pytest.importorskip("torch")
    before = torch.get_num_threads()
    base = ["evaluate", "--scheme", "EE", "--rows", "1", "--cols", "1", "--steps", "3",
            "--no-progress", "--json"]
    try:
        torch.set_num_threads(2)
        assert main(base) == 0
        assert torch.get_num_threads() == 1  # the default: fastest for these small networks
        assert main([*base, "--threads", "2"]) == 0
        assert torch.get_num_threads() == 2
        capsys.readouterr()
        assert main([*base, "--threads", "0"]) == 2
        assert "--threads: must be an integer >= 1" in capsys.readouterr().err
    finally:
        torch.set_num_threads(before)


def test_evaluate_unwritable_out(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    code = main(["evaluate", "--rows", "1", "--cols", "1", "--steps", "2", "--no-progress",
                 "--out", str(blocker / "r.json")])
    err = capsys.readouterr().err
    assert code == 2 and "--out: cannot write" in err and "Traceback" not in err


def test_evaluate_warns_on_checkpoint_config_mismatch(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from mivecc_agents.policies import pretrained_path

    if pretrained_path("cloud") is None:
        pytest.skip("no shipped cloud policy")
    code = main(["evaluate", "--scheme", "EEC", "--rows", "1", "--cols", "1", "--steps", "2",
                 "--no-progress", "--json"])
    out, err = capsys.readouterr()
    assert code == 0
    json.loads(out)
    assert "warning: shipped cloud policy: the cloud policy was trained on a 3x3 grid" in err
    code = main(["evaluate", "--scheme", "EEC", "--rows", "1", "--cols", "1", "--steps", "2",
                 "--no-progress", "--set", "k_cloud=30"])
    err = capsys.readouterr().err
    assert code == 2 and "reads K=60 state graphs" in err


def test_evaluate_json_has_null_for_no_data(capsys: pytest.CaptureFixture[str]) -> None:
    """Two steps: no vehicle has exited, so travel velocity and trip time have no data."""
    code = main(["evaluate", "--rows", "1", "--cols", "1", "--steps", "2", "--no-progress",
                 "--json"])
    out = capsys.readouterr().out
    assert code == 0
    assert "NaN" not in out
    result = json.loads(out)
    for key in ("avg_travel_velocity_mps", "avg_travel_velocity_no_wait_mps",
                "mean_trip_time_s", "mean_wait_time_s", "throughput_vph"):
        assert result[key] is None, key
    assert result["throughput"] == 0


@pytest.mark.slow
def test_train_stdout_is_only_the_checkpoint_path(tmp_path: Path) -> None:
    """A real (tiny) training run: stdout is the checkpoint path, TorchRL's log on stderr, no
    PettingZoo version warning."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    env.pop("TORCHRL_CONSOLE_STREAM", None)
    proc = subprocess.run(
        [sys.executable, "-m", "mivecc_agents.cli", "train", "--frames", "100",
         "--episode-steps", "50", "--rows", "1", "--cols", "1", "--threads", "1",
         "--out", str(tmp_path / "run"), "--no-progress"],
        capture_output=True, text=True, env=env, check=False, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == [str(tmp_path / "run" / "edge.pt")]
    assert "PettingZoo in TorchRL is tested" not in proc.stderr
    assert (tmp_path / "run" / "edge.pt").is_file()


def test_train_warns_when_the_frozen_edge_policy_was_trained_elsewhere(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Stage II with an edge checkpoint trained under other dynamics: a warning on stderr (the
    run is stopped here by a missing --resume file, checked next, so nothing heavy runs)."""
    from mivecc_agents.checkpoints import save_checkpoint
    from mivecc_agents.networks import make_actor_net, make_critic_net

    edge = save_checkpoint(tmp_path / "edge.pt", {
        "stage": "edge", "kind": "edge", "grid_size": 15,
        "actor": make_actor_net("edge").state_dict(),
        "critic": make_critic_net("edge").state_dict(), "frames": 0, "updates": 0,
        "metrics": {}, "preset": {},
        "config": MiVeCCConfig(rows=1, cols=1, scheme="EE", v_max_mps=15.0).to_dict(),
    })
    code = main(["train", "--no-progress", "--stage", "cloud", "--edge-checkpoint", str(edge),
                 "--resume", str(tmp_path / "missing.pt"), "--out", str(tmp_path / "run")])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 2, err
    assert lines[0].startswith("mivecc: warning: --edge-checkpoint: trained with other dynamics")
    assert "v_max_mps=15.0 (here 13.0)" in lines[0]
    assert lines[1].startswith("mivecc: error: --resume:")


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["evaluate", "--seeds", "a"], "argument --seeds: invalid int value: 'a'"),
        (["evaluate", "--scheme", "XYZ"], "argument --scheme: invalid choice: 'XYZ'"),
        (["train", "--frames", "many"], "argument --frames: invalid int value: 'many'"),
        (["evaluate", "--no-such-option"], "unrecognized arguments: --no-such-option"),
        (["bogus"], "argument COMMAND: invalid choice: 'bogus'"),
    ],
)
def test_malformed_arguments_are_one_line_exit_2(
    capsys: pytest.CaptureFixture[str], argv: list[str], expected: str
) -> None:
    # argparse's own errors (types, choices, unknown options): one line pointing to --help,
    # not the whole usage block
    code = main(argv)
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and expected in err, err
    assert err.strip().endswith("--help)")


def test_a_file_that_is_not_a_checkpoint_is_named_in_one_short_line(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    # torch's loader error goes on with advice about untrusted pickles: only its first
    # sentence is kept
    notes = tmp_path / "notes.pt"
    notes.write_text("not a checkpoint\n")
    code = main(["evaluate", "--scheme", "EE", "--steps", "10", "--edge-checkpoint", str(notes),
                 "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "not a readable mivecc checkpoint" in err and len(err) < 300, err


def test_evaluate_checks_a_checkpoint_its_scheme_ignores(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    # scheme E runs without coordinators: a wrong path is still an error, a good file a warning
    code = main(["evaluate", "--steps", "5", "--edge-checkpoint", str(tmp_path / "none.pt"),
                 "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "--edge-checkpoint" in err and "no such checkpoint" in err, err
    from mivecc_agents.policies import pretrained_path

    code = main(["evaluate", "--steps", "5", "--scheme", "signalized", "--cloud-checkpoint",
                 str(pretrained_path("cloud", "paper")), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 0
    assert "--cloud-checkpoint: scheme signalized runs without coordinators" in err


def test_evaluate_refuses_a_repeated_seed(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["evaluate", "--steps", "5", "--seeds", "0", "1", "0", "--no-progress"])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert err.strip() == "mivecc: error: --seeds: each value at most once, got 0 twice"


@pytest.mark.parametrize(("raised", "code", "message"), [
    (KeyboardInterrupt, 130, "mivecc: interrupted\n"),
    (BrokenPipeError, 0, ""),  # e.g. `mivecc fields | head`: quiet, like other tools
])
def test_interrupt_and_closed_pipe_end_without_traceback(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
    raised: type[BaseException], code: int, message: str,
) -> None:
    import mivecc_agents.cli as cli

    def stopped(args: object) -> int:
        raise raised

    monkeypatch.setattr(cli, "cmd_fields", stopped)
    monkeypatch.setattr(sys, "stdout", sys.stdout)  # restored after the test
    assert cli.main(["fields"]) == code
    assert capsys.readouterr().err == message
