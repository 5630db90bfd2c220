"""City map files: read and validate ``colliders.csv`` (home line, header, one box per row).

Obstacle rows are ``north, east, alt, half_north, half_east, half_alt``: box centre and half sizes in metres in the
map frame (NED at the map's home ``lat0, lon0``; ``alt`` upwards).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

COLLIDERS_HEADER = ("posx", "posy", "posz", "halfsizex", "halfsizey", "halfsizez")
_HOME_RE = re.compile(
    r"^\s*lat0\s+(?P<lat>[-+0-9.eE]+)\s*,\s*lon0\s+(?P<lon>[-+0-9.eE]+)\s*$",
)


class MapFormatError(ValueError):
    """A map file that cannot be read; ``str()`` names the file and line."""

    def __init__(self, path: str | Path, line: int, problem: str):
        self.path = str(path)
        self.line = line
        self.problem = problem
        super().__init__(f"{self.path}:{line}: {problem}")



@dataclass(frozen=True)
class CityMap:
    """A city map: home position (degrees) and obstacle boxes ``(N, 6)`` in metres, map frame."""

    lat0_deg: float
    lon0_deg: float
    obstacles: np.ndarray
    path: str = "<memory>"


def read_colliders(path: str | Path) -> CityMap:
    """Read a ``colliders.csv`` map file.

    Format: line 1 ``lat0 <deg>, lon0 <deg>``; line 2 the header
    ``posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ``; then one row per box ``north, east, alt, half_north,
    half_east, half_alt`` in metres. Blank lines are ignored.

    Raises
    ------
    MapFormatError
        Naming the file and line, for a missing or garbled home line or header, a row without 6 numbers,
        a NaN or infinite value, a negative half size, or a file with no obstacles.
    OSError
        If the file cannot be opened.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise MapFormatError(path, 1, f"not a text file ({exc.reason})") from None
    lines = text.splitlines()
    if not lines:
        raise MapFormatError(path, 1, "empty file; expected 'lat0 <deg>, lon0 <deg>'")
    lat0, lon0 = _parse_home_line(path, lines[0])
    if len(lines) < 2 or [c.strip().lower() for c in lines[1].split(",")] != list(COLLIDERS_HEADER):
        got = lines[1].strip() if len(lines) >= 2 else "end of file"
        raise MapFormatError(path, 2, f"expected header 'posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ', got {got!r}")

    line_numbers = [n for n, line in enumerate(lines[2:], start=3) if line.strip()]
    if not line_numbers:
        raise MapFormatError(path, 3, "no obstacle rows after the header")
    rows = [lines[n - 1] for n in line_numbers]
    try:
        obstacles = np.loadtxt(rows, delimiter=",", dtype=np.float64, ndmin=2)
    except ValueError:
        obstacles = None
    if obstacles is None or obstacles.shape[1] != 6:
        for n, row in zip(line_numbers, rows):
            _parse_row(path, n, row)
        raise MapFormatError(path, line_numbers[0], "rows are not 6 comma-separated numbers")  # pragma: no cover

    bad_value = ~np.isfinite(obstacles).all(axis=1)
    if bad_value.any():
        n = line_numbers[int(np.argmax(bad_value))]
        raise MapFormatError(path, n, "NaN or infinite value")
    negative = (obstacles[:, 3:] < 0).any(axis=1)
    if negative.any():
        n = line_numbers[int(np.argmax(negative))]
        raise MapFormatError(path, n, "negative half size")
    return CityMap(lat0, lon0, obstacles, str(path))


def _parse_home_line(path: Path, line: str) -> tuple[float, float]:
    match = _HOME_RE.match(line)
    if match is None:
        raise MapFormatError(path, 1, f"expected 'lat0 <deg>, lon0 <deg>', got {line.strip()!r}")
    try:
        lat0, lon0 = float(match["lat"]), float(match["lon"])
    except ValueError:
        raise MapFormatError(path, 1, f"home is not two numbers: {line.strip()!r}") from None
    if not (-90.0 <= lat0 <= 90.0 and -180.0 <= lon0 <= 180.0):
        raise MapFormatError(path, 1, f"home lat0 {lat0}, lon0 {lon0} is outside [-90, 90] x [-180, 180]")
    return lat0, lon0


def _parse_row(path: Path, line_number: int, row: str) -> None:
    fields = row.split(",")
    if len(fields) != 6:
        raise MapFormatError(path, line_number, f"expected 6 columns, got {len(fields)}")
    for value in fields:
        try:
            float(value)
        except ValueError:
            raise MapFormatError(path, line_number, f"not a number: {value.strip()!r}") from None


def read_home(path: str | Path) -> tuple[float, float]:
    """Return the map's home ``(lat0_deg, lon0_deg)`` from line 1 of a ``colliders.csv`` file."""
    with open(path, encoding="utf-8") as f:
        return _parse_home_line(Path(path), f.readline())
