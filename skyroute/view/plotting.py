"""Pictures of maps, plans and flown tracks. The only module that imports matplotlib.

Every drawing function takes an ``ax`` and returns it; :func:`save_plan_figure` puts them together into a PNG.
North is up and east is right, axes in metres of the map frame.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; never needs a display
import matplotlib.patches  # noqa: E402
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


def draw_discovered(ax, points_ne: np.ndarray, truth: np.ndarray | None = None):
    """Observed obstacle cells ``(K, 2)`` (map ``north_m, east_m`` of 1 m cells) as red squares; ``truth`` boxes
    ``(N, 6)`` the map did not have (e.g. the changed city's walls), outlined in red, if given."""
    pts = np.asarray(points_ne, dtype=float).reshape(-1, 2)
    if truth is not None and len(truth):
        t = np.asarray(truth, dtype=float)
        for n, e, _a, dn, de, _da in t:
            ax.add_patch(matplotlib.patches.Rectangle((e - de, n - dn), 2 * de, 2 * dn, fill=False,
                                                      edgecolor="tab:red", linewidth=0.8, linestyle="--", zorder=2))
        ax.plot([], [], "--", color="tab:red", linewidth=0.8, label="not on the map (truth)")
    if len(pts):
        ax.scatter(pts[:, 1], pts[:, 0], s=4, marker="s", color="tab:red", label="discovered obstacles", zorder=3)
    return ax


def draw_replans(ax, replans: list):
    """Each replan's new route (faded blue, dashed) and where it was made (a red cross, numbered). ``replans``
    are objects with ``north_m``, ``east_m`` and ``waypoints`` ((K, 4) or None)."""
    for k, r in enumerate(replans):
        wp = getattr(r, "waypoints", None)
        if wp is not None and len(wp):
            ax.plot(wp[:, 1], wp[:, 0], "--", color="tab:cyan", linewidth=0.9, alpha=0.8, zorder=3,
                    label="replanned routes" if k == 0 else None)
        ax.plot(r.east_m, r.north_m, "x", color="tab:red", markersize=7, zorder=6,
                label="replans" if k == 0 else None)
        ax.annotate(str(k + 1), (r.east_m, r.north_m), textcoords="offset points", xytext=(4, 4), fontsize=7,
                    color="tab:red", zorder=6)
    return ax


def draw_height_map(ax, floor: np.ndarray, north_offset: float, east_offset: float):
    """The 2.5D height map: each cell's lowest free altitude (obstacle top plus margin over the rounded grown
    footprint), coloured; cells free at any altitude are left blank. Returns the image (for a colour bar)."""
    n, m = floor.shape
    shown = np.where(np.isfinite(floor), floor, np.nan)
    extent = (east_offset, east_offset + m, north_offset, north_offset + n)
    return ax.imshow(shown, origin="lower", extent=extent, cmap="viridis", alpha=0.5, interpolation="nearest",
                     zorder=1.5)


def route_profile(points: np.ndarray, floor: np.ndarray, north_offset: float, east_offset: float,
                  step_m: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Along a route ``(K, 3)`` ``[north_m, east_m, altitude_m]``: the horizontal distance of samples every
    ``step_m``, the route's altitude there and the height map's floor under it (``-inf`` where free)."""
    points = np.asarray(points, dtype=float)
    distance, altitude, under = [0.0], [points[0, 2]], []
    samples = [points[:1, :2]]
    for a, b in zip(points[:-1], points[1:]):
        length = float(np.hypot(*(b[:2] - a[:2])))
        count = max(1, int(np.ceil(max(length, abs(b[2] - a[2])) / step_m)))
        t = np.arange(1, count + 1) / count
        samples.append(a[:2] + t[:, None] * (b[:2] - a[:2]))
        distance.extend(distance[-1] + t * length)
        altitude.extend(a[2] + t * (b[2] - a[2]))
    cells = np.floor(np.concatenate(samples) - (north_offset, east_offset)).astype(int)
    inside = (cells >= 0).all(axis=1) & (cells < floor.shape).all(axis=1)
    under = np.full(len(cells), -np.inf)
    under[inside] = floor[cells[inside, 0], cells[inside, 1]]
    return np.array(distance), np.array(altitude), under


def draw_profile(ax, points: np.ndarray, floor: np.ndarray, north_offset: float, east_offset: float):
    """Altitude along the route against the distance flown over the ground, above the floor it must clear."""
    distance, altitude, under = route_profile(points, floor, north_offset, east_offset)
    ground = np.where(np.isfinite(under), under, 0.0)
    ax.fill_between(distance, 0, ground, step="mid", color="0.6", label="floor: obstacle top + margin")
    ax.plot(distance, altitude, "-", color="tab:blue", linewidth=1.5, label="route")
    turns = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(np.asarray(points, float)[:, :2], axis=0).T))))
    ax.plot(turns, np.asarray(points, float)[:, 2], "o", color="tab:blue", markersize=3)
    ax.set_xlim(0, max(float(distance[-1]), 1.0))
    ax.set_ylim(0, max(float(altitude.max()), float(ground.max())) * 1.15 + 1)
    ax.set_xlabel("distance along the route (m)")
    ax.set_ylabel("altitude (m)")
    ax.legend(loc="upper right", fontsize=8)
    return ax


def plan_title(plan, altitude_m: float, safety_m: float, flown: bool = False) -> str:
    """What a figure shows, in words: the planner, the altitudes it really flies, the margin."""
    top = float(np.max(plan.waypoints[:, 2]))
    track = " and the flown track" if flown else ""
    if top > altitude_m + 1e-9 or float(np.min(plan.waypoints[:, 2])) < altitude_m - 1e-9:
        end = float(plan.waypoints[-1, 2])
        return (f"{plan.planner} plan{track}: from {altitude_m:g} m, up to {top:.0f} m, ending at {end:.0f} m; "
                f"safety {safety_m:g} m")
    return f"{plan.planner} plan{track} at {altitude_m:g} m, safety {safety_m:g} m"


def save_plan_figure(
    path: str | Path,
    obstacles: np.ndarray,
    plan,
    *,
    altitude_m: float,
    safety_m: float,
    track_ne: np.ndarray | None = None,
    grid: tuple[np.ndarray, float, float] | None = None,
    floor: tuple[np.ndarray, float, float] | None = None,
    title: str = "",
    discovered_ne: np.ndarray | None = None,
    replans: list | None = None,
    truth_added: np.ndarray | None = None,
) -> Path:
    """Write a PNG of the map, the planner's structure, the plan and (optionally) the flown track, over the
    configuration space ``grid = (grid, north_offset, east_offset)`` of a plan at one altitude, or, for a route
    that changes altitude, over the height map ``floor = (floor, north_offset, east_offset)`` with the route's
    altitude profile below. A flight that sensed obstacles adds them (``discovered_ne``, :func:`draw_discovered`),
    every replan (:func:`draw_replans`) and, for a test city, the boxes the map lacked (``truth_added``)."""
    rows = 2 if floor is not None else 1
    fig, axes = plt.subplots(rows, 1, figsize=(9, 9 + 3 * (rows - 1)), dpi=110, squeeze=False,
                             gridspec_kw={"height_ratios": [3, 1]} if rows == 2 else None)
    ax = axes[0, 0]
    try:
        draw_obstacles(ax, obstacles, None if floor is not None else altitude_m, safety_m)
        if floor is not None:
            image = draw_height_map(ax, *floor)
            fig.colorbar(image, ax=ax, shrink=0.7, label="lowest free altitude (m)")
            draw_profile(axes[1, 0], plan.waypoints[:, :3], *floor)
        elif grid is not None:
            draw_grid(ax, *grid)
        draw_structure(ax, getattr(plan, "structure", {}) or {})
        draw_plan(ax, plan.raw_path_ne, plan.waypoints)
        if discovered_ne is not None or truth_added is not None:
            draw_discovered(ax, np.empty((0, 2)) if discovered_ne is None else discovered_ne, truth_added)
        if replans:
            draw_replans(ax, replans)
        if track_ne is not None:
            draw_track(ax, track_ne)
        ax.legend(loc="upper right", fontsize=8)
        ax.set_title(title or plan_title(plan, altitude_m, safety_m, flown=track_ne is not None))
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
    return Path(path)


def save_planner_gallery(
    path: str | Path,
    obstacles: np.ndarray,
    plans: list,
    *,
    altitude_m: float,
    safety_m: float,
    grid: tuple[np.ndarray, float, float],
    columns: int = 3,
) -> Path:
    """One panel per plan, side by side on the same map and configuration space: each planner's structure and
    route, with its length and highest altitude in the panel's title."""
    count = len(plans)
    rows = (count + columns - 1) // columns
    fig, axes = plt.subplots(rows, columns, figsize=(5 * columns, 5.2 * rows), dpi=90, squeeze=False)
    try:
        for ax, plan in zip(axes.ravel(), plans):
            draw_obstacles(ax, obstacles, altitude_m, safety_m)
            draw_grid(ax, *grid)
            draw_structure(ax, getattr(plan, "structure", {}) or {})
            draw_plan(ax, plan.raw_path_ne, plan.waypoints)
            top = float(np.max(plan.waypoints[:, 2]))
            height = f", up to {top:.0f} m" if top > altitude_m + 1e-9 else ""
            ax.set_title(f"{plan.planner}: {plan.length_m:.0f} m, {len(plan.waypoints)} waypoints{height}",
                         fontsize=10)
            ax.tick_params(labelsize=7)
        for ax in axes.ravel()[count:]:
            ax.set_visible(False)
        fig.suptitle(f"The same query with every planner, from {altitude_m:g} m, safety {safety_m:g} m")
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
    return Path(path)


def save_exploration_figure(path, *, known: np.ndarray, hits: np.ndarray, frontiers: np.ndarray, disk: np.ndarray,
                            north_offset: float, east_offset: float, targets: np.ndarray | None = None,
                            track_ne: np.ndarray | None = None, start_ne=(0.0, 0.0), radius_m: float = 0.0,
                            truth: np.ndarray | None = None, title: str | None = None) -> Path:
    """An exploration: the known area (pale green, seen free), observed obstacle cells (dark red), the frontiers
    left (orange), the explored disk's edge, the targets ``(K, 3)`` ``[north_m, east_m, collected]`` (stars: green
    collected, red not), the flown track and, for a test city, the true boxes ``truth`` (grey outlines).
    Grids ``[north_idx, east_idx]`` with cell ``(0, 0)``'s south-west corner at ``(north_offset, east_offset)``."""
    n, m = known.shape
    extent = (east_offset, east_offset + m, north_offset, north_offset + n)
    image = np.ones((n, m, 4))
    image[..., 3] = 0.0
    image[known & ~hits] = (0.55, 0.85, 0.55, 0.6)
    image[~known & disk] = (0.85, 0.85, 0.85, 0.5)
    image[hits] = (0.55, 0.05, 0.05, 1.0)
    image[frontiers] = (1.0, 0.55, 0.0, 1.0)
    fig, ax = plt.subplots(figsize=(9, 9), dpi=110)
    try:
        if truth is not None and len(truth):
            boxes = np.asarray(truth, float)
            polys = [[(e - de, nn - dn), (e + de, nn - dn), (e + de, nn + dn), (e - de, nn + dn)]
                     for nn, e, _, dn, de, _ in boxes]
            ax.add_collection(PolyCollection(polys, facecolors="none", edgecolors="0.4", linewidths=0.6,
                                             label="true buildings", zorder=1))
        ax.imshow(image, origin="lower", extent=extent, interpolation="nearest", zorder=2)
        ax.add_patch(matplotlib.patches.Circle((start_ne[1], start_ne[0]), radius_m, fill=False, color="tab:blue",
                                               linestyle="--", linewidth=1.0, label="explored area", zorder=3))
        if track_ne is not None and len(track_ne):
            draw_track(ax, track_ne)
        if targets is not None and len(targets):
            t = np.asarray(targets, float)
            done = t[:, 2] > 0
            ax.plot(t[done, 1], t[done, 0], "*", color="tab:green", markersize=14, label="target collected", zorder=5)
            ax.plot(t[~done, 1], t[~done, 0], "*", color="tab:red", markersize=14, label="target not collected",
                    zorder=5)
        ax.plot([start_ne[1]], [start_ne[0]], "o", color="tab:blue", label="home", zorder=5)
        ax.plot([], [], "s", color=(0.55, 0.85, 0.55), label="seen free")
        ax.plot([], [], "s", color=(0.55, 0.05, 0.05), label="observed obstacle")
        ax.plot([], [], "s", color=(1.0, 0.55, 0.0), label="frontier left")
        ax.set_xlim(start_ne[1] - radius_m - 35, start_ne[1] + radius_m + 35)
        ax.set_ylim(start_ne[0] - radius_m - 35, start_ne[0] + radius_m + 35)
        ax.set_aspect("equal")
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
        ax.legend(loc="upper right", fontsize=8)
        ax.set_title(title or f"exploration: {100 * (known & disk).sum() / max(disk.sum(), 1):.1f} % of the area known")
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
    return Path(path)
