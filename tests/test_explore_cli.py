"""``--explore``'s refusals: one line on stderr, exit 2, before anything connects."""

import pytest

import motion_planning as mp


@pytest.mark.parametrize("args, words", [
    (["--explore", "50", "--goal_lat", "37.79", "--goal_lon", "-122.39"], "takes no goal"),
    (["--explore-time", "60"], "need --explore"),
    (["--save-map", "out.csv"], "need --explore"),
    (["--explore", "0"], "--explore must be"),
    (["--explore", "nan"], "--explore must be"),
    (["--explore", "50", "--explore-time", "-1"], "--explore-time must be"),
    (["--explore", "50", "--plan-only"], "not with --plan-only"),
    (["--explore", "50", "--map", "/nonexistent/known.csv"], "cannot read map file"),
    (["--explore", "50", "--save-map", "/nonexistent/dir/out.csv"], "is not a directory"),
    (["--explore", "50", "--alt", "inf"], "--alt must be"),
])
def test_bad_exploration_options_are_one_line_and_exit_2(args, words, capsys, tmp_path):
    code = mp.main([*args, "--log-dir", str(tmp_path / "logs"), "--connection", "tcp:127.0.0.1:9"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("error: ") and err.count("\n") == 1 and words in err, err
    assert not (tmp_path / "logs").exists() or not any((tmp_path / "logs").iterdir())


def test_a_bad_known_map_is_refused_at_its_line(tmp_path, capsys):
    bad = tmp_path / "known.csv"
    bad.write_text("lat0 37.79, lon0 -122.39\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n1,2,3\n")
    assert mp.main(["--explore", "50", "--map", str(bad), "--connection", "tcp:127.0.0.1:9"]) == 2
    err = capsys.readouterr().err
    assert "known.csv:3:" in err and err.count("\n") == 1


def test_an_area_wider_than_the_autopilots_geofence_is_refused_before_arming(sim_start, tmp_path, capsys):
    # the exploration may go anywhere within its radius: ArduCopter would return at the fence (measured on SITL)
    sim = sim_start(map_path=mp.DEFAULT_MAP, autopilot="ardupilot", speedup=20.0, scale_timeouts=True,
                    params={"FENCE_ENABLE": 1, "FENCE_RADIUS": 20})
    code = mp.main(["--connection", f"tcp:127.0.0.1:{sim.port}", "--explore", "30", "--alt", "5", "--timeout", "5",
                    "--log-dir", str(tmp_path / "logs")])
    report = sim.stop()
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("error: the route leaves the autopilot's geofence: it goes 30 m from home, the fence "
                          "allows 18 m (FENCE_RADIUS=20 m") and err.count("\n") == 1, err
    assert report["armed_time_s"] == 0
