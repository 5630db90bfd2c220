"""What `pip install .` ships: a wheel built from this checkout, its top level, its modules and console scripts."""

from __future__ import annotations

import configparser
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: The wheel's top level, as the user asked: the classic entry points, the simulator and one project package.
TOP_LEVEL = {"motion_planning.py", "planning_utils.py", "sim", "skyroute"}
#: One xdist worker builds the wheel once for every test here (split across two, each would build its own).
pytestmark = pytest.mark.xdist_group("wheel")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> zipfile.ZipFile:
    """A wheel built by pip from a copy of the files a source distribution holds (the checkout stays clean)."""
    src = tmp_path_factory.mktemp("src")
    for name in ("pyproject.toml", "README.md", "motion_planning.py", "planning_utils.py"):
        shutil.copy(ROOT / name, src / name)
    for package in ("skyroute", "sim"):
        shutil.copytree(ROOT / package, src / package, ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--wheel-dir", str(out), str(src)],
                   check=True, capture_output=True, text=True, timeout=300)
    (path,) = out.glob("*.whl")
    with zipfile.ZipFile(path) as z:
        yield z


def _top_level(wheel: zipfile.ZipFile) -> set[str]:
    return {name.split("/")[0] for name in wheel.namelist() if ".dist-info/" not in name}


def test_the_wheel_has_only_the_classic_modules_the_sim_and_one_package_at_its_top_level(wheel):
    assert _top_level(wheel) == TOP_LEVEL


def test_the_wheel_ships_every_module_of_the_checkout(wheel):
    shipped = set(wheel.namelist())
    for package in ("skyroute", "sim"):
        for path in (ROOT / package).rglob("*.py"):
            assert path.relative_to(ROOT).as_posix() in shipped


def test_the_checkout_has_no_other_top_level_python_modules():
    # A new top-level module would be left out of the wheel (or would be a generic name in site-packages).
    modules = {p.name for p in ROOT.glob("*.py")}
    packages = {p.parent.name for p in ROOT.glob("*/__init__.py")} - {"tests"}
    assert modules | packages == TOP_LEVEL


def test_console_scripts_point_at_existing_functions(wheel):
    (entry_points,) = [n for n in wheel.namelist() if n.endswith(".dist-info/entry_points.txt")]
    config = configparser.ConfigParser()
    config.read_string(wheel.read(entry_points).decode())
    scripts = dict(config["console_scripts"])
    assert set(scripts) == {"motion-planning", "mock-autopilot"}
    for target in scripts.values():
        module, function = target.split(":")
        source = wheel.read(module.replace(".", "/") + ".py").decode()
        assert f"def {function}(" in source


def test_the_wheel_ships_the_live_views_page_and_vendored_three_js_with_its_licence(wheel):
    shipped = set(wheel.namelist())
    static = ROOT / "skyroute" / "view" / "static"
    files = {p.relative_to(ROOT).as_posix() for p in static.rglob("*") if p.is_file()}
    assert {"skyroute/view/static/index.html", "skyroute/view/static/vendor/three/three.module.js",
            "skyroute/view/static/vendor/three/LICENSE"} <= files
    assert files <= shipped
