"""Bad input to the simulator and the config fails with a message naming the argument; numpy
scalars are accepted like the Python values they hold."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env.config import ConfigError, MiVeCCConfig, from_overrides
from mivecc_env.sim.core import Simulator


def _sim(batch_size: int = 2) -> Simulator:
    cfg = MiVeCCConfig(rows=1, cols=1, density_vplh=2100, scheme="EEC")
    return Simulator(cfg, batch_size=batch_size, seed=0)


def _run_until_vehicles(sim: Simulator) -> None:
    for _ in range(30):
        sim.step()
    assert sim.active.any()


# --- Simulator.step action arrays -------------------------------------------------------
@pytest.mark.parametrize("name", ["edge_accel", "cloud_accel"])
def test_step_rejects_transposed_action(name: str) -> None:
    sim = _sim()
    bad = np.zeros(sim.active.shape[::-1])
    with pytest.raises(ValueError, match=rf"^{name}: must have shape \(2, {sim.capacity}\)"):
        sim.step(**{name: bad})


def test_step_rejects_stale_capacity_array() -> None:
    sim = Simulator(MiVeCCConfig(rows=1, cols=1, density_vplh=3600), batch_size=1, seed=0,
                    capacity=8)
    stale = np.zeros((1, sim.capacity))
    while sim.capacity == stale.shape[1]:
        sim.step(edge_accel=np.zeros((1, sim.capacity)))
    with pytest.raises(ValueError, match=r"^edge_accel: must have shape .*grows"):
        sim.step(edge_accel=stale)


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (np.inf, "finite or NaN"),
        (-np.inf, "finite or NaN"),
    ],
)
def test_step_rejects_infinite_action(value: float, message: str) -> None:
    sim = _sim()
    a = np.zeros(sim.active.shape)
    a[0, 0] = value
    with pytest.raises(ValueError, match=rf"^cloud_accel: .*{message}"):
        sim.step(cloud_accel=a)


def test_step_rejects_non_numeric_action() -> None:
    sim = _sim()
    with pytest.raises(ValueError, match=r"^edge_accel: must be a numeric"):
        sim.step(edge_accel=np.full(sim.active.shape, "x"))
    with pytest.raises(ValueError, match=r"^edge_accel: must be a numeric"):
        sim.step(edge_accel=np.zeros(sim.active.shape, dtype=bool))


def test_step_accepts_nan_int_and_list_actions() -> None:
    """NaN is "no action"; integer arrays and nested lists of the right shape are numeric."""
    a, b = _sim(), _sim()
    _run_until_vehicles(a)
    _run_until_vehicles(b)
    a.step(edge_accel=np.full(a.active.shape, np.nan), cloud_accel=None)
    b.step()
    np.testing.assert_array_equal(a.s, b.s)  # NaN everywhere == no action at all
    a.step(edge_accel=np.zeros(a.active.shape, dtype=np.int64))
    a.step(edge_accel=np.zeros(a.active.shape).tolist())


# --- batch size and seeds ---------------------------------------------------------------
def test_numpy_integer_batch_size_is_accepted() -> None:
    sim = Simulator(MiVeCCConfig(rows=1, cols=1), batch_size=np.int64(4), seed=np.int64(3))
    assert sim.batch_size == 4 and type(sim.batch_size) is int


@pytest.mark.parametrize("bad", [0, -1, 2.0, "4", True, None])
def test_bad_batch_size_names_argument(bad: object) -> None:
    with pytest.raises(ValueError, match=r"^batch_size: must be an integer >= 1"):
        Simulator(MiVeCCConfig(rows=1, cols=1), batch_size=bad)  # type: ignore[arg-type]


@pytest.mark.parametrize("bad", [-1, 1.5, "abc", {"a": 1}, True, [0, -2], [0, 1.5]])
def test_bad_seed_names_argument(bad: object) -> None:
    with pytest.raises(ValueError, match=r"^seed: must be None, an integer >= 0"):
        Simulator(MiVeCCConfig(rows=1, cols=1), batch_size=2, seed=bad)  # type: ignore[arg-type]
    sim = _sim()
    with pytest.raises(ValueError, match=r"^seed: "):
        sim.reset(bad)  # type: ignore[arg-type]


def test_seed_list_of_wrong_length_names_argument() -> None:
    with pytest.raises(ValueError, match=r"^seed: need one seed per environment \(2\), got 3"):
        _sim().reset([1, 2, 3])


def test_numpy_seeds_equal_python_seeds() -> None:
    a, b = _sim(), _sim()
    a.reset(np.uint32(7))
    b.reset(7)
    _run_until_vehicles(a)
    _run_until_vehicles(b)
    np.testing.assert_array_equal(a.s, b.s)
    a.reset(np.array([4, 5]))
    b.reset([4, 5])
    _run_until_vehicles(a)
    _run_until_vehicles(b)
    np.testing.assert_array_equal(a.s, b.s)


# --- config -----------------------------------------------------------------------------
def test_numpy_scalars_are_accepted_as_python_values() -> None:
    cfg = MiVeCCConfig(
        rows=np.int64(3), cols=np.int32(2), density_vplh=np.float32(1500.0),
        scheme=np.str_("EEC"), same_lane_rule=np.bool_(True), omega=np.float64(0.3),
    )
    assert (cfg.rows, cfg.cols, cfg.scheme, cfg.same_lane_rule) == (3, 2, "EEC", True)
    assert type(cfg.rows) is int and type(cfg.scheme) is str and type(cfg.same_lane_rule) is bool
    assert type(cfg.density_vplh) is float and cfg.density_vplh == 1500.0
    assert from_overrides(density=np.float32(900), rows=np.float64(2.0)).rows == 2
    assert cfg == MiVeCCConfig(rows=3, cols=2, density_vplh=1500.0, scheme="EEC",
                               same_lane_rule=True, omega=0.3)


def test_numpy_scalars_are_still_range_checked() -> None:
    with pytest.raises(ConfigError, match=r"^rows: must be an integer in \[1, 16\]"):
        MiVeCCConfig(rows=np.int64(0))
    with pytest.raises(ConfigError, match=r"^scheme: must be one of"):
        MiVeCCConfig(scheme=np.str_("X"))


def test_density_and_density_vplh_together_are_rejected() -> None:
    with pytest.raises(ConfigError, match=r"^density: given together with density_vplh"):
        from_overrides(density=900, density_vplh=2100)
    with pytest.raises(ConfigError, match=r"^density: given together with density_vplh"):
        from_overrides(density_vplh=2100, density=900)


def test_vehicles_longer_than_the_lane_spacing_are_rejected() -> None:
    with pytest.raises(ConfigError, match=r"^vehicle_length_m: must be at most 2 \* lane_offset"):
        MiVeCCConfig(lane_offset_m=1.5, vehicle_length_m=3.5)
    MiVeCCConfig(lane_offset_m=1.5, vehicle_length_m=3.0)  # exactly the spacing is allowed


def test_time_step_that_lets_a_vehicle_pass_another_is_rejected() -> None:
    # 13 m/s * 0.4 s = 5.2 m >= 2 * 2 m: a vehicle could jump across a collision zone
    with pytest.raises(ConfigError, match=r"^dt_s: v_max_mps \* dt_s = 5\.2 m per step"):
        MiVeCCConfig(dt_s=0.4)
    MiVeCCConfig(dt_s=0.3)  # 3.9 m < 4 m
    with pytest.raises(ConfigError, match=r"^dt_s: "):
        MiVeCCConfig(dt_s=0.1, v_max_mps=40.0, vehicle_length_m=1.0)


@pytest.mark.parametrize("bad", [-1, 1.5, "abc", {"a": 1}])
def test_parallel_env_reset_bad_seed_names_argument(bad: object) -> None:
    from mivecc_env import mivecc_v0

    env = mivecc_v0.parallel_env(rows=1, cols=1)
    with pytest.raises(ValueError, match=r"^seed: must be None, an integer >= 0"):
        env.reset(seed=bad)  # type: ignore[arg-type]
    obs_a, _ = env.reset(seed=np.int64(3))
    obs_b, _ = env.reset(seed=3)
    assert all(np.array_equal(obs_a[k], obs_b[k]) for k in obs_a)


def test_zero_dimensional_seed_array_names_argument() -> None:
    with pytest.raises(ValueError, match=r"^seed: must be None, an integer >= 0"):
        Simulator(MiVeCCConfig(rows=1, cols=1), batch_size=2,
                  seed=np.array(3))  # type: ignore[arg-type]


def test_non_numeric_densities_name_argument() -> None:
    with pytest.raises(ValueError, match=r"^densities: expected 2 numbers \[veh/lane/h\]$"):
        Simulator(MiVeCCConfig(rows=1, cols=1), batch_size=2, densities=["a", "b"])


def test_reset_at_needs_one_seed_per_environment() -> None:
    sim = _sim()
    with pytest.raises(ValueError, match=r"^seeds: need one seed per reset environment \(1\), "
                       r"got 2$"):
        sim.reset_at([1], [4, 5])


def test_action_that_cannot_become_an_array_names_argument() -> None:
    class Unconvertible:  # like a torch tensor that requires grad
        def __array__(self, *args: object, **kwargs: object) -> np.ndarray:
            raise RuntimeError("cannot convert")

    sim = _sim()
    with pytest.raises(ValueError, match=r"^cloud_accel: must be a numeric array of shape "
                       r"\(2, \d+\) \(batch_size, capacity\), got Unconvertible"):
        sim.step(cloud_accel=Unconvertible())


def test_reset_at_names_bad_environment_indices() -> None:
    sim = _sim()
    for bad, message in (([5], r"must be integers in \[0, 1\], got \[5\]"),
                         ([-1], r"must be integers in \[0, 1\], got \[-1\]"),
                         ([0, 0], r"repeated indices \[0, 0\]"),
                         (np.array([True, False]), r"must be integers in \[0, 1\], got dtype bool"),
                         ([0.0], r"must be integers in \[0, 1\], got dtype float64")):
        with pytest.raises(ValueError, match=rf"^env_index: {message}$"):
            sim.reset_at(bad, [1] * len(bad))
    sim.reset_at([], [])  # nothing to restart


def test_raw_edge_must_be_one_bool_per_environment() -> None:
    sim = _sim()
    for bad, got in ((np.ones(3, bool), r"bool of shape \(3,\)"),
                     (np.ones(2, int), r"int64 of shape \(2,\)"),
                     (True, r"bool of shape \(\)")):
        with pytest.raises(ValueError, match=rf"^raw_edge: must be a \(2,\) bool array \(one per "
                           rf"environment\), got {got}$"):
            sim.step(raw_edge=bad)
    sim.step(raw_edge=np.array([True, False]))


def test_vehicle_table_names_an_environment_the_simulator_lacks() -> None:
    sim = _sim()
    assert set(sim.vehicle_table(1)) == {"vid", "lane", "s", "v", "a", "xy"}
    with pytest.raises(IndexError, match=r"^env: must be an integer in \[-2, 2\)"):
        sim.vehicle_table(2)
