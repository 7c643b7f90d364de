"""The action rule (``mivecc_env.actions``) through every front end: ParallelEnv, AEC, the
batched env and the gymnasium views.

NaN in a padded column (mask 0) is accepted and changes nothing; NaN in a real column is
rejected naming the agent (or argument) and the column; a torch tensor that requires grad is
accepted as its values.
"""

from __future__ import annotations

import re

import gymnasium
import numpy as np
import pytest

import mivecc_env  # noqa: F401  (registers the gymnasium ids)
from mivecc_env import mivecc_v0
from mivecc_env.actions import checked_action
from mivecc_env.batched import BatchedMiVeCCEnv
from mivecc_env.single_agent import MiVeCCEdgeVectorEnv

KW = {"rows": 1, "cols": 2, "density": 1800, "max_steps": 300, "scheme": "EEC"}
WARMUP = 100  # steps until some columns are real and some padded


def mixed(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(real, padded) column indices of ``mask``; the test needs both kinds."""
    real, padded = np.flatnonzero(mask), np.flatnonzero(mask == 0)
    assert real.size and padded.size, f"test setup: mask {mask} needs real and padded columns"
    return real, padded


def action(mask: np.ndarray, padded_value: float, value: float = 0.5) -> np.ndarray:
    """``value`` in the real columns, ``padded_value`` in the padded ones (float32)."""
    return np.where(mask != 0, value, padded_value).astype(np.float32)


def parallel_after_warmup():
    env = mivecc_v0.parallel_env(**KW)
    env.reset(seed=3)
    for _ in range(WARMUP - 1):
        env.step({})
    infos = env.step({})[4]
    return env, infos


# --------------------------------------------------------------------------------------------
# the rule itself
def test_rule_padded_nan_ok_real_nan_and_padded_inf_rejected() -> None:
    mask = np.array([1, 1, 0, 0], np.float32)
    out = checked_action([0.1, -0.2, np.nan, np.nan], "a", (4,), 3.0, mask)
    assert np.isnan(out[2:]).all() and out[:2].tolist() == pytest.approx([0.1, -0.2])
    with pytest.raises(ValueError, match=re.escape("a: ") + ".*NaN or inf.*index 1"):
        checked_action([0.1, np.nan, 0.0, 0.0], "a", (4,), 3.0, mask)
    with pytest.raises(ValueError, match=r"NaN or inf.*index 3"):  # inf is out of the box
        checked_action([0.1, 0.0, 0.0, np.inf], "a", (4,), 3.0, mask)
    with pytest.raises(ValueError, match=re.escape("[-3.0, 3.0]") + ".*index 2"):
        checked_action([0.1, 0.0, 3.5, 0.0], "a", (4,), 3.0, mask)
    with pytest.raises(ValueError, match="NaN or inf"):  # no mask: every column is real
        checked_action([0.1, 0.0, np.nan, 0.0], "a", (4,), 3.0)


def test_rule_requires_grad_tensor() -> None:
    torch = pytest.importorskip("torch")
    t = torch.tensor([0.5, -1.0, float("nan")], requires_grad=True)
    out = checked_action(t * 2, "a", (3,), 3.0, np.array([1, 1, 0]))
    assert out.dtype == np.float64 and out[:2].tolist() == [1.0, -2.0]
    with pytest.raises(ValueError, match=r"NaN or inf.*index 2"):
        checked_action(t, "a", (3,), 3.0)


# --------------------------------------------------------------------------------------------
# ParallelEnv
@pytest.mark.parametrize("agent", ["edge_0", "edge_1", "cloud_0"])
def test_parallel_padded_nan_accepted_and_ignored(agent: str) -> None:
    a, infos_a = parallel_after_warmup()
    b, infos_b = parallel_after_warmup()
    mask = infos_a[agent]["mask"]
    np.testing.assert_array_equal(mask, infos_b[agent]["mask"])
    mixed(mask)
    out_a = a.step({agent: action(mask, np.nan)})
    out_b = b.step({agent: action(mask, 0.0)})
    for k in out_a[0]:
        np.testing.assert_array_equal(out_a[0][k], out_b[0][k])
    assert out_a[1] == out_b[1]
    np.testing.assert_array_equal(a.sim.v, b.sim.v)
    np.testing.assert_array_equal(a.sim.s, b.sim.s)


@pytest.mark.parametrize("agent", ["edge_1", "cloud_0"])
def test_parallel_real_nan_rejected(agent: str) -> None:
    env, infos = parallel_after_warmup()
    real, _ = mixed(infos[agent]["mask"])
    act = action(infos[agent]["mask"], np.nan)
    act[real[-1]] = np.nan
    before = env.sim.step_count
    with pytest.raises(ValueError, match=re.escape(f"actions[{agent!r}]") + ".*NaN or inf.*"
                       + re.escape(f"(first at index {real[-1]})")):
        env.step({agent: act})
    assert env.sim.step_count == before


def test_parallel_requires_grad_tensor_is_its_values() -> None:
    torch = pytest.importorskip("torch")
    a, infos = parallel_after_warmup()
    b, _ = parallel_after_warmup()
    acts = {ag: action(infos[ag]["mask"], 0.0, v) for ag, v in
            (("edge_0", 1.0), ("edge_1", -0.5), ("cloud_0", 0.25))}
    tensors = {ag: torch.tensor(x, requires_grad=True) * 1.0 for ag, x in acts.items()}
    out_a = a.step(tensors)
    out_b = b.step(acts)
    assert out_a[1] == out_b[1]
    np.testing.assert_array_equal(a.sim.v, b.sim.v)
    # a tensor with a bad value is still rejected with the documented error
    bad = torch.full((15,), 9.0, requires_grad=True)
    with pytest.raises(ValueError, match=re.escape("actions['edge_1']") + ".*clip"):
        a.step({"edge_1": bad})


# --------------------------------------------------------------------------------------------
# AEC
def aec_run(make_action) -> tuple[object, list[float]]:
    """Play WARMUP + 1 cycles; in the last one every agent acts ``make_action(mask)``."""
    env = mivecc_v0.env(**KW)
    env.reset(seed=3)
    n = len(env.possible_agents)
    for _ in range(WARMUP * n):
        env.step(np.zeros(env.action_space(env.agent_selection).shape, np.float32))
    for _ in range(n):
        agent = env.agent_selection
        env.step(make_action(env.infos[agent]["mask"]))
    return env, [env.rewards[a] for a in env.possible_agents]


def test_aec_padded_nan_and_tensor() -> None:
    env_a, r_a = aec_run(lambda m: action(m, np.nan))
    env_b, r_b = aec_run(lambda m: action(m, 0.0))
    assert r_a == r_b
    np.testing.assert_array_equal(env_a.unwrapped.sim.v, env_b.unwrapped.sim.v)
    torch = pytest.importorskip("torch")
    _, r_c = aec_run(lambda m: torch.tensor(action(m, 0.0), requires_grad=True))
    assert r_c == r_b


def test_aec_real_nan_rejected() -> None:
    def bad(m: np.ndarray) -> np.ndarray:
        act = action(m, np.nan)
        act[np.flatnonzero(m)[0]] = np.nan
        return act

    with pytest.raises(ValueError, match=r"actions\['(edge_\d|cloud_0)'\].*NaN or inf"):
        aec_run(bad)


# --------------------------------------------------------------------------------------------
# batched env
def batched_after_warmup() -> tuple[BatchedMiVeCCEnv, object]:
    env = BatchedMiVeCCEnv(batch_size=2, **KW)
    env.reset(seed=[3, 4])
    out = None
    for _ in range(WARMUP):
        out = env.step()
    return env, out


def test_batched_padded_nan_accepted_real_nan_rejected() -> None:
    a, out = batched_after_warmup()
    b, _ = batched_after_warmup()
    mixed(out.edge_mask.ravel())
    mixed(out.cloud_mask.ravel())
    step_a = a.step(action(out.edge_mask, np.nan), action(out.cloud_mask, np.nan))
    step_b = b.step(action(out.edge_mask, 0.0), action(out.cloud_mask, 0.0))
    np.testing.assert_array_equal(step_a.edge_reward, step_b.edge_reward)
    np.testing.assert_array_equal(a.sim.v, b.sim.v)
    edge = action(step_a.edge_mask, np.nan)
    real = tuple(int(i) for i in np.argwhere(step_a.edge_mask != 0)[0])
    edge[real] = np.nan
    with pytest.raises(ValueError, match=re.escape("edge_action: ") + ".*NaN or inf.*"
                       + re.escape(f"(first at index {real})")):
        a.step(edge)
    cloud = action(step_a.cloud_mask, np.nan)
    cloud[0, np.flatnonzero(step_a.cloud_mask[0])[0]] = np.nan
    with pytest.raises(ValueError, match=re.escape("cloud_action: ") + ".*NaN or inf"):
        a.step(None, cloud)


def test_batched_requires_grad_tensor() -> None:
    torch = pytest.importorskip("torch")
    a, out = batched_after_warmup()
    b, _ = batched_after_warmup()
    edge = action(out.edge_mask, 0.0, -0.75)
    step_a = a.step(torch.tensor(edge, requires_grad=True))
    step_b = b.step(edge)
    np.testing.assert_array_equal(step_a.edge_reward, step_b.edge_reward)
    np.testing.assert_array_equal(a.sim.v, b.sim.v)


# --------------------------------------------------------------------------------------------
# gymnasium views
def test_gymnasium_single_agent() -> None:
    def make():
        e = gymnasium.make("mivecc/MiVeCCEdge-v0", **KW)
        e.reset(seed=3)
        info = None
        for _ in range(WARMUP):
            info = e.step(np.zeros(15, np.float32))[4]
        return e, info["mask"]

    a, mask = make()
    b, _ = make()
    mixed(mask)
    r_a = a.step(action(mask, np.nan))[1]
    r_b = b.step(action(mask, 0.0))[1]
    assert r_a == r_b
    np.testing.assert_array_equal(a.unwrapped.parallel_env.sim.v,
                                  b.unwrapped.parallel_env.sim.v)
    mask = a.step(np.zeros(15, np.float32))[4]["mask"]
    act = action(mask, np.nan)
    act[np.flatnonzero(mask)[0]] = np.nan
    with pytest.raises(ValueError, match=re.escape("actions['edge_0']") + ".*NaN or inf"):
        a.step(act)
    torch = pytest.importorskip("torch")
    a.step(torch.zeros(15, requires_grad=True))


def test_gymnasium_vector_view() -> None:
    env = MiVeCCEdgeVectorEnv(num_envs=2, **KW)
    env.reset(seed=3)
    for _ in range(WARMUP):
        infos = env.step(np.zeros((2, 15), np.float32))[4]
    mask = infos["mask"]
    mixed(mask.ravel())
    env.step(action(mask, np.nan))
    mask = env.step(np.zeros((2, 15), np.float32))[4]["mask"]
    act = action(mask, np.nan)
    real = tuple(int(i) for i in np.argwhere(mask != 0)[0])
    act[real] = np.nan
    with pytest.raises(ValueError, match=re.escape("actions: ") + ".*NaN or inf.*"
                       + re.escape(f"(first at index {real})")):
        env.step(act)
    torch = pytest.importorskip("torch")
    env.step(torch.zeros((2, 15), requires_grad=True))
