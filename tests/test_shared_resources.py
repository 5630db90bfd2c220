"""The tests' one location rule for what a fresh clone lacks (tests/shared.py) and the closing line that shows
how many tests needing it ran (tests/summary.py)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from skyroute import sfmap
from tests import shared

PROJECT_ROOT = Path(__file__).resolve().parents[1]  # the directory holding pyproject.toml


def test_the_project_root_is_where_pyproject_is():
    assert (shared.ROOT / "pyproject.toml").is_file() and shared.ROOT == PROJECT_ROOT


def test_the_shared_directory_is_the_variable_when_set_else_shared_beside_the_project_root(monkeypatch, tmp_path):
    monkeypatch.setenv("SKYROUTE_SHARED", str(tmp_path / "elsewhere"))
    assert shared.shared_dir() == tmp_path / "elsewhere"
    monkeypatch.setenv("SKYROUTE_SHARED", "")  # set but empty counts as unset
    assert shared.shared_dir() == PROJECT_ROOT.parent / "shared"
    monkeypatch.delenv("SKYROUTE_SHARED")
    assert shared.shared_dir() == PROJECT_ROOT.parent / "shared"


def test_the_sf_map_downloader_follows_the_same_rule(monkeypatch, tmp_path):
    for value in (str(tmp_path / "elsewhere"), "", None):
        if value is None:
            monkeypatch.delenv("SKYROUTE_SHARED", raising=False)
        else:
            monkeypatch.setenv("SKYROUTE_SHARED", value)
        assert sfmap.shared_dir() == shared.shared_dir()


def test_the_sitl_helpers_find_the_autopilots_by_the_same_rule(monkeypatch, tmp_path):
    from tests import sitl_support

    fake = tmp_path / "fake-shared"
    (fake / "sitl" / "px4" / "bin").mkdir(parents=True)
    copter, px4 = fake / "sitl" / "arducopter", fake / "sitl" / "px4" / "bin" / "px4"
    for binary in (copter, px4):
        binary.write_text("#!/bin/sh\n")
    monkeypatch.setenv("SKYROUTE_SHARED", str(fake))
    assert sitl_support.arducopter_binary() is None and sitl_support.px4_binary() is None  # not executable
    for binary in (copter, px4):
        binary.chmod(0o755)
    assert sitl_support.shared_dir() == shared.shared_dir() == fake
    assert sitl_support.arducopter_binary() == copter == shared.arducopter()
    assert sitl_support.px4_binary() == px4 and shared.px4_dir() == fake / "sitl" / "px4"
    monkeypatch.setenv("SKYROUTE_SHARED", str(tmp_path / "nothing-here"))
    assert sitl_support.arducopter_binary() is None and sitl_support.px4_binary() is None


def test_a_shared_file_that_is_not_the_sf_map_is_not_used(monkeypatch, tmp_path):
    monkeypatch.setenv("SKYROUTE_CACHE", str(tmp_path / "empty-cache"))
    fake = tmp_path / "fake-shared"
    (fake / "maps").mkdir(parents=True)
    (fake / "maps" / shared.SF_MAP_NAME).write_text("lat0 37.792480, lon0 -122.397450\nposX,posY,posZ,halfSizeX,"
                                                     "halfSizeY,halfSizeZ\n0,0,5,5,5,5\n")
    monkeypatch.setenv("SKYROUTE_SHARED", str(fake))
    assert shared.sf_map() is None


@shared.needs_sf_map
def test_a_copy_in_the_downloaders_cache_is_found_without_a_shared_directory(monkeypatch, tmp_path):
    cache = tmp_path / "cache"
    cache.mkdir()
    (cache / shared.SF_MAP_NAME).write_bytes(shared.sf_map().read_bytes())
    monkeypatch.setenv("SKYROUTE_CACHE", str(cache))
    monkeypatch.setenv("SKYROUTE_SHARED", str(tmp_path / "no-shared"))
    assert shared.sf_map() == cache / shared.SF_MAP_NAME


def test_the_closing_summary_counts_marked_tests_that_ran_and_were_skipped(tmp_path):
    (tmp_path / "pytest.ini").write_text("[pytest]\nmarkers =\n    sf_map: x\n    sitl: x\n    browser: x\n")
    (tmp_path / "test_marked.py").write_text(textwrap.dedent("""
        import pytest

        pytestmark = pytest.mark.sitl

        @pytest.mark.sf_map
        def test_ran():
            pass

        @pytest.mark.sf_map
        @pytest.mark.skipif(True, reason="absent")
        def test_skipped_at_setup():
            pass

        @pytest.mark.sf_map
        def test_failed():
            assert False

        @pytest.mark.browser
        def test_skipped_in_its_body():
            pytest.skip("no browser")

        def test_sitl_in_its_name_only_counts_by_the_module_mark():
            pass
    """))
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "tests.summary", "-p", "no:cacheprovider", str(tmp_path)],
        capture_output=True, text=True, cwd=tmp_path, env={"PYTHONPATH": str(PROJECT_ROOT), "PATH": ""},
        timeout=120,
    )
    lines = result.stdout.splitlines()
    summary = [line for line in lines if line.startswith("needs-resource tests:")]
    assert summary == ["needs-resource tests: sf_map 2 ran, 1 skipped; sitl 3 ran, 2 skipped; browser 0 ran, "
                       "1 skipped"], result.stdout + result.stderr
    # Before pytest's own closing line, which CI reads.
    assert lines.index(summary[0]) < len(lines) - 1 and "1 failed, 2 passed, 2 skipped" in lines[-1]
