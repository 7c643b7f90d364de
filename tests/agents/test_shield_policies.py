"""Shipped policies per (model, safety shield): selection, fallback and the mismatch warning."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

pytest.importorskip("torch")

from mivecc_agents import policies as policies_module
from mivecc_agents.cli import main
from mivecc_agents.policies import (
    check_policy_config,
    load_policy,
    pretrained_path,
    pretrained_policies,
)
from mivecc_env.config import from_overrides


@pytest.fixture
def shipped_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A copy of the shipped folder whose released model has a shield edge and no shield
    cloud, and whose default model has no shield policy (the real shipped files, so that
    they load)."""
    folder = tmp_path / "pretrained"
    shutil.copytree(policies_module.PRETRAINED_DIR, folder)
    for shield in (folder / "shield", folder / "released" / "shield"):
        shutil.rmtree(shield, ignore_errors=True)
    (folder / "released" / "shield").mkdir()
    shutil.copy(folder / "edge.pt", folder / "released" / "shield" / "edge.pt")
    monkeypatch.setattr(policies_module, "PRETRAINED_DIR", folder)
    return folder


def test_the_shield_policy_is_picked_only_with_the_shield(shipped_dir: Path) -> None:
    shielded = shipped_dir / "released" / "shield" / "edge.pt"
    assert pretrained_path("edge", "released", safety_shield=True) == shielded
    assert pretrained_path("edge", "released") == shipped_dir / "released" / "edge.pt"
    # no shield cloud for the released model, no shield folder for the default model: the
    # policies trained without the shield
    assert pretrained_path("cloud", "released", True) == shipped_dir / "released" / "cloud.pt"
    assert pretrained_path("edge", "paper", True) == shipped_dir / "edge.pt"
    picked = pretrained_policies("released", safety_shield=True)
    assert picked["edge"].checkpoint == str(shielded)
    assert picked["cloud"].checkpoint == str(shipped_dir / "released" / "cloud.pt")


def test_mivecc_evaluate_picks_by_model_and_shield(
    shipped_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["evaluate", "--scheme", "EE", "--rows", "1", "--cols", "1", "--density", "900",
            "--steps", "50", "--seed", "0", "--json", "--set", "model=released"]
    for shield, expected in (("true", "released/shield/edge.pt"), ("false", "released/edge.pt")):
        assert main([*base, f"safety_shield={shield}"]) == 0
        out, _ = capsys.readouterr()
        result = json.loads(out)
        assert result["edge_checkpoint"] == str(shipped_dir / expected)
        assert result["safety_shield"] is (shield == "true")


def test_a_shield_mismatch_is_warned_about() -> None:
    edge = load_policy(pretrained_path("edge", "released"))
    config = from_overrides(model="released", rows=1, cols=1, scheme="EE")
    shielded = config.replace(safety_shield=True)
    edge.config = {**edge.config, "safety_shield": True}  # as a shield-trained checkpoint
    assert check_policy_config(edge, shielded) == []
    messages = check_policy_config(edge, config)
    assert messages == ["the edge policy was trained with safety_shield=True, the environment "
                        "has safety_shield=False"]
    edge.config.pop("safety_shield")  # trained before the shield existed: nothing to compare
    assert check_policy_config(edge, config) == []
