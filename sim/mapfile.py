"""Read and validate a ``colliders.csv`` map file.

The rules (shared with the project's client, which implements the same list itself; tests feed both programs
the same files):

* UTF-8 text; a UTF-8 byte-order mark at the start is accepted and ignored. Lines end with ``\n`` (or ``\r\n``).
* Numbers are decimal: an optional sign, digits with an optional fraction, an optional exponent, spaces around
  them allowed (no ``nan``, ``inf``, ``1_000`` or hex).
* Line 1: ``lat0 <deg>, lon0 <deg>``: finite numbers, latitude in [-90, 90], longitude in [-180, 180].
* Line 2: the header ``posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ`` (case-insensitive, spaces allowed around
  the names). A file without it is refused at line 2 rather than losing its first building.
* Every non-blank row after it: exactly 6 comma-separated finite numbers ``north, east, up, half_north,
  half_east, half_up`` (metres, box centre and half sizes), half sizes >= 0, every box within
  :data:`MAX_HORIZONTAL_M` of home horizontally (``|north| + half_north`` and ``|east| + half_east``) and
  :data:`MAX_VERTICAL_M` vertically (``|up| + half_up``). At least one row.
* Bounds the client adds for its 1 m planning grids, kept here so that both refuse the same files: footprints
  spanning more than :data:`MAX_GRID_CELLS` square metres (refused at the row that stretches the map that far),
  files over :data:`MAX_FILE_BYTES`, anything that is not a regular file.

A refusal is a :class:`MapFormatError` whose text is one line: ``<file>:<line>: <why>``, quoting at most a short,
printable excerpt of what was found.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

HEADER = ("posx", "posy", "posz", "halfsizex", "halfsizey", "halfsizez")
#: A box may reach at most this far from home horizontally (m).
MAX_HORIZONTAL_M = 25_000.0
#: ... and this far above or below the map datum (m).
MAX_VERTICAL_M = 10_000.0
#: Larger files are refused before reading (a 256 MiB map would hold millions of boxes; /dev/zero never ends).
MAX_FILE_BYTES = 256 * 1024 * 1024
#: The boxes' footprints (bounding box, whole metres) may cover at most this many square metres.
MAX_GRID_CELLS = 200_000_000
#: ``\d`` as the client's reader has it (Unicode digits included: float() reads them).
_DECIMAL = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"
_NUMBER_RE = re.compile(rf"\s*{_DECIMAL}\s*")
_HOME_RE = re.compile(rf"\s*lat0\s+(?P<lat>{_DECIMAL})\s*,\s*lon0\s+(?P<lon>{_DECIMAL})\s*")
_EXCERPT_CHARS = 40


class MapFormatError(ValueError):
    """A map file that cannot be used; ``str()`` is one line naming the file, the line and why."""

    def __init__(self, path: str | Path, line: int, problem: str) -> None:
        self.path = str(path)
        self.line = line
        self.problem = problem
        super().__init__(f"{self.path}:{line}: {problem}")


def excerpt(text: str) -> str:
    """A short printable quote of ``text`` for an error message.

    >>> excerpt("abc")
    "'abc'"
    >>> excerpt("x" * 100)[-4:]
    "...'"
    """
    clean = "".join(c if c.isprintable() else "?" for c in text.strip())
    if len(clean) > _EXCERPT_CHARS:
        clean = clean[:_EXCERPT_CHARS] + "..."
    return repr(clean)


def read_colliders(path: str | Path) -> tuple[float, float, np.ndarray]:
    """``(lat0_deg, lon0_deg, boxes)`` of a map file; ``boxes`` has shape (N, 6), N >= 1.

    Raises
    ------
    MapFormatError
        For any rule of the module docstring broken.
    OSError
        If the file cannot be read.
    """
    path = Path(path)
    if not path.is_file():
        raise MapFormatError(path, 1, "not a regular file")
    if path.stat().st_size > MAX_FILE_BYTES:
        raise MapFormatError(path, 1, f"larger than {MAX_FILE_BYTES // 2**20} MiB")
    with path.open("rb") as f:
        data = f.read(MAX_FILE_BYTES + 1)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise MapFormatError(path, line, f"not UTF-8 text (byte 0x{data[exc.start]:02x})") from None
    lines = [line[:-1] if line.endswith("\r") else line for line in text.split("\n")]
    if lines[-1] == "":
        lines.pop()  # the newline that ends the last line
    if not lines:
        raise MapFormatError(path, 1, "empty file; expected 'lat0 <deg>, lon0 <deg>'")
    lat0, lon0 = parse_home_line(path, lines[0])
    if len(lines) < 2 or tuple(c.strip().lower() for c in lines[1].split(",")) != HEADER:
        got = excerpt(lines[1]) if len(lines) >= 2 else "the end of the file"
        raise MapFormatError(path, 2, f"expected the header 'posX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ', "
                                      f"found {got}")
    rows = [(n, _parse_row(path, n, line)) for n, line in enumerate(lines[2:], start=3) if line.strip()]
    if not rows:
        raise MapFormatError(path, 3, "no obstacle rows after the header")
    _check_span(path, rows)
    return lat0, lon0, np.array([r for _, r in rows], dtype=float)


def _check_span(path: Path, rows: list[tuple[int, list[float]]]) -> None:
    """Refuse footprints spanning more than MAX_GRID_CELLS m^2, at the first row that makes them do so."""
    n_lo = e_lo = math.inf
    n_hi = e_hi = -math.inf
    for n, (north, east, _up, half_n, half_e, _half_u) in rows:
        n_lo, n_hi = min(n_lo, math.floor(north - half_n)), max(n_hi, math.ceil(north + half_n))
        e_lo, e_hi = min(e_lo, math.floor(east - half_e)), max(e_hi, math.ceil(east + half_e))
        if (n_hi - n_lo) * (e_hi - e_lo) > MAX_GRID_CELLS:
            raise MapFormatError(path, n, f"this box stretches the map to {n_hi - n_lo:.0f} x {e_hi - e_lo:.0f} m, "
                                          f"over {MAX_GRID_CELLS / 1e6:.0f} M square metres")


def parse_home_line(path: str | Path, line: str) -> tuple[float, float]:
    """``(lat0_deg, lon0_deg)`` of line 1."""
    match = _HOME_RE.fullmatch(line)
    if match is None:
        raise MapFormatError(path, 1, f"expected 'lat0 <deg>, lon0 <deg>', found {excerpt(line)}")
    lat0, lon0 = float(match["lat"]), float(match["lon"])
    if not (math.isfinite(lat0) and math.isfinite(lon0)):
        raise MapFormatError(path, 1, f"home lat0 {lat0}, lon0 {lon0} is not finite")
    if not (-90.0 <= lat0 <= 90.0 and -180.0 <= lon0 <= 180.0):
        raise MapFormatError(path, 1, f"home lat0 {lat0}, lon0 {lon0} is outside [-90, 90] x [-180, 180]")
    return lat0, lon0


def _parse_row(path: Path, n: int, line: str) -> list[float]:
    fields = line.split(",")
    if len(fields) != 6:
        raise MapFormatError(path, n, f"expected 6 comma-separated numbers, found {len(fields)} fields")
    values = []
    for field in fields:
        if _NUMBER_RE.fullmatch(field) is None:
            raise MapFormatError(path, n, f"not a number: {excerpt(field)}")
        value = float(field)
        if not math.isfinite(value):
            raise MapFormatError(path, n, f"{field.strip()} is not a finite number")
        values.append(value)
    north, east, up, half_n, half_e, half_u = values
    if min(half_n, half_e, half_u) < 0:
        raise MapFormatError(path, n, "a half size is negative")
    if abs(north) + half_n > MAX_HORIZONTAL_M or abs(east) + half_e > MAX_HORIZONTAL_M:
        raise MapFormatError(path, n, f"box reaches more than {MAX_HORIZONTAL_M:g} m from home horizontally")
    if abs(up) + half_u > MAX_VERTICAL_M:
        raise MapFormatError(path, n, f"box reaches more than {MAX_VERTICAL_M:g} m above or below the datum")
    return values
