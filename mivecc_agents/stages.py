"""The two training stages: the scheme each runs, the agent group it trains, and the error
raised when training cannot start."""

from __future__ import annotations

#: The agent groups of the MiVeCC envs in TorchRL (edge nodes, cloud).
GROUPS = ("edge", "cloud")
#: Stage I trains the edge policy in scheme EE; stage II the cloud policy in scheme EEC.
STAGES: dict[str, dict[str, str]] = {
    "edge": {"scheme": "EE", "group": "edge"},
    "cloud": {"scheme": "EEC", "group": "cloud"},
}


class TrainingError(RuntimeError):
    """Training cannot start (bad arguments, missing stage-I checkpoint, missing ray...)."""
