"""City map files: read and validate ``colliders.csv`` (home line, header, one box per row).

Obstacle rows are ``north, east, alt, half_north, half_east, half_alt``: box centre and half sizes in metres in the
map frame (NED at the map's home ``lat0, lon0``; ``alt`` upwards).

The format, rule by rule (the simulator's reader in ``sim/world.py`` implements the same list; tests feed both
the same files):

* UTF-8 text; a UTF-8 byte-order mark at the start is ignored. Lines end with ``\\n`` (or ``\\r\\n``).
* Line 1: ``lat0 <deg>, lon0 <deg>`` with finite decimal numbers, latitude in [-90, 90], longitude in
  [-180, 180].
* Line 2: the header ``posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ`` (case-insensitive, spaces allowed around
  the names). A file without it is refused at line 2.
* Every other non-blank line: exactly 6 comma-separated finite decimal numbers (optional sign, digits with an
  optional fraction, optional exponent; spaces around them are fine), half sizes >= 0, every box within 25 km of
  home horizontally (``|north| + half_north <= 25000``, same for east) and ``|alt| + half_alt <= 10000``.
* At least one box, unless the caller allows an empty map (only the two header lines).

On top of the format the client bounds what a map may ask of its 1 m grids (:data:`MAX_GRID_CELLS`) and reads at
most :data:`MAX_FILE_BYTES`. Every problem is a :class:`MapFormatError` whose one-line message names the file, the
line and why; text quoted from the file is a short, printable excerpt.
"""

from __future__ import annotations

import io
import math
import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Boxes must lie within this many metres of home, north and east (|centre| + half size).
MAX_HORIZONTAL_M = 25_000.0
#: ... and within this many metres of the map datum vertically (|alt| + half_alt).
MAX_VERTICAL_M = 10_000.0
#: The most 1 m cells the client's planners rasterise a map into (about 14 x 14 km; the grid planners keep a few
#: bytes per cell, grid3d and prm nine). A map whose footprints span more is refused when it is read.
MAX_GRID_CELLS = 200_000_000
#: The largest map file the client reads (a little over 8 million boxes).
MAX_FILE_BYTES = 256 * 2**20

COLLIDERS_HEADER = ("posx", "posy", "posz", "halfsizex", "halfsizey", "halfsizez")
_HEADER_TEXT = "posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ"
_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_NUMBER_RE = re.compile(rf"\s*{_NUMBER}\s*")
_HOME_RE = re.compile(rf"\s*lat0\s+(?P<lat>{_NUMBER})\s*,\s*lon0\s+(?P<lon>{_NUMBER})\s*")
# Rows made of these characters only go to NumPy's reader; anything else goes line by line (and fails there).
_OTHER_THAN_NUMBERS = re.compile(r"[^0-9eE+\-., \t\r\n]")
_EXCERPT_CHARS = 40


class MapFormatError(ValueError):
    """A map file that cannot be used; ``str()`` is one line naming the file, the line (if any) and why."""

    def __init__(self, path: str | Path, line: int | None, problem: str):
        self.path = str(path)
        self.line = line
        self.problem = problem
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {problem}")


@dataclass(frozen=True)
class CityMap:
    """A city map: home position (degrees) and obstacle boxes ``(N, 6)`` in metres, map frame."""

    lat0_deg: float
    lon0_deg: float
    obstacles: np.ndarray
    path: str = "<memory>"


def excerpt(text: str, limit: int = _EXCERPT_CHARS) -> str:
    """``text`` quoted for a one-line message: at most ``limit`` characters, non-printable ones escaped."""
    shown = repr(text[:limit])
    return shown if len(text) <= limit else f"{shown}... ({len(text)} characters)"


def read_colliders(
    path: str | Path, *, allow_empty: bool = False, max_grid_cells: int = MAX_GRID_CELLS
) -> CityMap:
    """Read and validate a ``colliders.csv`` map file (the rules are in the module docstring).

    Parameters
    ----------
    path : str or Path
        The file.
    allow_empty : bool
        Accept a map with no boxes (only the home line and the header), e.g. for exploring unknown space.
    max_grid_cells : int
        Refuse a map whose footprints span more 1 m cells than this.

    Raises
    ------
    MapFormatError
        For any malformed content, naming the file and line.
    OSError
        If the file cannot be opened or read.
    """
    path = Path(path)
    info = os.stat(path)
    if not stat.S_ISREG(info.st_mode):
        raise MapFormatError(path, None, "not a regular file")
    if info.st_size > MAX_FILE_BYTES:
        raise MapFormatError(path, None, f"the file is {info.st_size / 2**20:.0f} MiB; the client reads map files "
                                         f"of at most {MAX_FILE_BYTES // 2**20} MiB")
    return parse_colliders(path.read_bytes(), path, allow_empty=allow_empty, max_grid_cells=max_grid_cells)


def parse_colliders(
    data: bytes, path: str | Path = "<memory>", *, allow_empty: bool = False, max_grid_cells: int = MAX_GRID_CELLS
) -> CityMap:
    """:func:`read_colliders` on the file's bytes; ``path`` only names the file in messages."""
    text = _decode(data, path)
    if not text:
        raise MapFormatError(path, 1, "empty file; expected 'lat0 <deg>, lon0 <deg>'")
    first_end = text.find("\n")
    lat0, lon0 = parse_home_line(path, text if first_end < 0 else text[:first_end])
    if first_end < 0:
        raise MapFormatError(path, 2, f"expected header '{_HEADER_TEXT}', got the end of the file")
    second_end = text.find("\n", first_end + 1)
    line2 = text[first_end + 1 :] if second_end < 0 else text[first_end + 1 : second_end]
    if [name.strip().lower() for name in _strip_cr(line2).split(",")] != list(COLLIDERS_HEADER):
        raise MapFormatError(path, 2, f"expected header '{_HEADER_TEXT}', got {excerpt(_strip_cr(line2))}")
    body = "" if second_end < 0 else text[second_end + 1 :]
    obstacles = _parse_rows(path, body)
    if len(obstacles) == 0 and not allow_empty:
        raise MapFormatError(path, 3, "no obstacle rows after the header")
    _check_grid_size(path, body, obstacles, max_grid_cells)
    return CityMap(lat0, lon0, obstacles, str(path))


def read_home(path: str | Path) -> tuple[float, float]:
    """Return the map's home ``(lat0_deg, lon0_deg)`` from line 1 of a ``colliders.csv`` file."""
    with open(path, "rb") as f:
        head = f.read(64 * 1024)
    text = _decode(head.split(b"\n", 1)[0], path)
    return parse_home_line(path, text)


def parse_home_line(path: str | Path, line: str) -> tuple[float, float]:
    """``(lat0_deg, lon0_deg)`` from a home line ``lat0 <deg>, lon0 <deg>``; :class:`MapFormatError` otherwise."""
    line = _strip_cr(line)
    match = _HOME_RE.fullmatch(line)
    if match is None:
        got = "an empty line" if not line.strip() else excerpt(line)
        raise MapFormatError(path, 1, f"expected 'lat0 <deg>, lon0 <deg>', got {got}")
    lat0, lon0 = float(match["lat"]), float(match["lon"])
    if not (math.isfinite(lat0) and math.isfinite(lon0)):
        raise MapFormatError(path, 1, f"home lat0 {match['lat']}, lon0 {match['lon']} is not finite")
    if not (-90.0 <= lat0 <= 90.0 and -180.0 <= lon0 <= 180.0):
        raise MapFormatError(path, 1, f"home lat0 {lat0:g}, lon0 {lon0:g} is outside [-90, 90] x [-180, 180]")
    return lat0, lon0


# ---------------------------------------------------------------------------------------------------------------
# Helpers


def _decode(data: bytes, path: str | Path) -> str:
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise MapFormatError(path, line, f"not UTF-8 text (byte 0x{data[exc.start]:02x} at column {column})") from None
    return text[1:] if text.startswith("\ufeff") else text


def _strip_cr(line: str) -> str:
    return line[:-1] if line.endswith("\r") else line


def _parse_rows(path: str | Path, body: str) -> np.ndarray:
    """The boxes ``(N, 6)``: NumPy's reader when the rows hold only number characters, else line by line."""
    obstacles = None
    if not body.strip():
        return np.zeros((0, 6))
    if _OTHER_THAN_NUMBERS.search(body) is None:
        try:
            obstacles = np.loadtxt(io.StringIO(body), delimiter=",", comments=None, dtype=np.float64, ndmin=2)
        except ValueError:
            obstacles = None
    if obstacles is None or obstacles.shape[1] != 6:
        return _parse_rows_one_by_one(path, body)
    bad = ~np.isfinite(obstacles).all(axis=1)
    bad |= (obstacles[:, 3:] < 0).any(axis=1)
    bad |= (np.abs(obstacles[:, :2]) + obstacles[:, 3:5] > MAX_HORIZONTAL_M).any(axis=1)
    bad |= np.abs(obstacles[:, 2]) + obstacles[:, 5] > MAX_VERTICAL_M
    if bad.any():
        row = int(np.argmax(bad))
        raise MapFormatError(path, _row_lines(body)[row], _row_problem(obstacles[row]))
    return obstacles


def _parse_rows_one_by_one(path: str | Path, body: str) -> np.ndarray:
    rows = []
    for number, line in enumerate(body.split("\n"), start=3):
        line = _strip_cr(line)
        if not line.strip():
            continue
        fields = line.split(",")
        if len(fields) != 6:
            raise MapFormatError(path, number, f"expected 6 comma-separated numbers, got {len(fields)} fields: "
                                               f"{excerpt(line)}")
        for field in fields:
            if _NUMBER_RE.fullmatch(field) is None:
                raise MapFormatError(path, number, f"not a number: {excerpt(field.strip())}")
        row = [float(field) for field in fields]
        problem = _row_problem(np.array(row))
        if problem:
            raise MapFormatError(path, number, problem)
        rows.append(row)
    return np.array(rows, dtype=np.float64).reshape(-1, 6)


def _row_problem(row: np.ndarray) -> str:
    """What is wrong with one parsed row ``north, east, alt, half_north, half_east, half_alt`` ('' if nothing)."""
    if not np.isfinite(row).all():
        return "a value is too large to be a finite number"
    if (row[3:] < 0).any():
        return f"negative half size ({', '.join(f'{v:g}' for v in row[3:])})"
    for axis, name in ((0, "north-south"), (1, "east-west")):
        reach = abs(row[axis]) + row[3 + axis]
        if reach > MAX_HORIZONTAL_M:
            return (f"the box reaches {reach:.6g} m from home ({name}); boxes must lie within "
                    f"{MAX_HORIZONTAL_M / 1000:g} km of home")
    reach = abs(row[2]) + row[5]
    if reach > MAX_VERTICAL_M:
        return f"the box reaches {reach:.6g} m from the ground; boxes must lie within {MAX_VERTICAL_M:g} m of it"
    return ""


def _row_lines(body: str) -> list[int]:
    """File line number of each non-blank row of ``body`` (which starts at line 3)."""
    return [n for n, line in enumerate(body.split("\n"), start=3) if line.strip()]


def _check_grid_size(path: str | Path, body: str, obstacles: np.ndarray, max_grid_cells: int) -> None:
    """Refuse boxes whose footprints span more than ``max_grid_cells`` 1 m cells, naming the first row (in file
    order) that makes the span too big."""
    if len(obstacles) == 0:
        return
    north, east, _, d_north, d_east, _ = obstacles.T
    n_lo, n_hi = np.minimum.accumulate(np.floor(north - d_north)), np.maximum.accumulate(np.ceil(north + d_north))
    e_lo, e_hi = np.minimum.accumulate(np.floor(east - d_east)), np.maximum.accumulate(np.ceil(east + d_east))
    cells = (n_hi - n_lo) * (e_hi - e_lo)
    if cells[-1] <= max_grid_cells:
        return
    row = int(np.argmax(cells > max_grid_cells))
    span_n, span_e = n_hi[row] - n_lo[row], e_hi[row] - e_lo[row]
    raise MapFormatError(
        path, _row_lines(body)[row],
        f"this box stretches the map to {span_n:.0f} x {span_e:.0f} m, {cells[row] / 1e6:.0f} M cells at 1 m; "
        f"the planner's grids hold at most {max_grid_cells / 1e6:.0f} M cells",
    )
