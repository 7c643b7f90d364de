"""Checkpoint validation: clear CheckpointError instead of deep torch errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mivecc_agents.checkpoints import CheckpointError, load_checkpoint, save_checkpoint
from mivecc_agents.networks import make_actor_net, make_critic_net
from mivecc_agents.policies import load_policy, pretrained_path


def _payload(kind="edge"):
    return {
        "stage": kind,
        "kind": kind,
        "grid_size": 15 if kind == "edge" else 60,
        "actor": make_actor_net(kind).state_dict(),
        "critic": make_critic_net(kind).state_dict(),
        "frames": 0,
        "updates": 0,
        "metrics": {},
        "config": {},
        "preset": {},
    }


@pytest.fixture
def ckpt(tmp_path):
    return save_checkpoint(tmp_path / "edge.pt", _payload())


def test_roundtrip(ckpt):
    data = load_checkpoint(ckpt, expected_kind="edge")
    assert data["format_version"] == 1 and data["env_version"] == "mivecc_v0"
    assert not list(ckpt.parent.glob("*.tmp"))


def test_missing_file(tmp_path):
    with pytest.raises(CheckpointError, match="no such"):
        load_checkpoint(tmp_path / "nope.pt")


def test_corrupt_file(tmp_path):
    p = tmp_path / "bad.pt"
    p.write_bytes(b"this is not a checkpoint at all")
    with pytest.raises(CheckpointError, match="corrupt or truncated"):
        load_checkpoint(p)


def test_truncated_file(ckpt, tmp_path):
    data = ckpt.read_bytes()
    p = tmp_path / "trunc.pt"
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError):
        load_checkpoint(p)
    with pytest.raises(CheckpointError):
        load_policy(p)


def test_not_mivecc(tmp_path):
    p = tmp_path / "other.pt"
    torch.save({"state_dict": {}}, p)
    with pytest.raises(CheckpointError, match="not a mivecc checkpoint"):
        load_checkpoint(p)


def test_wrong_kind(ckpt):
    with pytest.raises(CheckpointError, match="'cloud' policy is needed"):
        load_checkpoint(ckpt, expected_kind="cloud")
    with pytest.raises(CheckpointError):
        load_policy(ckpt, expected_kind="cloud")


def test_k_mismatch_and_version(tmp_path):
    bad = _payload()
    bad["grid_size"] = 20
    p = save_checkpoint(tmp_path / "k.pt", bad)
    with pytest.raises(CheckpointError, match="K mismatch"):
        load_checkpoint(p)
    data = torch.load(save_checkpoint(tmp_path / "v.pt", _payload()), weights_only=True)
    data["format_version"] = 99
    torch.save(data, tmp_path / "v.pt")
    with pytest.raises(CheckpointError, match="newer"):
        load_checkpoint(tmp_path / "v.pt")


def _rewritten(tmp_path, name, change):
    """A saved edge checkpoint with ``change`` applied to its dict, written back raw."""
    path = save_checkpoint(tmp_path / name, _payload())
    data = torch.load(path, weights_only=True)
    change(data)
    torch.save(data, path)
    return path


def test_missing_entries_env_version_and_unknown_kind(tmp_path):
    p = _rewritten(tmp_path, "m.pt", lambda d: d.pop("critic"))
    with pytest.raises(CheckpointError, match=r"corrupt mivecc checkpoint, missing \['critic'\]"):
        load_checkpoint(p)
    p = _rewritten(tmp_path, "e.pt", lambda d: d.update(env_version="mivecc_v9"))
    with pytest.raises(CheckpointError, match="trained on env 'mivecc_v9', this package "
                       "provides 'mivecc_v0'"):
        load_checkpoint(p)
    p = _rewritten(tmp_path, "k.pt", lambda d: d.update(kind="fog"))
    with pytest.raises(CheckpointError, match="unknown network kind 'fog'"):
        load_checkpoint(p)
    with pytest.raises(CheckpointError, match="unknown network kind 'fog'"):
        load_policy(p)


def test_a_failed_save_leaves_the_old_file_and_no_temporary(ckpt, monkeypatch):
    before = ckpt.read_bytes()

    def broken_save(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        save_checkpoint(ckpt, _payload())
    assert ckpt.read_bytes() == before
    assert not list(ckpt.parent.glob(".*.tmp"))


def test_weights_do_not_fit(tmp_path):
    bad = _payload()
    bad["actor"] = make_actor_net("cloud").state_dict()
    p = save_checkpoint(tmp_path / "w.pt", bad)
    with pytest.raises(CheckpointError, match="do not fit"):
        load_policy(p)


def test_pretrained_path_is_path_or_none():
    for kind in ("edge", "cloud"):
        p = pretrained_path(kind)
        assert p is None or p.is_file()


def test_export_policy_drops_training_state(tmp_path):
    import numpy as np

    from mivecc_agents.checkpoints import export_policy

    full = _payload()
    full["loss"] = {"x": torch.zeros(3)}
    full["optimizer"] = {"state": {}}
    src = save_checkpoint(tmp_path / "full.pt", full)
    dst = export_policy(src, tmp_path / "slim.pt")
    data = load_checkpoint(dst, expected_kind="edge")
    assert "loss" not in data and "optimizer" not in data
    obs = np.zeros((2, 15, 15, 3), np.float32)
    mask = np.ones((2, 15), np.float32)
    np.testing.assert_array_equal(load_policy(src)(obs, mask), load_policy(dst)(obs, mask))


def test_cli_has_train_subcommand():
    from mivecc_agents.cli import build_parser

    args = build_parser().parse_args(["train", "--stage", "cloud", "--density", "900", "1500"])
    assert args.stage == "cloud" and args.density == [900.0, 1500.0]


def test_unknown_kind_or_model_of_the_shipped_policies_is_refused(ckpt):
    from mivecc_agents.policies import pretrained_policies

    with pytest.raises(ValueError, match=r"^kind: must be 'edge' or 'cloud', got 'fog'$"):
        pretrained_path("fog")
    with pytest.raises(ValueError, match=r"^model: must be one of \['paper', 'released'\], "
                       r"got 'relased'$"):
        pretrained_path("edge", "relased")
    with pytest.raises(ValueError, match="model: must be one of"):  # even with both given
        pretrained_policies("relased", edge=ckpt, cloud=ckpt)


def test_shipped_pretrained_policies_load():
    import numpy as np

    from mivecc_agents.policies import pretrained_policies

    pols = pretrained_policies()
    for kind, fn in pols.items():
        k = fn.grid_size
        a = fn(np.zeros((2, k, k, 3), np.float32), np.ones((2, k), np.float32))
        assert a.shape == (2, k) and np.all(np.abs(a) <= 3), kind


def test_pretrained_policies_take_a_given_checkpoint_per_kind():
    from mivecc_agents.policies import pretrained_path, pretrained_policies

    # the default model's edge in place of the released model's, the released cloud kept
    edge = pretrained_path("edge", "paper")
    pols = pretrained_policies("released", edge=edge)
    assert pols["edge"].checkpoint == str(edge)
    assert pols["cloud"].checkpoint == str(pretrained_path("cloud", "released"))
    with pytest.raises(Exception, match="cloud"):  # a checkpoint of the wrong kind
        pretrained_policies("released", cloud=edge)


def test_evaluation_with_a_checkpoint_is_deterministic():
    """Same shipped checkpoints and seed -> identical metrics for EE and EEC."""
    from mivecc_agents.evaluation import evaluate_scheme
    from mivecc_agents.policies import pretrained_policies

    policies = pretrained_policies()
    if set(policies) != {"edge", "cloud"}:
        pytest.skip("shipped policies missing")
    for scheme in ("EE", "EEC"):
        runs = [evaluate_scheme(scheme, 1, 1, 1500, 400, 7, policies=policies, progress=False)
                for _ in range(2)]
        assert runs[0]["coordinator_actions"] == "policy"
        skip = {"steps_per_s", "wall_s"}
        assert {k: v for k, v in runs[0].items() if k not in skip} == {
            k: v for k, v in runs[1].items() if k not in skip}
    # and the policy does act: EE differs from E on the same seed
    e = evaluate_scheme("E", 1, 1, 1500, 400, 7, progress=False)
    ee = evaluate_scheme("EE", 1, 1, 1500, 400, 7, policies=policies, progress=False)
    assert e["mean_speed_mps"] != ee["mean_speed_mps"]


def test_a_policy_needs_graphs_and_masks_of_one_leading_shape_and_a_file_to_save_to(tmp_path):
    policy = load_policy(save_checkpoint(tmp_path / "edge.pt", _payload()))
    assert policy(np.zeros((2, 15, 15, 3)), np.ones((2, 15))).shape == (2, 15)
    with pytest.raises(ValueError, match=r"with the same leading shape, got \(2, 15, 15, 3\) "
                       r"and \(3, 15\)$"):
        policy(np.zeros((2, 15, 15, 3)), np.ones((3, 15)))
    with pytest.raises(IsADirectoryError, match=r"is a folder; a checkpoint needs a file name"):
        save_checkpoint(tmp_path, _payload())
