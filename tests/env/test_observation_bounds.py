"""Every observation lies in its declared ``Box(-1, 1)``, in every control mode and scheme.

Signal braking reaches ``-idm_max_decel_mps2`` (9 m/s^2), three times ``a_max``: the
acceleration channel is scaled by the control mode's largest magnitude
(:func:`mivecc_env.sim.state_graph.accel_scale_mps2`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mivecc_env import mivecc_v0
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.state_graph import accel_scale_mps2, edge_graphs
from tests.sim._scenario import EAST, SOUTH, hand_sim, place

CONTROLS = next(
    f.metadata["choices"] for f in dataclasses.fields(MiVeCCConfig) if f.name == "control"
)
SCHEMES = next(
    f.metadata["choices"] for f in dataclasses.fields(MiVeCCConfig) if f.name == "scheme"
)


def random_run_stays_in_box(steps: int, seed: int, **kw: object) -> float:
    """Run ``steps`` random-action steps, assert every observation and the state lie in their
    spaces; return the lowest acceleration [m/s^2] any vehicle had (to show the run was hard)."""
    env = mivecc_v0.parallel_env(max_steps=steps, **kw)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    lowest = 0.0
    while True:
        for agent, o in obs.items():
            space = env.observation_space(agent)
            assert space.contains(o), (
                f"{agent} at step {env.sim.step_count} ({kw}): min {o.min(axis=(0, 1))} "
                f"max {o.max(axis=(0, 1))} outside {space}"
            )
        if env.sim.active.any():
            lowest = min(lowest, float(env.sim.a[env.sim.active].min()))
        if not env.agents:
            return lowest
        acts = {
            a: rng.uniform(-1, 1, env.action_space(a).shape) * env.config.a_max_mps2
            for a in env.agents
        }
        obs, *_ = env.step(acts)


def test_signal_braking_stays_in_the_box() -> None:
    # This seed brakes harder than -a_max at a red light within 400 steps (~step 300).
    cfg = {"rows": 2, "cols": 2, "density": 3000, "control": "signalized", "scheme": "EEC"}
    lowest = random_run_stays_in_box(400, seed=2, **cfg)
    assert lowest < -MiVeCCConfig().a_max_mps2, "the run never braked beyond a_max: vacuous"


@pytest.mark.slow
@pytest.mark.parametrize("control", CONTROLS)
@pytest.mark.parametrize("scheme", SCHEMES)
def test_long_random_runs_stay_in_the_box(control: str, scheme: str) -> None:
    for seed, (rows, cols, density) in enumerate([(2, 2, 3000), (1, 3, 1500), (1, 1, 3600)]):
        random_run_stays_in_box(
            1000, seed=seed, rows=rows, cols=cols, density=density, control=control,
            scheme=scheme,
        )


@pytest.mark.parametrize(
    ("control", "scale"), [("unsignalized", 3.0), ("signalized", 9.0)]
)
def test_acceleration_channel_is_scaled_not_saturated(control: str, scale: float) -> None:
    cfg = MiVeCCConfig(rows=1, cols=1, control=control)
    assert accel_scale_mps2(cfg) == scale
    sim = hand_sim(cfg)
    a_lo = -scale  # the hardest braking of the mode; a_max = 3 in both
    place(sim, [(EAST, 130.0, 10.0), (EAST, 100.0, 12.0), (SOUTH, 135.0, 11.0)],
          accel=[a_lo, a_lo / 2, 3.0])
    view = sim.view
    g = edge_graphs(sim.network, view, sim.safety.sv, sim.v.ravel()[view.vehicle],
                    sim.a.ravel()[view.vehicle], 1, cfg)
    heads = g.obs[0, 0, 0, :3, 2]  # row 0 (the vehicle itself), acceleration channel
    expected = np.array([a_lo, a_lo / 2, 3.0])[g.view_index[0, 0, :3]] / scale
    np.testing.assert_allclose(heads, expected, rtol=1e-6)
    assert heads.min() == -1.0
