"""Checksums of written files and the output-directory lock, on their own (no workflow): what
a corrupt file, a damaged checksum, a stale or a live lock give."""

from __future__ import annotations

import json
import logging
import os
import socket
import subprocess

import numpy as np
import pytest
import xarray as xr

from granular_multiscale import checkpoint, integrity, output_lock
from granular_multiscale.atomic import atomic_path
from granular_multiscale.data import DataFileError, read_run


def _write(path, data: bytes):
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def _flip(path, offset: int = 100):
    with open(path, "r+b") as f:
        f.seek(offset)
        byte = f.read(1)
        f.seek(offset)
        f.write(bytes([byte[0] ^ 0xFF]))


def test_atomic_write_records_a_checksum_that_sha256sum_accepts(tmp_path):
    path = tmp_path / "a" / "data.bin"
    _write(path, os.urandom(5000))
    assert integrity.recorded(path) == integrity.digest(path)
    integrity.verify(path)
    check = subprocess.run(["sha256sum", "-c", integrity.sidecar(path).name], cwd=path.parent, capture_output=True,
                           text=True)
    assert check.returncode == 0 and "data.bin: OK" in check.stdout
    # written with the umask's mode, not the temporary file's 0600
    mask = os.umask(0)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask == integrity.sidecar(path).stat().st_mode & 0o777


@pytest.mark.parametrize("damage", ["flip", "truncate", "sidecar"])
def test_a_damaged_file_is_named(tmp_path, damage):
    path = tmp_path / "data.bin"
    _write(path, os.urandom(5000))
    if damage == "flip":
        _flip(path)
    elif damage == "truncate":
        os.truncate(path, 1000)
    else:
        integrity.sidecar(path).write_text("not a checksum")
    with pytest.raises(integrity.CorruptFileError, match=f"model file {path} is corrupt"):
        integrity.verify(path, "model file")
    assert integrity.scan(tmp_path)[0][0] == path


def test_a_file_without_checksum_is_read_unverified(tmp_path):
    path = tmp_path / "by_hand.bin"
    path.write_bytes(b"written by hand")
    integrity.verify(path)
    assert integrity.scan(tmp_path) == []


def test_read_run_names_a_corrupt_run_file(tmp_path):
    path = tmp_path / "run.h5"
    ds = xr.Dataset({"x": ("step", np.arange(2000.0))})
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf")
    _flip(path, path.stat().st_size - 3000)  # inside the data: HDF5 itself would read it back
    with pytest.raises(DataFileError, match=f"run file {path} is corrupt"):
        read_run(path, required=("x",))


def test_scan_sets_aside_a_corrupt_file_and_what_was_built_from_it(tmp_path):
    out = tmp_path / "out"
    files = {name: out / name for name in ("dataset.h5", "model.pt", "run.h5", "figure.png", "other.h5")}
    for path in files.values():
        _write(path, os.urandom(200))
    orphan = integrity.sidecar(out / "gone.h5")
    orphan.write_text("0" * 64 + "  gone.h5\n")
    inputs = {str(files["model.pt"]): [str(files["dataset.h5"])], str(files["run.h5"]): [str(files["model.pt"])],
              str(files["figure.png"]): [str(files["run.h5"]), str(files["other.h5"])]}
    _flip(files["dataset.h5"], 10)
    corrupt = integrity.scan(out)
    assert [p for p, _ in corrupt] == [files["dataset.h5"]] and not orphan.exists()
    stale = integrity.built_from([files["dataset.h5"]], inputs)
    assert stale == sorted([files["model.pt"], files["run.h5"], files["figure.png"]])
    folder = integrity.set_aside(out, corrupt + [(p, "built from it") for p in stale])
    assert sorted(p.name for p in out.iterdir() if p.is_file()) == ["other.h5", "other.h5.sha256"]
    assert (folder / "dataset.h5").is_file() and (folder / "dataset.h5.sha256").is_file()
    assert folder.parent == out / "corrupt" and integrity.scan(out) == []  # corrupt/ is not scanned again


def test_a_corrupt_checkpoint_is_set_aside_with_a_warning(tmp_path, caplog):
    path = tmp_path / "run.ckpt"
    checkpoint.save(path, {"signature": "s", "material_state": None, "step": 3})
    assert checkpoint.load(path)["step"] == 3
    _flip(path, 20)
    logger = logging.getLogger("test_integrity")
    with caplog.at_level(logging.WARNING):
        assert checkpoint.resume(path, "s", None, logger) is None
    assert f"checkpoint {path} set aside: checkpoint {path} is corrupt" in caplog.text
    assert not path.exists() and not integrity.sidecar(path).exists()


# ---- the output-directory lock ---------------------------------------------------------------

def _holder(pid, **changes):
    holder = {"pid": pid, "host": socket.gethostname(), "process_start": output_lock._start_time(pid),
              "cwd": "/another/clone", "started": "2026-01-01 00:00:00 UTC"}
    return {**holder, **changes}


def test_lock_is_taken_and_given_back(tmp_path):
    output_lock.acquire(tmp_path)
    holder = output_lock.read_holder(tmp_path)
    assert holder["pid"] == os.getpid() and holder["cwd"] == os.getcwd()
    output_lock.acquire(tmp_path)  # this process holds it already
    assert output_lock.held_by_other(tmp_path) is None
    output_lock.release(tmp_path)
    assert not output_lock.lock_file(tmp_path).exists()


def test_a_live_holder_is_named(tmp_path):
    sleeper = subprocess.Popen(["sleep", "30"])
    try:
        output_lock.lock_file(tmp_path).write_text(json.dumps(_holder(sleeper.pid)))
        assert output_lock.held_by_other(tmp_path)["pid"] == sleeper.pid
        with pytest.raises(output_lock.OutputLockedError, match=rf"pid {sleeper.pid} on host {socket.gethostname()}, "
                                                                r"started 2026-01-01 00:00:00 UTC, from /another/clone; "
                                                                r"wait for it to finish"):
            output_lock.acquire(tmp_path)
        output_lock.release(tmp_path)  # not ours: stays
        assert output_lock.read_holder(tmp_path)["pid"] == sleeper.pid
    finally:
        sleeper.kill()
        sleeper.wait()


@pytest.mark.parametrize("stale", ["pid gone", "pid reused", "unreadable"])
def test_a_stale_lock_is_taken_over_with_a_warning(tmp_path, stale):
    if stale == "pid gone":
        dead = subprocess.Popen(["true"])
        dead.wait()
        text = json.dumps(_holder(dead.pid, process_start="1"))
    elif stale == "pid reused":  # a running process, started at another time than the holder
        text = json.dumps(_holder(os.getppid(), process_start="1"))
    else:
        text = "{half a lock"
    output_lock.lock_file(tmp_path).write_text(text)
    warnings = []
    output_lock.acquire(tmp_path, warn=warnings.append)
    assert output_lock.read_holder(tmp_path)["pid"] == os.getpid()
    assert len(warnings) == 1
    assert ("unreadable lock file" if stale == "unreadable" else "stale lock") in warnings[0]


def test_a_lock_from_another_host_says_how_to_remove_it(tmp_path):
    output_lock.lock_file(tmp_path).write_text(json.dumps(_holder(1, host="node17")))
    with pytest.raises(output_lock.OutputLockedError,
                       match=rf"on host node17.*if it no longer runs on node17, remove {tmp_path}/.workflow.lock"):
        output_lock.acquire(tmp_path)
