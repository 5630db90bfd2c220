"""The plan-only command line, run through main(argv) exactly as a user runs it (no drone)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from motion_planning import DEFAULT_MAP, main
from planning_utils import read_colliders
from skyroute.frames import Geodetic, LocalNED, ned_to_geodetic
from tests import clearance, geodesy, shared
from tests.exit_codes import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_NO_PATH, EXIT_OK

ROOT = Path(__file__).resolve().parents[1]
HOME = Geodetic(37.792480, -122.397450, 0.0)


def latlon(north_m: float, east_m: float) -> list[str]:
    p = ned_to_geodetic(LocalNED(north_m, east_m, 0.0), HOME)
    return ["--goal_lat", f"{p.lat_deg:.8f}", "--goal_lon", f"{p.lon_deg:.8f}"]


@pytest.fixture
def walled_map(tmp_path) -> Path:
    """An 80 m map: a 20 m tall wall north of home from E -30 to 30, posts marking the corners."""
    path = tmp_path / "walled.csv"
    path.write_text(
        "lat0 37.792480, lon0 -122.397450\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n"
        "20,0,10,1,30,10\n-40,-40,1,1,1,1\n40,40,1,1,1,1\n"
    )
    return path


def test_json_plan_goes_round_the_wall_and_every_leg_is_free(walled_map, capsys):
    code = main(["--plan-only", "--json", "--map", str(walled_map), "--alt", "5", "--safety", "2", *latlon(35.3, 0.3)])
    assert code == 0
    doc = json.loads(capsys.readouterr().out)
    waypoints = np.array(doc["waypoints"])
    assert waypoints.shape[1] == 4
    assert np.allclose(waypoints[0, :2], (0.5, 0.5)) and np.allclose(waypoints[-1, :2], (35.5, 0.5), atol=0.01)
    assert (waypoints[:, 2] == 5).all()
    assert np.abs(waypoints[:, 1]).max() >= 32  # round an end of the wall (30 m + 2 m margin)
    assert clearance.legs_too_close(waypoints, read_colliders(walled_map).obstacles, 2) == []
    for k in range(1, len(waypoints)):  # headings point along the arriving leg
        leg = waypoints[k, :2] - waypoints[k - 1, :2]
        assert math.isclose(waypoints[k, 3], math.atan2(leg[1], leg[0]), abs_tol=1e-3)
    stats = doc["stats"]
    assert stats["waypoints_after_pruning"] == len(waypoints) < stats["waypoints_before_pruning"]
    assert stats["length_m"] <= stats["cost_m"] + 1e-6
    assert doc["goal"]["north_m"] == pytest.approx(35.3, abs=0.01)


def test_text_output_lists_waypoints_and_one_stats_line(walled_map, capsys):
    assert main(["--plan-only", "--map", str(walled_map), "--safety", "2", *latlon(35.3, 0.3)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith("waypoints:")
    assert lines[-1].startswith("grid plan: cost ") and "nodes expanded" in lines[-1] and "->" in lines[-1]


def test_start_lat_lon_moves_the_start(walled_map, capsys):
    start = ned_to_geodetic(LocalNED(-30.3, 25.3, 0), HOME)
    code = main([
        "--plan-only", "--json", "--map", str(walled_map), "--safety", "2", *latlon(35.3, 0.3),
        "--start_lat", str(start.lat_deg), "--start_lon", str(start.lon_deg),
    ])
    assert code == 0
    first = json.loads(capsys.readouterr().out)["waypoints"][0]
    assert first[:2] == pytest.approx([-30.5, 25.5], abs=0.01)


def test_plot_writes_a_png(walled_map, tmp_path, capsys):
    out = tmp_path / "plan.png"
    assert main(["--plan-only", "--map", str(walled_map), "--safety", "2", *latlon(35.3, 0.3), "--plot", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_goal_inside_a_building_names_the_nearest_free_point(walled_map, capsys):
    code = main(["--plan-only", "--map", str(walled_map), "--safety", "2", *latlon(20.3, 10.3)])
    err = capsys.readouterr().err.strip()
    assert code == EXIT_BAD_INPUT
    assert len(err.splitlines()) == 1
    assert "inside a building" in err and "nearest free point: " in err and "N 23.5 m, E 10.5 m" in err


def test_goal_in_the_safety_margin_says_so(walled_map, capsys):
    assert main(["--plan-only", "--map", str(walled_map), "--safety", "2", *latlon(22.5, 0.3)]) == EXIT_BAD_INPUT
    assert "within the 2 m safety margin" in capsys.readouterr().err


def test_goal_off_the_map_is_refused(walled_map, capsys):
    assert main(["--plan-only", "--map", str(walled_map), *latlon(500, 0)]) == EXIT_BAD_INPUT
    assert "is off the map" in capsys.readouterr().err


def test_no_path_exits_3(tmp_path, capsys):
    boxed = tmp_path / "boxed.csv"  # a closed courtyard around the goal
    boxed.write_text(
        "lat0 37.792480, lon0 -122.397450\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n"
        "30,0,20,1,15,20\n0,0,20,1,15,20\n15,-14,20,15,1,20\n15,14,20,15,1,20\n-40,-40,1,1,1,1\n40,40,1,1,1,1\n"
    )
    code = main(["--plan-only", "--map", str(boxed), "--safety", "1", *latlon(15.3, 0.3), "--start_lat",
                 str(ned_to_geodetic(LocalNED(-20.3, 0.3, 0), HOME).lat_deg), "--start_lon", str(HOME.lon_deg + 1e-6)])
    assert code == EXIT_NO_PATH
    assert "no path from" in capsys.readouterr().err


@pytest.mark.parametrize(
    "content, fragment",
    [("lat0 37.7, lon0 -122.3\nposX,posY\n", ":2: expected header"), ("", ":1: empty file")],
)
def test_malformed_map_is_one_line_and_exit_2(tmp_path, capsys, content, fragment):
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    assert main(["--plan-only", "--map", str(bad), *latlon(1, 1)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and fragment in err


def test_missing_map_file_is_a_clear_error(tmp_path, capsys):
    assert main(["--plan-only", "--map", str(tmp_path / "nope.csv"), *latlon(1, 1)]) == EXIT_BAD_INPUT
    assert "cannot read map file" in capsys.readouterr().err


def test_missing_goal_is_a_clear_error(capsys):
    assert main(["--plan-only"]) == EXIT_BAD_INPUT
    assert "--goal_lat" in capsys.readouterr().err


def test_help_shows_defaults():
    result = subprocess.run(
        [sys.executable, str(ROOT / "motion_planning.py"), "--help"], capture_output=True, text=True, check=True
    )
    assert "(default: 5.0)" in result.stdout and "--plan-only" in result.stdout


def test_default_map_is_the_project_map_and_plans_from_home(capsys):
    assert DEFAULT_MAP == ROOT / "colliders.csv"
    assert main(["--plan-only", "--json", *latlon(-300.3, 350.3)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["start"]["north_m"] == 0 and doc["start"]["east_m"] == 0
    assert doc["waypoints"][-1][:2] == pytest.approx([-300.5, 350.5], abs=0.01)


def test_3d_goal_inside_a_margin_names_the_nearest_free_point(walled_map, capsys):
    # The wall is 20 m tall: a goal 1.5 m beside it at 21 m altitude is within the 2 m margin of its top.
    code = main(["--plan-only", "--map", str(walled_map), "--safety", "2", "--planner", "grid3d",
                 "--goal_alt", "21", *latlon(22.5, 0.3)])
    err = capsys.readouterr().err.strip()
    assert code == EXIT_BAD_INPUT and len(err.splitlines()) == 1
    assert "the goal" in err and "is blocked; nearest free point: " in err


@pytest.mark.parametrize(
    "extra, fragment",
    [
        (["--safety", "nan"], "--safety must be >= 0"),  # NaN would make every building "low": a straight line
        (["--alt", "nan"], "--alt must be > 0"),
        (["--alt", "inf"], "--alt must be > 0"),
        (["--alt", "-3"], "--alt must be > 0"),
        (["--goal_alt", "-5", "--planner", "grid3d"], "--goal_alt must be >= 0"),
        (["--timeout", "nan"], "--timeout must be > 0"),
        (["--arm-timeout", "-1"], "--arm-timeout must be > 0"),
        (["--port", "99999"], "--port must be >= 1 and <= 65535"),
        (["--seed", "-1"], "--seed must be >= 0"),
    ],
)
def test_non_finite_or_out_of_range_numbers_are_refused(walled_map, capsys, extra, fragment):
    assert main(["--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3), *extra]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and fragment in err


@pytest.mark.parametrize("lat, lon", [("1000", "5"), ("nan", "-122.39"), ("37.79", "-200")])
def test_impossible_coordinates_are_refused_as_typed(lat, lon, capsys):
    assert main(["--plan-only", "--goal_lat", lat, "--goal_lon", lon]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "must be >= -" in err and (lat in err or lon in err)


def test_goal_alt_with_a_2d_planner_is_refused(walled_map, capsys):
    assert main(["--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3), "--goal_alt", "30"]) == EXIT_BAD_INPUT
    assert "--goal_alt needs a 3D planner" in capsys.readouterr().err


def test_goal_beside_a_low_building_is_refused_because_the_descent_passes_it(tmp_path, capsys):
    # A 3 m high shed: the drone cruises over it at 10 m, but landing 1 m beside it descends through its margin.
    shed = tmp_path / "shed.csv"
    shed.write_text(
        "lat0 37.792480, lon0 -122.397450\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n"
        "20,0,1.5,2,2,1.5\n-40,-40,0.5,0.5,0.5,0.5\n40,40,0.5,0.5,0.5,0.5\n"
    )
    code = main(["--plan-only", "--map", str(shed), "--alt", "10", "--safety", "3", *latlon(23.3, 0.3)])
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT
    assert "safety margin of a building lower than the flight altitude" in err and "nearest free landing point" in err
    assert main(["--plan-only", "--map", str(shed), "--alt", "10", "--safety", "3", *latlon(26.3, 0.3)]) == 0


def test_plot_into_a_missing_directory_is_refused_before_planning(walled_map, tmp_path, capsys):
    target = tmp_path / "missing" / "plan.png"
    assert main(["--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3), "--plot", str(target)]) == EXIT_BAD_INPUT
    captured = capsys.readouterr()
    assert "is not a directory" in captured.err and captured.out == ""


def test_an_installed_script_without_a_map_beside_it_uses_the_working_directory(tmp_path, monkeypatch):
    from skyroute.cli import main as cli

    monkeypatch.setattr(cli, "__file__", str(tmp_path / "site-packages" / "skyroute" / "cli" / "main.py"))
    assert cli.default_map_path() == Path("colliders.csv")
    monkeypatch.setattr(cli, "__file__", str(ROOT / "skyroute" / "cli" / "main.py"))
    assert cli.default_map_path() == ROOT / "colliders.csv"


# ---------------------------------------------------------------------------------------------------------------
# The SF map, bad map files and options, progress lines


SF_MAP = shared.sf_map()


@shared.needs_sf_map
def test_the_goal_a_square_margin_shut_in_a_pocket_plans_on_the_sf_map(capsys):
    # Issue 10's case: with square-grown buildings this goal sat in a pocket (exit 3); an independent 0.5 m
    # raster connects it with more than 6.5 m of clearance.
    code = main(["--plan-only", "--json", "--start_lat", "37.79397782", "--start_lon", "-122.40056186",
                 "--goal_lat", "37.79335444", "--goal_lon", "-122.39467596", "--alt", "5", "--safety", "5",
                 "--map", str(SF_MAP)])
    assert code == 0, capsys.readouterr().err
    doc = json.loads(capsys.readouterr().out)
    obstacles = read_colliders(SF_MAP).obstacles
    tall = obstacles[obstacles[:, 2] + obstacles[:, 5] + 5 > 5]
    for a, b in zip(np.array(doc["waypoints"])[:-1, :2], np.array(doc["waypoints"])[1:, :2]):
        for point in a + np.linspace(0, 1, 50)[:, None] * (b - a):
            gap = np.maximum(np.abs(point - tall[:, :2]) - tall[:, 3:5], 0)
            assert np.hypot(gap[:, 0], gap[:, 1]).min() >= 5 - 1e-9


@pytest.mark.parametrize("row, fragment", [
    ("1e300,0,5,5,5,5", ":3: the box reaches 1e+300 m from home"),
    ("0,0,5,1e9,5,5", ":3: the box reaches 1e+09 m from home"),
    ("1e7,0,5,5,5,5", ":3: the box reaches 1e+07 m from home"),
    ("0,0,inf,5,5,5", ":3: not a number: 'inf'"),
])
def test_maps_that_used_to_crash_or_hang_are_one_line_and_exit_2(tmp_path, capsys, row, fragment):
    bad = tmp_path / "bad.csv"
    bad.write_text("lat0 37.792480, lon0 -122.397450\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n" + row + "\n")
    assert main(["--plan-only", "--map", str(bad), *latlon(1, 1)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and fragment in err and "Traceback" not in err


def test_a_missing_map_named_with_map_gets_no_hint_to_pass_map(tmp_path, capsys, monkeypatch):
    assert main(["--plan-only", "--map", str(tmp_path / "nope.csv"), *latlon(1, 1)]) == EXIT_BAD_INPUT
    assert "pass --map" not in capsys.readouterr().err
    from skyroute.cli import main as cli

    monkeypatch.setattr(cli, "DEFAULT_MAP", tmp_path / "colliders.csv")
    assert main(["--plan-only", *latlon(1, 1)]) == EXIT_BAD_INPUT
    assert "(pass --map FILE)" in capsys.readouterr().err


def test_samples_must_be_a_sensible_count(walled_map, capsys):
    assert main(["--plan-only", "--map", str(walled_map), "--planner", "prm", "--samples", "1",
                 *latlon(35.3, 0.3)]) == EXIT_BAD_INPUT
    assert "--samples must be >= 2" in capsys.readouterr().err


def test_prm_whose_roadmap_cannot_reach_a_courtyard_plans_through_its_fallback(tmp_path, capsys):
    # The courtyard's walls are 40 m tall, above the roadmap's 5-25 m band: the roadmap cannot get in, the complete
    # grid3d search it falls back to climbs over (so the goal the grid planner cannot reach is reachable).
    boxed = tmp_path / "boxed.csv"
    boxed.write_text(
        "lat0 37.792480, lon0 -122.397450\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n"
        "30,0,20,1,15,20\n0,0,20,1,15,20\n15,-14,20,15,1,20\n15,14,20,15,1,20\n-40,-40,1,1,1,1\n40,40,1,1,1,1\n"
    )
    start = ned_to_geodetic(LocalNED(-20.3, 0.3, 0), HOME)
    code = main(["--plan-only", "--json", "--map", str(boxed), "--safety", "1", "--planner", "prm",
                 *latlon(15.3, 0.3), "--start_lat", str(start.lat_deg), "--start_lon", str(start.lon_deg)])
    assert code == 0, capsys.readouterr().err
    doc = json.loads(capsys.readouterr().out)
    assert doc["stats"]["fallback"] == "grid3d" and max(w[2] for w in doc["waypoints"]) >= 41


@pytest.mark.compile_notice
def test_the_compile_notice_is_printed_unless_quiet(walled_map, capsys):
    import numba

    for quiet, expected in ((["-q"], ""), ([], "compiling the planner's kernels")):
        assert main(["--plan-only", "--map", str(walled_map), "--safety", "2", *latlon(35.3, 0.3), *quiet]) == 0
        capsys.readouterr()
        numba.njit(lambda x: x + 1)(1)  # something that has to be compiled
        assert expected in capsys.readouterr().err


@pytest.mark.slow  # ~20 s: every kernel compiled from cold in a child process
def test_the_kernels_compile_once_and_load_from_the_disk_cache_after(walled_map, tmp_path):
    # A fresh cache directory: the first run compiles (and says so once), the second loads everything from disk.
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    args = [sys.executable, str(ROOT / "motion_planning.py"), "--plan-only", "--map", str(walled_map), "--safety",
            "2", *latlon(35.3, 0.3)]
    first = subprocess.run(args, capture_output=True, text=True, env=env, timeout=600)
    second = subprocess.run(args, capture_output=True, text=True, env=env, timeout=600)
    assert first.returncode == second.returncode == 0, first.stderr + second.stderr
    assert first.stderr.count("compiling the planner's kernels") == 1
    assert "compiling" not in second.stderr
    assert second.stdout.splitlines()[:-1] == first.stdout.splitlines()[:-1]  # the same waypoints (not timings)


def test_a_plan_only_grid_run_loads_no_graph_or_plotting_library():
    code = ("import sys, runpy; sys.argv = ['motion_planning.py', '--plan-only', '-q', '--goal_lat', '37.789774', "
            "'--goal_lon', '-122.393473']; import motion_planning; motion_planning.main(sys.argv[1:]); "
            "print(sorted(m for m in ('scipy', 'skimage', 'networkx', 'matplotlib', 'pymavlink') if m in sys.modules))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert result.stdout.strip().splitlines()[-1] == "[]"


# ---------------------------------------------------------------------------------------------------------------
# What README.md promises: the exit codes and the --json document


def test_readme_documents_the_exit_codes_these_tests_check():
    text = " ".join((ROOT / "README.md").read_text().split())
    assert f"Exit codes: {EXIT_OK} success; {EXIT_FAILED} the mission took off but did not complete" in text
    assert f"; {EXIT_BAD_INPUT} bad input or a refusal before takeoff" in text
    assert f"; {EXIT_NO_PATH} no path" in text and f"; {EXIT_INTERRUPTED} interrupted by Ctrl-C or SIGTERM" in text


# Seattle, far from the default map's home: a document that reported the default home, or the SF one, fails.
SEATTLE = (47.620500, -122.349300)


def test_json_documents_home_map_altitude_and_safety_as_given(tmp_path, capsys):
    path = tmp_path / "seattle.csv"
    path.write_text(f"lat0 {SEATTLE[0]:.6f}, lon0 {SEATTLE[1]:.6f}\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n"
                    "20,0,10,1,30,10\n-40,-40,1,1,1,1\n40,40,1,1,1,1\n")
    first_line = path.read_text().splitlines()[0]
    home_lat, home_lon = (float(field.split()[1]) for field in first_line.split(","))
    start = geodesy.ned_to_latlon(-30.3, 25.3, home_lat, home_lon)
    goal = geodesy.ned_to_latlon(35.3, 0.3, home_lat, home_lon)
    code = main(["--plan-only", "--json", "--map", str(path), "--alt", "7.5", "--safety", "2.5",
                 "--start_lat", f"{start[0]:.9f}", "--start_lon", f"{start[1]:.9f}",
                 "--goal_lat", f"{goal[0]:.9f}", "--goal_lon", f"{goal[1]:.9f}"])
    assert code == EXIT_OK, capsys.readouterr().err
    doc = json.loads(capsys.readouterr().out)
    assert {"waypoints", "stats", "home", "start", "goal", "map", "altitude_m", "safety_m"} <= doc.keys()
    assert doc["home"] == {"lat_deg": home_lat, "lon_deg": home_lon}
    assert doc["map"] == str(path)
    assert doc["altitude_m"] == 7.5 and doc["safety_m"] == 2.5
    for name, (lat, lon), (north_m, east_m) in (("start", start, (-30.3, 25.3)), ("goal", goal, (35.3, 0.3))):
        assert (doc[name]["lat_deg"], doc[name]["lon_deg"]) == pytest.approx((lat, lon), abs=1e-8)
        assert (doc[name]["north_m"], doc[name]["east_m"]) == pytest.approx((north_m, east_m), abs=0.01)
    waypoints = np.array(doc["waypoints"])
    assert (waypoints[:, 2] == 7.5).all()  # flown at the altitude given
    assert waypoints[0, :2] == pytest.approx([-30.5, 25.5]) and waypoints[-1, :2] == pytest.approx([35.5, 0.5])


# A child running the real command line, with planning replaced by a step that signals the process and waits, so
# the signal arrives while "planning" (deterministically; no race against a real planner's speed).
_INTERRUPTED_CHILD = """
import os, signal, sys, time
import skyroute.cli.main as cli

def planning_interrupted(*args, **kwargs):
    os.kill(os.getpid(), signal.{signal})
    time.sleep(60)
    raise SystemExit("the signal did not interrupt planning")

cli.make_plan = planning_interrupted
# Python turns SIGINT into KeyboardInterrupt unless it started with SIGINT ignored (a background job, some test
# runners): make it do so here as in a terminal.
signal.signal(signal.SIGINT, signal.default_int_handler)
sys.exit(cli.main(sys.argv[1:]))
"""


@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM"])
def test_a_signal_while_planning_exits_130_with_one_line(walled_map, signal_name):
    result = subprocess.run(
        [sys.executable, "-c", _INTERRUPTED_CHILD.format(signal=signal_name), "--plan-only", "-q", "--map",
         str(walled_map), "--safety", "2", *latlon(35.3, 0.3)],
        capture_output=True, text=True, cwd=ROOT, timeout=120,
    )
    assert result.returncode == EXIT_INTERRUPTED, result.stderr
    assert result.stderr.strip() == "interrupted" and result.stdout == ""


def test_a_reader_that_leaves_early_gets_exit_1_and_no_traceback(walled_map):
    # `... --json | head -c 0`: the pipe's reading end is closed before the plan is written.
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "motion_planning.py"), "--plan-only", "--json", "-q", "--map", str(walled_map),
         "--safety", "2", *latlon(35.3, 0.3)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(timeout=120) == EXIT_FAILED and err == ""


# ---------------------------------------------------------------------------------------------------------------
# Options: README's defaults, the ranges refused, the parts of the map a goal may be in


def readme_option_defaults() -> dict[str, object]:
    """README's options table as ``{option: default}``, the default read from the table's words: a number, a
    quoted word, ``off`` (a flag not given), ``none``; options sharing a row share its comma-separated defaults."""
    defaults = {}
    for line in (ROOT / "README.md").read_text().splitlines():
        cells = [cell.strip() for cell in line.split("|")[1:-1]]
        if len(cells) != 3 or not cells[0].startswith("`-"):
            continue
        names = [name.strip("`").split()[0] for name in cells[0].split(", ")]
        names = [name for name in names if name.startswith("--")]
        words = [word.strip("`") for word in cells[1].split(", ")] if len(names) > 1 else [cells[1].strip("`")]
        for name, word in zip(names, words):
            if word.startswith("off"):
                defaults[name] = None if name == "--view" else False
            elif word == "none":
                defaults[name] = None
            elif word.replace(".", "", 1).isdigit():
                defaults[name] = float(word) if "." in word and word.count(".") == 1 else word
            elif " " not in word and ":" not in word and not word.startswith("("):
                defaults[name] = word
    return defaults


def test_the_parsers_defaults_are_readmes_and_run_has_the_same():
    import inspect

    from skyroute.cli import main as cli

    documented = readme_option_defaults()
    assert {"--alt", "--safety", "--seed", "--samples", "--port", "--host", "--speedup", "--timeout",
            "--arm-timeout", "--link-timeout", "--log-dir", "--planner", "--sim", "--json"} <= documented.keys()
    parser = cli.build_parser()
    parsed = vars(parser.parse_args([]))
    dests = {opt: action.dest for action in parser._actions for opt in action.option_strings}
    run_defaults = {name: p.default for name, p in inspect.signature(cli.run).parameters.items()}
    for option, default in documented.items():
        value = parsed[dests[option]]
        if isinstance(default, float) or (isinstance(default, str) and default.isdigit()):
            assert value == float(default), option
        else:
            assert value == default, option
        if dests[option] in run_defaults:  # run(), the API under the command line, has the same defaults
            assert run_defaults[dests[option]] == value, option


@pytest.mark.parametrize("name, accepted, refused", [
    ("goal_lat", [-90.0, 90.0], [-90.000001, 90.000001]),
    ("start_lat", [-90.0, 90.0], [-90.000001, 90.000001]),
    ("goal_lon", [-180.0, 180.0], [-180.000001, 180.000001]),
    ("start_lon", [-180.0, 180.0], [-180.000001, 180.000001]),
    ("alt", [1e-9, 10_000.0], [0.0, 10_000.000001]),
    ("safety", [0.0, 1_000.0], [-1e-9, 1_000.000001]),
    ("goal_alt", [0.0, 10_000.0], [-1e-9, 10_000.000001]),
    ("speedup", [1e-9, 1_000.0], [0.0, 1_000.000001]),
    ("timeout", [1e-9, 86_400.0], [0.0, 86_400.000001]),
    ("arm_timeout", [1e-9, 86_400.0], [0.0, 86_400.000001]),
    ("link_timeout", [1e-9, 86_400.0], [0.0, 86_400.000001]),
    ("port", [1, 65_535], [0, 65_536]),
    ("seed", [0, 2**32 - 1], [-1, 2**32]),
    ("samples", [2, 1_000_000], [1, 1_000_001]),
    ("target_system", [1, 255], [0, 256]),
    ("ground_amsl", [-500.0, -100.0, 9_000.0], [-500.5, 9_000.5]),
])
def test_numbers_are_checked_at_both_ends_of_their_range(name, accepted, refused):
    from skyroute.cli import main as cli

    flag = name.replace("_", "-") if name in ("arm_timeout", "link_timeout", "target_system", "ground_amsl") else name
    for value in accepted:
        cli.check_numbers(**{name: value})
    for value in refused:
        with pytest.raises(cli.UserError, match=f"--{flag} must"):
            cli.check_numbers(**{name: value})


def test_the_numeric_options_are_read_as_numbers():
    from skyroute.cli import main as cli

    args = vars(cli.build_parser().parse_args(["--target-system", "7", "--ground-amsl", "12.5", "--explore", "40",
                                               "--explore-time", "90"]))
    got = {k: args[k] for k in ("target_system", "ground_amsl", "explore", "explore_time")}
    assert got == {"target_system": 7, "ground_amsl": 12.5, "explore": 40.0, "explore_time": 90.0}
    assert type(got["target_system"]) is int and all(type(got[k]) is float for k in got if k != "target_system")


@pytest.mark.parametrize("extra, fragment", [
    (["--target-system", "0"], "--target-system must be >= 1"),
    (["--ground-amsl", "9001"], "--ground-amsl must be"),
])
def test_a_vehicle_option_out_of_range_is_refused_even_when_only_planning(walled_map, capsys, extra, fragment):
    assert main(["--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3), *extra]) == EXIT_BAD_INPUT
    assert fragment in capsys.readouterr().err


@pytest.mark.parametrize("given, fragment", [
    (["--explore-time", "90"], "need --explore RADIUS_M"),
    (["--save-map", "out.csv"], "need --explore RADIUS_M"),
    (["--explore", "40", "--plan-only"], "--explore flies: not with --plan-only"),
])
def test_any_exploration_option_goes_to_the_exploration_checks(given, fragment, capsys):
    assert main(given) == EXIT_BAD_INPUT
    assert fragment in capsys.readouterr().err


def test_a_plan_only_run_without_a_start_plans_from_the_maps_home(walled_map, capsys):
    assert main(["--plan-only", "--json", "--map", str(walled_map), *latlon(35.3, 0.3)]) == EXIT_OK
    start = json.loads(capsys.readouterr().out)["start"]
    assert (start["north_m"], start["east_m"]) == (0.0, 0.0)


def test_a_3d_goal_off_the_map_is_refused_naming_the_goal(walled_map, capsys):
    code = main(["--plan-only", "--map", str(walled_map), "--planner", "grid3d", "--goal_alt", "5",
                 *latlon(500.0, 0.3)])
    assert code == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.startswith("error: goal ") and "off the map" in err


def test_a_plan_only_export_says_where_it_was_written(walled_map, tmp_path, capsys):
    out_file = tmp_path / "plan.geojson"
    assert main(["--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3), "--export", str(out_file)]) == EXIT_OK
    assert f"exported to {out_file}" in capsys.readouterr().out and out_file.is_file()


def test_a_speedup_out_of_range_is_refused_before_any_work(walled_map, capsys):
    assert main(["--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3), "--speedup", "0"]) == EXIT_BAD_INPUT
    assert "--speedup must be > 0" in capsys.readouterr().err


def test_a_start_needs_both_coordinates(walled_map, capsys):
    start = ned_to_geodetic(LocalNED(-30.3, 25.3, 0), HOME)
    for given in (["--start_lat", str(start.lat_deg)], ["--start_lon", str(start.lon_deg)]):
        assert main(["--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3), *given]) == EXIT_BAD_INPUT
        assert "give both --start_lat and --start_lon, or neither" in capsys.readouterr().err


def test_a_start_for_a_real_vehicle_is_refused_before_connecting(walled_map, tmp_path, capsys):
    start = ned_to_geodetic(LocalNED(-30.3, 25.3, 0), HOME)
    code = main(["--map", str(walled_map), *latlon(35.3, 0.3), "--start_lat", str(start.lat_deg), "--start_lon",
                 str(start.lon_deg), "--log-dir", str(tmp_path / "logs"), "--port", "9"])
    assert code == EXIT_BAD_INPUT
    assert "--start_lat/--start_lon need --plan-only or --sim" in capsys.readouterr().err
    assert not (tmp_path / "logs").exists()  # refused before any log was opened


def test_a_goal_needs_both_coordinates(walled_map, capsys):
    goal_lat, _ = latlon(35.3, 0.3)[1], None
    assert main(["--plan-only", "--map", str(walled_map), "--goal_lat", goal_lat]) == EXIT_BAD_INPUT
    assert "give the goal as --goal_lat DEG --goal_lon DEG" in capsys.readouterr().err


# walled_map's grid: posts at N/E -41..-39 and 39..41 fix it to north and east -41..41 m, 82 x 82 cells.
@pytest.mark.parametrize("north_m, east_m, on_map", [
    (-40.5, 0.5, True), (40.5, 0.5, True), (0.5, -40.5, True), (0.5, 40.5, True),  # the edge rows and columns
    (-41.5, 0.5, False), (41.5, 0.5, False), (0.5, -41.5, False), (0.5, 41.5, False),  # one cell beyond
])
def test_goals_on_the_maps_edge_cells_plan_and_one_cell_beyond_is_off_the_map(walled_map, capsys, north_m, east_m,
                                                                             on_map):
    code = main(["--plan-only", "--json", "--map", str(walled_map), "--safety", "0.5", *latlon(north_m, east_m)])
    captured = capsys.readouterr()
    if on_map:
        assert code == EXIT_OK, captured.err
        assert json.loads(captured.out)["waypoints"][-1][:2] == pytest.approx([north_m, east_m], abs=0.01)
    else:
        assert code == EXIT_BAD_INPUT
        assert "is off the map, which spans N -41..41 m, E -41..41 m from home" in captured.err


def test_a_goal_beside_a_bollard_lower_than_a_metre_is_refused(tmp_path, capsys):
    # A 0.4 m bollard: the drone flies over it, but landing 0.3 m from it is inside the 0.5 m margin on the ground.
    bollard = tmp_path / "bollard.csv"
    bollard.write_text("lat0 37.792480, lon0 -122.397450\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n"
                       "10,0.5,0.2,0.5,0.5,0.2\n-40,-40,0.1,0.1,0.1,0.1\n40,40,0.1,0.1,0.1,0.1\n")
    code = main(["--plan-only", "--map", str(bollard), "--alt", "5", "--safety", "0.5", *latlon(10.7, 1.2)])
    assert code == EXIT_BAD_INPUT
    assert "safety margin of a building lower than the flight altitude" in capsys.readouterr().err
    assert main(["--plan-only", "--map", str(bollard), "--alt", "5", "--safety", "0.5", *latlon(10.5, 2.5)]) == 0


def test_an_unreadable_map_names_the_operating_systems_reason(tmp_path, capsys):
    missing = tmp_path / "nope.csv"
    assert main(["--plan-only", "--map", str(missing), *latlon(1, 1)]) == EXIT_BAD_INPUT
    assert capsys.readouterr().err.strip() == f"error: cannot read map file {missing}: No such file or directory"


def _signal_the_process_while_planning(*args, **kwargs):
    # What the SIGTERM handler main installed does when the signal comes, called directly (no real signal, so a
    # main that installed none fails here instead of killing the test run).
    handler = signal.getsignal(signal.SIGTERM)
    assert callable(handler), "main installed no SIGTERM handler"
    handler(signal.SIGTERM, None)
    raise AssertionError("the handler did not interrupt planning")


def test_sigterm_while_planning_in_process_exits_130_and_restores_the_handler(walled_map, capsys, monkeypatch):
    from skyroute.cli import main as cli

    before = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(cli, "make_plan", _signal_the_process_while_planning)
    try:
        code = main(["--plan-only", "-q", "--map", str(walled_map), "--safety", "2", *latlon(35.3, 0.3)])
    except BaseException as exc:  # noqa: BLE001 (a KeyboardInterrupt escaping main is the failure looked for)
        pytest.fail(f"main let {exc!r} escape")
    captured = capsys.readouterr()
    assert code == EXIT_INTERRUPTED and captured.err.strip() == "interrupted" and captured.out == ""
    assert signal.getsignal(signal.SIGTERM) is before


def test_the_text_output_lists_the_same_waypoints_as_the_json(walled_map, capsys):
    args = ["--plan-only", "--map", str(walled_map), "--safety", "2", *latlon(35.3, 0.3)]
    assert main(args) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert main([*args, "--json"]) == 0
    waypoints = json.loads(capsys.readouterr().out)["waypoints"]
    rows = [line.split() for line in lines[1:-1]]
    assert [int(row[0]) for row in rows] == list(range(len(waypoints)))
    assert np.allclose([[float(v) for v in row[1:]] for row in rows], waypoints, atol=0.006)


def test_a_plan_only_start_inside_the_margin_is_refused_not_snapped(walled_map, capsys):
    # Snapping a start out of the margin is for a vehicle already there (a flight); a planned start is a choice.
    start = ned_to_geodetic(LocalNED(18.3, 0.3, 0), HOME)  # 0.7 m south of the wall, inside the 2 m margin
    code = main(["--plan-only", "--map", str(walled_map), "--safety", "2", *latlon(35.3, 0.3),
                 "--start_lat", str(start.lat_deg), "--start_lon", str(start.lon_deg)])
    assert code == EXIT_BAD_INPUT
    assert "start" in (err := capsys.readouterr().err) and "within the 2 m safety margin" in err


def test_grid3d_lands_on_the_rooftop_goal_alt_names(walled_map, capsys):
    # The wall's top is 20 m: a goal on it at 23 m (above the 2 m margin) is the last waypoint.
    code = main(["--plan-only", "--json", "--map", str(walled_map), "--safety", "2", "--planner", "grid3d",
                 "--goal_alt", "23", *latlon(20.3, 10.3)])
    assert code == EXIT_OK, capsys.readouterr().err
    last = json.loads(capsys.readouterr().out)["waypoints"][-1]
    assert last[:3] == pytest.approx([20.5, 10.5, 23.0], abs=0.01)


def test_the_prm_seed_chooses_the_roadmap(walled_map, capsys):
    def waypoints(seed: str):
        assert main(["--plan-only", "--json", "--map", str(walled_map), "--safety", "2", "--planner", "prm",
                     "--samples", "300", "--seed", seed, *latlon(35.3, 0.3)]) == EXIT_OK
        return json.loads(capsys.readouterr().out)["waypoints"]

    assert waypoints("1") == waypoints("1") and waypoints("1") != waypoints("2")


def test_a_goal_on_a_map_without_a_free_cell_says_so(tmp_path, capsys):
    covered = tmp_path / "covered.csv"  # one 30 m tower over the whole map
    covered.write_text("lat0 37.792480, lon0 -122.397450\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n"
                       "0,0,15,20,20,15\n")
    assert main(["--plan-only", "--map", str(covered), *latlon(1, 1)]) == EXIT_BAD_INPUT
    assert capsys.readouterr().err.strip().endswith("; no free point on the map")


@pytest.mark.parametrize("option", ["--timeout", "--arm-timeout", "--link-timeout"])
def test_a_flight_timeout_given_on_the_command_line_is_read_as_a_number_and_range_checked(walled_map, capsys,
                                                                                          option):
    # checked before any planning or connecting, even with --plan-only: a string would not compare with a number
    assert main(["--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3), option, "0"]) == EXIT_BAD_INPUT
    assert f"{option} must be" in one_error_line(capsys.readouterr().err)
    assert main(["--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3), option, "7.5"]) == EXIT_OK


def test_an_unknown_planner_is_refused_by_the_parser_naming_the_choices(walled_map, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3), "--planner", "dijkstra"])
    assert exit_info.value.code == EXIT_BAD_INPUT  # argparse's usage error is 2, README's bad input
    err = capsys.readouterr().err
    assert "invalid choice: 'dijkstra'" in err and "'grid'" in err and "'voronoi'" in err


def test_v_is_the_short_form_of_verbose(walled_map, capsys):
    assert main(["-v", "--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3)]) == EXIT_OK


def one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]


@pytest.mark.parametrize("option, value", [("--start_lat", "91"), ("--start_lon", "-181")])
def test_a_start_out_of_range_is_refused_on_the_command_line(walled_map, capsys, option, value):
    start = ned_to_geodetic(LocalNED(-30.3, 25.3, 0), HOME)
    given = {"--start_lat": str(start.lat_deg), "--start_lon": str(start.lon_deg), option: value}
    argv = ["--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3)]
    for name, text in given.items():
        argv += [name, text]
    assert main(argv) == EXIT_BAD_INPUT
    assert f"{option} must be" in one_error_line(capsys.readouterr().err)


def test_main_puts_back_the_sigterm_handler_it_found(walled_map, capsys):
    import signal

    def mine(signum, frame):  # a handler of the embedding program's
        pass

    previous = signal.signal(signal.SIGTERM, mine)
    try:
        assert main(["--plan-only", "--map", str(walled_map), *latlon(35.3, 0.3)]) == EXIT_OK
        assert signal.getsignal(signal.SIGTERM) is mine
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_json_with_a_plot_and_an_export_prints_only_the_json_document(walled_map, tmp_path, capsys):
    plot, export = tmp_path / "plan.png", tmp_path / "plan.geojson"
    code = main(["--plan-only", "--json", "--map", str(walled_map), "--safety", "2", *latlon(35.3, 0.3),
                 "--plot", str(plot), "--export", str(export)])
    out = capsys.readouterr().out
    assert code == EXIT_OK
    assert json.loads(out)["waypoints"]  # one document: no 'plot written' or export lines around it
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and json.loads(export.read_text())["type"]
