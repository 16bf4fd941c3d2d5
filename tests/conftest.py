"""What the test modules share: the `needs_yade` marker (skipped, with the reason, where YADE
cannot be imported) and a material-point set that simulates a killed run."""

from __future__ import annotations

import functools

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
