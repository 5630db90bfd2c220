"""Flight logs are never overwritten: two runs started in the same second each keep their own files."""

from __future__ import annotations

import time

from skyroute.cli.flying import open_logs


def test_two_runs_in_the_same_second_keep_separate_logs(tmp_path, monkeypatch):
    monkeypatch.setattr(time, "strftime", lambda fmt, *a: "20261201-120000")
    paths, handlers = [], []
    for _ in range(3):
        nav, tlog, handler = open_logs(tmp_path / "logs")
        handlers.append(handler)
        tlog.write_bytes(b"")  # the link creates it when it connects
        paths += [nav, tlog]
    for handler in handlers:
        handler.close()
    assert len(set(paths)) == 6
    assert sorted(p.name for p in (tmp_path / "logs").iterdir()) == sorted(p.name for p in paths)
