"""Shared fixtures of the agent tests."""

from __future__ import annotations

import warnings

import pytest


@pytest.fixture(autouse=True)
def _quiet():
    """TorchRL warns about PettingZoo versions and deprecations on every env: keep logs short."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield
