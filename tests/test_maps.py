"""The map file reader, rule by rule: every malformed file is one MapFormatError naming the file, the line and
why, never a traceback or a hang; and what the client's grids may be asked to hold is bounded."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from skyroute import maps
from skyroute.maps import MapFormatError, parse_colliders, read_colliders, read_home
from tests import shared

HOME = "lat0 37.792480, lon0 -122.397450\n"
HEADER = "posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n"
BOX = "1,2,3,4,5,6\n"


def write_map(tmp_path: Path, content: str | bytes) -> Path:
    path = tmp_path / "map.csv"
    path.write_bytes(content.encode() if isinstance(content, str) else content)
    return path


def test_reads_home_and_rows_skipping_blank_lines(tmp_path):
    city = read_colliders(write_map(tmp_path, HOME + HEADER + BOX + "\n   \n-1.5,2,3,0.5,0.5,3\n"))
    assert (city.lat0_deg, city.lon0_deg) == (37.79248, -122.39745)
    assert city.obstacles.tolist() == [[1, 2, 3, 4, 5, 6], [-1.5, 2, 3, 0.5, 0.5, 3]]


@pytest.mark.parametrize("content", [
    "\ufeff" + HOME + HEADER + BOX,                                     # a UTF-8 byte-order mark
    HOME.replace("\n", "\r\n") + HEADER.replace("\n", "\r\n") + "1,2,3,4,5,6\r\n",   # Windows line ends
    HOME + " PosX , posy,POSZ,halfsizex , HalfSizeY,halfSizeZ \n" + BOX,  # header case and spaces
    HOME + HEADER + " +1.5e0 , -2., .5 ,4,5,6E-1 \n",                   # number forms
    HOME + HEADER + BOX.rstrip("\n"),                                   # no newline at the end
])
def test_accepted_variants(tmp_path, content):
    city = read_colliders(write_map(tmp_path, content))
    assert city.obstacles.shape == (1, 6) and (city.lat0_deg, city.lon0_deg) == (37.79248, -122.39745)


def test_read_home_returns_lat_then_lon(tmp_path):
    assert read_home(write_map(tmp_path, HOME + HEADER + BOX)) == (37.79248, -122.39745)
    assert read_home(write_map(tmp_path, "\ufeff" + HOME + HEADER + BOX)) == (37.79248, -122.39745)


BAD_MAPS = [
    # (content, line, what the message says)
    ("", 1, "empty file"),
    (b"\xff\xfe\x00garbage", 1, r"not UTF-8 text \(byte 0xff at column 1\)"),
    ((HOME + HEADER + BOX).encode() + b"1,2,\xe9,4,5,6\n", 4, r"not UTF-8 text \(byte 0xe9 at column 5\)"),
    ("37.7, -122.3\n" + HEADER + BOX, 1, "expected 'lat0 <deg>, lon0 <deg>'"),
    ("lat0 95.0, lon0 1.0\n" + HEADER + BOX, 1, "outside"),
    ("lat0 37.7, lon0 -180.5\n" + HEADER + BOX, 1, "outside"),
    ("lat0 nan, lon0 1.0\n" + HEADER + BOX, 1, "expected 'lat0"),
    ("lat0 1e999, lon0 1.0\n" + HEADER + BOX, 1, "not finite"),
    ("lat0 37.7, lon0 -122.3\n", 2, "expected header"),
    ("lat0 37.7, lon0 -122.3", 2, "expected header"),
    (HOME + BOX + BOX, 2, "expected header"),                            # no header: refused, not a lost box
    (HOME + "x,y,z\n" + BOX, 2, "expected header"),
    (HOME + HEADER, 3, "no obstacle rows"),
    (HOME + HEADER + "\n\n", 3, "no obstacle rows"),
    (HOME + HEADER + BOX + "1,2,3,4,5\n", 4, "expected 6 comma-separated numbers, got 5 fields"),
    (HOME + HEADER + BOX + "1,2,3,4,5,6,\n", 4, "got 7 fields"),
    (HOME + HEADER + BOX + "1,2,x,4,5,6\n", 4, "not a number: 'x'"),
    (HOME + HEADER + BOX + "\n1,2,nan,4,5,6\n", 5, "not a number: 'nan'"),
    (HOME + HEADER + "1,2,inf,4,5,6\n", 3, "not a number: 'inf'"),
    (HOME + HEADER + "1,2,1_000,4,5,6\n", 3, "not a number: '1_000'"),
    (HOME + HEADER + "0x10,2,3,4,5,6\n", 3, "not a number"),
    (HOME + HEADER + "1,2,3,4,5,6 # a comment\n", 3, "not a number"),
    (HOME + HEADER + "1,2,3,4,5,1e400\n", 3, "too large to be a finite number"),
    (HOME + HEADER + "1e300,2,3,4,5,6\n", 3, "within 25 km of home"),
    (HOME + HEADER + BOX + "1,2,3,-4,5,6\n", 4, "negative half size"),
    (HOME + HEADER + "24999,0,3,2,5,6\n", 3, r"reaches 25001 m from home \(north-south\)"),
    (HOME + HEADER + "0,-1e7,3,4,5,6\n", 3, r"\(east-west\)"),
    (HOME + HEADER + "0,0,3,4,5,1e9\n", 3, "within 10000 m"),
    (HOME + HEADER + "1,2,3,4,5,6\r1,2,3,4,5,6\n", 3, "got 11 fields"),              # a lone carriage return
    (HOME + HEADER + BOX + "-1,2,3,4,5,6\n1,2,3,-4,5,6\n1,2,3,4,5\n", 5, "negative half size"),  # first problem
]


@pytest.mark.parametrize("content, line, message", BAD_MAPS)
def test_bad_map_files_are_one_line_naming_the_file_and_line(tmp_path, content, line, message):
    path = write_map(tmp_path, content)
    with pytest.raises(MapFormatError) as info:
        read_colliders(path)
    text = str(info.value)
    assert re.search(message, text), text
    assert info.value.line == line
    assert text.startswith(f"{path}:{line}: ") and "\n" not in text


def test_a_problem_in_a_big_file_is_found_at_its_line(tmp_path):
    rows = [f"{10 * (k % 100)},{10 * (k // 100)},5,5,5,5" for k in range(20_000)]
    rows[15_000] = "1,2,3,4,-5,6"
    path = write_map(tmp_path, HOME + HEADER + "\n".join(rows) + "\n")
    with pytest.raises(MapFormatError, match=re.escape("negative half size (4, -5, 6)")) as info:
        read_colliders(path)
    assert info.value.line == 15_003


def test_fast_and_line_by_line_readers_agree(tmp_path):
    # Blank lines of spaces send a file through the line-by-line reader; the same rows must read the same.
    rows = "1,2,3,4,5,6\n-7.25,8e1,0.5,.5,1.,2\n"
    fast = parse_colliders((HOME + HEADER + rows).encode()).obstacles
    slow = parse_colliders((HOME + HEADER + "   \n" + rows).encode()).obstacles
    np.testing.assert_array_equal(fast, slow)


def test_junk_on_line_1_is_quoted_as_a_short_printable_excerpt(tmp_path):
    junk = "\x00\x1b[31m" + "x" * 4096
    with pytest.raises(MapFormatError) as info:
        read_colliders(write_map(tmp_path, junk + "\n" + HEADER + BOX))
    text = str(info.value)
    assert len(text) < 250 and "(4102 characters)" in text
    assert text.isprintable() and "\\x00" in text


def test_an_empty_map_is_allowed_only_when_asked(tmp_path):
    path = write_map(tmp_path, HOME + HEADER)
    with pytest.raises(MapFormatError, match="no obstacle rows"):
        read_colliders(path)
    city = read_colliders(path, allow_empty=True)
    assert city.obstacles.shape == (0, 6)


def test_a_map_bigger_than_the_grids_hold_names_the_row_that_stretches_it(tmp_path):
    # Two boxes 20 km apart north and east are fine for the format, but 400 M cells at 1 m are too many.
    content = HOME + HEADER + "0,0,5,5,5,5\n100,100,5,5,5,5\n-10000,0,5,5,5,5\n10000,10000,5,5,5,5\n"
    with pytest.raises(MapFormatError) as info:
        read_colliders(write_map(tmp_path, content))
    assert info.value.line == 6
    assert "stretches the map to 20010 x 10010 m, 200 M cells at 1 m;" in str(info.value)
    assert str(info.value).endswith("the planner's grids hold at most 200 M cells")
    assert read_colliders(write_map(tmp_path, content), max_grid_cells=10**9).obstacles.shape == (4, 6)


def test_the_grid_size_limit_is_inclusive():
    # One 10 x 10 m box: 100 cells at 1 m.
    content = (HOME + HEADER + "0,0,5,5,5,5\n").encode()
    assert parse_colliders(content, max_grid_cells=100).obstacles.shape == (1, 6)
    with pytest.raises(MapFormatError, match="10 x 10 m, 0 M cells at 1 m; the planner's grids hold at most 0 M"):
        parse_colliders(content, max_grid_cells=99)


def test_a_file_that_is_not_a_regular_file_is_refused_without_reading_it(tmp_path):
    import os

    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)  # reading it would block forever
    with pytest.raises(MapFormatError, match="not a regular file"):
        read_colliders(fifo)


def test_an_oversized_file_is_refused_before_it_is_read(tmp_path, monkeypatch):
    monkeypatch.setattr(maps, "MAX_FILE_BYTES", 100)
    with pytest.raises(MapFormatError, match="at most 0 MiB"):
        read_colliders(write_map(tmp_path, HOME + HEADER + BOX * 20))
    monkeypatch.setattr(maps, "MAX_FILE_BYTES", 2 * 2**20)
    big = write_map(tmp_path, HOME + HEADER + BOX * (3 * 2**20 // len(BOX) + 1))  # just over 3 MiB
    with pytest.raises(MapFormatError, match="the file is 3 MiB; .* of at most 2 MiB"):
        read_colliders(big)


@shared.needs_sf_map
def test_reads_the_sf_map_unchanged():
    city = read_colliders(shared.sf_map())
    assert city.obstacles.shape == (3845, 6)
    assert (city.lat0_deg, city.lon0_deg) == (37.79248, -122.39745)


# Where the limits are: at each limit a map is read, just past it refused (README: home within +-90/+-180 degrees,
# boxes within 25 km of home horizontally and 10 km of the ground, half sizes >= 0). A blank line of spaces sends
# the rows through the line-by-line reader, which checks each row on its own; both readers must agree.
@pytest.mark.parametrize("lat0, lon0", [(90, 0), (-90, 0), (0, 180), (0, -180)])
def test_a_home_on_the_limits_of_latitude_and_longitude_is_read(tmp_path, lat0, lon0):
    assert read_home(write_map(tmp_path, f"lat0 {lat0}, lon0 {lon0}\n" + HEADER + BOX)) == (lat0, lon0)


@pytest.mark.parametrize("lat0, lon0", [(90.5, 0), (-90.5, 0), (0, 180.5), (0, -180.5)])
def test_a_home_just_past_the_limits_is_refused_on_line_1(tmp_path, lat0, lon0):
    with pytest.raises(MapFormatError, match="outside") as info:
        read_colliders(write_map(tmp_path, f"lat0 {lat0}, lon0 {lon0}\n" + HEADER + BOX))
    assert info.value.line == 1


AT_THE_LIMITS = ["24990,0,5,10,1,5", "-24990,0,5,10,1,5", "0,24990,5,1,10,5", "0,-24990,5,1,10,5",
                 "0,0,9990,1,1,10", "0,0,-9990,1,1,10", "0,0,5,0,0,0"]


@pytest.mark.parametrize("row", AT_THE_LIMITS)
@pytest.mark.parametrize("blank", ["", "   \n"], ids=["fast-reader", "line-by-line"])
def test_boxes_on_the_limits_are_read(tmp_path, blank, row):  # one a map: together they pass the grid size limit
    obstacles = read_colliders(write_map(tmp_path, HOME + HEADER + blank + row + "\n")).obstacles
    assert obstacles.tolist() == [[float(v) for v in row.split(",")]]


@pytest.mark.parametrize("row, message", [
    ("24990,0,0,10.5,1,5", r"reaches 25000.5 m from home \(north-south\)"),
    ("0,-24990,0,1,10.5,5", r"reaches 25000.5 m from home \(east-west\)"),  # the east half size, not the height
    ("0,0,9990,1,1,10.5", "reaches 10000.5 m from the ground"),
    ("0,0,-9990,20,20,10.5", "reaches 10000.5 m from the ground"),  # its height, not a half size
    ("0,0,5,0,-0.5,0", "negative half size"),
])
@pytest.mark.parametrize("blank", ["", "   \n"], ids=["fast-reader", "line-by-line"])
def test_boxes_just_past_the_limits_are_refused_at_their_line(tmp_path, blank, row, message):
    with pytest.raises(MapFormatError, match=message) as info:
        read_colliders(write_map(tmp_path, HOME + HEADER + blank + BOX + row + "\n"))
    assert info.value.line == 4 + len(blank.splitlines())


def test_refusals_before_reading_name_the_file_without_a_line(tmp_path, monkeypatch):
    import os

    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    with pytest.raises(MapFormatError) as info:
        read_colliders(fifo)
    assert str(info.value) == f"{fifo}: not a regular file" and info.value.line is None
    assert info.value.problem == "not a regular file"
    exact = write_map(tmp_path, HOME + HEADER + BOX * 20)
    monkeypatch.setattr(maps, "MAX_FILE_BYTES", exact.stat().st_size)  # the limit is inclusive
    assert read_colliders(exact).obstacles.shape == (20, 6)
    monkeypatch.setattr(maps, "MAX_FILE_BYTES", exact.stat().st_size - 1)
    with pytest.raises(MapFormatError) as info:
        read_colliders(exact)
    assert str(info.value).startswith(f"{exact}: the file is 0 MiB")


@pytest.mark.parametrize("content, line, why", [
    (b"lat0 \xff, lon0 1\n" + (HEADER + BOX).encode(), 1, "not UTF-8 text"),
    (("lat0 95.0, lon0 1.0\n" + HEADER + BOX).encode(), 1, "outside"),
])
def test_read_home_names_the_file_and_line_of_a_bad_home(tmp_path, content, line, why):
    path = write_map(tmp_path, content)
    with pytest.raises(MapFormatError, match=why) as info:
        read_home(path)
    assert str(info.value).startswith(f"{path}:{line}: ")


@pytest.mark.parametrize("content, line, message", [
    ("\n" + HEADER + BOX, 1, "got an empty line"),  # the first line empty: said so, not a quote of what follows
    (HOME + HEADER.rstrip("\n"), 3, "no obstacle rows"),  # a header with no newline after it is still the header
    (b"\n\xff" + (HEADER + BOX).encode(), 2, r"not UTF-8 text \(byte 0xff at column 1\)"),  # after a first "\n"
])
def test_the_first_two_lines_are_read_exactly(tmp_path, content, line, message):
    with pytest.raises(MapFormatError, match=message) as info:
        read_colliders(write_map(tmp_path, content))
    assert info.value.line == line


def test_a_bad_byte_after_a_leading_newline_is_placed_at_its_own_line_and_column(tmp_path):
    path = write_map(tmp_path, (HOME + HEADER + BOX).encode() + b"\n\xe9,2,3,4,5,6\n")
    with pytest.raises(MapFormatError, match=r"byte 0xe9 at column 1\)") as info:
        read_colliders(path)
    assert info.value.line == 5


def test_the_row_named_for_an_oversized_map_is_the_first_past_the_limit_not_the_one_reaching_it(tmp_path):
    # 10 x 10 cells, then 10 x 20 (reaching 200: allowed), then 10 x 30: the third row (line 5) is past it
    content = HOME + HEADER + "5,5,5,5,5,5\n5,15,5,5,5,5\n5,25,5,5,5,5\n"
    path = write_map(tmp_path, content)
    assert read_colliders(path, max_grid_cells=300).obstacles.shape == (3, 6)
    with pytest.raises(MapFormatError) as info:
        read_colliders(path, max_grid_cells=200)
    assert info.value.line == 5 and str(info.value).startswith(f"{path}:5: this box stretches the map")


def test_a_problem_in_rows_with_spaces_is_found_at_its_line(tmp_path):
    path = write_map(tmp_path, HOME + HEADER + "1, 2, 3, 4, 5, 6\n\n1, 2, 3, 4, -5, 6\n")  # a blank line between
    with pytest.raises(MapFormatError, match="negative half size") as info:
        read_colliders(path)
    assert info.value.line == 5


def test_an_excerpt_of_exactly_the_limit_is_whole_and_one_more_is_cut():
    assert maps.excerpt("x" * 10, limit=10) == repr("x" * 10)
    assert maps.excerpt("x" * 11, limit=10) == repr("x" * 10) + "... (11 characters)"


def test_parse_colliders_refuses_an_empty_map_by_default():
    with pytest.raises(MapFormatError, match="no obstacle rows"):
        parse_colliders((HOME + HEADER).encode())
    assert parse_colliders((HOME + HEADER).encode(), allow_empty=True).obstacles.shape == (0, 6)
