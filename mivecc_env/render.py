"""Pictures of the simulator: an RGB frame and the paper's velocity / density heat maps.

* :func:`render_rgb` draws one environment of a :class:`~mivecc_env.sim.core.Simulator` as a
  ``(H, W, 3)`` uint8 image with pure numpy (no matplotlib on this path): dark background,
  grey roads along every row and column line, lighter intersection boxes, and each vehicle as
  a small filled square coloured by its speed (red at 0 m/s, yellow at ``v_min_mps``, green at
  ``v_max_mps``). The y axis points up, as in the network's coordinates.
* :func:`heatmap_grids` bins the vehicles of one environment on a regular grid of square cells
  over the network: mean velocity [m/s] and vehicle count (or vehicles per km of lane).
* :func:`save_heatmaps` writes both grids as PNGs with matplotlib's object API (no pyplot, no
  display needed).

Pixel ``(row, col)`` of a frame covers ``x in [col, col + 1) / px_per_m`` and
``y in [H - 1 - row, H - row) / px_per_m`` [m]; heat-map cell ``[iy, ix]`` covers
``x in [ix, ix + 1) * cell_m`` and ``y in [iy, iy + 1) * cell_m`` (row 0 is the south edge).
"""

from __future__ import annotations

import math
import pathlib
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray

from mivecc_env.sim.checks import check_env_index
from mivecc_env.sim.network import GridNetwork

if TYPE_CHECKING:
    from mivecc_env.sim.core import Simulator

UInt8Array = NDArray[np.uint8]
FloatArray = NDArray[np.float64]

#: Frame colours (RGB).
BACKGROUND_RGB = (18, 20, 28)
ROAD_RGB = (78, 80, 88)
INTERSECTION_RGB = (112, 114, 124)
CENTRELINE_RGB = (150, 140, 70)
#: Colour of empty heat-map cells (the paper shows them purple).
EMPTY_CELL_COLOR = "#3d1a5b"

#: Margin of the road on each side of the outermost lane centreline [m].
ROAD_MARGIN_M = 2.0
#: Drawn vehicle size [m] (the model's ``vehicle_length_m`` default) and minimum size [px].
VEHICLE_SIZE_M = 2.0
VEHICLE_MIN_PX = 3


def _speed_lut() -> UInt8Array:
    """(256, 3) uint8 red-yellow-green ramp (matplotlib's ``RdYlGn`` when available)."""
    u = np.linspace(0.0, 1.0, 256)
    try:
        from matplotlib import colormaps

        rgba = colormaps["RdYlGn"](u)
        return np.round(rgba[:, :3] * 255).astype(np.uint8)
    except Exception:  # pragma: no cover - matplotlib is a dependency, this is a fallback
        red = np.where(u < 0.5, 1.0, 2.0 * (1.0 - u))
        green = np.where(u < 0.5, 2.0 * u, 1.0)
        rgb = np.stack([0.15 + 0.8 * red, 0.15 + 0.7 * green, np.full_like(u, 0.2)], axis=1)
        return np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)


#: Speed colormap: entry 0 is v = 0 (red), 128 is v_min (yellow), 255 is v_max (green).
SPEED_LUT: UInt8Array = _speed_lut()


def speed_to_lut_index(v: FloatArray, v_min: float, v_max: float) -> NDArray[np.intp]:
    """Index into :data:`SPEED_LUT` of each velocity ``v`` [m/s].

    Piecewise linear: ``[0, v_min]`` maps to the lower half (red to yellow), ``[v_min, v_max]``
    to the upper half (yellow to green), so the unsignalized range stays well resolved while
    stopped vehicles (signalized control) show red. Values outside ``[0, v_max]`` are clipped.
    """
    v = np.asarray(v, dtype=np.float64)
    v_min = float(min(max(v_min, 0.0), v_max))
    lo = 0.5 * v / v_min if v_min > 0 else np.ones_like(v) * 0.5
    hi = 0.5 + 0.5 * (v - v_min) / max(v_max - v_min, 1e-9)
    u = np.where(v < v_min, lo, hi)
    return np.clip(np.round(u * 255), 0, 255).astype(np.intp)


def frame_shape(network: GridNetwork, px_per_m: float = 1.0) -> tuple[int, int]:
    """``(H, W)`` in pixels of a frame of ``network`` at ``px_per_m`` pixels per metre."""
    width_m, height_m = network.extent_m
    return _n_cells(height_m * px_per_m), _n_cells(width_m * px_per_m)


def _n_cells(size: float) -> int:
    """``ceil(size)`` (at least 1), tolerant to floating-point noise."""
    return max(1, math.ceil(size - 1e-9))


_BACKGROUND_CACHE: dict[tuple, UInt8Array] = {}

#: Largest frame :func:`render_rgb` draws [pixels] (1e8 pixels: 300 MB of RGB).
MAX_FRAME_PX = 100_000_000


def _check_scale(network: GridNetwork, px_per_m: float) -> None:
    """Refuse a scale that is not a finite number > 0 or whose frame exceeds
    :data:`MAX_FRAME_PX` (naming the largest scale this network allows)."""
    if isinstance(px_per_m, bool) or not (isinstance(px_per_m, int | float | np.number)
                                           and 0 < px_per_m < math.inf):
        raise ValueError(f"px_per_m: must be a finite number > 0 [pixels/m], got {px_per_m!r}")
    width_m, height_m = network.extent_m
    if width_m * height_m * px_per_m**2 > MAX_FRAME_PX:
        largest = math.sqrt(MAX_FRAME_PX / (width_m * height_m))
        raise ValueError(
            f"px_per_m: {px_per_m!r} makes a frame of {width_m * px_per_m:.0f} x "
            f"{height_m * px_per_m:.0f} px; at most {largest:.3g} on this "
            f"{width_m:.0f} m x {height_m:.0f} m network ({MAX_FRAME_PX:.0e} px)")


def _pixel_span(lo_m: float, hi_m: float, px_per_m: float, n: int) -> slice:
    """Pixel index range ``[floor(lo), ceil(hi))`` of the metre interval, clipped to ``n``."""
    a = max(0, math.floor(lo_m * px_per_m))
    b = min(n, max(a + 1, math.ceil(hi_m * px_per_m)))
    return slice(a, b)


def _background(network: GridNetwork, px_per_m: float) -> UInt8Array:
    """Static part of a frame (roads, intersections), cached per geometry and scale."""
    key = (network.rows, network.cols, network.segment_length_m, network.lane_offset_m,
           float(px_per_m))
    cached = _BACKGROUND_CACHE.get(key)
    if cached is not None:
        return cached
    h, w = frame_shape(network, px_per_m)
    img = np.empty((h, w, 3), dtype=np.uint8)
    img[:] = BACKGROUND_RGB
    half = network.lane_offset_m + ROAD_MARGIN_M
    seg = network.segment_length_m
    road_x = (np.arange(network.cols) + 1) * seg  # vertical roads
    road_y = (np.arange(network.rows) + 1) * seg  # horizontal roads

    def rows_of(y_lo: float, y_hi: float) -> slice:  # flip: row 0 is the top (north) edge
        span = _pixel_span(y_lo, y_hi, px_per_m, h)
        return slice(h - span.stop, h - span.start)

    line_px = max(1, round(0.3 * px_per_m))
    for y in road_y:
        img[rows_of(y - half, y + half), :] = ROAD_RGB
    for x in road_x:
        img[:, _pixel_span(x - half, x + half, px_per_m, w)] = ROAD_RGB
    # dashed centre lines (5 m dash, 5 m gap), drawn before the boxes so boxes stay clean
    dash = (np.arange(w) / px_per_m) % 10.0 < 5.0
    for y in road_y:
        r0 = h - 1 - min(h - 1, math.floor(y * px_per_m))
        img[max(0, r0 - line_px // 2): r0 - line_px // 2 + line_px, dash] = CENTRELINE_RGB
    dash_rows = ((h - 1 - np.arange(h)) / px_per_m) % 10.0 < 5.0
    for x in road_x:
        c0 = min(w - 1, math.floor(x * px_per_m))
        img[dash_rows, max(0, c0 - line_px // 2): c0 - line_px // 2 + line_px] = CENTRELINE_RGB
    for x in road_x:
        for y in road_y:
            img[rows_of(y - half, y + half), _pixel_span(x - half, x + half, px_per_m, w)] = (
                INTERSECTION_RGB
            )
    img.setflags(write=False)
    _BACKGROUND_CACHE[key] = img
    return img


def render_rgb(sim: Simulator, env: int = 0, px_per_m: float = 1.0) -> UInt8Array:
    """Draw environment ``env`` of ``sim`` as an RGB image.

    Args:
        sim: the simulator.
        env: environment index in the batch.
        px_per_m: scale [pixels per metre]; the frame covers the whole network
            (``extent_m``), so a 3x3 grid with 150 m segments is 600 x 600 px at 1 px/m.

    Returns:
        ``(H, W, 3)`` uint8 array, north up. Each vehicle is a filled square of
        ``max(VEHICLE_MIN_PX, round(2 m * px_per_m))`` pixels centred on its position,
        coloured by speed through :data:`SPEED_LUT` (see :func:`speed_to_lut_index`).

    Raises:
        ValueError: ``px_per_m`` not a finite number > 0, or a frame over
            :data:`MAX_FRAME_PX` pixels (the message gives the largest scale allowed).
        IndexError: ``env`` outside the batch.
    """
    _check_scale(sim.network, px_per_m)
    env = check_env_index(env, sim.batch_size)
    network = sim.network
    img = _background(network, px_per_m).copy()
    h, w = img.shape[:2]
    m = sim.active[env]
    if not m.any():
        return img
    lane, s, v = sim.lane[env, m], sim.s[env, m], sim.v[env, m]
    xy = network.xy(lane, s)
    cfg = sim.config
    colour = SPEED_LUT[speed_to_lut_index(v, cfg.v_min_mps, cfg.v_max_mps)]  # (n, 3)

    size = max(VEHICLE_MIN_PX, round(VEHICLE_SIZE_M * px_per_m))
    offsets = np.arange(size) - (size - 1) // 2
    col_c = np.floor(xy[:, 0] * px_per_m).astype(np.intp)
    row_c = h - 1 - np.floor(xy[:, 1] * px_per_m).astype(np.intp)
    rows = np.clip(row_c[:, None, None] + offsets[None, :, None], 0, h - 1)  # (n, k, 1)
    cols = np.clip(col_c[:, None, None] + offsets[None, None, :], 0, w - 1)  # (n, 1, k)
    rows, cols = np.broadcast_arrays(rows, cols)
    img[rows, cols] = colour[:, None, None, :]
    return img


# ----------------------------------------------------------------------------------------
# heat maps
def _cell_grid_shape(network: GridNetwork, cell_m: float) -> tuple[int, int]:
    """Cells per axis ``(ny, nx)`` of the heat-map grid; ``ValueError`` unless ``cell_m`` is
    a finite length > 0 [m]."""
    if not (isinstance(cell_m, int | float | np.number) and 0 < cell_m < math.inf):
        raise ValueError(f"cell_m: must be a finite length > 0 [m], got {cell_m!r}")
    width_m, height_m = network.extent_m
    return _n_cells(height_m / cell_m), _n_cells(width_m / cell_m)


def lane_length_per_cell(network: GridNetwork, cell_m: float = 10.0) -> FloatArray:
    """``(ny, nx)`` total length of lane centreline inside each cell [m].

    Lanes are axis-aligned; a lane lying exactly on a cell border counts for the cell a
    vehicle on it is binned into (``floor``), consistently with :func:`heatmap_grids`.
    """
    ny, nx = _cell_grid_shape(network, cell_m)
    out = np.zeros((ny, nx))
    edges_x = np.minimum(np.arange(nx + 1) * cell_m, network.extent_m[0])
    edges_y = np.minimum(np.arange(ny + 1) * cell_m, network.extent_m[1])
    for lane in range(network.n_lanes):
        ox, oy = network.lane_origin[lane]
        if network.lane_horizontal[lane]:
            iy = min(ny - 1, math.floor(oy / cell_m))
            out[iy] += np.diff(edges_x)
        else:
            ix = min(nx - 1, math.floor(ox / cell_m))
            out[:, ix] += np.diff(edges_y)
    return out


def heatmap_grids(
    sim: Simulator,
    env: int = 0,
    cell_m: float = 10.0,
    density: Literal["count", "veh_per_km"] = "count",
) -> tuple[FloatArray, FloatArray]:
    """Velocity and density of environment ``env`` on square cells over the network.

    Args:
        sim: the simulator.
        env: environment index in the batch.
        cell_m: cell side [m]; the grid has ``ceil(extent / cell_m)`` cells per axis, cell
            ``[iy, ix]`` covering ``[ix, ix+1) * cell_m`` east and ``[iy, iy+1) * cell_m``
            north of the south-west corner (vehicles on the far edges go to the last cell).
        density: ``"count"``: vehicles per cell; ``"veh_per_km"``: vehicles per km of lane,
            the count divided by the lane length inside the cell (NaN where no lane passes).

    Returns:
        ``(velocity, density)``, both ``(ny, nx)`` float arrays: the mean velocity [m/s] of
        the vehicles in each cell (NaN where the cell is empty) and the density.
    """
    if density not in ("count", "veh_per_km"):
        raise ValueError(f"density: must be 'count' or 'veh_per_km', got {density!r}")
    env = check_env_index(env, sim.batch_size)
    network = sim.network
    ny, nx = _cell_grid_shape(network, cell_m)
    m = sim.active[env]
    xy = network.xy(sim.lane[env, m], sim.s[env, m])
    v = sim.v[env, m]
    ix = np.clip(np.floor(xy[:, 0] / cell_m).astype(np.intp), 0, nx - 1)
    iy = np.clip(np.floor(xy[:, 1] / cell_m).astype(np.intp), 0, ny - 1)
    flat = iy * nx + ix
    count = np.bincount(flat, minlength=ny * nx).reshape(ny, nx).astype(np.float64)
    v_sum = np.bincount(flat, weights=v, minlength=ny * nx).reshape(ny, nx)
    with np.errstate(invalid="ignore", divide="ignore"):
        velocity = np.where(count > 0, v_sum / np.maximum(count, 1), np.nan)
        if density == "veh_per_km":
            length = lane_length_per_cell(network, cell_m)
            dens = np.where(length > 0, count / (length / 1000.0), np.nan)
        else:
            dens = count
    return velocity, dens


def save_heatmaps(
    sim: Simulator,
    path_prefix: str | pathlib.Path,
    env: int = 0,
    cell_m: float = 10.0,
    title: str | None = None,
    density: Literal["count", "veh_per_km"] = "count",
    dpi: int = 120,
) -> list[pathlib.Path]:
    """Write ``<prefix>_velocity.png`` and ``<prefix>_density.png`` (see :func:`heatmap_grids`).

    Axes are in metres from the network's south-west corner; road centrelines are drawn
    faintly for orientation; empty cells are :data:`EMPTY_CELL_COLOR` (purple). Velocity uses
    a fixed scale ``[0, v_max]`` [m/s] so pictures of different runs compare directly.

    Args:
        sim: the simulator.
        path_prefix: output path without the suffix; parent folders are created.
        env: environment index in the batch.
        cell_m: cell side [m].
        title: first title line (e.g. scheme, density); the simulated time and the number of
            vehicles are appended.
        density: unit of the density map, as in :func:`heatmap_grids`.
        dpi: resolution of the PNGs [dots per inch].

    Returns:
        The two paths written, velocity first.
    """
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import BoundaryNorm, ListedColormap, Normalize
    from matplotlib.figure import Figure
    from mpl_toolkits.axes_grid1 import make_axes_locatable

    prefix = pathlib.Path(path_prefix)
    prefix.parent.mkdir(parents=True, exist_ok=True)
    velocity, dens = heatmap_grids(sim, env, cell_m, density)
    network, cfg = sim.network, sim.config
    width_m, height_m = network.extent_m
    ny, nx = velocity.shape
    extent = (0.0, nx * cell_m, 0.0, ny * cell_m)
    n_veh = int(sim.active[env].sum())
    t_s = float(sim.env_time_s[env])
    info = f"t = {t_s:.1f} s, {n_veh} vehicles in network, {cell_m:g} m cells"
    full_title = f"{title}\n{info}" if title else info

    velocity_cmap = matplotlib.colormaps["RdYlGn"].with_extremes(bad=EMPTY_CELL_COLOR)
    # YlOrRd without its palest quarter, so that one vehicle stands out from the background
    density_cmap = ListedColormap(
        matplotlib.colormaps["YlOrRd"](np.linspace(0.25, 1.0, 256))
    ).with_extremes(bad=EMPTY_CELL_COLOR)
    dens_ticks = None
    if density == "count":
        dens_label = f"vehicles per cell ({cell_m:g} m x {cell_m:g} m)"
        n_max = max(1, int(np.nanmax(dens)) if dens.size else 1)
        dens_norm = BoundaryNorm(np.arange(n_max + 1) + 0.5, density_cmap.N)
        dens_ticks = np.arange(1, n_max + 1)[:: max(1, n_max // 10)]
    else:
        dens_label = "density [veh/km of lane]"
        finite = dens[np.isfinite(dens)]
        dens_norm = Normalize(0.0, max(1.0, float(finite.max()) if finite.size else 1.0))
    plots = (
        ("velocity", velocity, velocity_cmap, Normalize(0.0, cfg.v_max_mps),
         "mean velocity [m/s]", None),
        ("density", np.where(dens > 0, dens, np.nan), density_cmap, dens_norm, dens_label,
         dens_ticks),
    )
    paths = []
    for name, grid, cmap, norm, label, ticks in plots:
        fig = Figure(figsize=(6.4, min(9.0, 1.6 + 4.6 * height_m / width_m)), dpi=dpi)
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
        im = ax.imshow(np.ma.masked_invalid(grid), origin="lower", extent=extent, cmap=cmap,
                       norm=norm, interpolation="nearest", aspect="equal")
        seg = network.segment_length_m
        for k in range(network.rows):
            ax.axhline((k + 1) * seg, color="white", lw=0.4, alpha=0.25, zorder=0.5)
        for k in range(network.cols):
            ax.axvline((k + 1) * seg, color="white", lw=0.4, alpha=0.25, zorder=0.5)
        ax.set_xlim(0, width_m)
        ax.set_ylim(0, height_m)
        ax.set_xlabel("x (east) [m]")
        ax.set_ylabel("y (north) [m]")
        ax.set_title(f"{name}: {full_title}", fontsize=9)
        cax = make_axes_locatable(ax).append_axes("right", size="4%", pad=0.12)
        cbar = fig.colorbar(im, cax=cax, ticks=ticks)
        cbar.set_label(label)
        ax.text(1.0, -0.11, "purple: no vehicle", transform=ax.transAxes, ha="right",
                va="top", fontsize=7, color=EMPTY_CELL_COLOR)
        fig.tight_layout()
        path = prefix.with_name(f"{prefix.name}_{name}.png")
        fig.savefig(path)
        paths.append(path)
    return paths
