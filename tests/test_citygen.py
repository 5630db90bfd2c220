"""Tests for the city generator: determinism, file format, free space where the drone starts, sizes, scale.

The checks rasterise the map themselves (1 m cells, boxes grown by a safety margin) instead of using
planning_utils, so a bug in create_grid cannot hide a bug here.
"""

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from skyroute import citygen
from tests import shared

REPO = Path(__file__).resolve().parent.parent
SHIPPED = REPO / "colliders.csv"


@pytest.fixture(scope="module")
def city():
    return citygen.generate_city()


def read(path):
    return np.loadtxt(path, delimiter=",", dtype=np.float64, skiprows=2, ndmin=2)


def free_at_ground(city, half_extent_m, safety_m, altitude_m=5.0, extent=None):
    """1 m occupancy, True = free, cell (i, j) covers north [n0 + i, n0 + i + 1), east [e0 + j, e0 + j + 1) with
    (n0, e0) = (-h, -h), or ``extent`` = ((n0, n1), (e0, e1)). Boxes grown by the margin as squares (simpler than
    the planner's rounded margin and stricter, which is what a "streets connect" check wants)."""
    (n0, n1), (e0, e1) = extent or ((-half_extent_m, half_extent_m), (-half_extent_m, half_extent_m))
    rows, cols = int(n1 - n0), int(e1 - e0)
    tall = city[city[:, 2] + city[:, 5] + safety_m > altitude_m]
    lo_n = np.clip(np.floor(tall[:, 0] - tall[:, 3] - safety_m - n0), 0, rows).astype(int)
    hi_n = np.clip(np.ceil(tall[:, 0] + tall[:, 3] + safety_m - n0), 0, rows).astype(int)
    lo_e = np.clip(np.floor(tall[:, 1] - tall[:, 4] - safety_m - e0), 0, cols).astype(int)
    hi_e = np.clip(np.ceil(tall[:, 1] + tall[:, 4] + safety_m - e0), 0, cols).astype(int)
    # 2-D difference array: +1 at each box's lower corner, -1 past its upper corner; cumsum paints the boxes.
    diff = np.zeros((rows + 1, cols + 1), dtype=np.int32)
    np.add.at(diff, (lo_n, lo_e), 1)
    np.add.at(diff, (hi_n, lo_e), -1)
    np.add.at(diff, (lo_n, hi_e), -1)
    np.add.at(diff, (hi_n, hi_e), 1)
    return diff.cumsum(0).cumsum(1)[:rows, :cols] == 0


def test_same_seed_same_city_other_seed_other_city():
    a = citygen.generate_city(size_m=600.0, seed=11)
    b = citygen.generate_city(size_m=600.0, seed=11)
    c = citygen.generate_city(size_m=600.0, seed=12)
    assert np.array_equal(a, b)
    assert a.shape != c.shape or not np.array_equal(a, c)


def test_written_file_reads_back_exactly_with_header(tmp_path, city):
    path = tmp_path / "c.csv"
    citygen.write_colliders(path, city, 37.792480, -122.397450)
    lines = path.read_text().splitlines()
    assert lines[0] == "lat0 37.792480, lon0 -122.397450"
    assert lines[1] == "posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ"
    assert len(lines) == city.shape[0] + 2
    assert np.array_equal(read(path), city)


def test_header_takes_the_given_home(tmp_path):
    path = tmp_path / "c.csv"
    citygen.write_colliders(path, np.array([[10.0, -20.0, 3.0, 5.0, 5.0, 3.0]]), -33.5, 151.25)
    assert path.read_text().splitlines()[0] == "lat0 -33.500000, lon0 151.250000"
    assert np.array_equal(read(path), [[10.0, -20.0, 3.0, 5.0, 5.0, 3.0]])


def test_write_rejects_bad_arrays(tmp_path):
    with pytest.raises(ValueError, match="N, 6"):
        citygen.write_colliders(tmp_path / "x.csv", np.zeros((3, 5)))
    with pytest.raises(ValueError):
        citygen.write_colliders(tmp_path / "x.csv", np.array([[0.0, 0, 1, 1, 1, np.nan]]))


def test_boxes_stand_on_the_ground_inside_the_square(city):
    assert np.all(city[:, 2] == city[:, 5])
    assert np.all(np.abs(city[:, :2]) + city[:, 3:5] <= 450.0)
    # "about 900 x 900 m": the boxes span most of the square in both directions
    for axis in (0, 1):
        span = (city[:, axis] + city[:, 3 + axis]).max() - (city[:, axis] - city[:, 3 + axis]).min()
        assert span > 850.0


def test_buildings_are_10m_segments_with_plausible_heights(city):
    building = city[:, 3] == 5.0
    height = 2 * city[building, 5]
    assert np.all(city[building, 4] == 5.0)
    assert np.all((height >= 3.0) & (height <= 200.0))
    assert 3000 < building.sum() < 8000
    assert 8.0 <= np.median(height) <= 25.0  # mostly low
    assert 0.02 <= np.mean(height > 50.0) <= 0.2  # a downtown of towers, not a forest of them
    assert np.any(height > 150.0)
    # one box per 10 m lattice cell, no duplicates
    assert np.unique(city[building, :2], axis=0).shape[0] == building.sum()


def test_trees_are_small_and_do_not_touch_buildings(city):
    building = city[:, 3] == 5.0
    trees, blds = city[~building], city[building]
    assert 100 < trees.shape[0] < 2000
    assert np.all((trees[:, 3] >= 1.0) & (trees[:, 3] <= 2.0) & (trees[:, 3] == trees[:, 4]))
    assert np.all((2 * trees[:, 5] >= 5.0) & (2 * trees[:, 5] <= 12.0))
    gap_n = np.abs(trees[:, None, 0] - blds[None, :, 0]) - trees[:, None, 3] - 5.0
    gap_e = np.abs(trees[:, None, 1] - blds[None, :, 1]) - trees[:, None, 4] - 5.0
    assert np.all(np.maximum(gap_n, gap_e) >= 0.5)


def test_origin_has_clearance_at_ground_level(city):
    # Horizontal distance from (0, 0) to the nearest point of every box, whatever its height.
    dn = np.maximum(np.abs(city[:, 0]) - city[:, 3], 0.0)
    de = np.maximum(np.abs(city[:, 1]) - city[:, 4], 0.0)
    assert np.hypot(dn, de).min() >= 10.0


def test_streets_connect_the_origin_to_the_whole_city_at_5m_safety(city):
    free = free_at_ground(city, 450.0, safety_m=5.0)
    labels, _ = ndimage.label(free, structure=np.ones((3, 3)))
    home = labels[450, 450]  # the cell holding the origin
    assert home != 0
    reach = labels == home
    assert reach.mean() > 0.2  # streets, avenue and plaza: a large connected free area
    rows, cols = np.nonzero(reach)
    assert rows.min() < 30 and rows.max() > 870 and cols.min() < 30 and cols.max() > 870
    # the plaza: somewhere within 250 m of the origin a free disc of radius >= 25 m (50 m across)
    dist = ndimage.distance_transform_edt(free)
    assert dist[200:700, 200:700].max() >= 25.0


def test_default_cli_reproduces_the_shipped_map_byte_for_byte(tmp_path):
    out = tmp_path / "colliders.csv"
    assert citygen.main(["-o", str(out)]) == 0
    assert out.read_bytes() == SHIPPED.read_bytes()


# The classic SF map's extent around home (metres; from its 3845 boxes): north -315.24..604.76, east
# -444.23..475.77. Goals from the exercise's writeups lie in it.
SF_EXTENT = ((-315.24, 604.77), (-444.24, 475.77))


@pytest.fixture(scope="module")
def bundled():
    return citygen.generate_bundled_city()


def test_the_bundled_map_keeps_the_900m_city_box_for_box(bundled, city):
    assert np.array_equal(bundled[: len(city)], city)
    assert np.array_equal(read(SHIPPED), bundled)


def test_the_bundled_map_covers_the_sf_maps_extent(bundled):
    lo = (bundled[:, :2] - bundled[:, 3:5]).min(axis=0)
    hi = (bundled[:, :2] + bundled[:, 3:5]).max(axis=0)
    (n0, n1), (e0, e1) = SF_EXTENT
    assert lo[0] <= n0 and hi[0] >= n1 and lo[1] <= e0 and hi[1] >= e1


@shared.needs_sf_map
def test_the_sf_extent_above_is_the_real_maps():
    sf = read(shared.sf_map())
    (n0, n1), (e0, e1) = SF_EXTENT
    assert np.allclose((sf[:, :2] - sf[:, 3:5]).min(axis=0), [n0, e0], atol=0.01)
    assert np.allclose((sf[:, :2] + sf[:, 3:5]).max(axis=0), [n1, e1], atol=0.01)


def test_a_ring_road_separates_the_900m_city_from_the_extension(bundled, city):
    added = bundled[len(city):]
    lo, hi = added[:, :2] - added[:, 3:5], added[:, :2] + added[:, 3:5]
    edge = 450.0 + citygen.RING_ROAD_M
    assert ((lo[:, 0] >= edge) | (hi[:, 0] <= -edge) | (lo[:, 1] >= edge) | (hi[:, 1] <= -edge)).all()
    assert len(added) > 500 and np.all(added[:, 2] == added[:, 5])


def test_the_bundled_streets_connect_home_to_the_whole_map_at_5m_safety(bundled):
    extent = ((-450.0, 620.0), (-450.0, 490.0))
    free = free_at_ground(bundled, 0, safety_m=5.0, extent=extent)
    labels, _ = ndimage.label(free, structure=np.ones((3, 3)))
    home = labels[450, 450]
    assert home != 0
    rows, cols = np.nonzero(labels == home)
    assert rows.min() < 30 and rows.max() > 1040 and cols.min() < 30 and cols.max() > 910


def test_cli_help_shows_defaults(capsys):
    with pytest.raises(SystemExit) as exc:
        citygen.main(["--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    text = " ".join(text.split())
    assert f"default: {citygen.DEFAULT_SEED}" in text and "default: the project's map" in text


def test_cli_writes_a_square_city_when_given_a_size(tmp_path, capsys):
    out = tmp_path / "c.csv"
    assert citygen.main(["--size-m", "400", "--seed", "3", "-o", str(out)]) == 0
    assert np.array_equal(read(out), citygen.generate_city(size_m=400.0, seed=3))
    assert "400 m square, seed 3" in capsys.readouterr().out


def test_cli_rejects_a_tiny_city(tmp_path, capsys):
    assert citygen.main(["--size-m", "50", "-o", str(tmp_path / "x.csv")]) == 2
    assert "size_m" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_5km_city_has_plausible_count_and_extent():
    city = citygen.generate_city(size_m=5000.0, seed=5)
    assert 80_000 < city.shape[0] < 300_000
    lo = (city[:, :2] - city[:, 3:5]).min(axis=0)
    hi = (city[:, :2] + city[:, 3:5]).max(axis=0)
    assert np.all(lo >= -2500.0) and np.all(hi <= 2500.0)
    assert np.all(hi - lo > 4900.0)
    dn = np.maximum(np.abs(city[:, 0]) - city[:, 3], 0.0)
    de = np.maximum(np.abs(city[:, 1]) - city[:, 4], 0.0)
    assert np.hypot(dn, de).min() >= 10.0
