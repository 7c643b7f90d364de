"""MiVeCCConfig: the paper's defaults, validation messages, cross-field checks, immutability."""

from __future__ import annotations

import dataclasses
import math

import pytest

from mivecc_env.config import ConfigError, MiVeCCConfig, from_overrides
from mivecc_env.sim.core import Simulator


def test_defaults_are_the_papers_values() -> None:
    c = MiVeCCConfig()
    # network: 3x3 grid, 150 m segments; vehicles 2 m
    assert (c.rows, c.cols) == (3, 3)
    assert c.segment_length_m == 150.0
    assert c.vehicle_length_m == 2.0
    # kinematics: v in [6, 13], v0 = 10, a in [-3, 3], T = 0.1 s
    assert (c.v_min_mps, c.v_max_mps, c.v_init_mps) == (6.0, 13.0, 10.0)
    assert (c.a_min_mps2, c.a_max_mps2) == (-3.0, 3.0)
    assert c.dt_s == 0.1
    # safety value constants
    assert (c.sv_alpha_d, c.sv_beta_d) == (10.0, 10.0)
    assert (c.sv_alpha_t, c.sv_beta_t) == (1.5, 2.0)
    assert (c.sv_alpha_acc, c.sv_beta_acc, c.sv_lambda_acc) == (1.5, 12.0, 0.2)
    assert (c.sv_min, c.sv_max) == (-20.0, 20.0)
    # end node and fusion
    assert c.eta == 3.0
    assert c.omega == 0.2
    # state graphs, density indicator, episode
    assert (c.k_edge, c.k_cloud) == (15, 60)
    assert c.di_n == 5
    assert c.max_steps == 3000
    # the project's readings (documented choices)
    assert c.end_rule == "sensible"
    assert c.scheme == "E"
    assert c.control == "unsignalized"
    assert c.edge_sv_gate is None
    assert c.same_lane_rule is False
    assert c.min_headway_s == 1.0
    assert c.lane_offset_m == 5.0
    assert c.sv_d_threshold_m == 10.0


@pytest.mark.parametrize(
    ("overrides", "field", "allowed"),
    [
        ({"rows": 0}, "rows", "[1, 16]"),
        ({"cols": 17}, "cols", "[1, 16]"),
        ({"density_vplh": -1.0}, "density_vplh", "[1.0, 3600.0]"),
        ({"dt_s": math.nan}, "dt_s", "[0.01, 1.0]"),
        ({"dt_s": math.inf}, "dt_s", "[0.01, 1.0]"),
        ({"eta": 0.0}, "eta", "(0.0, 100.0]"),
        ({"omega": 1.5}, "omega", "[0.0, 1.0]"),
        ({"k_edge": 1}, "k_edge", "[2, 256]"),
        ({"rows": 2.5}, "rows", "an integer"),
        ({"rows": "3"}, "rows", "an integer"),
        ({"v_max_mps": True}, "v_max_mps", "a number"),
    ],
)
def test_out_of_range_names_field_and_range(
    overrides: dict[str, object], field: str, allowed: str
) -> None:
    with pytest.raises(ConfigError) as info:
        MiVeCCConfig(**overrides)  # type: ignore[arg-type]
    message = str(info.value)
    assert message.startswith(f"{field}:")
    assert allowed in message


def test_density_alias_out_of_range() -> None:
    with pytest.raises(ConfigError, match=r"density_vplh: must be a number in \[1\.0, 3600\.0\]"):
        from_overrides(density=-1)


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"end_rule": "foo"}, "end_rule"),
        ({"scheme": "EEE"}, "scheme"),
        ({"control": "lights"}, "control"),
        ({"sv_acc_source": "rear"}, "sv_acc_source"),
        ({"same_lane_rule": 1}, "same_lane_rule"),  # an int is not a bool
    ],
)
def test_bad_choice_lists_the_choices(overrides: dict[str, object], field: str) -> None:
    with pytest.raises(ConfigError) as info:
        MiVeCCConfig(**overrides)  # type: ignore[arg-type]
    assert str(info.value).startswith(f"{field}: must be one of [")


def test_end_rule_message_lists_both_readings() -> None:
    with pytest.raises(ConfigError, match=r"end_rule: must be one of \['sensible', 'literal'\]"):
        MiVeCCConfig(end_rule="foo")  # type: ignore[arg-type]


def test_unknown_key_suggests_the_close_name() -> None:
    with pytest.raises(ConfigError, match=r"densty: unknown configuration field.*'density'"):
        from_overrides(densty=900)
    with pytest.raises(ConfigError, match=r"dt: unknown .*'dt_s'"):
        MiVeCCConfig().replace(dt=0.2)
    with pytest.raises(ConfigError, match="unknown configuration field"):
        from_overrides(zzzzzz=1)


def test_constructor_unknown_keyword_raises_type_error() -> None:
    # The dataclass constructor behaves like any Python call; the keyword APIs suggest a fix.
    with pytest.raises(TypeError, match="densty"):
        MiVeCCConfig(densty=900)  # type: ignore[call-arg]
    with pytest.raises(ConfigError, match="density"):
        from_overrides(densty=900)


def test_integral_float_for_integer_field_is_an_int_or_rejected() -> None:
    try:
        cfg = MiVeCCConfig(rows=2.0, cols=1)  # type: ignore[arg-type]
    except ConfigError:
        return
    Simulator(cfg, seed=0).step()  # today: TypeError in build_grid
    assert isinstance(cfg.rows, int)


def test_from_overrides_converts_integral_floats() -> None:
    cfg = from_overrides(rows=2.0, cols=1)
    assert cfg.rows == 2
    assert isinstance(cfg.rows, int)


def test_edge_sv_gate_is_optional_number() -> None:
    assert MiVeCCConfig(edge_sv_gate=-2.0).edge_sv_gate == -2.0
    assert MiVeCCConfig(edge_sv_gate=None).edge_sv_gate is None
    with pytest.raises(ConfigError, match="edge_sv_gate"):
        MiVeCCConfig(edge_sv_gate=True)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="edge_sv_gate"):
        MiVeCCConfig(edge_sv_gate=5000.0)


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"v_min_mps": 13.0}, "v_min_mps"),  # v_min must be below v_max (13)
        ({"v_min_mps": 8.0, "v_max_mps": 7.0, "v_init_mps": 7.0}, "v_min_mps"),
        ({"v_init_mps": 5.0}, "v_init_mps"),  # below v_min = 6 when unsignalized
        ({"v_init_mps": 14.0}, "v_init_mps"),  # above v_max = 13
        ({"control_radius_m": 76.0}, "control_radius_m"),  # half of 150 m is 75
        ({"projection_window_m": 145.0}, "projection_window_m"),  # 150 - 5 = 145, open
        ({"segment_length_m": 40.0, "lane_offset_m": 10.0, "control_radius_m": 20.0,
          "projection_window_m": 20.0}, "lane_offset_m"),  # 2 * 10 not below 40 / 2
    ],
)
def test_cross_field_checks(overrides: dict[str, object], field: str) -> None:
    with pytest.raises(ConfigError) as info:
        MiVeCCConfig(**overrides)  # type: ignore[arg-type]
    assert str(info.value).startswith(f"{field}:")


def test_cross_field_checks_accept_the_boundaries() -> None:
    MiVeCCConfig(control_radius_m=75.0)
    MiVeCCConfig(projection_window_m=144.9)
    # under signals the velocity floor is 0, so a standing start is allowed
    cfg = MiVeCCConfig(control="signalized", v_init_mps=0.0)
    assert cfg.velocity_floor_mps == 0.0
    assert MiVeCCConfig().velocity_floor_mps == 6.0


def test_frozen_and_replace() -> None:
    cfg = MiVeCCConfig(rows=1, cols=1)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.rows = 2  # type: ignore[misc]
    other = cfg.replace(scheme="EE", density=2100)
    assert (other.scheme, other.density_vplh, other.rows) == ("EE", 2100, 1)
    assert (cfg.scheme, cfg.density_vplh) == ("E", 900.0)
    with pytest.raises(ConfigError, match="rows"):
        cfg.replace(rows=0)
    assert cfg.n_intersections == 1
    assert MiVeCCConfig().n_intersections == 9
    assert cfg.to_dict()["rows"] == 1
