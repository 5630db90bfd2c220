"""A small deterministic city generator that writes maps in the classic ``colliders.csv`` format.

The project's own map (``colliders.csv`` at the repository root) is produced by this module; run
``python -m skyroute.citygen`` to regenerate it byte for byte, or
``python -m skyroute.citygen --size-m 5000 -o city5k.csv`` for a
larger city to benchmark with.

The project's map (:func:`generate_bundled_city`) covers the extent of the classic exercise's San Francisco map
around the same home (north -315..605 m, east -444..476 m), so goals from the exercise are on it: the 900 m city
of seed 2 (the original bundled map, kept box for box, since tests and the README fly to goals on it), a 20 m
ring road round it, and beyond the ring the blocks of a second generated city (seed 102) out to north 620 m and
east 490 m.

Frame and units: every box is ``north_m, east_m, centre_alt_m, half_north_m, half_east_m, half_alt_m`` in the
local NED-ish map frame whose origin is the home point ``lat0, lon0`` written on the file's first line. Boxes
stand on the ground (``centre_alt_m == half_alt_m``). The city is a square of side ``size_m`` centred on the
origin.

What the city holds (all drawn from one ``numpy.random.Generator`` seeded by ``seed``):

- a grid of streets 20-30 m wide (building face to building face), with a street intersection at the origin so
  the drone's default start has at least 10 m of clearance at ground level;
- one diagonal avenue (per ~4 km of city side) cutting through the blocks;
- blocks made of 10 m x 10 m building segments grouped into lots; a lot's segments share a height, give or
  take a little. Heights are mostly low (median ~12 m); lots near a downtown centre are towers of up to 200 m;
- one block next to the origin left empty as an open plaza, and a few empty lots (parking, courtyards);
- trees (1-2 m half size, 5-12 m tall) on the sidewalks of some of the wider streets, kept out of intersections.

>>> city = generate_city(size_m=300.0, seed=1)
>>> city.shape[1]
6
>>> bool(np.all(city[:, 2] == city[:, 5]))
True
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

DEFAULT_SEED = 2
DEFAULT_SIZE_M = 900.0
#: The bundled map's extent, (north min, north max), (east min, east max) in metres: the 900 m city's south and
#: west edges, and a little past the SF map's north (604.8 m) and east (475.8 m) edges. A low bollard in the
#: north-east corner makes the map's grid reach it.
BUNDLED_EXTENT_M = ((-450.0, 620.0), (-450.0, 490.0))
EXTENSION_SEED = 102
RING_ROAD_M = 20.0
DEFAULT_LAT0_DEG = 37.792480
DEFAULT_LON0_DEG = -122.397450
HEADER_COLUMNS = "posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ"

SEGMENT_M = 10.0
STREET_WIDTHS_M = np.array([20, 22, 24, 26, 30])
STREET_WIDTH_P = np.array([0.3, 0.2, 0.2, 0.15, 0.15])
BLOCK_SEGMENTS = np.arange(6, 12)  # block side in 10 m segments: 60..110 m
MIN_HEIGHT_M = 3.0
MAX_HEIGHT_M = 200.0
TREE_STREET_MIN_WIDTH_M = 24  # trees only where the street keeps >= 7 m clear either side of its centreline
TREE_SETBACK_M = 3.0  # tree centre to building face
AVENUE_WIDTH_M = 30.0
DOWNTOWN_RADIUS_M = 160.0


def _streets_1d(half_size_m: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Street centrelines and widths along one axis, with a street at 0, covering ``[-half_size_m, half_size_m]``.

    Returns sorted ``(centres_m, widths_m)``; consecutive streets are separated by a block whose side is a
    multiple of 10 m, and every street edge lies on a whole metre.
    """
    centres, widths = [0.0], [float(rng.choice(STREET_WIDTHS_M[2:]))]  # the origin street is a wide one
    for direction in (1.0, -1.0):
        c, w = 0.0, widths[0]
        while abs(c) - w / 2 < half_size_m:
            block = SEGMENT_M * rng.choice(BLOCK_SEGMENTS)
            w_next = float(rng.choice(STREET_WIDTHS_M, p=STREET_WIDTH_P))
            c += direction * (w / 2 + block + w_next / 2)
            w = w_next
            centres.append(c)
            widths.append(w)
    order = np.argsort(centres)
    return np.asarray(centres)[order], np.asarray(widths)[order]


def _segments_1d(
    centres: np.ndarray, widths: np.ndarray, half_size_m: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres of the 10 m building segments along one axis, their block index and their lot index.

    A lot is a run of consecutive segments in one block: each segment after a block's first starts a new lot
    with probability 0.4. Segments that would stick out of the city square are dropped.
    """
    starts = centres[:-1] + widths[:-1] / 2
    ends = centres[1:] - widths[1:] / 2
    counts = np.round((ends - starts) / SEGMENT_M).astype(np.int64)
    block = np.repeat(np.arange(counts.size), counts)
    first = np.cumsum(counts) - counts
    within = np.arange(block.size) - first[block]
    pos = starts[block] + SEGMENT_M * (within + 0.5)
    new_lot = (within == 0) | (rng.random(block.size) < 0.4)
    lot = np.cumsum(new_lot) - 1
    inside = np.abs(pos) + SEGMENT_M / 2 <= half_size_m
    return pos[inside], block[inside], lot[inside]


def _avenue_lines(size_m: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Points and unit directions (north, east) of the diagonal avenues: one per ~4 km of side, none at the origin."""
    n = max(1, int(round(size_m / 4000.0)))
    angle = np.deg2rad(rng.uniform(30.0, 60.0, n))
    direction = np.stack([np.sin(angle), np.cos(angle)], axis=1)
    # Spread the avenues across the city, each offset from the origin perpendicular to its direction.
    offset = size_m * ((np.arange(n) + 0.5) / n - 0.5) + rng.uniform(0.12, 0.2, n) * min(size_m, 1000.0)
    normal = np.stack([-direction[:, 1], direction[:, 0]], axis=1)
    return normal * offset[:, None], direction


def _distance_to_lines(north: np.ndarray, east: np.ndarray, points: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Smallest perpendicular distance in metres from each (north, east) point to any of the given lines."""
    dn = north[:, None] - points[None, :, 0]
    de = east[:, None] - points[None, :, 1]
    return np.min(np.abs(dn * dirs[None, :, 1] - de * dirs[None, :, 0]), axis=1)


def _lot_heights(
    lot_north: np.ndarray, lot_east: np.ndarray, size_m: float, rng: np.random.Generator
) -> np.ndarray:
    """Height in metres of every lot on the (north lot, east lot) lattice, shape (lots_north, lots_east).

    Ordinary lots: lognormal, median 12 m. Near a downtown centre a lot becomes a tower (40-200 m) with
    probability ``0.85 * exp(-(d / R)^2)``, R = 160 m. One downtown per ~4 km^2, the first 250-350 m from the origin.
    """
    n_centres = max(1, int(round(size_m * size_m / 4.0e6)))
    first = rng.uniform(250.0, 350.0) * np.array([np.cos(a := rng.uniform(0, 2 * np.pi)), np.sin(a)])
    centres = np.vstack([first, rng.uniform(-size_m / 2, size_m / 2, (n_centres - 1, 2))])
    shape = (lot_north.size, lot_east.size)
    base = np.exp(rng.normal(np.log(12.0), 0.55, shape))
    tower = 40.0 + 160.0 * rng.beta(1.6, 2.2, shape)
    d2 = np.full(shape, np.inf)
    for cn, ce in centres:  # a handful of centres, each a vectorised pass over the lot lattice
        d2 = np.minimum(d2, (lot_north[:, None] - cn) ** 2 + (lot_east[None, :] - ce) ** 2)
    p_tower = 0.85 * np.exp(-d2 / DOWNTOWN_RADIUS_M**2)
    height = np.where(rng.random(shape) < p_tower, tower, base)
    return np.clip(np.round(height), MIN_HEIGHT_M, MAX_HEIGHT_M)


def _trees(
    centres: np.ndarray,
    widths: np.ndarray,
    cross_centres: np.ndarray,
    cross_widths: np.ndarray,
    half_size_m: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Trees on both sidewalks of some wide streets along one axis, as (along_m, across_m, half_m, height_m).

    ``centres``/``widths`` are the streets whose centreline is at a fixed ``across`` coordinate; trees are kept
    out of the crossing streets (``cross_*``) and their centres 3 m back from the city edge.
    """
    wide = np.flatnonzero((widths >= TREE_STREET_MIN_WIDTH_M) & (np.abs(centres) < half_size_m))
    planted = wide[rng.random(wide.size) < 0.6]
    spacing = 11.0
    along = np.arange(-half_size_m + 3.0, half_size_m - 3.0, spacing)
    street = np.repeat(planted, 2 * along.size)
    side = np.tile(np.repeat([-1.0, 1.0], along.size), planted.size)
    a = np.tile(along, 2 * planted.size) + rng.uniform(-2.0, 2.0, street.size)
    across = centres[street] + side * (widths[street] / 2 - TREE_SETBACK_M)
    # Drop trees inside (or within 4 m of) a crossing street, and a quarter of the rest at random.
    k = np.clip(np.searchsorted(cross_centres, a), 1, cross_centres.size - 1)
    gap = np.minimum(
        np.abs(a - cross_centres[k - 1]) - cross_widths[k - 1] / 2,
        np.abs(a - cross_centres[k]) - cross_widths[k] / 2,
    )
    inside = (np.abs(a) < half_size_m - 3.0) & (np.abs(across) < half_size_m - 3.0)
    keep = (gap > 4.0) & inside & (rng.random(street.size) < 0.75)
    half = np.round(rng.uniform(1.0, 2.0, street.size), 1)
    height = np.round(rng.uniform(5.0, 12.0, street.size), 1)
    return np.stack([a, across, half, height], axis=1)[keep]


def generate_city(
    size_m: float = DEFAULT_SIZE_M,
    seed: int = DEFAULT_SEED,
    lat0_deg: float = DEFAULT_LAT0_DEG,
    lon0_deg: float = DEFAULT_LON0_DEG,
) -> np.ndarray:
    """Generate a city of axis-aligned boxes standing on the ground.

    Parameters
    ----------
    size_m : float
        Side of the square city in metres, centred on the origin (at least 200 m).
    seed : int
        Seed of the ``numpy.random.Generator``; the same seed and size give the same city.
    lat0_deg, lon0_deg : float
        Home point of the map. Accepted so callers can pass a whole map description; the geometry does not
        depend on it (write it with :func:`write_colliders`).

    Returns
    -------
    numpy.ndarray
        Shape (N, 6) float64: ``north_m, east_m, centre_alt_m, half_north_m, half_east_m, half_alt_m``, with
        ``centre_alt_m == half_alt_m``. Values are rounded to 0.1 m so a written file reads back exactly.

    Raises
    ------
    ValueError
        If ``size_m`` is below 200 m or not finite.

    Examples
    --------
    >>> a = generate_city(size_m=400.0, seed=3)
    >>> b = generate_city(size_m=400.0, seed=3)
    >>> bool(np.array_equal(a, b)), bool(np.all(np.abs(a[:, :2]) + a[:, 3:5] <= 200.0))
    (True, True)
    """
    if not np.isfinite(size_m) or size_m < 200.0:
        raise ValueError(f"size_m must be a finite number >= 200 m, got {size_m!r}")
    del lat0_deg, lon0_deg  # the home point only goes in the file header
    rng = np.random.default_rng(seed)
    half_size = size_m / 2.0

    n_centres, n_widths = _streets_1d(half_size, rng)
    e_centres, e_widths = _streets_1d(half_size, rng)
    n_pos, n_block, n_lot = _segments_1d(n_centres, n_widths, half_size, rng)
    e_pos, e_block, e_lot = _segments_1d(e_centres, e_widths, half_size, rng)

    # Lot lattice: a lot's representative position is its first segment's (good enough for downtown distance).
    n_lot_id, n_first = np.unique(n_lot, return_index=True)
    e_lot_id, e_first = np.unique(e_lot, return_index=True)
    heights = _lot_heights(n_pos[n_first], e_pos[e_first], size_m, rng)
    empty_lot = rng.random(heights.shape) < 0.05
    n_lot_idx = np.searchsorted(n_lot_id, n_lot)
    e_lot_idx = np.searchsorted(e_lot_id, e_lot)

    # Every segment of every block: the outer product of the two 1-D segment lists.
    ii, jj = np.meshgrid(np.arange(n_pos.size), np.arange(e_pos.size), indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    north, east = n_pos[ii], e_pos[jj]
    li, lj = n_lot_idx[ii], e_lot_idx[jj]
    height = heights[li, lj] * rng.uniform(0.9, 1.1, ii.size)
    height = np.clip(np.round(height), MIN_HEIGHT_M, MAX_HEIGHT_M)

    # The plaza: the block north-east of the origin intersection.
    plaza_n = np.searchsorted(n_centres, 0.0, side="right") - 1
    plaza_e = np.searchsorted(e_centres, 0.0, side="right") - 1
    plaza = (n_block[ii] == plaza_n) & (e_block[jj] == plaza_e)

    av_points, av_dirs = _avenue_lines(size_m, rng)
    clear = AVENUE_WIDTH_M / 2 + SEGMENT_M / np.sqrt(2.0)  # a box's corner must stay out of the avenue
    on_avenue = _distance_to_lines(north, east, av_points, av_dirs) < clear
    keep = ~(plaza | on_avenue | empty_lot[li, lj])
    half_seg = np.full(int(keep.sum()), SEGMENT_M / 2)
    buildings = np.stack(
        [north[keep], east[keep], height[keep] / 2, half_seg, half_seg, height[keep] / 2], axis=1
    )

    # Trees: along north-south streets (fixed east) and east-west streets (fixed north).
    t_ns = _trees(e_centres, e_widths, n_centres, n_widths, half_size, rng)  # along = north, across = east
    t_ew = _trees(n_centres, n_widths, e_centres, e_widths, half_size, rng)  # along = east, across = north
    t_north = np.concatenate([t_ns[:, 0], t_ew[:, 1]])
    t_east = np.concatenate([t_ns[:, 1], t_ew[:, 0]])
    t_half = np.concatenate([t_ns[:, 2], t_ew[:, 2]])
    t_height = np.concatenate([t_ns[:, 3], t_ew[:, 3]])
    in_avenue = _distance_to_lines(t_north, t_east, av_points, av_dirs) < AVENUE_WIDTH_M / 2 + t_half
    t = ~in_avenue
    trees = np.stack(
        [t_north[t], t_east[t], t_height[t] / 2, t_half[t], t_half[t], t_height[t] / 2], axis=1
    )
    return np.round(np.vstack([buildings, trees]), 1) + 0.0  # + 0.0 turns -0.0 into 0.0


def extend_city(
    core: np.ndarray, core_half_m: float, extent_m: tuple[tuple[float, float], tuple[float, float]], seed: int,
    ring_m: float = RING_ROAD_M,
) -> np.ndarray:
    """Extend a square city ``core`` (side ``2 core_half_m`` round the origin) to a rectangular extent.

    The boxes of ``core`` stay as they are; around it runs a ring road ``ring_m`` wide; beyond the ring come the
    boxes of another generated city (``seed``) that lie wholly inside ``extent_m`` ((north min, north max),
    (east min, east max), metres) and clear of the ring. Rows are the core's, then the new ones.

    >>> core = generate_city(size_m=300.0, seed=1)
    >>> city = extend_city(core, 150.0, ((-150.0, 400.0), (-150.0, 150.0)), seed=7)
    >>> bool(np.array_equal(city[: len(core)], core)), bool((city[len(core):, 0] - city[len(core):, 3] >= 170).all())
    (True, True)
    """
    (n_min, n_max), (e_min, e_max) = extent_m
    reach = max(abs(n_min), abs(n_max), abs(e_min), abs(e_max))
    outer = generate_city(size_m=2.0 * math.ceil(reach), seed=seed)
    lo, hi = outer[:, :2] - outer[:, 3:5], outer[:, :2] + outer[:, 3:5]
    inside = (lo[:, 0] >= n_min) & (hi[:, 0] <= n_max) & (lo[:, 1] >= e_min) & (hi[:, 1] <= e_max)
    edge = core_half_m + ring_m
    beyond_ring = (lo[:, 0] >= edge) | (hi[:, 0] <= -edge) | (lo[:, 1] >= edge) | (hi[:, 1] <= -edge)
    return np.vstack([core, outer[inside & beyond_ring]])


def generate_bundled_city() -> np.ndarray:
    """The project's map: the 900 m city of seed 2 extended to :data:`BUNDLED_EXTENT_M` (see the module notes)."""
    core = generate_city(DEFAULT_SIZE_M, DEFAULT_SEED)
    city = extend_city(core, DEFAULT_SIZE_M / 2.0, BUNDLED_EXTENT_M, EXTENSION_SEED)
    (_, n_max), (_, e_max) = BUNDLED_EXTENT_M
    bollard = [n_max - 0.5, e_max - 0.5, 0.5, 0.5, 0.5, 0.5]  # 1 m tall, 1 m square
    return np.vstack([city, [bollard]])


def write_colliders(
    path: str | Path, obstacles: np.ndarray, lat0_deg: float = DEFAULT_LAT0_DEG, lon0_deg: float = DEFAULT_LON0_DEG
) -> None:
    """Write boxes to ``path`` in the classic ``colliders.csv`` format.

    Line 1 is ``lat0 <deg>, lon0 <deg>`` (6 decimals), line 2 the column header, then one row per box
    (``north, east, alt, half_north, half_east, half_alt`` in metres). Each value is written with the shortest
    text that reads back to the same float64, so ``np.loadtxt(path, delimiter=",", skiprows=2)`` returns
    ``obstacles`` exactly.

    Raises
    ------
    ValueError
        If ``obstacles`` is not an (N, 6) array of finite numbers.
    """
    obstacles = np.asarray(obstacles, dtype=np.float64)
    if obstacles.ndim != 2 or obstacles.shape[1] != 6 or not np.all(np.isfinite(obstacles)):
        raise ValueError(f"obstacles must be a finite (N, 6) array, got shape {obstacles.shape}")
    lines = [f"lat0 {lat0_deg:.6f}, lon0 {lon0_deg:.6f}", HEADER_COLUMNS]
    lines.extend(",".join(map(repr, row)) for row in obstacles.tolist())
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")


def main(argv: list[str] | None = None) -> int:
    """Command line: generate a city and write it as a colliders file. Returns the exit code."""
    parser = argparse.ArgumentParser(
        prog="python -m skyroute.citygen",
        description="Generate a deterministic city map in the colliders.csv format. "
        "With no --size-m it regenerates the project's colliders.csv (the 900 m city of seed 2, extended to the "
        "SF map's extent).",
    )
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED, help="random seed (default: %(default)s)")
    parser.add_argument(
        "--size-m", type=float, help="side of a square city in metres (default: the project's map)"
    )
    parser.add_argument("-o", "--output", default="colliders.csv", help="output file (default: %(default)s)")
    parser.add_argument(
        "--lat0", type=float, default=DEFAULT_LAT0_DEG, help="home latitude, deg (default: %(default)s)"
    )
    parser.add_argument(
        "--lon0", type=float, default=DEFAULT_LON0_DEG, help="home longitude, deg (default: %(default)s)"
    )
    args = parser.parse_args(argv)
    if args.size_m is None and args.seed == DEFAULT_SEED:
        city, what = generate_bundled_city(), "the project's map"
    else:
        size_m = DEFAULT_SIZE_M if args.size_m is None else args.size_m
        try:
            city = generate_city(size_m=size_m, seed=args.seed, lat0_deg=args.lat0, lon0_deg=args.lon0)
        except ValueError as err:
            print(f"citygen: error: {err}", file=sys.stderr)
            return 2
        what = f"{size_m:g} m square, seed {args.seed}"
    write_colliders(args.output, city, args.lat0, args.lon0)
    print(f"wrote {city.shape[0]} boxes ({what}) to {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
