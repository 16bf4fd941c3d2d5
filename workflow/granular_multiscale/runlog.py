"""Logging for rule scripts: one log file per rule (Snakemake's ``log:``) plus stderr,
and the rule's wall time written at the end.

A failure is reported once: the log file gets the full traceback, stderr one line
(``<what> failed after 1.2 s: ValueError: ... (full traceback: <log>)``). Without this the
traceback showed twice on stderr, once logged and once more from Python's own handler of the
re-raised exception, above Snakemake's own error block.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from pathlib import Path

#: attribute timed_rule sets on an exception whose traceback is in the log file
_REPORTED = "_granular_multiscale_reported"


class _OneLineFormatter(logging.Formatter):
    """stderr's format: a record's message without its traceback (the log file has it)."""

    def format(self, record: logging.LogRecord) -> str:
        saved = record.exc_info, record.exc_text, record.stack_info
        record.exc_info = record.exc_text = record.stack_info = None
        try:
            return super().format(record)
        finally:  # the file handler formats the same record, traceback included
            record.exc_info, record.exc_text, record.stack_info = saved


def _excepthook(kind, error, traceback) -> None:
    """An exception that timed_rule already reported (one line on stderr, the traceback in
    the log file) ends the script silently, with exit status 1; any other as Python would."""
    if getattr(error, _REPORTED, False):
        return
    sys.__excepthook__(kind, error, traceback)


def setup_logging(log_path: str | Path | None, name: str = "granular_multiscale") -> logging.Logger:
    datefmt = "%H:%M:%S"
    root = logging.getLogger(name)
    root.setLevel(logging.INFO)
    root.handlers.clear()
    stderr = logging.StreamHandler(sys.stderr)
    stderr.setFormatter(_OneLineFormatter("%(asctime)s %(levelname)s %(message)s", datefmt))
    root.addHandler(stderr)
    if log_path:
        Path(log_path).parent.mkdir(parents=True, exist_ok=True)
        file = logging.FileHandler(log_path, mode="w")
        file.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s", datefmt))
        root.addHandler(file)
        sys.excepthook = _excepthook  # only changes what happens to exceptions timed_rule reported
    return root


def _log_file(logger: logging.Logger) -> str | None:
    return next((h.baseFilename for h in logger.handlers if isinstance(h, logging.FileHandler)), None)


@contextlib.contextmanager
def timed_rule(logger: logging.Logger, what: str):
    """Log start, end and wall time of a rule's work; log the exception before re-raising
    (callers, e.g. tests calling a script's main(), still get the exception itself)."""
    t0 = time.perf_counter()
    logger.info("%s: start", what)
    try:
        yield
    except Exception as error:
        log_file = _log_file(logger)
        where = f" (full traceback: {log_file})" if log_file else ""
        logger.error("%s failed after %.1f s: %s: %s%s", what, time.perf_counter() - t0, type(error).__name__,
                     error, where, exc_info=True)
        if log_file:
            with contextlib.suppress(AttributeError):  # an exception type without __dict__ keeps its traceback
                setattr(error, _REPORTED, True)
        raise
    logger.info("%s: done, wall time %.1f s", what, time.perf_counter() - t0)
