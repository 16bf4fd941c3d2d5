"""What the test modules share: the `needs_yade` marker (skipped, with the reason, where YADE
cannot be imported), the longest modules first on the workers of `pytest -n`, the package's logging
restored after each test, a material-point set that simulates a killed run, and the tiny
elastoplastic chain built once for the tests that read it."""

from __future__ import annotations

import functools
import logging
import os
import sys

import pytest
from filelock import FileLock

from granular_multiscale.dem.check_yade import yade_version

#: the modules that take longest, longest first (2 to 6 minutes each here): `pytest -n` (pyproject.toml:
#: --dist loadscope --no-loadscope-reorder) deals whole modules to its workers in the order they are
#: collected, so these go first and the short ones fill the gaps
LONGEST_MODULES = ("test_report", "test_problems", "test_faults", "test_adaptive", "test_dem_run",
                   "test_rve_procedure")


@functools.cache
def yade_missing() -> str | None:
    """Why YADE cannot be imported here, or None if it can."""
    try:
        yade_version()
    except RuntimeError as error:
        return str(error).splitlines()[0]
    return None


def pytest_collection_modifyitems(config, items):
    if "PYTEST_XDIST_WORKER" in os.environ:  # `pytest -n`: the longest modules first
        rank = {name: k for k, name in enumerate(LONGEST_MODULES)}
        items.sort(key=lambda item: rank.get(item.module.__name__, len(rank)))
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


@pytest.fixture(scope="session")
def tiny_elastoplastic_chain(tmp_path_factory):
    """config/tiny.yaml's chain on the analytic elastoplastic reference with NNσ and ND as ensembles
    of two (the ensemble's path through the rules), its report built in the same call
    (--report-after-run: the headline page is the one this run has just written), and the
    surrogate stage's metric tables. Built once for the session, whichever worker asks first:
    test_report.py reads its report, test_surrogate_pipeline.py its surrogate stage."""
    from dem_fixtures import session_folder
    from tiny_chain import TinyChain, snakemake

    folder = session_folder(tmp_path_factory, "elastoplastic_chain")
    with FileLock(f"{folder}.lock"):
        chain = TinyChain.at(folder, "elastoplastic", surrogate={"ensemble_size": 2})
        if not chain.report.exists():  # written once every job has succeeded
            metrics = chain.plan.layout.table("fem_ml_curve_errors.csv")
            snakemake("-j2", *chain.config_args, "--report", str(chain.report), "--report-after-run", "--",
                      *chain.targets, metrics)
    return chain


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
