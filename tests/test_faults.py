"""Fault injection at the tiny scale: corrupt and truncated files of every kind the pipeline
reads back, a kill between an RVE snapshot and the checkpoint that commits it, two workflows
on one output directory, a step too large to converge. Each test asserts the exit status and
the named error, and that a rerun after the fault gives the numbers of a clean run, bit for bit.
(Non-finite and out-of-range config values: tests/test_config_values.py.)"""

from __future__ import annotations

import os
import pickle
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from dem_fixtures import ROOT, packing, tiny_config

from granular_multiscale import integrity, output_lock
from granular_multiscale.data import DataFileError, read_run
from granular_multiscale.plan import Layout
from granular_multiscale.surrogate.dataset import DatasetError, read_dataset
from granular_multiscale.surrogate.models import ModelFileError, SurrogateModel

pytestmark = pytest.mark.slow
SNAKEMAKE = [str(Path(sys.executable).with_name("snakemake"))]


def same_numbers(a_file, b_file):
    a, b = read_run(a_file), read_run(b_file)
    assert set(a.data_vars) == set(b.data_vars)
    for name in a.data_vars:
        if "time" not in name:  # how long it took (wall_time, dem_cpu_time, ...) is not a result
            x, y = a[name].values, b[name].values
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name


def flip(path: Path, offset: int) -> None:
    """Overwrite 8 bytes inside the file (the bytes the archive's own CRC would have caught)."""
    with open(path, "r+b") as f:
        f.seek(offset)
        f.write(b"\xde\xad\xbe\xef\xde\xad\xbe\xef")


def truncate(path: Path) -> None:
    os.truncate(path, path.stat().st_size // 2)


def snakemake(args, cwd=ROOT, check=True, **kwargs):
    result = subprocess.run([*SNAKEMAKE, *args], cwd=cwd, capture_output=True, text=True, timeout=900, **kwargs)
    if check:
        assert result.returncode == 0, result.stderr[-4000:]
    return result


def elastoplastic_chain(tmp_path, **settings):
    """Options of the tiny elastoplastic chain writing under tmp_path/out, and its FEM–ML run."""
    out = tmp_path / "out"
    override = tmp_path / "override.yaml"
    override.write_text(yaml.safe_dump({"output_dir": str(out), "reference_material": "elastoplastic", **settings}))
    return out, ["--configfile", str(ROOT / "config" / "tiny.yaml"), str(override)]


def test_corrupt_inputs_are_named_set_aside_and_rebuilt(tmp_path):
    """A network, a dataset, a reference run and an RVE-path file, each flipped or truncated:
    the reader names it, the next workflow run sets all four aside with what was built from
    them, rebuilds them, and the FEM–ML run equals the clean run's. (One rerun for the four:
    a rerun per file costs a minute each and proves the same.)"""
    out, options = elastoplastic_chain(tmp_path)
    L = Layout(out)
    target = Path(L.fem_ml("path2"))
    snakemake(["-j2", *options, "--", str(target)])
    clean = tmp_path / "clean.h5"
    shutil.copy(target, clean)
    model, dataset, run, rve_paths = (Path(p) for p in (L.model("sigma"), L.dataset("train"),
                                                        L.run("fem_elastoplastic", "path1"), L.rve_paths("designed")))
    readers = {model: (lambda p: SurrogateModel.load(p), ModelFileError, "model file"),
               dataset: (read_dataset, DatasetError, "dataset file"),
               run: (read_run, DataFileError, "run file"),
               rve_paths: (read_run, DataFileError, "run file")}
    for path, (reader, error, what) in readers.items():  # both damages are named by every reader
        for damage in (lambda p: flip(p, 12000), truncate):
            kept = path.read_bytes()
            damage(path)
            with pytest.raises(error, match=f"{what} {path} is corrupt"):
                reader(path)
            path.write_bytes(kept)
    flip(model, 12000)
    truncate(dataset)
    flip(run, 20000)
    truncate(rve_paths)
    rerun = snakemake(["-j2", *options, "--", str(target)])
    for path in readers:
        assert f"{path} set aside in {out}/corrupt/" in rerun.stderr, (path, rerun.stderr[-3000:])
        integrity.verify(path)
    assert f"{target} set aside" in rerun.stderr and "built from" in rerun.stderr
    assert len(list((out / "corrupt").iterdir())) == 1  # one folder for the rerun that set files aside
    same_numbers(clean, target)


def test_a_step_too_large_to_converge_fails_its_rule(tmp_path):
    """One 25 % axial-strain step with one Newton iteration and no cutback: the rule exits
    non-zero, names the step once on stderr (the traceback stays in the log) and writes no run."""
    out, options = elastoplastic_chain(tmp_path, load_paths={"huge": {"segments": [[1, 0.25]]}}, training_path="huge",
                                       validation_path="huge", surrogate={"training_sources": ["huge"]},
                                       newton={"max_cutbacks": 0, "max_iterations": 1})
    L = Layout(out)
    result = snakemake(["-j1", *options, "--", L.run("fem_elastoplastic", "huge")], check=False)
    assert result.returncode != 0
    assert "load step 1 (axial strain 0 -> 0.25) did not converge after 0 cutbacks" in result.stderr
    assert result.stderr.count("Traceback (most recent call last)") == 0, result.stderr[-3000:]
    assert "Traceback" in Path(L.log("fem_elastoplastic/huge")).read_text()
    assert not Path(L.run("fem_elastoplastic", "huge")).exists()


def _clone(tmp_path) -> Path:
    """A second checkout of the workflow's files (its own working directory and .snakemake/)."""
    clone = tmp_path / "clone"
    clone.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", ".snakemake", "results")
    for name in ("Snakefile", "workflow", "scripts", "config"):
        source = ROOT / name
        (shutil.copytree(source, clone / name, ignore=ignore) if source.is_dir() else shutil.copy(source, clone / name))
    return clone


def test_a_second_workflow_on_one_output_directory_stops(tmp_path):
    """While one workflow writes the output directory, a second one from another clone stops
    before any job, naming the first (pid, host, start); once the first is done, the second
    finds nothing to do."""
    out, options = elastoplastic_chain(tmp_path)
    target = Layout(out).model("sigma")  # four jobs after the lock is taken: about 20 s here with -j1
    first = subprocess.Popen([*SNAKEMAKE, "-j1", *options, "--", str(target)], cwd=ROOT, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
    lock = output_lock.lock_file(out)
    deadline = time.time() + 120
    while not lock.exists() and first.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    assert lock.exists(), first.stderr.read()[-3000:]
    clone = _clone(tmp_path)
    second = snakemake(["-j1", *options, "--", str(target)], cwd=clone, check=False)
    assert first.poll() is None, "the first workflow ended before the second was tried: the test proves nothing"
    assert second.returncode == 1
    assert f"Output directory locked: output directory {out} is in use by another workflow: pid {first.pid} on host" \
           in second.stderr and f"from {ROOT}" in second.stderr, second.stderr[-3000:]
    assert first.wait(timeout=300) == 0, first.stderr.read()[-3000:]
    assert not lock.exists()
    again = snakemake(["-j1", *options, "--", str(target)], cwd=clone)
    assert "Nothing to be done" in again.stdout + again.stderr


RUNNER = """
import os, pickle, signal, sys
from granular_multiscale import checkpoint
from granular_multiscale.drivers.fem_dem import run_fem_dem
from granular_multiscale.runlog import setup_logging
config, packings, output, path, kill_at = pickle.load(open(sys.argv[1], "rb"))
save = checkpoint.save
def save_or_die(target, payload):  # the checkpoint of step `kill_at`: its RVE snapshot is written
    if payload["step"] == kill_at:
        os.killpg(os.getpgid(0), signal.SIGKILL)
    save(target, payload)
checkpoint.save = save_or_die
run_fem_dem(config, "p", packings, output, path, 2, logger=setup_logging(None))
"""


def _fem_dem(tmp_path, config, packings, output, ckpt, kill_at=-1):
    args = tmp_path / f"args_{output.stem}.pkl"
    args.write_bytes(pickle.dumps((config, packings, str(output), str(ckpt), kill_at)))
    proc = subprocess.run([sys.executable, "-c", RUNNER, str(args)], capture_output=True, text=True, timeout=600,
                          start_new_session=True)
    return proc


@pytest.mark.needs_yade
def test_kill_between_snapshot_and_commit_and_a_corrupt_snapshot(tmp_path_factory, tmp_path):
    """FEM–DEM with RVE snapshots every 2 commits. (1) Killed with -9 after the snapshot of
    commit 4 was written, before the checkpoint of step 3 committed it: the rerun resumes from
    the previous checkpoint and its snapshot. (2) Killed after step 4's checkpoint, that
    checkpoint's snapshot truncated: the rerun sets the checkpoint aside, with a warning naming
    the snapshot, and starts afresh. Both equal an uninterrupted run bit for bit."""
    path, _ = packing(tmp_path_factory)
    config = tiny_config(tmp_path / "o", {"p": [[6, 0.006]]}, snapshot_interval=2)
    packings = [str(path)]
    clean = tmp_path / "clean.h5"
    assert _fem_dem(tmp_path, config, packings, clean, tmp_path / "clean.ckpt").returncode == 0

    ckpt = tmp_path / "a.ckpt"
    scenes = ckpt.with_name(ckpt.name + ".scenes")
    killed = _fem_dem(tmp_path, config, packings, tmp_path / "a.h5", ckpt, kill_at=3)
    assert killed.returncode == -signal.SIGKILL
    assert (scenes / "commit00004_slot0.pkl").exists() and pickle.loads(ckpt.read_bytes())["step"] == 2
    resumed = _fem_dem(tmp_path, config, packings, tmp_path / "a.h5", ckpt)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert "resumed after 3 commits (snapshot after commit 2 + 1 replayed" in resumed.stderr, resumed.stderr[-3000:]
    same_numbers(clean, tmp_path / "a.h5")

    ckpt = tmp_path / "b.ckpt"
    scenes = ckpt.with_name(ckpt.name + ".scenes")
    assert _fem_dem(tmp_path, config, packings, tmp_path / "b.h5", ckpt, kill_at=5).returncode == -signal.SIGKILL
    snapshot = scenes / "commit00004_slot0.pkl"
    assert pickle.loads(ckpt.read_bytes())["step"] == 4 and snapshot.exists()
    truncate(snapshot)
    resumed = _fem_dem(tmp_path, config, packings, tmp_path / "b.h5", ckpt)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"checkpoint {ckpt} set aside" in resumed.stderr and f"RVE snapshot {snapshot} is corrupt" in resumed.stderr
    same_numbers(clean, tmp_path / "b.h5")


def test_a_corrupt_packing_is_named_and_rebuilt(tmp_path):
    """A truncated RVE packing: the DEM material set names it (not YADE's 'gzip error'), and the
    next workflow run rebuilds it. YADE's archive holds its writing time, so the files differ:
    the consolidated state (stress, porosity, contacts, steps) must not."""
    import json

    from granular_multiscale.dem.material import DemMaterialPointSet

    out = tmp_path / "out"
    override = tmp_path / "override.yaml"
    override.write_text(yaml.safe_dump({"output_dir": str(out), "dem": {"n_spheres": 100}}))
    options = ["--configfile", str(ROOT / "config" / "tiny.yaml"), str(override)]
    L = Layout(out)
    packing_file, summary_file = Path(L.packings(1)[0]), Path(L.packing_summary())

    def state():
        (summary,) = json.loads(summary_file.read_text())["packings"]
        return {k: v for k, v in summary.items() if k not in ("wall_time", "particle_step_time", "log")}

    snakemake(["-j1", *options, "--", str(packing_file)])
    clean = state()
    truncate(packing_file)
    config = tiny_config(out, {"p": [[1, 0.001]]})
    with pytest.raises(integrity.CorruptFileError, match=f"RVE packing {packing_file} is corrupt"):
        DemMaterialPointSet(4, [packing_file], settings=config["dem"])
    rerun = snakemake(["-j1", *options, "--", str(packing_file)])
    assert f"{packing_file} set aside" in rerun.stderr
    integrity.verify(packing_file)
    assert state() == clean
