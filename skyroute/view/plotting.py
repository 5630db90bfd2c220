"""Pictures of maps, plans and flown tracks. The only module that imports matplotlib.

Every drawing function takes an ``ax`` and returns it; :func:`save_plan_figure` puts them together into a PNG.
North is up and east is right, axes in metres of the map frame.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; never needs a display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402


def draw_obstacles(ax, obstacles: np.ndarray, altitude_m: float | None = None, safety_m: float = 0.0):
    """Obstacle footprints as grey rectangles, darker when taller; those below ``altitude_m - safety_m`` pale."""
    north, east, alt, dn, de, da = np.asarray(obstacles, dtype=float).T
    # Rectangles in (x = east, y = north).
    corners = np.stack(
        [
            np.column_stack([east - de, north - dn]),
            np.column_stack([east + de, north - dn]),
            np.column_stack([east + de, north + dn]),
            np.column_stack([east - de, north + dn]),
        ],
        axis=1,
    )
    top = alt + da
    shade = 0.75 - 0.55 * np.clip(top / max(float(top.max()), 1.0), 0, 1)
    colours = np.column_stack([shade, shade, shade, np.ones_like(shade)])
    if altitude_m is not None:
        low = top + safety_m <= altitude_m
        colours[low] = (0.88, 0.88, 0.88, 1.0)
    ax.add_collection(PolyCollection(corners, facecolors=colours, edgecolors="none", zorder=1))
    ax.set_xlim(float((east - de).min()), float((east + de).max()))
    ax.set_ylim(float((north - dn).min()), float((north + dn).max()))
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    return ax


def draw_grid(ax, grid: np.ndarray, north_offset: float, east_offset: float):
    """The configuration space: blocked cells (obstacles grown by the safety margin) as a pale red overlay."""
    n, m = grid.shape
    extent = (east_offset, east_offset + m, north_offset, north_offset + n)
    overlay = np.zeros((n, m, 4))
    overlay[grid] = (0.85, 0.2, 0.2, 0.18)
    ax.imshow(overlay, origin="lower", extent=extent, interpolation="nearest", zorder=1.5)
    return ax


def draw_structure(ax, structure: dict):
    """A planner's own structure under the path: ``edges`` ``(E, 2, 2)`` segments and ``nodes`` ``(M, 2)``
    points, both ``(north_m, east_m)``."""
    edges = structure.get("edges")
    if edges is not None and len(edges):
        segments = np.asarray(edges, dtype=float)[..., ::-1]  # (north, east) -> (x = east, y = north)
        ax.add_collection(LineCollection(segments, colors="tab:green", linewidths=0.4, alpha=0.6, zorder=2))
    nodes = structure.get("nodes")
    if nodes is not None and len(nodes):
        nodes = np.asarray(nodes, dtype=float)
        ax.plot(nodes[:, 1], nodes[:, 0], ".", color="tab:green", markersize=1.5, alpha=0.6, zorder=2)
    return ax


def draw_plan(ax, raw_path_ne: np.ndarray, waypoints: np.ndarray):
    """The unpruned path as a thin line and the pruned waypoints as a thicker line with markers."""
    raw = np.asarray(raw_path_ne, dtype=float)
    wp = np.asarray(waypoints, dtype=float)
    ax.plot(raw[:, 1], raw[:, 0], "-", color="tab:orange", linewidth=0.8, label="searched path", zorder=3)
    ax.plot(wp[:, 1], wp[:, 0], "o-", color="tab:blue", linewidth=1.5, markersize=3, label="waypoints", zorder=4)
    ax.plot(wp[0, 1], wp[0, 0], "s", color="tab:green", markersize=8, label="start", zorder=5)
    ax.plot(wp[-1, 1], wp[-1, 0], "*", color="tab:red", markersize=12, label="goal", zorder=5)
    return ax


def draw_track(ax, track_ne: np.ndarray):
    """A flown track ``(T, 2)`` of ``(north_m, east_m)``."""
    track = np.asarray(track_ne, dtype=float)
    if len(track):
        ax.plot(track[:, 1], track[:, 0], "-", color="tab:purple", linewidth=1.0, label="flown", zorder=4)
    return ax


def save_plan_figure(
    path: str | Path,
    obstacles: np.ndarray,
    plan,
    *,
    altitude_m: float,
    safety_m: float,
    track_ne: np.ndarray | None = None,
    grid: tuple[np.ndarray, float, float] | None = None,
    title: str = "",
) -> Path:
    """Write a PNG of the map, the planner's structure, the plan and (optionally) the flown track and the
    configuration space ``grid = (grid, north_offset, east_offset)``."""
    fig, ax = plt.subplots(figsize=(9, 9), dpi=110)
    try:
        draw_obstacles(ax, obstacles, altitude_m, safety_m)
        if grid is not None:
            draw_grid(ax, *grid)
        draw_structure(ax, getattr(plan, "structure", {}) or {})
        draw_plan(ax, plan.raw_path_ne, plan.waypoints)
        if track_ne is not None:
            draw_track(ax, track_ne)
        ax.legend(loc="upper right", fontsize=8)
        flown = " and the flown track" if track_ne is not None else ""
        ax.set_title(title or f"{plan.planner} plan{flown} at {altitude_m:g} m, safety {safety_m:g} m")
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
    return Path(path)
