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


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """Torch on one thread (two spinning OpenMP threads on a shared 2-core box made updates
    ~10x slower); the caller's setting is restored."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
