"""The batched env: environment b of a batch is a B = 1 run, bit for bit; partial resets; input."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from mivecc_env import ConfigError, mivecc_v0
from mivecc_env.batched import REWARD_TERMS, BatchedMiVeCCEnv, BatchStep
from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.network import GridNetwork
from mivecc_env.sim.state_graph import select_cloud_decisions, select_edge_decisions

FIELDS = ("edge_obs", "edge_mask", "cloud_obs", "cloud_mask", "edge_reward", "cloud_reward",
          "truncated", "episode_steps")


def actions(rng: np.random.Generator, env: BatchedMiVeCCEnv) -> tuple[np.ndarray, np.ndarray]:
    """Uniform actions of one environment: (n_edge, K_edge), ``cloud_action_shape``."""
    a = env.config.a_max_mps2
    return (rng.uniform(-a, a, (env.n_edge, env.k_edge)),
            rng.uniform(-a, a, env.cloud_action_shape))


def row(out: BatchStep, b: int) -> dict[str, np.ndarray]:
    """Every array of environment ``b`` of a step."""
    got = {f: getattr(out, f)[b] for f in FIELDS if getattr(out, f) is not None}
    got |= {f"edge_{k}": v[b] for k, v in out.edge_terms.items()}
    got |= {f"cloud_{k}": v[b] for k, v in out.cloud_terms.items()}
    return got


def assert_same(a: dict[str, np.ndarray], b: dict[str, np.ndarray], where: str) -> None:
    assert a.keys() == b.keys(), where
    for k in a:
        # array_equal on the raw bytes: bit-identical, not merely close.
        x, y = np.asarray(a[k]), np.asarray(b[k])
        assert x.dtype == y.dtype and x.shape == y.shape, f"{where}: {k}"
        assert x.tobytes() == y.tobytes(), f"{where}: {k} differs"


def run_against_singles(
    kw: dict, seeds: list[int], densities: list[float], steps: int,
    resets: dict[int, list[int]] | None = None,
) -> float:
    """Step a batch and B separate B = 1 envs with the same per-env seeds, demands and actions,
    comparing every observation, mask, reward term and summary at every step.

    ``resets``: step -> environments restarted (``reset_at``) after that step; the matching
    single env is reset unseeded (its next seed). Returns the number of real columns seen.
    """
    resets = resets or {}
    n = len(seeds)
    batch = BatchedMiVeCCEnv(batch_size=n, densities=densities, **kw)
    singles = [BatchedMiVeCCEnv(batch_size=1, densities=[d], **kw) for d in densities]
    rngs = [np.random.default_rng(1000 + s) for s in seeds]
    out = batch.reset(seed=seeds)
    refs = [e.reset(seed=s) for e, s in zip(singles, seeds, strict=True)]
    seen = 0.0
    for t in range(steps + 1):
        summary = batch.summary()
        for b in range(n):
            assert_same(row(out, b), row(refs[b], 0), f"step {t} env {b}")
            single = singles[b].summary()
            assert_same({k: v[b] for k, v in summary.items()},
                        {k: v[0] for k, v in single.items()}, f"summary step {t} env {b}")
        seen += float(out.edge_mask.sum())
        if t == steps:
            break
        acts = [actions(rng, batch) for rng in rngs]
        out = batch.step(np.stack([a[0] for a in acts]), np.stack([a[1] for a in acts]))
        refs = [e.step(a[0][None], a[1][None]) for e, a in zip(singles, acts, strict=True)]
        if t in resets:
            out = batch.reset_at(resets[t])
            for b in resets[t]:
                refs[b] = singles[b].reset()
            # the envs not reset keep their step's observations (reset_at rebuilds them
            # from the same state: identical)
    return seen


KW = {"rows": 1, "cols": 2, "scheme": "EEC", "max_steps": 1000}


def test_batch_of_7_mixed_densities_matches_single_runs() -> None:
    seeds = [3, 11, 0, 7, 123456789, 5, 42]
    densities = [600.0, 1800.0, 2400.0, 900.0, 1200.0, 3000.0, 1800.0]
    seen = run_against_singles(KW, seeds, densities, steps=150)
    assert seen > 1000  # vehicles were observed: the comparison was not of empty graphs


def test_partial_reset_restarts_with_own_next_seed() -> None:
    seeds = [1, 2, 3]
    seen = run_against_singles(KW, seeds, [1800.0] * 3, steps=120,
                               resets={40: [1], 70: [0, 2], 90: [1]})
    assert seen > 0


def test_partial_reset_clock_truncation_and_summary() -> None:
    env = BatchedMiVeCCEnv(batch_size=3, rows=1, cols=1, density=1800, max_steps=30)
    env.reset(seed=0)
    for _ in range(20):
        out = env.step()
    out = env.reset_at(np.array([False, True, False]))
    assert out.episode_steps.tolist() == [20, 0, 20]
    assert env.summary()["sim_time_s"].tolist() == [2.0, 0.0, 2.0]
    assert env.summary()["arrived"][1] == 0
    for _ in range(10):
        out = env.step()
    assert out.truncated.tolist() == [True, False, True]
    assert not out.terminated.any()
    s = env.summary()
    acc = s["backlog"] + s["in_network"] + s["throughput"] + s["collided_vehicles"]
    np.testing.assert_array_equal(s["arrived"], acc)


def test_same_int_seed_offsets_per_env_and_parallel_env_is_b1() -> None:
    kw = {"rows": 1, "cols": 2, "density": 1800, "scheme": "EEC", "max_steps": 50}
    batch = BatchedMiVeCCEnv(batch_size=2, **kw)
    out = batch.reset(seed=10)
    pars = [mivecc_v0.parallel_env(**kw) for _ in range(2)]
    obs = [p.reset(seed=10 + b)[0] for b, p in enumerate(pars)]
    for t in range(50):
        for b in range(2):
            np.testing.assert_array_equal(out.edge_obs[b, 1], obs[b]["edge_1"])
            np.testing.assert_array_equal(out.cloud_obs[b], obs[b]["cloud_0"])
        out = batch.step()
        steps = [p.step({}) for p in pars]
        obs = [s[0] for s in steps]
        for b in range(2):
            assert out.edge_reward[b].tolist() == [steps[b][1][f"edge_{i}"] for i in range(2)]
            assert out.truncated[b] == (t == 49) == steps[b][3]["cloud_0"]


def test_observe_defaults_by_scheme() -> None:
    ee = BatchedMiVeCCEnv(batch_size=2, rows=1, cols=1, scheme="EE").reset(seed=0)
    assert ee.cloud_obs is None and ee.cloud_mask is None
    assert ee.edge_obs.shape == (2, 1, 15, 15, 3) and ee.edge_obs.dtype == np.float32
    eec = BatchedMiVeCCEnv(batch_size=2, rows=1, cols=1, scheme="EEC").reset(seed=0)
    assert eec.cloud_obs.shape == (2, 60, 60, 3) and eec.cloud_mask.shape == (2, 60)
    only = BatchedMiVeCCEnv(batch_size=2, rows=1, cols=1, observe={"cloud"}).reset(seed=0)
    assert only.edge_obs is None and only.cloud_obs is not None
    assert set(only.edge_terms) == set(REWARD_TERMS)


def test_bad_input_names_the_argument() -> None:
    env = BatchedMiVeCCEnv(batch_size=2, rows=1, cols=2, scheme="EEC")
    with pytest.raises(RuntimeError, match="reset"):
        env.step()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"edge_action: .*\(2, 2, 15\).*got shape \(2, 15\)"):
        env.step(np.zeros((2, 15)))
    bad = np.zeros((2, 60))
    bad[1, 4] = np.inf  # NaN is accepted in padded columns (tests/env/test_action_rule.py)
    with pytest.raises(ValueError, match=r"cloud_action: .*NaN or inf.*\(1, 4\)"):
        env.step(None, bad)
    with pytest.raises(ValueError, match=r"cloud_action: .*\[-3.0, 3.0\]"):
        env.step(None, np.full((2, 60), 3.5))
    with pytest.raises(ValueError, match="env_index"):
        env.reset_at([2])
    with pytest.raises(ValueError, match="env_index"):
        env.reset_at(np.ones(3, dtype=bool))
    with pytest.raises(ValueError, match="seed"):
        env.reset_at([0, 1], seed=[1])
    with pytest.raises(ValueError, match=r"^seed: must be None, an integer >= 0, .* got -1$"):
        env.reset(seed=-1)
    with pytest.raises(ValueError, match=r"^seed: must be None, an integer >= 0, .* got -2$"):
        env.reset_at([1], seed=-2)
    with pytest.raises(ConfigError, match="densities"):
        BatchedMiVeCCEnv(batch_size=2, densities=[900.0])
    with pytest.raises(ConfigError, match="densities"):
        BatchedMiVeCCEnv(batch_size=2, densities=[900.0, 0.0])
    with pytest.raises(ConfigError, match="batch_size"):
        BatchedMiVeCCEnv(batch_size=0)
    with pytest.raises(ConfigError, match="observe"):
        BatchedMiVeCCEnv(observe={"edges"})


# --------------------------------------------------------------------------------------------
# Exact sort keys
def test_edge_decisions_sort_on_exact_sv() -> None:
    # Two vehicles in area 0 of environment 5000: a float key node * span + sv would round
    # their SV difference (1e-13) away and keep view order; the exact sort puts the lower first.
    cfg = MiVeCCConfig(rows=1, cols=1)
    net = GridNetwork.from_config(cfg)
    env = np.array([5000, 5000])
    view = SimpleNamespace(env=env, lane=np.zeros(2, np.int64), s=np.zeros(2))
    sv = np.array([0.5 + 1e-13, 0.5])
    span = cfg.sv_max - cfg.sv_min + 1.0
    float_key = env * span + (sv - cfg.sv_min)
    assert float_key[0] == float_key[1]  # the case the old key got wrong
    chosen, node, column = select_edge_decisions(net, view, sv, 15, cfg, np.zeros(2, np.int64))
    assert chosen.tolist() == [1, 0] and column.tolist() == [0, 1]
    assert node.tolist() == [5000, 5000]


def test_cloud_decisions_sort_on_exact_di() -> None:
    env = np.array([7000, 7000, 7001])
    view = SimpleNamespace(env=env)
    di = np.array([0.25, 0.25 + 1e-12, 3.0])
    di_max = 600.0
    assert (env * (di_max + 1) + (di_max - di))[0] == (env * (di_max + 1) + (di_max - di))[1]
    chosen, out_env, column = select_cloud_decisions(view, di, 60, di_max)
    assert chosen.tolist() == [1, 0, 2] and column.tolist() == [0, 1, 0]
    assert out_env.tolist() == [7000, 7000, 7001]


# --------------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("batch", [1, 7, 64])
def test_long_3x3_batches_match_single_runs(batch: int) -> None:
    kw = {"rows": 3, "cols": 3, "scheme": "EEC", "max_steps": 400}
    seeds = list(range(100, 100 + batch))
    densities = [float(d) for d in np.resize([900.0, 1500.0, 2100.0, 2700.0], batch)]
    resets = {150: [0], 250: list(range(0, batch, 3))}
    run_against_singles(kw, seeds, densities, steps=600, resets=resets)


def test_signalized_partial_reset_matches_single_runs() -> None:
    # Signal heads restart with their environment's clock.
    kw = {"rows": 1, "cols": 2, "control": "signalized", "max_steps": 1000}
    run_against_singles(kw, [4, 5], [1500.0, 1500.0], steps=250, resets={157: [1]})


def test_reset_at_refused_where_the_controller_has_one_clock() -> None:
    env = BatchedMiVeCCEnv(batch_size=2, rows=1, cols=1, control="reservation")
    env.reset(seed=0)
    with pytest.raises(NotImplementedError, match="reset_at"):
        env.reset_at([0])


def test_released_model_partial_reset_matches_single_runs() -> None:
    # The released model's per-environment state: random edge selection (drawn once per step,
    # not again when reset_at rebuilds the observations), stale-action records, entry lag.
    kw = {"rows": 1, "cols": 2, "scheme": "EEC", "max_steps": 1000, "model": "released"}
    seen = run_against_singles(kw, [1, 2, 3], [2100.0] * 3, steps=200,
                               resets={40: [1], 70: [0, 2], 90: [1], 150: [2]})
    assert seen > 1000


def test_more_bad_input_names_the_argument() -> None:
    with pytest.raises(ConfigError, match=r"^config: must be a MiVeCCConfig, got dict$"):
        BatchedMiVeCCEnv(config={"rows": 1})  # type: ignore[arg-type]
    env = BatchedMiVeCCEnv(batch_size=2, rows=1, cols=1, scheme="EE", observe={"cloud"})
    with pytest.raises(RuntimeError, match=r"^reset_at: call reset\(\) first$"):
        env.reset_at([0])
    env.reset(seed=0)
    with pytest.raises(RuntimeError, match="edge_action given but 'edge' is not observed"):
        env.step(np.zeros((2, 1, 15)))
    with pytest.raises(ValueError, match=r"^raw_edge: expected bools, got dtype int64$"):
        env.step(raw_edge=np.array([1, 0]))
    with pytest.raises(ValueError,
                       match=r"^raw_edge: expected one bool or 2 bools, got shape \(3,\)$"):
        env.step(raw_edge=[True, False, True])
    with pytest.raises(ValueError, match=r"^env_index: must be integers in \[0, 1\] or a \(2,\) "
                       r"bool mask, got dtype float64$"):
        env.reset_at([0.0])
    with pytest.raises(ValueError, match=r"^env_index: .*, got a bool mask of shape \(3,\)"):
        env.reset_at([True, False, True])
    with pytest.raises(ValueError, match=r"^env_index: repeated indices \[1, 1\]$"):
        env.reset_at([1, 1])
    with pytest.raises(ValueError, match=r"^seed: must be None, an integer >= 0, or a sequence "
                       r"of integers >= 0, got 'ab'$"):
        env.reset(seed="ab")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^seed: need one seed per environment \(2\), got 1$"):
        env.reset(seed=[3])
    cloud_only = BatchedMiVeCCEnv(batch_size=1, rows=1, cols=1, scheme="EEC", observe={"edge"})
    cloud_only.reset(seed=0)
    with pytest.raises(RuntimeError, match="cloud_action given but 'cloud' is not observed"):
        cloud_only.step(None, np.zeros((1, 60)))
    with pytest.raises(RuntimeError, match=r"start_chunk: only for continuous=True"):
        cloud_only.start_chunk([0])
    chunks = BatchedMiVeCCEnv(batch_size=1, rows=1, cols=1, continuous=True, max_steps=5)
    with pytest.raises(RuntimeError, match=r"^start_chunk: call reset\(\) first$"):
        chunks.start_chunk([0])


def test_densities_are_a_read_only_view() -> None:
    env = BatchedMiVeCCEnv(batch_size=2, rows=1, cols=1, densities=[600.0, 1800.0])
    d = env.densities
    assert d.tolist() == [600.0, 1800.0]
    with pytest.raises(ValueError, match="read-only"):
        d[0] = 0.0
    assert env.densities.tolist() == [600.0, 1800.0]
