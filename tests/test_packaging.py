"""What a non-editable install ships: every data file the packages read is in package-data.

A file that exists in the repository but matches no ``[tool.setuptools.package-data]`` glob
works in an editable install (tests, CI) and is missing from a wheel: the shipped policies and
the BenchMARL task configs are read at run time, so this guards them without building a wheel.
"""

from __future__ import annotations

import fnmatch
import subprocess
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11 (the package supports 3.10)

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("mivecc_env", "mivecc_agents")
#: Tracked files that are not data (kept out of wheels on purpose).
NOT_DATA = (".gitkeep",)


def _package_data() -> dict[str, list[str]]:
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["tool"]["setuptools"]["package-data"]


def _tracked_data_files() -> list[str]:
    try:
        out = subprocess.run(["git", "ls-files", *PACKAGES], cwd=ROOT, capture_output=True,
                             text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [p for p in out.splitlines()
            if not p.endswith(".py") and Path(p).name not in NOT_DATA]


def _glob_match(rel: str, pattern: str) -> bool:
    """setuptools' glob semantics: ``*`` stays within one path segment."""
    parts, pats = rel.split("/"), pattern.split("/")
    return len(parts) == len(pats) and all(
        fnmatch.fnmatchcase(a, b) for a, b in zip(parts, pats, strict=True))


def _shipped(path: str, globs: dict[str, list[str]]) -> bool:
    package, _, rel = path.partition("/")
    return any(_glob_match(rel, g) for g in globs.get(package, []))


def test_every_tracked_data_file_is_package_data() -> None:
    globs = _package_data()
    files = _tracked_data_files()
    assert any(p.endswith("pretrained/edge.pt") for p in files)  # the check sees real files
    missing = [p for p in files if not _shipped(p, globs)]
    assert not missing, f"in the repository but not in [tool.setuptools.package-data]: {missing}"


def test_shipped_policies_of_both_models_are_package_data() -> None:
    # both models' pairs, and their edges for the safety shield
    globs = _package_data()
    for rel in ("pretrained/edge.pt", "pretrained/cloud.pt", "pretrained/released/edge.pt",
                "pretrained/released/cloud.pt", "pretrained/shield/edge.pt",
                "pretrained/released/shield/edge.pt", "pretrained/signal_dqn_1x1.pt",
                "pretrained/signal_dqn_3x3.pt", "pretrained/coder_3x3.pt"):
        assert _shipped(f"mivecc_agents/{rel}", globs), rel
        assert (ROOT / "mivecc_agents" / rel).is_file(), rel


def test_license_file_matches_the_declared_license() -> None:
    with open(ROOT / "pyproject.toml", "rb") as f:
        declared = tomllib.load(f)["project"]["license"]
    text = (ROOT / "LICENSE").read_text()
    assert declared == "MIT" and text.startswith("MIT License")
