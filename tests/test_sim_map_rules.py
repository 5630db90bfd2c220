"""The sim's map reader and the client's refuse and accept the same files, at the same line.

The two never import each other (ARCHITECTURE.md rule 1): this test feeds both the same bytes.
"""

from __future__ import annotations

import pytest

from sim.mapfile import MapFormatError as SimMapError
from sim.mapfile import read_colliders as sim_read
from skyroute.maps import MapFormatError as ClientMapError
from skyroute.maps import read_colliders as client_read
from tests.test_sim_cli import BAD_MAPS

HEAD = b"lat0 37.792480, lon0 -122.397450\nposX,posY,posZ,halfSizeX,halfSizeY,halfSizeZ\n"
ROW = b"30,0,10,5,5,10\n"

CASES = {name: content for name, (content, _line, _why) in BAD_MAPS.items()}
CASES.update({
    "good": HEAD + ROW,
    "good-crlf-no-final-newline": HEAD.replace(b"\n", b"\r\n") + ROW.rstrip(),
    "good-bom-spaces-tabs": b"\xef\xbb\xbf lat0  37.79 ,lon0\t-122.39 \n posX , POSY,posZ,halfSizeX,halfSizeY,"
                            b"halfsizez \n\n\t+30 , -0 ,.5e1, 5., 5 ,10 \n\n",
    "underscore-number": HEAD + b"1_000,0,10,5,5,10\n",
    "hex-number": HEAD + b"0x10,0,10,5,5,10\n",
    "infinity-word": HEAD + b"infinity,0,10,5,5,10\n",
    "unicode-digit": HEAD + "\uff13\uff10,0,10,5,5,10\n".encode(),
    "form-feed-in-row": HEAD + b"30,0,10,5,5,10\x0c1,2,3,4,5,6\n",
    "nul-in-row": HEAD + b"30,0,10,5,5,10\x00\n",
    "home-no-space": b"lat037.79, lon0 -122.39\n" + HEAD.split(b"\n")[1] + b"\n" + ROW,
    "home-extra-text": b"lat0 37.79, lon0 -122.39 extra\n" + HEAD.split(b"\n")[1] + b"\n" + ROW,
    "header-only-blank-line-2": b"lat0 37.79, lon0 -122.39\n\n" + ROW,
    "span-too-wide": HEAD + b"-12000,-12000,5,1,1,5\n12000,12000,5,1,1,5\n",
    "span-just-fits": HEAD + b"-5000,-5000,5,1,1,5\n5000,5000,5,1,1,5\n",
    "edge-of-limits": HEAD + b"24990,-24990,9990,10,10,10\n",
    "just-past-limits": HEAD + b"24990.5,0,10,10,10,10\n",
})


def _verdict(read, error, path) -> tuple[str, int | None]:
    try:
        read(path)
    except error as exc:
        return "refused", exc.line
    return "accepted", None


@pytest.mark.parametrize("name", sorted(CASES))
def test_both_readers_agree(tmp_path, name):
    path = tmp_path / f"{name}.csv"
    path.write_bytes(CASES[name])
    sim = _verdict(sim_read, SimMapError, path)
    client = _verdict(client_read, ClientMapError, path)
    assert sim == client, f"sim {sim}, client {client}"
