"""Atomic file writes: every output of the workflow is written to a temporary file beside it
and renamed onto its name only when complete, so a kill or an error never leaves a
half-written file that a rerun (or a reader) would take for a finished one. The finished file
gets its checksum (``integrity.record``) and the mode of any file this user creates (the
umask's, not the temporary file's 0600)."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from . import integrity


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path in ``path``'s folder to write to: renamed onto ``path`` (with its
    checksum recorded) when the block ends without an error, removed when it raises (parent
    folders are created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, integrity.file_mode())
        integrity.record(path, content=tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
