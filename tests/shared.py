"""Where the tests find what a fresh clone does not have: one rule, and the skip marks built on it.

The rule (documented in tests/README.md): the shared directory is ``$SKYROUTE_SHARED`` if that variable is set
and not empty, else ``../shared`` next to the project root (the directory holding ``pyproject.toml``). In it:

* ``maps/udacity_sf_colliders.csv``: the classic San Francisco map, used only if its SHA-256 is the pinned one;
  without a shared copy, the copy ``python -m skyroute.sfmap`` keeps in its cache is used (same checksum);
* ``sitl/arducopter`` (ArduCopter SITL) and ``sitl/px4/bin/px4`` (PX4 SITL with SIH).

Each ``needs_*`` below is a list of marks for ``pytestmark`` or a decorator list: a category marker that
``tests/summary.py`` counts at the end of the run (so CI's output shows how many of these tests ran and how many
were skipped) and a ``skipif`` that names what is missing and where it was looked for.

This module imports nothing of the client (the simulator's tests use it too) until the SF map has no shared copy
and the downloader's cache is asked where it is.
"""

from __future__ import annotations

import hashlib
import os
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: The SHA-256 of Udacity's FCND-Motion-Planning ``colliders.csv`` (3845 boxes around 37.792480, -122.397450).
SF_MAP_SHA256 = "7819d36b7929e6437fe1b14fdf3dc50923fb9eb2e22ba158ba753672e37c06c1"
SF_MAP_NAME = "udacity_sf_colliders.csv"


def shared_dir() -> Path:
    """``$SKYROUTE_SHARED`` if set and not empty, else ``../shared`` next to the project root."""
    return Path(os.environ["SKYROUTE_SHARED"]) if os.environ.get("SKYROUTE_SHARED") else ROOT.parent / "shared"


def _is_sf_map(path: Path) -> bool:
    return path.is_file() and hashlib.sha256(path.read_bytes()).hexdigest() == SF_MAP_SHA256


@cache
def _sf_map_in(shared: Path) -> Path | None:
    candidate = shared / "maps" / SF_MAP_NAME
    if _is_sf_map(candidate):
        return candidate
    from skyroute import sfmap  # only where the shared directory has no copy: the downloader's cache

    cached = sfmap.cache_dir() / SF_MAP_NAME
    return cached if _is_sf_map(cached) else None


def sf_map() -> Path | None:
    """A verified copy of the SF map: the shared directory's, else the downloader's cache; None without one."""
    return _sf_map_in(shared_dir())


def arducopter() -> Path | None:
    """The ArduCopter SITL binary in the shared directory (an executable file), or None."""
    path = shared_dir() / "sitl" / "arducopter"
    return path if path.is_file() and os.access(path, os.X_OK) else None


def px4_dir() -> Path | None:
    """PX4 SITL's directory (``bin/px4``, ``etc/``) in the shared directory, or None."""
    path = shared_dir() / "sitl" / "px4"
    binary = path / "bin" / "px4"
    return path if binary.is_file() and os.access(binary, os.X_OK) else None


class Marks(list):
    """Marks usable both ways: ``pytestmark = needs_x`` (a list of marks) and ``@needs_x`` (a decorator)."""

    def __call__(self, test):
        for mark in reversed(self):
            test = mark(test)
        return test


needs_sf_map = Marks([
    pytest.mark.sf_map,
    pytest.mark.skipif(sf_map() is None, reason=f"no SF map at {shared_dir() / 'maps' / SF_MAP_NAME} "
                       "(or in python -m skyroute.sfmap's cache)"),
])
needs_arducopter = Marks([
    pytest.mark.sitl,
    pytest.mark.skipif(arducopter() is None, reason=f"no ArduCopter SITL at {shared_dir() / 'sitl' / 'arducopter'}"),
])
needs_px4 = Marks([
    pytest.mark.sitl,
    pytest.mark.skipif(px4_dir() is None, reason=f"no PX4 SITL at {shared_dir() / 'sitl' / 'px4' / 'bin' / 'px4'}"),
])
