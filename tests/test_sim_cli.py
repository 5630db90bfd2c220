"""``python -m sim``: help text, clean shutdown on signals, report file."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

import sim.config
import sim.world
from sim.__main__ import build_parser
from sim.__main__ import main as sim_main

ROOT = Path(__file__).resolve().parent.parent


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def test_help_documents_every_option():
    out = subprocess.run([sys.executable, "-m", "sim", "--help"], capture_output=True, text=True,
                         timeout=30, env=_env(), cwd=ROOT)
    assert out.returncode == 0
    text = " ".join(out.stdout.split())
    for action in build_parser()._actions:
        for flag in action.option_strings:
            assert flag in text, flag
        assert action.help, action.option_strings
    for needed in ("--map", "--host", "--port", "--speedup", "--start", "--report", "--tlog", "--autopilot",
                   "--strict", "--origin", "--radius", "--wind", "--gps-noise", "--gps-correlation", "--seed",
                   "--packet-loss", "--latency", "--outage", "--deny-arm", "--deny-command"):
        assert needed in text
    assert "(default: 5760)" in text and "(default: 127.0.0.1)" in text


def test_default_map_is_the_projects_then_cwd(tmp_path, monkeypatch):
    project, cwd = tmp_path / "project", tmp_path / "cwd"
    project.mkdir()
    cwd.mkdir()
    monkeypatch.setattr(sim.config, "PROJECT_ROOT", project)
    monkeypatch.chdir(cwd)
    assert sim.config.default_map_path() == cwd / "colliders.csv"
    (project / "colliders.csv").write_text("lat0 1, lon0 2\n")
    assert sim.config.default_map_path() == project / "colliders.csv"


def test_missing_map_is_a_clear_error(tmp_path):
    out = subprocess.run([sys.executable, "-m", "sim", "--map", str(tmp_path / "nope.csv")],
                         capture_output=True, text=True, timeout=30, env=_env(), cwd=tmp_path)
    assert out.returncode == 2 and "not found" in out.stderr


GOOD_HEAD = "lat0 37.792480, lon0 -122.397450\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n"


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--port", "99999"], "--port: must be in [0, 65535]"),
        (["--port", "-1"], "--port: must be >= 0"),
        (["--start", "1000,5"], "start must be LAT,LON within"),
        (["--start", "37.8"], "--start: expected LAT,LON or LAT,LON,ALT"),
        (["--start", "nan,5"], "--start: expected a finite number"),
        (["--start", "37.9,-122.39745"], "is off the map"),  # ~12 km north of a map that spans 35 m
        (["--start", "37.7927498,-122.397450"], "is inside box 1 of the map"),  # 30 m north: in the building
        (["--speedup", "nan"], "--speedup: expected a finite number"),
        (["--speedup", "0"], "--speedup: must be in (0, 1000]"),
        (["--speedup", "1001"], "--speedup: must be in (0, 1000]"),
        (["--packet-loss", "150"], "--packet-loss: must be in [0, 100]"),
        (["--packet-loss", "-5"], "--packet-loss: must be in [0, 100]"),
        (["--latency", "-100"], "--latency: must be in [0, 60000]"),
        (["--deny-arm", "-2"], "--deny-arm: must be >= 0"),
        (["--deny-arm", "1.5"], "--deny-arm: expected a whole number"),
        (["--gps-noise", "-1"], "--gps-noise: must be in [0, 1000]"),
        (["--gps-correlation", "0.5"], "--gps-correlation: must be in [1, 3600]"),
        (["--gust", "-1"], "--gust: must be in [0, 100]"),
        (["--radius", "-0.1"], "--radius: must be in [0, 100]"),
        (["--wind", "inf,0"], "--wind: expected a finite number"),
        (["--wind", "3"], "--wind: expected N,E"),
        (["--outage", "5,-3"], "outage duration must be in [0, 1e6] s"),
        (["--gps-loss", "10,0"], "GPS loss duration must be > 0 s"),
        (["--gps-loss", "-1"], "GPS loss start must be in [0, 1e6] s"),
        (["--gps-loss", "1,2,3"], "--gps-loss: expected T[,D]"),
        (["--physics-dt", "0"], "--physics-dt: must be in (0, 0.1]"),
        (["--duration", "-1"], "--duration: must be in (0, 1e+07]"),
        (["--boot", "slow"], "--boot: unknown boot preset 'slow'"),
        (["--boot", "armable=-1"], "boot armable must be in [0, 3600] s"),
        (["--param", "NOPE=1"], "unknown parameter 'NOPE' for the px4 personality"),
        (["--param", "COM_OF_LOSS_T"], "--param: expected NAME=VALUE"),
        (["--deny-command", "FLY_AWAY"], "unknown MAVLink command"),
        (["--autopilot", "betaflight"], "--autopilot: invalid choice"),
        (["--report", "/nonexistent/dir/r.json"], "is not a directory"),
        (["--map", "{bad_map}"], "bad.csv:1: expected 'lat0 <deg>, lon0 <deg>', found 'not a map'"),
        (["--map", "."], ":1: not a regular file"),
        (["--map", "/dev/zero"], "/dev/zero:1: not a regular file"),
        (["--map", "{garbled_map}"], "garbled.csv:3: not a number: 'x'"),
    ],
)
def test_bad_options_are_one_line_errors(sim_map, tmp_path, capsys, args, fragment):
    bad_map = tmp_path / "bad.csv"
    bad_map.write_text("not a map\n")
    garbled_map = tmp_path / "garbled.csv"
    garbled_map.write_text(GOOD_HEAD + "1,2,x,4,5,6\n")
    args = [a.format(bad_map=bad_map, garbled_map=garbled_map) for a in args]
    if "--map" not in args:
        args = ["--map", str(sim_map), *args]
    assert _main_exit_code(["--port", "0", "--duration", "0.5", *args]) == 2
    err = capsys.readouterr().err
    assert fragment in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def _main_exit_code(argv: list[str]) -> int:
    """``python -m sim``'s main in-process (argparse exits with SystemExit)."""
    try:
        return sim_main(argv)
    except SystemExit as exc:
        return exc.code


def test_a_bad_option_from_the_real_command_line_is_one_line():
    out = subprocess.run([sys.executable, "-m", "sim", "--packet-loss", "150"], capture_output=True, text=True,
                         timeout=30, env=_env(), cwd=ROOT)
    assert out.returncode == 2
    assert out.stderr == "error: argument --packet-loss: must be in [0, 100], got 150\n"


#: Map files the sim must refuse (shared rules, sim/mapfile.py), with the line and a fragment of why.
BAD_MAPS = {
    "empty": (b"", 1, "empty file"),
    "home-nan": (b"lat0 nan, lon0 5\n", 1, "expected 'lat0"),
    "home-inf": (b"lat0 1e999, lon0 5\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n1,1,1,1,1,1\n", 1,
                 "not finite"),
    "home-lat-range": (b"lat0 91, lon0 5\n", 1, "outside [-90, 90]"),
    "home-lon-range": (b"lat0 37, lon0 -181\n", 1, "outside [-90, 90] x [-180, 180]"),
    "no-header": (b"lat0 37.79, lon0 -122.39\n1,2,3,4,5,6\n", 2, "expected the header"),
    "no-rows": (GOOD_HEAD.encode(), 3, "no obstacle rows"),
    "blank-rows-only": (GOOD_HEAD.encode() + b"\n  \n", 3, "no obstacle rows"),
    "five-columns": (GOOD_HEAD.encode() + b"1,2,3,4,5\n", 3, "expected 6 comma-separated numbers"),
    "seven-columns": (GOOD_HEAD.encode() + b"1,2,3,4,5,6,7\n", 3, "found 7 fields"),
    "inf-value": (GOOD_HEAD.encode() + b"1,2,3,4,5,6\n1,2,inf,4,5,6\n", 4, "not a number: 'inf'"),
    "nan-value": (GOOD_HEAD.encode() + b"nan,2,3,4,5,6\n", 3, "not a number: 'nan'"),
    "overflowing-value": (GOOD_HEAD.encode() + b"1e999,2,3,4,5,6\n", 3, "1e999 is not a finite number"),
    "span-too-wide": (GOOD_HEAD.encode() + b"-12000,-12000,5,1,1,5\n12000,12000,5,1,1,5\n", 4, "stretches the map"),
    "huge-value": (GOOD_HEAD.encode() + b"1e300,2,3,4,5,6\n", 3, "more than 25000 m from home"),
    "huge-box": (GOOD_HEAD.encode() + b"0,0,5,1e9,1e9,5\n", 3, "more than 25000 m from home"),
    "far-box": (GOOD_HEAD.encode() + b"1e7,0,5,1,1,5\n", 3, "more than 25000 m from home"),
    "tall-box": (GOOD_HEAD.encode() + b"0,0,5000,1,1,5001\n", 3, "more than 10000 m above or below"),
    "negative-size": (GOOD_HEAD.encode() + b"1,2,3,-4,5,6\n", 3, "a half size is negative"),
    "latin1": (GOOD_HEAD.encode() + b"1,2,3,4,5,6 \xe9\n", 3, "not UTF-8 text"),
    "binary": (b"\x00\xff\xfe\x00" * 10, 1, "not UTF-8 text"),
    "junk-first-line": (b"x" * 4096 + b"\n", 1, "..."),
}


@pytest.mark.parametrize("name", sorted(BAD_MAPS))
def test_bad_map_is_refused_naming_file_line_and_reason(tmp_path, capsys, name):
    content, line, fragment = BAD_MAPS[name]
    path = tmp_path / f"{name}.csv"
    path.write_bytes(content)
    assert _main_exit_code(["--map", str(path), "--port", "0", "--duration", "0.5"]) == 2
    err = capsys.readouterr().err
    assert f"{path}:{line}: " in err and fragment in err, err
    assert len(err.strip().splitlines()) == 1 and len(err) < 300


@pytest.mark.parametrize("content", [
    "\ufefflat0 37.792480, lon0 -122.397450\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n30,0,10,5,5,10\n",
    "lat0 37.792480, lon0 -122.397450\r\n POSX , posy,posZ,HALFSIZEX,halfSizeY,halfSizeZ\r\n\r\n30,0,10,5,5,10\r\n",
])
def test_bom_case_spaces_and_blank_lines_are_accepted(tmp_path, content):
    path = tmp_path / "ok.csv"
    path.write_bytes(content.encode("utf-8"))
    city = sim.world.CityMap.from_csv(path)
    assert (city.lat0_deg, city.lon0_deg, len(city)) == (37.792480, -122.397450, 1)
    assert list(city.boxes[0]) == [30, 0, 10, 5, 5, 10]  # the first building is not lost


def test_a_huge_box_inside_the_limits_does_not_hang_the_start(tmp_path):
    """A 14 km box (as big as the map rules allow) would fill 300 000 spatial-index cells: the index is bounded."""
    path = tmp_path / "big.csv"
    path.write_text(GOOD_HEAD + "0,0,-10,7000,7000,5\n30,0,10,5,5,10\n")
    t0 = time.monotonic()
    city = sim.world.CityMap.from_csv(path)
    assert time.monotonic() - t0 < 5.0
    assert city.ground_up_m(100.0, 100.0, 50.0) == 0.0  # under the flat slab's top at -5 m: the map ground
    assert city.nearest_box(np.array([30.0, 8.0, 5.0])) == (3.0, 1)  # the building, not the slab 10 m below


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_cli_serves_and_shuts_down_cleanly_on_signal(sim_map, sim_connect, tmp_path, signum):
    report, tlog = tmp_path / "report.json", tmp_path / "flight.tlog"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim", "--map", str(sim_map), "--port", "0", "--speedup", "10",
         "--report", str(report), "--tlog", str(tlog)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(), cwd=tmp_path,
    )
    try:
        line = proc.stdout.readline()
        match = re.search(r"tcp:127\.0\.0\.1:(\d+)", line)
        assert match, line
        c = sim_connect(int(match.group(1)))
        c.wait_for("HEARTBEAT", timeout_s=5)
        assert c.arm().result == mavlink.MAV_RESULT_ACCEPTED
        time.sleep(0.2)
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    assert proc.returncode == 0, err
    lines = (line + out).splitlines()
    assert any("ARMED" in x for x in lines) and any("shutting down" in x for x in lines)
    assert any("report written" in x for x in lines)
    data = json.loads(report.read_text())
    assert [c["name"] for c in data["commands"]][-1] == "MAV_CMD_COMPONENT_ARM_DISARM"
    assert data["final"]["armed"] is True and data["collisions"] == []
    assert tlog.stat().st_size > 0
