"""Training settings of Coder (:mod:`mivecc_agents.coder`), without torch.

Coder's regional stage trains like PA-DQN (the same fields, :class:`SignalDQNSettings`); the
aggregation stage adds its own. Kept apart from the trainer so that the ``mivecc`` command line
lists them without importing torch.
"""

from __future__ import annotations

from dataclasses import dataclass

from mivecc_agents.signal_dqn_settings import SignalDQNSettings, _opt
from mivecc_env.config import ConfigError

__all__ = ["MAX_INTERSECTIONS", "CoderSettings", "check_coder_grid"]

#: Coder searches all 2^n joint phases of a grid of at most this many intersections (training
#: always; on larger grids a trained policy decides by coordinate ascent, :mod:`..coder`).
MAX_INTERSECTIONS = 12


def check_coder_grid(rows: int, cols: int, exhaustive: bool = True) -> None:
    """ConfigError unless Coder can run on a ``rows`` x ``cols`` grid: both at least 2 (a
    region is a 2x2 block) and, for the exhaustive search of training, at most
    :data:`MAX_INTERSECTIONS` intersections."""
    if rows < 2 or cols < 2 or (exhaustive and rows * cols > MAX_INTERSECTIONS):
        bound = f" and at most {MAX_INTERSECTIONS} intersections" if exhaustive else ""
        raise ConfigError(f"rows, cols: Coder needs a grid of at least 2x2{bound}, got "
                          f"{rows}x{cols}")


@dataclass(frozen=True)
class CoderSettings(SignalDQNSettings):
    """Settings of :func:`mivecc_agents.coder.train_coder`: those of PA-DQN for the regional
    stage (``episodes`` its episodes), on a 3x3 grid by default, and the aggregation stage's."""

    episodes: int = _opt(30, "episodes of the regional stage; each runs `batch` environments "
                         "for `episode_steps` steps")
    rows: int = _opt(3, "intersection rows of the training grid (>= 2)")
    cols: int = _opt(3, "intersection columns of the training grid (>= 2)")
    global_episodes: int = _opt(15, "episodes of the aggregation stage (regional networks "
                                "frozen)")
    global_eps_start: float = _opt(0.2, "exploration probability at the start of the "
                                   "aggregation stage (it decays to eps_end)")
    global_hidden: int = _opt(32, "units of the aggregation network's hidden layer")

    def check(self) -> CoderSettings:
        """Return self, or raise :class:`ConfigError` naming the first bad field."""
        super().check()
        for name, hi in (("global_episodes", 100_000), ("global_hidden", 4096)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= hi:
                raise ConfigError(f"{name}: must be an integer in [1, {hi}], got {value!r}")
        value = self.global_eps_start
        if isinstance(value, bool) or not isinstance(value, int | float) or not (
                0.0 <= value <= 1.0):
            raise ConfigError(f"global_eps_start: must be a number in [0.0, 1.0], got {value!r}")
        check_coder_grid(self.rows, self.cols)
        return self
