"""Checksums of every file the pipeline writes and reads back.

A file written through :func:`granular_multiscale.atomic.atomic_path` gets a sidecar
``<name>.sha256`` in ``sha256sum``'s format (``sha256sum -c`` checks it by hand). A reader calls
:func:`verify` before it trusts the file; a file whose bytes no longer match is a
:class:`CorruptFileError` naming the path. Why a sidecar and not the formats' own checks: a
network archive (``torch.load``) does not check its CRC, and a flipped byte inside an HDF5
dataset or a pickled scene reads back as plausible numbers.

A file without a sidecar (written before checksums existed, or by hand) is read unverified.

    record(path)                 write path's sidecar
    verify(path)                 CorruptFileError if path does not match its sidecar
    scan(root)                   the corrupt files under an output folder
    built_from(files, records)   what was built from them (Snakemake's records of each job's inputs)
    set_aside(root, corrupt)     move them to root/corrupt/<time>/..., so the workflow rebuilds them
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

SUFFIX = ".sha256"
#: folders of an output directory that :func:`scan` leaves alone: checkpoints are verified, and
#: set aside, by the run that resumes them; corrupt/ holds what was set aside already
SCAN_SKIPS = ("checkpoints", "corrupt")


class CorruptFileError(OSError):
    """A file does not match the checksum recorded when it was written; the message names it."""


def file_mode() -> int:
    """The mode of a file this user creates (0666 less the umask): temporary files start 0600."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def sidecar(path: str | Path) -> Path:
    path = Path(path)
    return path.with_name(path.name + SUFFIX)


def digest(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def record(path: str | Path, content: str | Path | None = None) -> None:
    """Write ``path``'s sidecar atomically, hashing ``content`` (default ``path``): the writer of
    a temporary file records it under the final name before renaming it there."""
    path = Path(path)
    line = f"{digest(content or path)}  {path.name}\n"
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".sha256.tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(line)
        os.chmod(tmp, file_mode())
        os.replace(tmp, sidecar(path))
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def recorded(path: str | Path) -> str | None:
    """The checksum recorded for ``path``, or None without a (readable) sidecar."""
    try:
        text = sidecar(path).read_text()
    except (FileNotFoundError, UnicodeDecodeError):
        return None
    word = text.split(maxsplit=1)[0] if text.strip() else ""
    return word if len(word) == 64 else ""


def problem(path: str | Path) -> str | None:
    """Why ``path`` cannot be trusted, or None (it matches its sidecar, or has none)."""
    expected = recorded(path)
    if expected is None:
        return None
    if expected == "":
        return f"its checksum file {sidecar(path)} is damaged"
    path = Path(path)
    if not path.is_file():
        return "it is missing"
    found = digest(path)
    if found != expected:
        return f"its sha256 {found[:12]}… differs from {expected[:12]}… recorded when it was written"
    return None


def verify(path: str | Path, what: str = "file") -> None:
    """Raise :class:`CorruptFileError` naming ``path`` if it does not match its recorded checksum."""
    reason = problem(path)
    if reason is not None:
        raise CorruptFileError(f"{what} {path} is corrupt: {reason}. Rerun the workflow: it sets the file aside "
                               f"and rebuilds it (or delete the file and its {SUFFIX} to rebuild it by hand)")


def forget(path: str | Path) -> None:
    """Remove ``path`` and its sidecar."""
    Path(path).unlink(missing_ok=True)
    sidecar(path).unlink(missing_ok=True)


def scan(root: str | Path) -> list[tuple[Path, str]]:
    """(file, reason) of every file under ``root`` that no longer matches its sidecar; sidecars
    whose file is gone (a job that failed after Snakemake removed its output) are removed."""
    root = Path(root)
    corrupt = []
    if not root.is_dir():
        return corrupt
    for side in sorted(root.rglob("*" + SUFFIX)):
        rel = side.relative_to(root)
        if rel.parts[0] in SCAN_SKIPS:
            continue
        path = side.with_name(side.name[: -len(SUFFIX)])
        if not path.exists():
            side.unlink(missing_ok=True)
            continue
        reason = problem(path)
        if reason is not None:
            corrupt.append((path, reason))
    return corrupt


def snakemake_inputs(metadata_dir: str | Path = ".snakemake/metadata") -> dict[str, list[str]]:
    """{output: its job's input files} (absolute paths) from the records Snakemake keeps in the
    working directory, one JSON file per output named by the output's base64 path; {} without
    them (another clone built the outputs)."""
    inputs = {}
    root = Path(metadata_dir)
    if not root.is_dir():
        return inputs
    for f in root.rglob("*"):
        if not f.is_file():
            continue
        try:  # long names are split into folders of 255 characters
            name = "".join(f.relative_to(root).parts)
            output = base64.urlsafe_b64decode(name + "=" * (-len(name) % 4)).decode()
            record = json.loads(f.read_text())
        except (ValueError, OSError, UnicodeDecodeError):
            continue
        if isinstance(record, dict):
            inputs[os.path.abspath(output)] = [os.path.abspath(i) for i in record.get("input") or []]
    return inputs


def built_from(files: list[Path], inputs: dict[str, list[str]]) -> list[Path]:
    """The existing outputs built, directly or through others, from ``files``, by ``inputs``
    ({output: its job's inputs}). Snakemake does not rebuild a missing file whose dependants are
    up to date, so a corrupt file's dependants are set aside with it."""
    consumers: dict[str, list[str]] = {}
    for output, used in inputs.items():
        for i in used:
            consumers.setdefault(i, []).append(output)
    todo = [os.path.abspath(f) for f in files]
    seen = set(todo)
    found = []
    while todo:
        for output in consumers.get(todo.pop(), []):
            if output not in seen:
                seen.add(output)
                todo.append(output)
                if os.path.exists(output):
                    found.append(Path(output))
    return sorted(found)


def set_aside(root: str | Path, corrupt: list[tuple[Path, str]]) -> Path | None:
    """Move each corrupt file (and its sidecar) to ``root/corrupt/<UTC time>.<random>/<its path>``; the
    folder, or None if there was nothing to move."""
    if not corrupt:
        return None
    root = Path(root)
    (root / "corrupt").mkdir(exist_ok=True)
    target = Path(tempfile.mkdtemp(prefix=time.strftime("%Y%m%dT%H%M%SZ.", time.gmtime()), dir=root / "corrupt"))
    for path, _ in corrupt:
        dest = target / Path(os.path.abspath(path)).relative_to(os.path.abspath(root))
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(str(path), dest)
        if sidecar(path).exists():
            shutil.move(str(sidecar(path)), sidecar(dest))
    return target
