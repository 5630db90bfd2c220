"""The exit codes README.md documents, written here rather than imported from the code, so that a test comparing
with them fails when the code's constants change (``tests/test_cli_plan.py`` checks README still says these)."""

EXIT_OK = 0
EXIT_FAILED = 1  # the mission took off but did not complete
EXIT_BAD_INPUT = 2  # bad input or a refusal before takeoff
EXIT_NO_PATH = 3
EXIT_INTERRUPTED = 130  # Ctrl-C or SIGTERM
