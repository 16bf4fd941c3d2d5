"""FEM–DEM runs at the tiny scale: the rules, determinism, kill + resume, Dask = local pool."""

from __future__ import annotations

import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from dem_fixtures import ROOT, TEST_SPHERES, packing, tiny_config

from granular_multiscale.data import read_run
from granular_multiscale.plan import Layout
from granular_multiscale.drivers.fem_dem import dem_newton_config, run_fem_dem

pytestmark = pytest.mark.slow
P0 = 1.0e5
# results that must not depend on how (or how often) a run was executed
RESULTS = ("strain", "stress", "tangent", "displacement", "top_force", "newton_iterations", "residual_norm",
           "particle_steps", "trials")


def _same_results(a, b, steps=None):
    for name in RESULTS:
        x, y = a[name].values, b[name].values
        if steps is not None:
            x, y = x[:steps], y[:steps]
        assert np.array_equal(x, y, equal_nan=True), name


def test_newton_overrides():
    config = tiny_config(Path("/tmp/unused"), {"p": [[1, 0.001]]})
    cfg = dem_newton_config(config)
    assert cfg["newton"]["tolerance"] == config["dem"]["newton"]["tolerance"] == 2e-3
    assert cfg["newton"]["max_iterations"] == 30
    # the tolerance study's choice for FEM–DEM, not the analytic materials' defaults
    assert (cfg["newton"]["predictor"], cfg["newton"]["acceleration"]) == ("extrapolate", "anderson")
    assert (config["newton"]["predictor"], config["newton"]["acceleration"]) == ("tangent", "none")
    assert cfg["newton"]["max_cutbacks"] == config["newton"]["max_cutbacks"]  # not overridden
    config["dem"]["newton"]["max_cutbacks"] = 1
    assert dem_newton_config(config)["newton"]["max_cutbacks"] == 1


def test_rules_write_the_data_contract(tmp_path):
    """`snakemake fem_dem/<path>.h5` at the tiny scale: packing, both runs, logs, benchmarks."""
    out = tmp_path / "out"
    config = tiny_config(out, {"path1": [[3, 0.003], [1, 0.002]], "path2": [[2, 0.002]]})
    config_file = tmp_path / "config.yaml"
    config_file.write_text(yaml.safe_dump(config))
    L = Layout(out)
    targets = [L.run("fem_dem", "path1"), L.run("fem_dem", "path2")]
    snakemake = Path(sys.executable).with_name("snakemake")
    result = subprocess.run([str(snakemake), "-j2", "--configfile", str(config_file), "--", *targets],
                            cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-4000:]
    summary = json.loads(Path(L.packing_summary()).read_text())
    assert summary["n_packings"] == 1 and summary["packings"][0]["n_spheres"] == TEST_SPHERES
    assert Path(L.packings(1)[0]).stat().st_size > 10_000
    for target, n_steps in zip(targets, (4, 2)):
        ds = read_run(target)
        assert ds.attrs["method"] == "dem" and ds.sizes["step"] == n_steps + 1 and ds.sizes["gp"] == 16
        # step 0: the consolidated RVEs carry the confinement (platen force = −p0 · area)
        assert ds.top_force.values[0] == pytest.approx(-P0 * 0.25, rel=0.01)
        assert np.abs(ds.stress.values[0, :, :3] + P0).max() < 0.01 * P0
        # compression raises the deviator: the platen pushes harder with every loading step
        assert np.all(np.diff(ds.top_force.values[: 1 + min(n_steps, 3)]) < 0)
        for name in ("dem_time", "dem_cpu_time", "overhead_time", "imbalance_time", "particle_steps", "trials"):
            assert name in ds, name
        assert np.all(ds.particle_steps.values[1:] > 0) and np.all(ds.trials.values[1:] >= 1)
        assert np.all(ds.dem_time.values[1:] > 0) and np.all(ds.overhead_time.values[1:] >= 0)
        assert ds.attrs["dem_particle_steps"] == pytest.approx(ds.particle_steps.values.sum())
        assert 0 < ds.attrs["dem_share_not_stepping"] < 1
        name = Path(target).stem
        log = Path(L.log(f"fem_dem/{name}")).read_text()
        assert log.count("axial strain") == n_steps + 1 and "time split" in log
        assert Path(L.benchmark(f"fem_dem/{name}")).exists()
        assert not Path(L.checkpoint(f"fem_dem/{name}")).exists()  # removed after success
        assert not Path(L.checkpoint(f"fem_dem/{name}") + ".scenes").exists()
    assert Path(L.benchmark("rve")).exists() and "consolidating" in Path(L.log("rve")).read_text()


RUNNER = """
import pickle, sys
from granular_multiscale.drivers.fem_dem import run_fem_dem
from granular_multiscale.runlog import setup_logging
config, packings, output, checkpoint, workers = pickle.load(open(sys.argv[1], "rb"))
run_fem_dem(config, "p", packings, output, checkpoint, workers, logger=setup_logging(None))
"""


def _run_in_subprocess(tmp_path, config, packings, output, checkpoint, workers):
    args = tmp_path / f"args_{Path(output).stem}.pkl"
    args.write_bytes(pickle.dumps((config, packings, str(output), str(checkpoint), workers)))
    return subprocess.Popen([sys.executable, "-c", RUNNER, str(args)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


def _kill_after_step(proc, checkpoint: Path, kill_step: int, timeout: float = 300) -> int:
    """SIGKILL the run's process group once its checkpoint holds step `kill_step`; the step reached."""
    deadline = time.time() + timeout
    step = -1
    while time.time() < deadline and proc.poll() is None:
        try:
            step = pickle.loads(checkpoint.read_bytes())["step"]
        except Exception:
            pass
        if step >= kill_step:
            os.killpg(proc.pid, signal.SIGKILL)
            break
        time.sleep(0.02)
    proc.wait()
    return step


@pytest.mark.needs_yade
def test_determinism_and_resume_after_kill(tmp_path_factory, tmp_path):
    """Two uninterrupted runs (2 and 1 workers) agree bit for bit; a run killed after its third
    converged step and started again resumes from the checkpoint (the newest RVE snapshot +
    at most one replayed step) and ends with the same numbers."""
    path, _ = packing(tmp_path_factory)
    config = tiny_config(tmp_path / "o", {"p": [[6, 0.006]]}, snapshot_interval=2)
    packings = [str(path)]
    ck = tmp_path / "ck"
    a = run_fem_dem(config, "p", packings, tmp_path / "a.h5", ck / "a.ckpt", 2)
    b = run_fem_dem(config, "p", packings, tmp_path / "b.h5", None, 1)
    _same_results(a, b)
    assert a.sizes["step"] == 7 and np.all(a.cutbacks.values == 0)

    checkpoint = ck / "c.ckpt"
    proc = _run_in_subprocess(tmp_path, config, packings, tmp_path / "c.h5", checkpoint, 2)
    step = _kill_after_step(proc, checkpoint, 3)
    assert 3 <= step < 6 and proc.returncode == -signal.SIGKILL, proc.stderr.read()[-2000:]
    assert not (tmp_path / "c.h5").exists()
    # commits = load steps + 1 (step 0, the initial state, is committed too); snapshots every 2
    assert (ck / "c.ckpt.scenes" / "commit00002_slot0.pkl").exists()
    # the killed run's RVE workers notice their driver is gone and leave
    proc2 = _run_in_subprocess(tmp_path, config, packings, tmp_path / "c.h5", checkpoint, 2)
    _, err = proc2.communicate(timeout=300)
    assert proc2.returncode == 0, err[-3000:]
    assert f"resuming from checkpoint {checkpoint} after step {step}" in err
    base = 2 * ((step + 1) // 2)
    assert f"resumed after {step + 1} commits (snapshot after commit {base} + {step + 1 - base} replayed" in err, err[-3000:]
    c = read_run(tmp_path / "c.h5")
    _same_results(a, c)
    # the resumed run's cost covers all its load steps, those before the kill included (their
    # wall times come from the checkpoint). No comparison with run a's seconds: on a loaded
    # 2-core machine a 2 s run varies by more than any tolerance that could still fail.
    assert np.all(c.wall_time.values[:step + 1] > 0)
    assert c.attrs["time_run_s"] >= c.wall_time.values.sum()
    assert c.attrs["dem_particle_steps"] == a.attrs["dem_particle_steps"] == c.particle_steps.values.sum()
    assert c.attrs["dem_trials"] == a.attrs["dem_trials"]
    assert c.attrs["total_newton_corrections"] == a.attrs["total_newton_corrections"]


@pytest.mark.needs_yade
def test_resume_after_a_config_change_starts_afresh(tmp_path_factory, tmp_path):
    """Killed, then started again with other DEM settings (dem.max_steps): the checkpoint is set
    aside with one log line and the run starts from the packings, with the result of a fresh run."""
    path, _ = packing(tmp_path_factory)
    packings = [str(path)]
    config = tiny_config(tmp_path / "o", {"p": [[5, 0.005]]}, snapshot_interval=2)
    checkpoint = tmp_path / "ck" / "p.ckpt"
    proc = _run_in_subprocess(tmp_path, config, packings, tmp_path / "p.h5", checkpoint, 2)
    assert _kill_after_step(proc, checkpoint, 2) >= 2 and proc.returncode == -signal.SIGKILL
    changed = tiny_config(tmp_path / "o", {"p": [[5, 0.005]]}, snapshot_interval=2, max_steps=15000)
    proc2 = _run_in_subprocess(tmp_path, changed, packings, tmp_path / "p.h5", checkpoint, 2)
    _, err = proc2.communicate(timeout=300)
    assert proc2.returncode == 0, err[-3000:]
    assert err.count("set aside") == 1 and "resuming" not in err, err[-3000:]
    fresh = run_fem_dem(changed, "p", packings, tmp_path / "fresh.h5", None, 2)
    _same_results(fresh, read_run(tmp_path / "p.h5"))


@pytest.mark.needs_yade
def test_dask_local_cluster_equals_local_pool(tmp_path_factory, tmp_path):
    from distributed import Client, LocalCluster

    path, _ = packing(tmp_path_factory)
    config = tiny_config(tmp_path / "o", {"p": [[1, 0.001]]})
    local = run_fem_dem(config, "p", [str(path)], tmp_path / "local.h5", None, 2)
    config["dem"]["executor"] = "dask"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        distributed = run_fem_dem(config, "p", [str(path)], tmp_path / "dask.h5", None, 2, dask_client=client)
    assert distributed.attrs["dem_executor"] == "dask"
    assert distributed.sizes["step"] == 2 and distributed.trials.values[1] >= 1
    _same_results(local, distributed)


def test_snakemake_killed_hard_resumes_after_unlock(tmp_path):
    """The README's recipe after `kill -9` of the whole Snakemake run: the same command is refused
    (Snakemake's lock stays), `--unlock` with the same options frees it, and the same command
    then resumes the FEM–DEM run from its checkpoint."""
    out = tmp_path / "out"
    config = tiny_config(out, {"path1": [[8, 0.008]]}, snapshot_interval=2)
    config_file = tmp_path / "config.yaml"
    config_file.write_text(yaml.safe_dump(config))
    # a working directory of its own: --unlock removes every lock of the directory it runs in
    workdir = tmp_path / "wd"
    workdir.mkdir()
    snakemake = [str(Path(sys.executable).with_name("snakemake")), "--snakefile", str(ROOT / "Snakefile"),
                 "--configfile", str(config_file)]
    L = Layout(out)
    target = L.run("fem_dem", "path1")
    checkpoint = Path(L.checkpoint("fem_dem/path1"))
    proc = subprocess.Popen([*snakemake, "-j2", "--", target], cwd=workdir, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    step = _kill_after_step(proc, checkpoint, 3, timeout=600)
    assert 3 <= step < 8 and proc.returncode == -signal.SIGKILL and not Path(target).exists()

    def run(*args):
        return subprocess.run([*snakemake, *args], cwd=workdir, capture_output=True, text=True, timeout=900)

    refused = run("-j2", "--", target)
    assert refused.returncode != 0 and "--unlock" in refused.stdout + refused.stderr
    assert run("--unlock").returncode == 0
    resumed = run("-j2", "--", target)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    log = Path(L.log("fem_dem/path1")).read_text()
    assert f"resuming from checkpoint {checkpoint} after step {step}" in log
    assert read_run(target).sizes["step"] == 9
