"""Logging for rule scripts: one log file per rule (Snakemake's ``log:``) plus stderr,
and the rule's wall time written at the end."""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from pathlib import Path


def setup_logging(log_path: str | Path | None, name: str = "granular_multiscale") -> logging.Logger:
    fmt = logging.Formatter("%(asctime)s %(levelname)s %(message)s", "%H:%M:%S")
    root = logging.getLogger(name)
    root.setLevel(logging.INFO)
    root.handlers.clear()
    handlers: list[logging.Handler] = [logging.StreamHandler(sys.stderr)]
    if log_path:
        Path(log_path).parent.mkdir(parents=True, exist_ok=True)
        handlers.append(logging.FileHandler(log_path, mode="w"))
    for h in handlers:
        h.setFormatter(fmt)
        root.addHandler(h)
    return root


@contextlib.contextmanager
def timed_rule(logger: logging.Logger, what: str):
    """Log start, end and wall time of a rule's work; log the exception before re-raising."""
    t0 = time.perf_counter()
    logger.info("%s: start", what)
    try:
        yield
    except Exception:
        logger.exception("%s: failed after %.1f s", what, time.perf_counter() - t0)
        raise
    logger.info("%s: done, wall time %.1f s", what, time.perf_counter() - t0)
