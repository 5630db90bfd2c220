"""MAVLink 2 signing (``--signing-key``): the sim signs what it sends and drops what is not signed with the key."""

from __future__ import annotations

import hashlib
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sim.signing import secret_key

M = mavlink
KEY_TEXT = "correct horse battery staple"


def test_key_rule_hex_is_the_key_other_text_its_sha256():
    raw = bytes(range(32))
    assert secret_key(raw.hex()) == raw
    assert secret_key(raw.hex().upper()) == raw
    assert secret_key(KEY_TEXT) == hashlib.sha256(KEY_TEXT.encode()).digest()  # MAVProxy's passphrase rule
    assert secret_key(raw.hex()[:-1]) == hashlib.sha256(raw.hex()[:-1].encode()).digest()  # 63 chars: text
    with pytest.raises(ValueError):
        secret_key("")


def _signed(client, key: bytes, link_id: int = 7) -> None:
    """Make a SimClient sign with ``key`` and verify what it receives (pymavlink's own signing)."""
    s = client.mav.signing
    s.secret_key = key
    s.sign_outgoing = True
    s.link_id = link_id
    s.timestamp = int((time.time() - 1420070400) * 1e5)
    s.allow_unsigned_callback = lambda _mav, _msg_id: False


def test_signed_link_works_and_everything_the_sim_sends_is_signed(sim_start, sim_connect):
    sim = sim_start(signing_key=KEY_TEXT)
    c = sim_connect(sim, gcs=False)
    _signed(c, secret_key(KEY_TEXT))
    hb = c.wait_for("HEARTBEAT", timeout_s=3)
    assert hb.get_msgbuf()[2] & M.MAVLINK_IFLAG_SIGNED  # incompat flags: signed
    ack = c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    assert c.mav.signing.goodsig_count > 0 and c.mav.signing.badsig_count == 0
    assert sim.report()["signing"] == {"enabled": True, "rejected_frames": 0}


@pytest.mark.parametrize("client_key", [None, "another key"])
def test_unsigned_or_wrongly_signed_frames_are_dropped_and_counted(sim_start, sim_connect, client_key):
    sim = sim_start(signing_key=KEY_TEXT)
    c = sim_connect(sim, gcs=False)
    if client_key is not None:
        _signed(c, secret_key(client_key))
    for _ in range(5):
        c.send(M.MAVLink_command_long_message(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
    time.sleep(0.5)
    report = sim.report()
    assert report["signing"]["rejected_frames"] == 5
    assert report["commands"] == [] and not sim.truth()["armed"]
    assert any(e["kind"] == "signing" for e in report["events"])


def test_cli_takes_a_signing_key(sim_map, tmp_path):
    import subprocess
    import sys

    from tests.test_sim_cli import ROOT, _env

    out = subprocess.run([sys.executable, "-m", "sim", "--map", str(sim_map), "--port", "0", "--duration", "0.3",
                          "--signing-key", "00" * 32], capture_output=True, text=True, timeout=30, env=_env(), cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert "signed" in out.stdout and "0 frame(s) dropped for their signature" in out.stdout
