"""The classic exercise's San Francisco map, fetched from its public source: ``python -m skyroute.sfmap``.

The map is ``colliders.csv`` of Udacity's FCND-Motion-Planning repository
(https://github.com/udacity/FCND-Motion-Planning), downtown San Francisco as 3845 boxes around home
37.792480, -122.397450. It belongs to Udacity and is not shipped here; the project's own ``colliders.csv`` is a
generated city with the same extent around the same home. The command downloads the file once, checks its SHA-256
against the copy the project was measured on, keeps it in a cache directory and prints its path, so that

    python motion_planning.py --plan-only --map "$(python -m skyroute.sfmap)" --goal_lat .. --goal_lon ..

plans on the real map. Where it looks, in order: a shared checkout (``$SKYROUTE_SHARED/maps/``, else ``../shared``
beside the project root) and the cache (``$SKYROUTE_CACHE``, else ``$XDG_CACHE_HOME/skyroute``, else
``~/.cache/skyroute``); only then the network.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import tempfile
import urllib.error
import urllib.request
from collections.abc import Sequence
from pathlib import Path

SF_URL = "https://raw.githubusercontent.com/udacity/FCND-Motion-Planning/master/colliders.csv"
SF_SHA256 = "7819d36b7929e6437fe1b14fdf3dc50923fb9eb2e22ba158ba753672e37c06c1"
SF_FILENAME = "udacity_sf_colliders.csv"
ATTRIBUTION = ("San Francisco map: colliders.csv from Udacity's FCND-Motion-Planning exercise, "
               "https://github.com/udacity/FCND-Motion-Planning")
_MAX_BYTES = 4 * 2**20  # the real file is 130 kB; anything much bigger is not it

ROOT = Path(__file__).resolve().parents[1]


class DownloadError(Exception):
    """The map could not be fetched or was not the expected file; ``str()`` is one line saying why."""


def shared_dir() -> Path:
    """The shared checkout: ``$SKYROUTE_SHARED`` if set, else ``../shared`` beside the project root."""
    return Path(os.environ["SKYROUTE_SHARED"]) if os.environ.get("SKYROUTE_SHARED") else ROOT.parent / "shared"


def cache_dir() -> Path:
    """Where a downloaded map is kept: ``$SKYROUTE_CACHE``, else ``$XDG_CACHE_HOME/skyroute``, else
    ``~/.cache/skyroute``."""
    if os.environ.get("SKYROUTE_CACHE"):
        return Path(os.environ["SKYROUTE_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "skyroute"


def sha256_of(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def local_copy() -> Path | None:
    """A verified copy already on this machine (shared checkout, then cache), or None."""
    for candidate in (shared_dir() / "maps" / SF_FILENAME, cache_dir() / SF_FILENAME):
        if candidate.is_file() and sha256_of(candidate) == SF_SHA256:
            return candidate
    return None


def download(url: str = SF_URL, dest: Path | None = None, timeout_s: float = 30.0) -> Path:
    """Fetch the map from ``url``, check its SHA-256, write it to ``dest`` (default: the cache) and return it.

    The file appears only once verified (written beside it and renamed), so an interrupted or wrong download
    leaves nothing behind.

    Raises
    ------
    DownloadError
        If the URL cannot be fetched (offline, refused, HTTP error, timeout) or the content is not the map.
    """
    dest = Path(dest) if dest is not None else cache_dir() / SF_FILENAME
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as response:  # noqa: S310 (http, https or file)
            data = response.read(_MAX_BYTES + 1)
    except urllib.error.HTTPError as exc:
        raise DownloadError(f"cannot download {url}: HTTP {exc.code} {exc.reason}") from None
    except urllib.error.URLError as exc:
        raise DownloadError(f"cannot download {url}: {exc.reason} (no network?)") from None
    except (OSError, ValueError) as exc:
        raise DownloadError(f"cannot download {url}: {exc}") from None
    digest = hashlib.sha256(data).hexdigest()
    if len(data) > _MAX_BYTES or digest != SF_SHA256:
        raise DownloadError(f"{url} is not the expected map: SHA-256 {digest[:16]}..., expected "
                            f"{SF_SHA256[:16]}... ({len(data)} bytes); nothing was saved")
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=dest.parent, prefix=dest.name, suffix=".part", delete=False) as tmp:
            tmp.write(data)
        os.replace(tmp.name, dest)
    except OSError as exc:
        raise DownloadError(f"cannot save the map to {dest}: {exc.strerror or exc}") from None
    return dest


def sf_map(url: str = SF_URL, *, refresh: bool = False) -> Path:
    """A verified local copy of the map, downloading it first if there is none (or if ``refresh``)."""
    found = None if refresh else local_copy()
    return found if found is not None else download(url)


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: print the path of a verified copy of the SF map, downloading it if needed."""
    parser = argparse.ArgumentParser(
        prog="python -m skyroute.sfmap",
        description="Download the classic exercise's San Francisco colliders.csv (checksum-verified, cached) and "
        "print its path.",
    )
    parser.add_argument("--url", default=SF_URL, help="where to fetch it from (default: %(default)s)")
    parser.add_argument("--refresh", action="store_true", help="download again even if a copy is cached")
    args = parser.parse_args(argv)
    try:
        path = sf_map(args.url, refresh=args.refresh)
    except DownloadError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(ATTRIBUTION, file=sys.stderr)
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
