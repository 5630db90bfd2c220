"""What the command line tells its caller: exit codes and the one-line error users can act on."""

from __future__ import annotations

EXIT_OK = 0
EXIT_FAILED = 1  # the mission started but did not complete
EXIT_BAD_INPUT = 2  # bad map, bad start/goal, no autopilot, refused command before takeoff
EXIT_NO_PATH = 3
EXIT_INTERRUPTED = 130


class UserError(Exception):
    """A problem the user can fix; the CLI prints it on one line and exits with ``exit_code``."""

    def __init__(self, message: str, exit_code: int = EXIT_BAD_INPUT):
        super().__init__(message)
        self.exit_code = exit_code
