"""The layer rules of ARCHITECTURE.md, checked on the source: every import of every module, however deep.

Each rule names who may import what; a test fails with the offending file, line and import.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


@functools.cache  # every rule reads the same files: parse each once per run
def _imports(path: Path, root: Path = ROOT) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` of every import in the file, including those inside functions."""
    module = _module_name(path, root)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            out.append((node.lineno, base))
            out += [(node.lineno, f"{base}.{alias.name}") for alias in node.names]  # `from pkg import module`
    return out


def _within(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == x or name.startswith(x + ".") for x in prefixes)


@functools.cache
def _python_files(root: Path) -> tuple[Path, ...]:
    return tuple(p for p in root.rglob("*.py") if not {".venv", "build"} & set(p.relative_to(root).parts))


def _sources(*prefixes: str, root: Path = ROOT) -> list[Path]:
    return sorted(p for p in _python_files(root) if _within(_module_name(p, root), prefixes))


def _violations(importers: list[Path], forbidden: tuple[str, ...], root: Path = ROOT) -> list[str]:
    return [f"{path.relative_to(root)}:{line} imports {name}"
            for path in importers for line, name in _imports(path, root) if _within(name, forbidden)]


CLIENT = ("skyroute", "motion_planning", "planning_utils")


def test_the_sim_imports_nothing_of_the_client():
    assert _sources("sim"), "no sim sources found"
    assert _violations(_sources("sim"), CLIENT) == []


def test_the_client_never_imports_the_sim():
    # --sim starts `python -m sim` as a child process; an import would let a shared bug hide.
    assert _violations(_sources(*CLIENT), ("sim",)) == []


def test_the_package_never_imports_the_top_level_entry_points():
    assert _violations(_sources("skyroute"), ("motion_planning", "planning_utils")) == []


def test_planning_never_imports_flight_vehicle_view_or_cli():
    layers_above = ("skyroute.flight", "skyroute.vehicle", "skyroute.view", "skyroute.cli")
    assert _violations(_sources("skyroute.planning", "skyroute.maps"), layers_above) == []


def test_the_mission_talks_to_the_vehicle_only_through_its_protocol():
    assert _violations(_sources("skyroute.flight"), ("skyroute.vehicle", "skyroute.planning", "skyroute.cli",
                                                     "pymavlink")) == []


def test_the_missions_copies_of_the_accuracy_allowance_agree_with_their_owners():
    """The mission may not import the vehicle or planning packages, so it keeps its own copies of the GPS-accuracy
    allowance they use; the warning it gives must name the same rule the sensing applies."""
    from skyroute.flight import mission
    from skyroute.planning import livemap
    from skyroute.vehicle import sensors

    assert mission.ACCURACY_SIGMAS == sensors.POSITION_ERROR_PER_ACCURACY
    assert mission.MARGIN_SHARE == livemap.MAX_TOLERANCE_PER_MARGIN


def test_scan_matching_reads_the_scans_position_error_with_the_factor_the_sensing_gave_it():
    from skyroute.planning import scanmatch
    from skyroute.vehicle import sensors

    assert scanmatch.SIGMAS == sensors.POSITION_ERROR_PER_ACCURACY


def test_the_vehicle_link_knows_nothing_of_planning_or_missions():
    assert _violations(_sources("skyroute.vehicle"), ("skyroute.planning", "skyroute.flight", "skyroute.cli")) == []


@pytest.mark.parametrize(("dependency", "owners"), [
    ("pymavlink", ("skyroute.vehicle",)),
    ("matplotlib", ("skyroute.view.plotting",)),
    ("aiohttp", ("skyroute.view.live",)),
    ("numba", ("skyroute.planning.kernels", "skyroute.planning.any_angle", "skyroute.planning.grid3d")),
    ("networkx", ("skyroute.planning.graphs", "skyroute.planning.sampling")),
    ("skimage", ("skyroute.planning.graphs", "skyroute.planning.explore")),
    ("scipy", ("skyroute.planning.graphs", "skyroute.planning.sampling", "skyroute.planning.replan",
               "skyroute.planning.livemap")),
    ("pymap3d", ("skyroute.frames",)),
])
def test_each_third_party_dependency_has_its_owners_only(dependency, owners):
    client = _sources(*CLIENT)
    assert _violations(client, (dependency,)), f"{dependency} is imported nowhere: the rule would check nothing"
    others = [p for p in client if not _within(_module_name(p), owners)]
    assert _violations(others, (dependency,)) == []


def test_the_rule_checker_sees_nested_and_relative_imports(tmp_path):
    pkg = tmp_path / "skyroute" / "flight"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "probe.py").write_text("def f():\n    from ..vehicle import link\n    import pymavlink.mavutil\n")
    found = _violations(_sources("skyroute.flight", root=tmp_path), ("skyroute.vehicle", "pymavlink"), tmp_path)
    assert found == ["skyroute/flight/probe.py:2 imports skyroute.vehicle",
                     "skyroute/flight/probe.py:2 imports skyroute.vehicle.link",
                     "skyroute/flight/probe.py:3 imports pymavlink.mavutil"]
