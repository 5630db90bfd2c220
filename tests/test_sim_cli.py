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

import pytest
from pymavlink.dialects.v20 import common as mavlink

import sim.config
from sim.__main__ import build_parser

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
                   "--strict", "--origin", "--radius", "--wind", "--gps-noise", "--seed", "--packet-loss",
                   "--latency", "--outage", "--deny-arm", "--deny-command"):
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


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--port", "99999"], "port must be in [0, 65535]"),
        (["--start", "1000,5"], "start must be LAT,LON within"),
        (["--speedup", "nan"], "speedup must be in (0, 1000]"),
        (["--report", "/nonexistent/dir/r.json"], "is not a directory"),
        (["--map", "{bad_map}"], "first line 'not a map' is not 'lat0"),
        (["--map", "."], "cannot read map"),
        (["--map", "{garbled_map}"], "cannot read map"),
    ],
)
def test_bad_options_are_one_line_errors(tmp_path, args, fragment):
    bad_map = tmp_path / "bad.csv"
    bad_map.write_text("not a map\n")
    garbled_map = tmp_path / "garbled.csv"
    garbled_map.write_text("lat0 37.79, lon0 -122.39\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n1,2,x,4,5,6\n")
    args = [a.format(bad_map=bad_map, garbled_map=garbled_map) for a in args]
    out = subprocess.run([sys.executable, "-m", "sim", "--duration", "0.5", *args], capture_output=True,
                         text=True, timeout=30, env=_env(), cwd=ROOT)
    assert out.returncode == 2, out.stderr
    assert fragment in out.stderr and len(out.stderr.strip().splitlines()) == 1


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
        assert c.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mavlink.MAV_RESULT_ACCEPTED
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
