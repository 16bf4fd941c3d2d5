"""Checkpoints of long runs: an atomic pickle per run, resumed only by the run it belongs to.

    save(path, payload)                          temporary file + rename: a kill keeps the last one
    resume(path, signature, material, logger)    the saved payload, or None (and the file set aside)
    checkpoint_and_scenes(path)                  a DEM run's checkpoint and its RVE snapshot folder

The FEM solver (``fem.triaxial``) and the RVE-path driver (``drivers.rve_paths``) checkpoint
after every step this way; the payload holds ``signature`` and ``material_state``.
"""

from __future__ import annotations

import logging
import pickle
import shutil
from pathlib import Path

from . import integrity
from .atomic import atomic_path


def save(path: Path, payload: dict) -> None:
    """Pickle atomically (temporary file + rename): a kill mid-write keeps the previous checkpoint."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        pickle.dump(payload, f, protocol=pickle.HIGHEST_PROTOCOL)


def load(path: Path) -> dict:
    """The pickled payload; :class:`integrity.CorruptFileError` if the file does not match its
    checksum or cannot be unpickled."""
    integrity.verify(path, "checkpoint")
    try:
        with open(path, "rb") as f:
            return pickle.load(f)
    except Exception as error:  # a checkpoint written before checksums existed, truncated
        raise integrity.CorruptFileError(f"checkpoint {path} cannot be read: {error}") from error


def resume(path: Path | None, signature, material, logger: logging.Logger) -> dict | None:
    """The checkpoint at ``path`` if it belongs to this run (same ``signature``) and ``material``
    accepts its state (``set_state`` is called); otherwise None, and a checkpoint that is there
    is removed with one warning saying why."""
    if path is None or not path.exists():
        return None
    reason = None
    try:
        saved = load(path)
    except integrity.CorruptFileError as error:
        saved, reason = None, str(error)
    if saved is not None and (not isinstance(saved, dict) or saved.get("signature") != signature):
        reason = "it belongs to another run"
    elif saved is not None:
        try:
            material.set_state(saved["material_state"])
        except (ValueError, OSError) as error:  # the set refuses a state it cannot continue (a snapshot
            reason = f"the material set cannot resume it ({error})"  # missing or corrupt: OSError)
    if reason is None:
        return saved
    integrity.forget(path)
    logger.warning("checkpoint %s set aside: %s; starting afresh", path, reason)
    return None


def checkpoint_and_scenes(checkpoint: str | Path | None) -> tuple[Path | None, Path | None]:
    """(checkpoint, folder of its RVE scene snapshots) of a DEM run; snapshots without their
    checkpoint belong to an older, finished or abandoned run and are removed."""
    if not checkpoint:
        return None, None
    checkpoint = Path(checkpoint)
    scenes_dir = checkpoint.with_name(checkpoint.name + ".scenes")
    if not checkpoint.exists() and scenes_dir.exists():
        shutil.rmtree(scenes_dir)
    return checkpoint, scenes_dir
