"""The SF map downloader, against a local HTTP server and file URLs (the test machines have no internet): it
checks the checksum, caches, says clearly when it cannot fetch, and never leaves a wrong file behind."""

from __future__ import annotations

import hashlib
import http.server
import socket
import threading
from pathlib import Path

import pytest

from skyroute import sfmap
from tests import shared

SHARED_COPY = shared.shared_dir() / "maps" / sfmap.SF_FILENAME
needs_copy = shared.Marks([
    pytest.mark.sf_map, pytest.mark.skipif(not SHARED_COPY.is_file(), reason="no shared copy of the SF map to serve"),
])


@pytest.fixture
def serve(tmp_path):
    """``serve(bytes) -> url`` on a loopback HTTP server in a thread, stopped at teardown."""
    servers = []

    def start(content: bytes) -> str:
        (tmp_path / "colliders.csv").write_bytes(content)

        class Handler(http.server.SimpleHTTPRequestHandler):
            def __init__(self, *args, **kwargs):
                super().__init__(*args, directory=str(tmp_path), **kwargs)

            def log_message(self, *args):
                pass

        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        servers.append(server)
        return f"http://127.0.0.1:{server.server_port}/colliders.csv"

    yield start
    for server in servers:
        server.shutdown()
        server.server_close()


@pytest.fixture
def cache(tmp_path, monkeypatch):
    directory = tmp_path / "cache"
    monkeypatch.setenv("SKYROUTE_CACHE", str(directory))
    monkeypatch.setenv("SKYROUTE_SHARED", str(tmp_path / "no-shared"))  # no shared checkout to find
    return directory


@needs_copy
def test_the_pinned_checksum_is_that_of_the_shared_copy():
    assert hashlib.sha256(SHARED_COPY.read_bytes()).hexdigest() == sfmap.SF_SHA256


@needs_copy
def test_downloads_verifies_and_caches_the_map(serve, cache, capsys):
    url = serve(SHARED_COPY.read_bytes())
    assert sfmap.local_copy() is None
    assert sfmap.main(["--url", url]) == 0
    out = capsys.readouterr()
    cached = cache / sfmap.SF_FILENAME
    assert out.out.strip() == str(cached) and "FCND-Motion-Planning" in out.err
    assert cached.read_bytes() == SHARED_COPY.read_bytes()
    assert sfmap.local_copy() == cached
    # Cached: the next call needs no server at all.
    assert sfmap.main(["--url", "http://127.0.0.1:9/unreachable"]) == 0
    assert capsys.readouterr().out.strip() == str(cached)


@needs_copy
def test_a_file_url_works_too(cache):
    assert sfmap.download(SHARED_COPY.as_uri()).read_bytes() == SHARED_COPY.read_bytes()


@needs_copy
def test_a_different_file_is_refused_and_nothing_is_cached(serve, cache, capsys):
    url = serve(SHARED_COPY.read_bytes().replace(b"85.5", b"95.5", 1))
    assert sfmap.main(["--url", url]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "is not the expected map" in err and len(err.splitlines()) == 1
    assert not cache.exists() or not any(cache.iterdir())


def test_offline_is_a_clear_one_line_error(cache, capsys):
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert sfmap.main(["--url", f"http://127.0.0.1:{port}/colliders.csv", "--refresh"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: cannot download http://127.0.0.1:") and len(err.splitlines()) == 1


def test_an_http_error_is_reported_with_its_status(serve, cache, capsys):
    url = serve(b"anything").replace("colliders.csv", "missing.csv")
    assert sfmap.main(["--url", url]) == 1
    assert "HTTP 404" in capsys.readouterr().err


@needs_copy
def test_the_shared_checkout_is_found_first(tmp_path, monkeypatch):
    monkeypatch.setenv("SKYROUTE_SHARED", str(SHARED_COPY.parents[1]))
    monkeypatch.setenv("SKYROUTE_CACHE", str(tmp_path / "cache"))
    assert sfmap.sf_map("http://127.0.0.1:9/unreachable") == SHARED_COPY
    assert not Path(tmp_path / "cache").exists()
