"""The installed package must contain every module the checkout has, or `pip install .` ships a broken client."""

from __future__ import annotations

from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python 3.11+

ROOT = Path(__file__).resolve().parents[1]


def test_every_top_level_module_is_listed_in_pyproject():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    listed = set(config["tool"]["setuptools"]["py-modules"])
    present = {p.stem for p in ROOT.glob("*.py")}
    assert listed == present


def test_every_package_is_listed_in_pyproject():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    present = {p.parent.name for p in ROOT.glob("*/__init__.py")} - {"tests"}
    assert set(config["tool"]["setuptools"]["packages"]) == present


def test_console_scripts_point_at_existing_functions():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    for target in config["project"]["scripts"].values():
        module, function = target.split(":")
        source = (ROOT / (module.replace(".", "/") + ".py")).read_text()
        assert f"def {function}(" in source
