"""Bad input to the MiVeCC environments fails early with a message that says what to fix."""

from __future__ import annotations

import re

import gymnasium
import numpy as np
import pytest

import mivecc_env  # noqa: F401  (registers the gymnasium id)
from mivecc_env import ConfigError, MiVeCCConfig, MiVeCCParallelEnv, mivecc_v0

GYM_ID = "mivecc/MiVeCCEdge-v0"


@pytest.fixture
def env() -> MiVeCCParallelEnv:
    """A reset 1 x 2 grid (agents edge_0, edge_1, cloud_0)."""
    e = mivecc_v0.parallel_env(rows=1, cols=2, density=1800, max_steps=50, scheme="EEC")
    e.reset(seed=0)
    for _ in range(5):
        e.step({})
    return e


def good_actions(env: MiVeCCParallelEnv) -> dict[str, np.ndarray]:
    return {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.agents}


def step_rejects(env: MiVeCCParallelEnv, agent: str, action: object, *fragments: str) -> None:
    """``step`` with ``agent``'s action replaced raises ValueError naming the agent and all
    ``fragments``, and leaves the environment where it was."""
    actions: dict[str, object] = dict(good_actions(env))
    actions[agent] = action
    before = env.sim.step_count
    with pytest.raises(ValueError, match=re.escape(repr(agent))) as err:
        env.step(actions)  # type: ignore[arg-type]
    for fragment in fragments:
        assert fragment in str(err.value)
    assert env.sim.step_count == before
    env.step(good_actions(env))  # still usable


# --------------------------------------------------------------------------------------------
# Actions
@pytest.mark.parametrize(
    ("agent", "shape", "expected"),
    [
        ("edge_0", (14,), "(15,)"),
        ("edge_1", (16,), "(15,)"),
        ("edge_1", (15, 1), "(15,)"),
        ("edge_0", (), "(15,)"),
        ("edge_0", (60,), "(15,)"),
        ("cloud_0", (15,), "(60,)"),
        ("cloud_0", (1, 60), "(60,)"),
    ],
)
def test_wrong_action_shape(
    env: MiVeCCParallelEnv, agent: str, shape: tuple[int, ...], expected: str
) -> None:
    step_rejects(
        env, agent, np.zeros(shape, np.float32), f"expected shape {expected}", f"got shape {shape}"
    )


@pytest.mark.parametrize("agent", ["edge_1", "cloud_0"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_action(agent: str, bad: float) -> None:
    # NaN is accepted in padded columns (mask 0): run until the agent has real ones.
    e = mivecc_v0.parallel_env(rows=1, cols=2, density=1800, max_steps=300, scheme="EEC")
    e.reset(seed=0)
    for _ in range(100):
        infos = e.step({})[4]
    col = int(np.flatnonzero(infos[agent]["mask"])[-1])
    action = np.zeros(e.action_space(agent).shape, np.float32)
    action[col] = bad
    step_rejects(e, agent, action, "NaN or inf", "[-3.0, 3.0]", f"index {col}")


@pytest.mark.parametrize("agent", ["edge_0", "cloud_0"])
@pytest.mark.parametrize("bad", [3.01, -3.5, 1e9])
def test_out_of_range_action(env: MiVeCCParallelEnv, agent: str, bad: float) -> None:
    action = np.zeros(env.action_space(agent).shape)
    action[-1] = bad
    step_rejects(env, agent, action, "[-3.0, 3.0]", "clip")


def test_out_of_range_follows_a_max() -> None:
    e = mivecc_v0.parallel_env(rows=1, cols=1, a_max_mps2=2.0, max_steps=5)
    e.reset(seed=0)
    e.step({"edge_0": np.full(15, 2.0)})
    with pytest.raises(ValueError, match=re.escape("[-2.0, 2.0]")):
        e.step({"edge_0": np.full(15, 2.5)})


def test_non_numeric_action(env: MiVeCCParallelEnv) -> None:
    step_rejects(env, "edge_1", ["a"] * 15, "expected shape (15,)", "non-numeric")
    step_rejects(env, "cloud_0", None, "expected shape (60,)")


@pytest.mark.parametrize("key", ["edge_2", "edge_99", "cloud_1", "foo", 0])
def test_unknown_agent(env: MiVeCCParallelEnv, key: object) -> None:
    actions: dict[object, np.ndarray] = dict(good_actions(env))
    actions[key] = np.zeros(15, np.float32)
    with pytest.raises(ValueError, match="unknown agents") as err:
        env.step(actions)  # type: ignore[arg-type]
    assert repr(str(key)) in str(err.value)
    assert "edge_0" in str(err.value)  # lists the valid agents


@pytest.mark.parametrize("key", ["edge_2", "cloud_1", 0, ["edge_0"]])
def test_spaces_of_an_unknown_agent_name_the_agents(env: MiVeCCParallelEnv, key: object) -> None:
    from mivecc_env import mivecc_edges_v0

    edges = mivecc_edges_v0.parallel_env(rows=1, cols=2)
    for e in (env, edges):
        for what in ("action_space", "observation_space"):
            with pytest.raises(KeyError, match=rf"{what}: unknown agent {re.escape(repr(key))}; "
                               r"agents are \['edge_0', 'edge_1'"):
                getattr(e, what)(key)
    with pytest.raises(KeyError, match="unknown agent 'cloud_0'"):  # not an agent of edges
        edges.action_space("cloud_0")
    assert env.action_space("cloud_0").shape == (60,)


def test_actions_not_a_dict(env: MiVeCCParallelEnv) -> None:
    with pytest.raises(ValueError, match="expected a dict"):
        env.step([np.zeros(15)] * 3)  # type: ignore[arg-type]


def test_single_agent_bad_action() -> None:
    e = gymnasium.make(GYM_ID, rows=1, cols=1, max_steps=10)
    e.reset(seed=0)
    with pytest.raises(ValueError, match=re.escape("'edge_0'")):
        e.step(np.full(15, np.inf))  # NaN would be accepted in the padded columns
    with pytest.raises(ValueError, match=re.escape("expected shape (15,)")):
        e.step(np.zeros(3))


# --------------------------------------------------------------------------------------------
# Configuration
@pytest.mark.parametrize(
    ("kwargs", "field", "fragments"),
    [
        ({"rows": 0}, "rows", ("[1, 16]", "got 0")),
        ({"cols": 17}, "cols", ("[1, 16]",)),
        ({"rows": 1.5}, "rows", ("an integer",)),
        ({"density": -5}, "density_vplh", ("[1.0, 3600.0]", "got -5")),
        ({"density": float("nan")}, "density_vplh", ("[1.0, 3600.0]",)),
        ({"max_steps": 0}, "max_steps", ("[1, ",)),
        ({"scheme": "X"}, "scheme", ("'E', 'EE', 'EEC'",)),
        ({"k_edge": 1}, "k_edge", ("[2, 256]",)),
        ({"render_mode": "ansi"}, "render_mode", ("rgb_array", "'ansi'")),
        ({"config": {"rows": 1}}, "config", ("MiVeCCConfig", "dict")),
        ({"densty": 900}, "densty", ("unknown", "did you mean 'density'")),
        ({"seed": 3}, "seed", ("unknown",)),
    ],
)
def test_bad_config(kwargs: dict[str, object], field: str, fragments: tuple[str, ...]) -> None:
    with pytest.raises(ConfigError) as err:
        mivecc_v0.parallel_env(**kwargs)
    message = str(err.value)
    assert message.startswith(f"{field}: ")
    for fragment in fragments:
        assert fragment in message


def test_config_error_is_a_value_error() -> None:
    assert issubclass(ConfigError, ValueError)


def test_config_object_and_overrides() -> None:
    cfg = MiVeCCConfig(rows=1, cols=1)
    e = mivecc_v0.parallel_env(config=cfg, density=1200)
    assert e.config.rows == 1 and e.config.density_vplh == 1200
    with pytest.raises(ConfigError, match="rows"):
        mivecc_v0.parallel_env(config=cfg, rows=-1)


def test_aec_env_bad_config() -> None:
    with pytest.raises(ConfigError, match="rows"):
        mivecc_v0.env(rows=0)


def test_aec_env_checks_an_action_when_it_is_given() -> None:
    aec = mivecc_v0.env(rows=1, cols=1, control="signalized", signal_agents=True, scheme="EE")
    aec.reset(seed=0)
    assert aec.agent_selection == "edge_0"
    with pytest.raises(ValueError, match=r"^actions\['edge_0'\]: expected shape \(15,\)"):
        aec.step(np.zeros(3))
    assert aec.agent_selection == "edge_0"  # the turn was not taken
    aec.step(np.zeros(15))
    while aec.agent_selection != "signal_0":
        aec.step(np.zeros(aec.action_space(aec.agent_selection).shape, np.float32))
    with pytest.raises(ValueError, match="signal_0"):
        aec.step(5)
    aec.step(1)  # a valid phase: the cycle completes
    assert aec.agent_selection == "edge_0"


def test_edges_aec_env_checks_an_action_when_it_is_given() -> None:
    from mivecc_env import mivecc_edges_v0

    aec = mivecc_edges_v0.env(rows=1, cols=2)
    aec.reset(seed=0)
    with pytest.raises(ValueError, match=r"^actions\['edge_0'\]: .*got shape \(60,\)"):
        aec.step(np.zeros(60))
    assert aec.agent_selection == "edge_0"
    aec.step(np.zeros(15))
    aec.step(np.zeros(15))
    assert aec.agent_selection == "edge_0"  # the cycle completed
    with pytest.raises(ValueError, match=r"^actions: unknown agents \['cloud_0'\]"):
        mivecc_edges_v0.parallel_env(rows=1, cols=2).check_action("cloud_0", np.zeros(60))


def test_parallel_env_checks_one_action(env: MiVeCCParallelEnv) -> None:
    assert env.check_action("edge_1", np.zeros(15)) is None
    with pytest.raises(ValueError, match=r"^actions\['cloud_0'\]: .*got shape \(15,\)"):
        env.check_action("cloud_0", np.zeros(15))
    with pytest.raises(ValueError, match=r"^actions: unknown agents \['edge_7'\]"):
        env.check_action("edge_7", np.zeros(15))


@pytest.mark.parametrize(
    ("kwargs", "fragments"),
    [
        ({"intersection": 99}, ("intersection", "[0, 0]", "99")),
        ({"intersection": -1}, ("intersection", "[0, 0]")),
        ({"intersection": True}, ("intersection",)),
        ({"intersection": 3, "rows": 2, "cols": 1}, ("intersection", "[0, 1]")),
        ({"density": -5}, ("density_vplh",)),
        ({"colls": 2}, ("colls", "unknown")),
    ],
)
def test_gymnasium_bad_config(kwargs: dict[str, object], fragments: tuple[str, ...]) -> None:
    kwargs = {"rows": 1, "cols": 1, **kwargs}
    with pytest.raises(ConfigError) as err:
        gymnasium.make(GYM_ID, **kwargs)
    for fragment in fragments:
        assert fragment in str(err.value)


# --------------------------------------------------------------------------------------------
# Call order
def test_step_before_reset() -> None:
    e = mivecc_v0.parallel_env(rows=1, cols=1)
    with pytest.raises(RuntimeError, match=r"reset\(\)"):
        e.step({})
    with pytest.raises(RuntimeError, match=r"reset\(\)"):
        e.state()


def test_step_after_episode_end() -> None:
    e = mivecc_v0.parallel_env(rows=1, cols=1, max_steps=2)
    e.reset(seed=0)
    e.step({})
    e.step({})
    assert e.agents == []
    with pytest.raises(RuntimeError, match=r"reset\(\)"):
        e.step({})
    e.reset()
    e.step({})


def test_check_action_raises_exactly_what_step_raises() -> None:
    """The AEC's early check (with its fast path for in-box arrays) and the parallel step
    accept and refuse the same actions, with the same message."""
    import torch

    env = mivecc_v0.parallel_env(rows=1, cols=2, density=1800, scheme="EEC", max_cycles=500)
    env.reset(seed=3)
    for _ in range(150):  # vehicles in the areas, so some columns are real and some padded
        env.step({a: np.zeros(env.action_space(a).shape, np.float32) for a in env.agents})
    mask = env.batched._last.edge_mask[0, 0]
    assert 0 < mask.sum() < mask.size
    real, padded = int(np.flatnonzero(mask)[0]), int(np.flatnonzero(mask == 0)[0])

    def with_value(col: int, value: float) -> np.ndarray:
        a = np.zeros(15)
        a[col] = value
        return a

    candidates = [
        np.zeros(15, np.float32), np.full(15, 3.0), np.full(15, 3.0 + 1e-3), list(range(15)),
        np.arange(15) % 3, with_value(real, np.nan), with_value(padded, np.nan),
        with_value(real, np.inf), with_value(padded, 99.0), np.zeros(14), np.zeros((1, 15)),
        torch.zeros(15), torch.full((15,), 5.0), "fast", None,
    ]
    zeros = {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.agents}

    def error(call, *args) -> str | None:
        try:
            call(*args)
        except ValueError as err:
            return str(err)
        return None

    for action in candidates:
        early = error(env.check_action, "edge_0", action)
        assert early == error(env.step, {**zeros, "edge_0": action}), (action, early)
