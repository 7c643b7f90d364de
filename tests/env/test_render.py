"""Rendering: numpy frames and the velocity / density heat maps."""

from __future__ import annotations

import numpy as np
import pytest

from mivecc_env import mivecc_v0
from mivecc_env.config import MiVeCCConfig
from mivecc_env.render import SPEED_LUT, heatmap_grids, render_rgb, save_heatmaps
from mivecc_env.sim.core import Simulator

CFG = MiVeCCConfig(rows=1, cols=1)


def one_vehicle(x_lane: int = 0, s: float = 100.0, v: float = 13.0) -> Simulator:
    sim = Simulator(CFG, seed=0)
    sim.active[0, 0] = True
    sim.lane[0, 0], sim.s[0, 0], sim.v[0, 0] = x_lane, s, v
    sim._refresh_view()
    return sim


def test_empty_frame_shape_and_type() -> None:
    frame = render_rgb(Simulator(CFG, seed=0))
    assert frame.shape == (300, 300, 3) and frame.dtype == np.uint8


def test_vehicle_drawn_at_its_position_in_its_speed_colour() -> None:
    sim = one_vehicle(s=100.0, v=13.0)  # eastbound lane of row 0: (100, 145) m
    frame = render_rgb(sim, px_per_m=1.0)
    empty = render_rgb(Simulator(CFG, seed=0), px_per_m=1.0)
    changed = np.argwhere(np.any(frame != empty, axis=-1))
    rows, cols = changed[:, 0], changed[:, 1]
    assert abs(cols.mean() - 100) <= 2
    assert abs((300 - 1 - rows.mean()) - 145) <= 2  # y points up
    assert tuple(frame[rows[0], cols[0]]) == tuple(SPEED_LUT[-1])  # v_max: top of the ramp


def test_heatmap_counts_and_mean_velocity() -> None:
    sim = Simulator(CFG, seed=3)
    for _ in range(400):
        sim.step()
    velocity, count = heatmap_grids(sim, cell_m=10.0)
    assert count.sum() == sim.in_network[0]
    m = sim.active[0]
    xy = sim.network.xy(sim.lane[0, m], sim.s[0, m])
    ix, iy = int(xy[0, 0] // 10), int(xy[0, 1] // 10)
    in_cell = (xy[:, 0] // 10 == ix) & (xy[:, 1] // 10 == iy)
    assert velocity[iy, ix] == pytest.approx(sim.v[0, m][in_cell].mean())
    assert np.isnan(velocity[count == 0]).all()


def test_heatmap_pngs_written(tmp_path) -> None:
    sim = Simulator(CFG, seed=0)
    for _ in range(200):
        sim.step()
    paths = save_heatmaps(sim, tmp_path / "hm", title="E 900")
    assert [p.name for p in paths] == ["hm_velocity.png", "hm_density.png"]
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 5000


def test_env_render_returns_a_frame() -> None:
    env = mivecc_v0.parallel_env(rows=1, cols=1, render_mode="rgb_array", max_steps=10)
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (300, 300, 3) and frame.dtype == np.uint8
    assert mivecc_v0.parallel_env(rows=1, cols=1).render() is None


def test_frame_size_follows_grid_and_scale() -> None:
    sim = Simulator(MiVeCCConfig(rows=3, cols=3), seed=0)
    assert render_rgb(sim).shape == (600, 600, 3)
    assert render_rgb(sim, px_per_m=2.0).shape == (1200, 1200, 3)
    assert render_rgb(Simulator(MiVeCCConfig(rows=1, cols=2), seed=0)).shape == (300, 450, 3)
    with pytest.raises(ValueError, match="px_per_m"):
        render_rgb(sim, px_per_m=0.0)


@pytest.mark.parametrize("scale", [float("nan"), float("inf"), -1.0, True, "2"])
def test_scale_not_a_finite_positive_number_is_named(scale: object) -> None:
    sim = Simulator(MiVeCCConfig(rows=1, cols=1), seed=0)
    with pytest.raises(ValueError, match=r"^px_per_m: must be a finite number > 0"):
        render_rgb(sim, px_per_m=scale)  # type: ignore[arg-type]


def test_frame_over_the_pixel_budget_is_refused_before_drawing() -> None:
    # 3x3: 600 m x 600 m; 1e8 px allow at most 16.7 px/m (a 1e6 px/m frame used to raise
    # numpy's MemoryError while allocating it)
    sim = Simulator(MiVeCCConfig(rows=3, cols=3), seed=0)
    with pytest.raises(ValueError, match=r"^px_per_m: 1000000.0 makes a frame of .* at most 16.7 "):
        render_rgb(sim, px_per_m=1e6)
    assert render_rgb(sim, px_per_m=0.05).shape == (30, 30, 3)  # the budget leaves small ones


def test_vehicle_square_has_minimum_size_and_background_is_not_mutated() -> None:
    empty_before = render_rgb(Simulator(CFG, seed=0), px_per_m=0.5)
    frame = render_rgb(one_vehicle(s=100.0), px_per_m=0.5)
    changed = np.any(frame != empty_before, axis=-1)
    assert changed.sum() == 9  # 2 m at 0.5 px/m is below the 3 px minimum
    empty_after = render_rgb(Simulator(CFG, seed=0), px_per_m=0.5)
    assert np.array_equal(empty_before, empty_after)


def test_speed_colours_red_to_green() -> None:
    stopped = render_rgb(one_vehicle(s=100.0, v=0.0))
    slow = render_rgb(one_vehicle(s=100.0, v=CFG.v_min_mps))
    row, col = 300 - 1 - 145, 100
    assert tuple(stopped[row, col]) == tuple(SPEED_LUT[0])
    assert tuple(slow[row, col]) == tuple(SPEED_LUT[128])
    assert stopped[row, col, 0] > stopped[row, col, 1]  # red
    assert SPEED_LUT[-1, 1] > SPEED_LUT[-1, 0]  # green


def test_vehicles_on_the_network_edge_are_clipped() -> None:
    sim = one_vehicle(s=float(CFG.segment_length_m * 2) - 1e-6)
    frame = render_rgb(sim)
    assert frame.shape == (300, 300, 3)
    _, count = heatmap_grids(sim)
    assert count.sum() == 1 and count[14, -1] == 1  # y = 145 m -> row 14, last column


def test_empty_heatmaps_and_lane_density_units(tmp_path) -> None:
    velocity, count = heatmap_grids(Simulator(CFG, seed=0), cell_m=10.0)
    assert velocity.shape == count.shape == (30, 30)
    assert np.isnan(velocity).all() and not count.any()
    assert len(save_heatmaps(Simulator(CFG, seed=0), tmp_path / "empty")) == 2
    _, per_km = heatmap_grids(one_vehicle(s=100.0), cell_m=10.0, density="veh_per_km")
    assert per_km[14, 10] == pytest.approx(100.0)  # one vehicle on 10 m of one lane
    assert np.isnan(per_km[0, 0])  # no lane passes the corner cell
    with pytest.raises(ValueError, match="cell_m"):
        heatmap_grids(Simulator(CFG, seed=0), cell_m=0.0)


def test_heatmaps_script_writes_pngs(tmp_path) -> None:
    import importlib.util
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "benchmarks" / "heatmaps.py"
    spec = importlib.util.spec_from_file_location("heatmaps_script", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    paths = module.main(["--rows", "1", "--cols", "1", "--steps", "30", "--out",
                         str(tmp_path)])
    assert len(paths) == 6 and all(p.stat().st_size > 1000 for p in paths)
    assert {p.name for p in paths} >= {"signalized_frame.png", "unsignalized_E_density.png"}


def test_gymnasium_edge_view_renders_human_headless() -> None:
    """``gymnasium.make("mivecc/MiVeCCEdge-v0", render_mode="human")`` draws without raising."""
    import gymnasium
    import matplotlib

    matplotlib.use("Agg")
    import mivecc_env  # noqa: F401  (registers the id)

    env = gymnasium.make("mivecc/MiVeCCEdge-v0", rows=1, cols=1, density=900, max_steps=20,
                         render_mode="human")
    assert "human" in env.metadata["render_modes"]
    env.reset(seed=0)
    for _ in range(5):
        env.step(env.action_space.sample() * 0.0)
    assert env.render() is None
    viewer = env.unwrapped.parallel_env._viewer
    assert viewer is not None and viewer.frames_shown >= 6  # reset + 5 steps (+ render)
    env.close()


def test_bad_environment_index_and_cell_size_are_named() -> None:
    from mivecc_env.render import lane_length_per_cell

    sim = Simulator(MiVeCCConfig(rows=1, cols=1), batch_size=2, seed=0)
    assert render_rgb(sim, -1).shape == render_rgb(sim, 1).shape
    for draw in (render_rgb, heatmap_grids):
        with pytest.raises(IndexError, match=r"^env: must be an integer in \[-2, 2\)"):
            draw(sim, 2)
    for bad in (0.0, -5.0, float("nan"), float("inf"), "10"):
        with pytest.raises(ValueError, match=r"^cell_m: must be a finite length > 0 \[m\]"):
            lane_length_per_cell(sim.network, bad)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match=r"^cell_m: "):
            heatmap_grids(sim, 0, bad)  # type: ignore[arg-type]
