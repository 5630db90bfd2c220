"""A pytest plugin (``-p tests.summary`` in pyproject's addopts): at the end of the run, one line saying how many
tests that need something a fresh clone lacks ran and how many were skipped, so CI's output shows it::

    needs-resource tests: sf_map 6 ran, 0 skipped; sitl 2 ran, 0 skipped; browser 1 ran, 0 skipped

The categories are the markers ``sf_map``, ``sitl`` and ``browser`` (``tests/shared.py`` adds the first two with
their skip conditions). A test counts as run if its body ran (passed or failed), as skipped if it was skipped at
set-up or in its body.
"""

from __future__ import annotations

import pytest

CATEGORIES = ("sf_map", "sitl", "browser")


class ResourceSummary:
    def __init__(self) -> None:
        self.marked: dict[str, set[str]] = {name: set() for name in CATEGORIES}
        self.ran: dict[str, set[str]] = {name: set() for name in CATEGORIES}
        self.skipped: dict[str, set[str]] = {name: set() for name in CATEGORIES}

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        # the report's keywords hold the test's marker names; under pytest-xdist the controller sees only reports
        for name in CATEGORIES:
            if name not in report.keywords:
                continue
            self.marked[name].add(report.nodeid)
            if report.skipped:
                self.skipped[name].add(report.nodeid)
            elif report.when == "call":
                self.ran[name].add(report.nodeid)

    def line(self) -> str:
        parts = [f"{name} {len(self.ran[name])} ran, {len(self.skipped[name] - self.ran[name])} skipped"
                 for name in CATEGORIES]
        return "needs-resource tests: " + "; ".join(parts)

    def pytest_terminal_summary(self, terminalreporter) -> None:
        terminalreporter.write_line(self.line())


def pytest_configure(config: pytest.Config) -> None:
    config.pluginmanager.register(ResourceSummary(), "skyroute-resource-summary")
