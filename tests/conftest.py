"""What the test modules share: the `needs_yade` marker (skipped, with the reason, where YADE
cannot be imported), the package's logging restored after each test, and a material-point set
that simulates a killed run."""

from __future__ import annotations

import functools
import logging
import sys

import pytest

from granular_multiscale.dem.check_yade import yade_version


@functools.cache
def yade_missing() -> str | None:
    """Why YADE cannot be imported here, or None if it can."""
    try:
        yade_version()
    except RuntimeError as error:
        return str(error).splitlines()[0]
    return None


def pytest_collection_modifyitems(config, items):
    needing = [item for item in items if item.get_closest_marker("needs_yade")]
    if needing and (reason := yade_missing()):
        for item in needing:
            item.add_marker(pytest.mark.skip(reason=f"needs YADE: {reason}"))


@pytest.fixture(autouse=True)
def _package_logging_restored():
    """A rule script's main() called in a test sets up the package's logger with a handler on the
    stderr pytest captures for that test; once the capture is closed, a later test's log record
    would be a logging error. Each test leaves the logger's handlers and the excepthook as it found them."""
    logger = logging.getLogger("granular_multiscale")
    handlers, level, hook = list(logger.handlers), logger.level, sys.excepthook
    yield
    logger.handlers[:] = handlers
    logger.setLevel(level)
    sys.excepthook = hook


class KilledAfterCommits:
    """Mixin for a material-point set: simulates a killed run by raising KeyboardInterrupt once
    `commits` commits have happened (``class Killed(KilledAfterCommits, Elastoplastic)``)."""

    def __init__(self, *args, commits, **kwargs):
        super().__init__(*args, **kwargs)
        self.commits_left = commits

    def commit(self, strain=None):
        if self.commits_left == 0:
            raise KeyboardInterrupt("simulated kill")
        self.commits_left -= 1
        super().commit(strain)
