"""The sim's ground targets: the file, the camera footprint, LANDING_TARGET contents, the report's truth."""

import math

import pytest

from sim.__main__ import build_parser, config_from_args
from sim.targets import GroundTargets, TargetFileError, read_targets


def test_targets_file_rows_and_header(tmp_path):
    f = tmp_path / "t.csv"
    f.write_text("north_m,east_m\n10,-5.5\n# a note\n\n-3e1, 2\n")
    assert read_targets(f) == ((10.0, -5.5), (-30.0, 2.0))


@pytest.mark.parametrize("text, line", [("1,2\n1,2,3\n", 2), ("x,y\n", 1), ("1,nan\n", 1), ("5\n", 1)])
def test_targets_file_refused_at_the_line(tmp_path, text, line):
    f = tmp_path / "t.csv"
    f.write_text(text)
    with pytest.raises(TargetFileError, match=f":{line}: "):
        read_targets(f)


def test_sim_cli_refuses_a_bad_targets_file_in_one_line(tmp_path, capsys):
    from sim.__main__ import main
    f = tmp_path / "t.csv"
    f.write_text("1;2\n")
    assert main(["--targets", str(f), "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "t.csv:1:" in err


def test_no_targets_by_default():
    assert config_from_args(build_parser().parse_args([])).targets == ()


def test_camera_sees_a_target_within_its_footprint_only():
    # 10 m up, a 30 degree half angle: 10 * tan(30 deg) = 5.77 m, + 2 m = 7.77 m
    t = GroundTargets([(0.0, 7.7), (0.0, 7.9)])
    t.step(1.0, (0.0, 0.0, 10.0))
    assert t.in_view.tolist() == [True, False]
    assert t.first_seen_s == [1.0, None]
    t.step(2.0, (0.0, 0.0, 31.0))  # above the camera's 30 m: nothing
    assert not t.in_view.any()


def test_landing_target_is_in_the_autopilots_local_frame():
    t = GroundTargets([(12.0, -4.0)])
    origin = (2.0, 1.0, 0.0)  # local origin 2 m north, 1 m east of the map's
    t.step(0.5, (10.0, -4.0, 5.0))
    (msg,) = t.messages(0.5, (10.0, -4.0, 5.0), origin)
    assert msg.get_type() == "LANDING_TARGET" and msg.position_valid == 1 and msg.target_num == 0
    assert (msg.x, msg.y, msg.z) == pytest.approx((10.0, -5.0, 0.0))
    assert msg.distance == pytest.approx(math.hypot(2.0, 5.0))
    assert t.messages(0.55, (10.0, -4.0, 5.0), origin) == []  # 5 Hz: the next one 0.2 s later


def test_visit_needs_3_m_horizontally_and_at_most_3_m_up():
    t = GroundTargets([(0.0, 0.0)])
    t.step(1.0, (1.0, 0.0, 4.0))   # close but too high
    t.step(2.0, (3.5, 0.0, 2.0))   # low but too far
    assert t.report()[0]["visited_s"] is None
    t.step(3.0, (2.0, 2.0, 2.5))   # 2.83 m at 2.5 m
    rep = t.report()[0]
    assert rep["visited_s"] == 3.0 and rep["first_seen_s"] == 1.0
    assert rep["closest_low_m"] == pytest.approx(2.828, abs=1e-3)
