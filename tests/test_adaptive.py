"""Adaptive FEM–DEM–ML at the tiny scale with real YADE RVEs and real (quickly trained)
networks: the DEM subset's replay, and the adaptive set at its two ends and in between.

* a replayed RVE is bit for bit the RVE that followed the same strains from step 0;
* threshold ∞ is FEM–ML and 100 % anchors (or threshold 0) FEM–DEM, bit for bit;
* a run killed after a few steps and started again ends with the numbers of an uninterrupted one.

The networks are an ensemble of 2 NNσ trained in seconds on a synthetic material-point run of the
elastoplastic model (as tests/test_surrogate_uncertainty.py), so they disagree with the
100-sphere RVEs — which makes the mixed specimen a hard case for Newton, not an easy one."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
import yaml
import figure_checks as check
from dem_fixtures import ROOT, SETTINGS, packing, tiny_config

from granular_multiscale.adaptive.material import (AdaptiveMaterialPointSet, anchor_points, residual_correction,
                                                   residual_correction_jacobian)
from granular_multiscale.analysis.metrics import curve_errors
from granular_multiscale.data import read_run, write_run
from granular_multiscale.dem.material import DemMaterialPointSet
from granular_multiscale.dem.subset import DemSubsetMaterialPointSet
from granular_multiscale.drivers.adaptive import DEM_TRAJECTORY_VARIABLES, configured_anchors, run_adaptive
from granular_multiscale.drivers.fem_dem import dem_newton_config, run_fem_dem
from granular_multiscale.drivers.fem_ml import run_fem_ml, surrogate_material
from granular_multiscale.drivers.reference import run_fem_reference
from granular_multiscale.materials.elastoplastic import Elastoplastic
from granular_multiscale.paths import load_paths_from_config
from granular_multiscale.plan import Layout
from granular_multiscale.surrogate.dataset import build_dataset
from granular_multiscale.surrogate.synthetic import material_point_run, triaxial_strain_paths
from granular_multiscale.surrogate.training import train
from granular_multiscale.tensors import ENGINEERING_FACTOR

pytestmark = pytest.mark.slow


def strain_history(n_points: int, n_commits: int, seed: int = 3) -> np.ndarray:
    """[commits, n, 6]: commit 0 at zero strain (the consolidated state), then triaxial-like
    increments of 1e-3 axial with a per-point lateral ratio and shear, one commit repeating the last."""
    rng = np.random.default_rng(seed)
    ratio = rng.uniform(0.3, 0.45, n_points)
    shear = rng.uniform(-0.05, 0.05, (n_points, 3))
    axial = 1e-3 * np.array([0, 1, 2, 3, 3, 2, 4][:n_commits])
    eps = np.zeros((n_commits, n_points, 6))
    eps[..., 0] = eps[..., 1] = ratio * axial[:, None]
    eps[..., 2] = -axial[:, None]
    eps[..., 3:] = shear * axial[:, None, None]
    return eps


def drive(dem, strains, activate: dict | None = None, detour: bool = True) -> list[np.ndarray]:
    """Commit `strains` one after another; before commit k activate the points activate[k]; with
    `detour`, a discarded trial elsewhere first (what Newton does). Returns the converged stresses
    [n, 6] after each commit."""
    converged = []
    for k, eps in enumerate(strains):
        if activate and k in activate:
            dem.activate(activate[k])
        if detour:
            dem.evaluate(0.5 * eps + 1e-4)
        dem.evaluate(eps)
        dem.commit(eps)
        converged.append(dem.conv_stress.copy())
    return converged


@pytest.mark.needs_yade
def test_replayed_rve_is_bit_for_bit_the_rve_that_followed_the_strains(tmp_path_factory):
    path, _ = packing(tmp_path_factory)
    n, strains = 4, strain_history(4, 7)
    kwargs = dict(n_workers=2, snapshot_interval=2)  # re-loads after commits 2, 4, 6: the replay must too
    with DemMaterialPointSet(n, [path], SETTINGS, **kwargs) as fem_dem:
        along = np.array(drive(fem_dem, strains, detour=False))  # [commit - 1, n, 6]
        reference, initial = fem_dem.conv_stress.copy(), fem_dem.initial_stress.copy()
        particle_steps = fem_dem.time_split()["particle_steps"]
    assert np.abs(reference - initial).max() > 1e3  # Pa: the strains did load the RVEs

    with DemSubsetMaterialPointSet(n, [path], SETTINGS, **kwargs) as late:
        drive(late, strains)  # nothing active: no DEM at all, and no scene loaded (lazy_scenes)
        assert late.time_split()["particle_steps"] == 0 and np.array_equal(late.conv_stress, initial)
        assert late.resident_scenes() == 0
        assert late.activate(range(n)) == n  # every point replays 7 commits at once
        assert late.resident_scenes() == n
        assert np.array_equal(late.conv_stress, reference)
        # one DEM increment per commit and point: what FEM–DEM spent without detours
        assert late._step["replay_particle_steps"] == particle_steps > 0

    with DemSubsetMaterialPointSet(n, [path], SETTINGS, **kwargs) as mixed:
        mixed.activate([1])  # an anchor: active from the start
        drive(mixed, strains, activate={3: [0, 2]})  # promoted before commit 3 (after 3 commits)
        assert np.array_equal(mixed.active, [True, True, True, False])
        assert np.array_equal(mixed.conv_stress[:3], reference[:3])
        assert np.array_equal(mixed.conv_stress[3], initial[3])  # never driven: the packing's state
        assert mixed.resident_scenes() == 3  # ... and never loaded
        # what the RVEs answered at every commit, the promoted points' past from their replay: the
        # stresses of the RVEs that followed the strains from the start; nothing for point 3
        answers = mixed.dem_responses()
        assert answers["stress"].shape == (8, n, 6) and np.array_equal(answers["strain"][1:], strains)
        assert np.array_equal(answers["stress"][1:, :3], along[:, :3]) and np.array_equal(answers["stress"][0], initial)
        assert answers["known"][:, :3].all() and not answers["known"][1:, 3].any() and answers["known"][0, 3]
        assert np.isnan(answers["tangent"][1:, 3]).all() and np.isfinite(answers["tangent"][:, :3]).all()
        state = mixed.get_state()
        assert state["strain_record"].shape == (8, n, 6)
        # resume: a fresh set replays the active points (bit for bit), and both continue alike
        with DemSubsetMaterialPointSet(n, [path], SETTINGS, **kwargs) as resumed:
            resumed.set_state(state)
            assert np.array_equal(resumed.conv_stress, mixed.conv_stress)
            last = strains[-1] + np.array([0.0003, 0.0003, -0.001, 0.0, 0.0, 0.0])
            for dem in (mixed, resumed):
                dem.evaluate(last)
                dem.commit(last)
            assert np.array_equal(resumed.conv_stress, mixed.conv_stress)
            assert np.array_equal(resumed.strain_record[-1], last)
            # the resumed set knows the same answers: its replay filled in the commits before the resume
            for key, value in resumed.dem_responses().items():
                np.testing.assert_array_equal(value, mixed.dem_responses()[key], err_msg=key)


def test_residual_correction_weights():
    """The kernel correction (pure numpy): weights that sum to 1 (a constant residual is carried
    exactly), the nearest DEM point's residual as the width goes to 0, the mean at width ∞, the
    average halfway between two points, and no 0/0 for a point far from every DEM point."""
    rng = np.random.default_rng(0)
    x_dem, x_sur = rng.uniform(0, 1, (5, 4)), rng.uniform(0, 1, (7, 4))
    constant = np.tile([1.0, 2.0, -3.0, 0.5, 0.0, -1.0], (5, 1))
    for length in (1e-3, 0.05, 1.0, np.inf):
        np.testing.assert_allclose(residual_correction(x_sur, x_dem, constant, length), constant[:1].repeat(7, 0),
                                   rtol=1e-14)
    residual = rng.normal(size=(5, 6))
    nearest = ((x_sur[:, None] - x_dem[None]) ** 2).sum(-1).argmin(axis=1)
    np.testing.assert_allclose(residual_correction(x_sur, x_dem, residual, 1e-4), residual[nearest], rtol=1e-12)
    np.testing.assert_allclose(residual_correction(x_sur, x_dem, residual, np.inf), residual.mean(0)[None].repeat(7, 0))
    two = np.array([[0.0, 0.0], [1.0, 0.0]])
    halfway = residual_correction(np.array([[0.5, 0.3]]), two, residual[:2], 0.2)
    np.testing.assert_allclose(halfway[0], residual[:2].mean(axis=0), rtol=1e-12)
    far = residual_correction(np.array([[100.0, 0.0]]), two, residual[:2], 0.01)
    np.testing.assert_array_equal(far[0], residual[1])
    # local: at a DEM point's state its full residual, a few widths from every DEM state almost nothing
    at = residual_correction(two[:1], two, residual[:2], 0.2, local=True)
    np.testing.assert_allclose(at[0], (residual[0] + np.exp(-12.5) * residual[1]) / (1 + np.exp(-12.5)), rtol=1e-12)
    fading = [np.abs(residual_correction(np.array([[1.0, d]]), two, residual[:2], 0.2, local=True)).max()
              for d in (0.2, 0.4, 0.6, 0.8)]
    assert np.all(np.diff(fading) < 0) and fading[-1] < 1e-3 * np.abs(residual[1]).max()
    assert np.abs(residual_correction(np.array([[100.0, 0.0]]), two, residual[:2], 0.01, local=True)).max() == 0


def test_residual_correction_jacobian_is_the_derivative_in_the_points_own_inputs():
    """Pass criterion: central differences of residual_correction in one surrogate point's inputs
    (the DEM points held) equal residual_correction_jacobian to 1e-6 of its largest entry, for the
    kernel, for the local kernel where its values sum to more than 1 (normalised) and to less (not),
    at several widths; the mean residual (width ∞) does not move."""
    rng = np.random.default_rng(1)
    x_dem, residual = rng.uniform(0, 1, (6, 4)), rng.normal(size=(6, 6))
    x_sur = np.vstack([rng.uniform(0, 1, (5, 4)), x_dem[:1] + 0.01, [[3.0, 3.0, 3.0, 3.0]]])
    h = 1e-6
    for local in (False, True):
        for length in (0.05, 0.3, 2.0):
            jacobian = residual_correction_jacobian(x_sur, x_dem, residual, length, local)
            assert jacobian.shape == (7, 6, 4)
            for f in range(4):
                step = np.zeros(4)
                step[f] = h
                numeric = (residual_correction(x_sur + step, x_dem, residual, length, local)
                           - residual_correction(x_sur - step, x_dem, residual, length, local)) / (2 * h)
                np.testing.assert_allclose(jacobian[:, :, f], numeric, rtol=0, atol=1e-6 * np.abs(jacobian).max())
    kernel_values = np.exp(-((x_sur[:, None] - x_dem[None]) ** 2).sum(-1) / (2 * 2.0**2)).sum(axis=1)
    assert kernel_values.max() > 1 > np.exp(-((x_sur[:, None] - x_dem[None]) ** 2).sum(-1) / (2 * 0.05**2)).sum(1).min()
    assert not residual_correction_jacobian(x_sur, x_dem, residual, np.inf).any()


def test_anchor_seed_draws_other_anchors_of_the_same_share(tmp_path):
    """adaptive.anchor_seed null: the anchors are drawn with the config's seed; a seed of its own
    draws another set of the same size (the bench of the anchors' draw relies on both)."""
    config = tiny_config(tmp_path, {"p": PATH})
    config["adaptive"]["anchor_fraction"] = 0.05
    by_config_seed, seed = configured_anchors({**config, "seed": 7}, 128)
    assert seed == 7 and np.array_equal(by_config_seed, anchor_points(128, 0.05, 7)) and by_config_seed.size == 6
    own, seed = configured_anchors({**config, "seed": 7, "adaptive": {**config["adaptive"], "anchor_seed": 1}}, 128)
    assert seed == 1 and own.size == 6 and not np.array_equal(own, by_config_seed)
    assert np.array_equal(own, anchor_points(128, 0.05, 1))


# -- the adaptive set in the FEM solver --------------------------------------------------------------
PATH = [[3, 0.003], [2, 0.0015], [3, 0.005]]  # loading, unloading, reloading: 8 steps
STEPS = 8
# what must not depend on how a run was made (FEM–DEM: also the DEM accounting that is not timing)
SAME = ("strain", "stress", "tangent", "displacement", "top_force", "volumetric_strain", "newton_iterations",
        "residual_norm", "cutbacks")
DEM_SAME = ("particle_steps", "trials")


def assert_same(a, b, names=SAME):
    for name in names:
        x, y = a[name].values, b[name].values
        if name == "residual_norm":  # NaN-padded to the run's longest step
            width = min(x.shape[1], y.shape[1])
            assert np.isnan(x[:, width:]).all() and np.isnan(y[:, width:]).all()
            x, y = x[:, :width], y[:, :width]
        assert np.array_equal(x, y, equal_nan=True), name


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """(config, packing paths, NNσ model file): the tiny mesh (16 Gauss points, 100-sphere RVEs) with
    FEM–DEM's Newton settings for every run, so that FEM–ML, FEM–DEM and adaptive runs compare bit for
    bit; an ensemble of 2 NNσ trained in seconds on the elastoplastic model."""
    torch.set_num_threads(1)
    folder = tmp_path_factory.mktemp("adaptive")
    path, _ = packing(tmp_path_factory)
    config = tiny_config(folder / "out", {"p": PATH})
    config["newton"].update(dem_newton_config(config)["newton"])
    config["surrogate"].update(newton={}, ensemble_size=2, epochs=150, learning_rate=5e-3, batch_size=256)
    load_path = load_paths_from_config(config)["p"]
    run = material_point_run(Elastoplastic.from_config(12, config), triaxial_strain_paths(load_path, 12, seed=2),
                             load_path)
    sigma, _, _ = train(*build_dataset(run, 0.75, seed=0), "sigma", config["surrogate"], seed=0, config=config)
    sigma.save(folder / "sigma.pt")
    return config, [str(path)], str(folder / "sigma.pt")


def adaptive(setup, threshold, anchor_fraction=0.0, **kwargs):
    config, packings, sigma = setup
    config = {**config, "adaptive": {**config["adaptive"], "anchor_fraction": anchor_fraction}}
    return run_adaptive(config, "p", threshold, packings, sigma, None, "autodiff", n_workers=2, **kwargs)


@pytest.fixture(scope="module")
def fem_ml_run(setup):
    config, _, sigma = setup
    return run_fem_ml(config, "p", sigma, None, "autodiff", progress=False)


@pytest.fixture(scope="module")
def fem_dem_run(setup, tmp_path_factory):
    config, packings, _ = setup
    return run_fem_dem(config, "p", packings, str(tmp_path_factory.mktemp("fem_dem") / "p.h5"), None, 2)


@pytest.mark.needs_yade
def test_threshold_infinity_is_fem_ml(setup, fem_ml_run, tmp_path):
    run = adaptive(setup, np.inf, trajectories=tmp_path / "dem_points.h5")
    # no point ran DEM: a file of no trajectories, which the dataset refuses by name (test_dataset.py)
    assert read_run(tmp_path / "dem_points.h5", required=DEM_TRAJECTORY_VARIABLES).sizes["gp"] == 0
    assert run.sizes["step"] == STEPS + 1 and run.attrs["completed"] == 1
    assert_same(run, fem_ml_run, SAME + ("stress_spread", "stress_spread_relative"))
    assert not run.point_mode.values.any() and run.attrs["dem_particle_steps"] == 0
    assert run.attrs["method"] == "adaptive" and run.attrs["adaptive_threshold"] == np.inf
    # the indicator it records is FEM–ML's relative spread (the stress is the surrogate's everywhere)
    np.testing.assert_array_equal(run.indicator.values, fem_ml_run.stress_spread_relative.values)


@pytest.mark.needs_yade
def test_the_off_training_indicator_is_the_distance_to_the_training_states(setup, fem_ml_run, tmp_path):
    """Indicators off_training, distance and shear_strain at threshold ∞: the run is FEM–ML, and at
    each converged step it records d / r − 1 (0 inside), or d / r, of FEM–ML's inputs against the
    training states the model file keeps, or the equivalent shear strain √(2/3)·‖dev ε‖ of its
    strains; networks whose file keeps no training states are refused naming the key."""
    from granular_multiscale.analysis.problem_surrogate import run_features
    from granular_multiscale.novelty import TrainingStates
    from granular_multiscale.surrogate.models import SurrogateModel

    config, packings, sigma = setup
    config = {**config, "adaptive": {**config["adaptive"], "indicator": "off_training"}}
    run = run_adaptive(config, "p", np.inf, packings, sigma, None, "autodiff", n_workers=2)
    model = SurrogateModel.load(sigma)
    states = TrainingStates(model.training_states, radius=model.training_radius)
    ratio = states.distance(run_features(fem_ml_run, model.history)) / states.radius
    expected = np.maximum(ratio - 1.0, 0.0)
    np.testing.assert_allclose(run.indicator.values, expected, rtol=1e-9, atol=1e-12)
    assert (expected > 0).any() and (expected == 0).any()  # points inside the data and beyond it
    assert not run.point_mode.values.any()
    distance = {**config, "adaptive": {**config["adaptive"], "indicator": "distance"}}
    run = run_adaptive(distance, "p", np.inf, packings, sigma, None, "autodiff", n_workers=2)
    np.testing.assert_allclose(run.indicator.values, ratio, rtol=1e-9, atol=1e-12)
    assert len(np.unique(np.round(ratio[ratio < 1], 9))) > 1  # it ranks the states inside the data too
    shear = {**config, "adaptive": {**config["adaptive"], "indicator": "shear_strain"}}
    run = run_adaptive(shear, "p", np.inf, packings, sigma, None, "autodiff", n_workers=2)
    strain = fem_ml_run.strain.transpose("step", "gp", "comp").values
    deviator = strain - strain[..., :3].mean(axis=-1, keepdims=True) * np.array([1, 1, 1, 0, 0, 0])
    expected_shear = np.sqrt(2 / 3 * (deviator[..., :3] ** 2 + 2 * deviator[..., 3:] ** 2).sum(axis=-1))
    np.testing.assert_allclose(run.indicator.values, expected_shear, rtol=1e-9, atol=1e-15)
    assert expected_shear[-1].min() > 1e-3  # the strains of the path, not zeros
    model.training_states = None
    model.save(tmp_path / "without.pt")
    for cfg in (config, distance):
        with pytest.raises(ValueError, match="adaptive.indicator"):
            run_adaptive(cfg, "p", np.inf, packings, str(tmp_path / "without.pt"), None, "autodiff", n_workers=2)


@pytest.mark.needs_yade
def test_threshold_zero_and_all_anchors_are_fem_dem(setup, fem_dem_run):
    for run in (adaptive(setup, 0.0), adaptive(setup, np.inf, anchor_fraction=1.0)):
        assert_same(run, fem_dem_run, SAME + DEM_SAME)
        assert run.point_mode.values.all() and run.attrs["dem_point_fraction"] == 1.0
        # every point DEM from the first evaluation on: nothing to replay
        assert run.attrs["dem_replay_particle_steps"] == 0
        assert run.attrs["dem_particle_steps"] == fem_dem_run.attrs["dem_particle_steps"] > 0
    assert run.attrs["adaptive_anchors"] == 16 and int(run.promotions.sum()) == 0


RUNNER = """
import pickle, sys
from granular_multiscale.drivers.adaptive import run_adaptive
from granular_multiscale.runlog import setup_logging
config, threshold, packings, sigma, output, checkpoint = pickle.load(open(sys.argv[1], "rb"))
run_adaptive(config, "p", threshold, packings, sigma, None, "autodiff", output, checkpoint, 2, setup_logging(None))
"""


@pytest.fixture(scope="module")
def between(setup, fem_ml_run, tmp_path_factory):
    """(threshold, run, what its RVEs answered): FEM–ML's spread grows from step 1 to step 3 (1 % at
    most at step 1, 3 % at step 3; the networks are rough): a threshold in between promotes nobody
    at step 1, somebody by step 3. The run keeps a checkpoint (removed at the end)."""
    indicator = fem_ml_run.stress_spread_relative.values
    threshold = float(0.5 * (indicator[1].max() + indicator[3].max()))
    folder = tmp_path_factory.mktemp("between")
    run = adaptive(setup, threshold, checkpoint=folder / "full.ckpt", trajectories=folder / "dem_points.h5")
    assert not (folder / "full.ckpt").exists()  # removed after success
    return threshold, run, read_run(folder / "dem_points.h5", required=DEM_TRAJECTORY_VARIABLES)


@pytest.mark.needs_yade
def test_promotions_and_resume_after_kill(setup, between, fem_ml_run, fem_dem_run, tmp_path):
    """At the threshold between: the points whose spread reaches it go DEM (replaying their history),
    the others stay surrogate; killed after the first promotion and started again, the run ends with
    the numbers of the uninterrupted run."""
    threshold, run, _ = between
    mode = run.point_mode.values
    first = int(np.flatnonzero(mode.any(axis=1))[0])
    assert 2 <= first <= 3 and 0 < mode[-1].sum() < 16, mode.sum(axis=1)
    assert np.all(np.diff(mode, axis=0) >= 0)  # DEM once promoted
    assert np.array_equal(run.dem_points.values, mode.sum(axis=1))
    assert np.array_equal(run.promotions.values, np.diff(mode.sum(axis=1), prepend=0))
    # the converged state of every step: each surrogate point's indicator is below the threshold
    assert np.all(run.indicator.values[mode == 0] < threshold)
    # a promoted point replayed its history (one DEM increment per past commit); before it, FEM–ML exactly
    promoted = run.promotions.values > 0
    assert np.all(run.replay_particle_steps.values[promoted] > 0) and np.all(run.replay_particle_steps[~promoted] == 0)
    assert run.attrs["dem_replay_particle_steps"] == run.replay_particle_steps.sum()
    # DEM ran at the DEM points only: trials and replays together cost less than FEM–DEM at all 16
    assert 0 < run.attrs["dem_particle_steps"] < 0.9 * fem_dem_run.attrs["dem_particle_steps"]
    assert_same(run.isel(step=slice(0, first)), fem_ml_run.isel(step=slice(0, first)))
    assert not np.array_equal(run.stress.values[first:], fem_ml_run.stress.values[first:])

    config, packings, sigma = setup
    checkpoint, output = tmp_path / "killed.ckpt", tmp_path / "killed.h5"
    args = tmp_path / "args.pkl"
    args.write_bytes(pickle.dumps((config, threshold, packings, sigma, str(output), str(checkpoint))))

    def start():
        return subprocess.Popen([sys.executable, "-c", RUNNER, str(args)], stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True, start_new_session=True)

    proc, step, deadline = start(), -1, time.time() + 300
    while time.time() < deadline and proc.poll() is None and step < first + 1:
        try:
            step = pickle.loads(checkpoint.read_bytes())["step"]
        except Exception:
            pass
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert first + 1 <= step < STEPS and not output.exists(), proc.stderr.read()[-2000:]
    again = start()
    _, err = again.communicate(timeout=300)
    assert again.returncode == 0, err[-3000:]
    assert f"resuming from checkpoint {checkpoint} after step {step}" in err
    assert "DEM subset resumed" in err and "differ from the checkpoint" not in err
    resumed = read_run(output)
    assert_same(resumed, run, SAME + ("point_mode", "indicator", "promotions", "particle_steps",
                                      "replay_particle_steps", "stress_spread"))


@pytest.mark.needs_yade
def test_control_copies_the_promotions_and_answers_with_the_elastoplastic_model(setup, between, tmp_path):
    """Control (b): the networks replaced by the elastoplastic model, the DEM points and the steps of
    their promotions copied from the network run. The same points are DEM at every step (so the
    same DEM work where the strains agree); until the first promotion the run is FEM with the
    elastoplastic model at every point, bit for bit; after it, the DEM points answer from their RVEs."""
    threshold, run, points = between
    schedule = write_run(points, tmp_path / "dem_points.h5", required=DEM_TRAJECTORY_VARIABLES)
    control = adaptive(setup, threshold, control="elastoplastic", schedule_from=schedule)
    assert np.array_equal(control.point_mode.values, run.point_mode.values)
    assert control.attrs["adaptive_indicator"] == "schedule" and control.attrs["adaptive_control"] == "elastoplastic"
    assert "stress_spread" not in control and control.attrs["dem_particle_steps"] > 0
    first = int(np.flatnonzero(run.point_mode.values.any(axis=1))[0])
    model = run_fem_reference(setup[0], "p", tmp_path / "model.h5")
    assert_same(control.isel(step=slice(0, first)), model.isel(step=slice(0, first)))
    dem = control.point_mode.values[-1].astype(bool)
    assert not np.allclose(control.stress.values[-1][dem], model.stress.values[-1][dem], rtol=1e-3)
    with pytest.raises(ValueError, match="3 points, this run has 16"):
        write_run(points.isel(gp=slice(0, 1)).assign_attrs(n_points=3), tmp_path / "bad.h5",
                  required=DEM_TRAJECTORY_VARIABLES)
        adaptive(setup, threshold, control="elastoplastic", schedule_from=tmp_path / "bad.h5")


@pytest.mark.needs_yade
def test_dem_points_are_training_data(setup, between, fem_dem_run):
    """What the RVEs of the promoted points answered, along their whole histories (the past from the
    replay): the adaptive run's stresses where they ran DEM, a source for the dataset like an RVE-path
    set, held out by trajectory class."""
    from granular_multiscale.data import run_tangent
    from granular_multiscale.history import history_from_sequence
    from granular_multiscale.surrogate.dataset import build_dataset_from_sources
    from granular_multiscale.tensors import tangent_to_upper

    config, _, _ = setup
    _, run, points = between
    assert int(run.cutbacks.sum()) == 0  # so that commit k is load step k
    mode = run.point_mode.values
    assert np.array_equal(points.gp.values, np.flatnonzero(mode[-1])) and points.sizes["step"] == STEPS + 1
    assert np.array_equal(points.promoted_at.values, mode[:, points.gp.values].argmax(axis=0))
    assert points.valid.values.all() and np.isfinite(points.stress.values).all()
    np.testing.assert_array_equal(points.strain.values, run.strain.values[:, points.gp.values])
    np.testing.assert_array_equal(points.history.values, history_from_sequence(points.strain.values))
    np.testing.assert_array_equal(points.gp_position.values, run.gp_position.values[points.gp.values])
    for j, gp in enumerate(points.gp.values):
        dem = mode[:, gp] == 1  # the steps it answered from DEM: the run's stress and tangent
        np.testing.assert_array_equal(points.stress.values[dem, j], run.stress.values[dem, gp])
        np.testing.assert_array_equal(points.tangent.values[dem, j], tangent_to_upper(run_tangent(run)[dem, gp]))
        # before: its RVE's answers from the replay, not the surrogate's that the run shows
        before = np.flatnonzero(~dem)[1:]  # step 0 is the consolidated state of both
        assert np.abs(points.stress.values[before, j] - run.stress.values[before, gp]).min() > 0
    train, heldout = build_dataset_from_sources([("fem_dem", fem_dem_run), ("dem points", points)], 0.75, 0,
                                                history_tolerance=config["surrogate"]["history_tolerance"])
    source = np.concatenate([train.source.values, heldout.source.values])
    assert (source == "dem points").sum() == points.sizes["gp"] and train.valid.values.any()


@pytest.mark.needs_yade
def test_rule_writes_the_run_its_log_and_benchmark(setup, between, tmp_path):
    """`snakemake <out>/adaptive/t<threshold>/p.h5` with the packing and networks in place (only the
    rule adaptive may run): the run of the driver, with the threshold from adaptive.thresholds."""
    config, packings, sigma = setup
    threshold, run, points = between
    out = tmp_path / "out"
    L = Layout(out)
    for source, target in ((packings[0], L.packings(1)[0]), (sigma, L.model("sigma")),
                           (sigma, L.model("tangent"))):  # the autodiff tangent reads no ND
        target = Path(target)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(open(source, "rb").read())
    config = {**config, "output_dir": str(out), "adaptive": {**config["adaptive"], "thresholds": [threshold, 0.5]},
              "surrogate": {**config["surrogate"], "tangent": "autodiff"}}
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    target = Path(L.adaptive(f"t{threshold:g}", "p"))
    snakemake = Path(sys.executable).with_name("snakemake")
    result = subprocess.run([str(snakemake), "-j2", "--configfile", str(tmp_path / "config.yaml"), "--allowed-rules",
                             "adaptive", "--", str(target)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    written = read_run(target)
    assert written.attrs["adaptive_threshold"] == threshold
    assert_same(written, run, SAME + ("point_mode", "promotions", "replay_particle_steps"))
    # its control (rule adaptive_control): the elastoplastic model with the run's DEM points
    control = L.adaptive(f"t{threshold:g}_elastoplastic", "p")
    result = subprocess.run([str(snakemake), "-j2", "--configfile", str(tmp_path / "config.yaml"), "--allowed-rules",
                             "adaptive_control", "--", str(control)], cwd=ROOT, capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    control = read_run(control)
    assert control.attrs["adaptive_control"] == "elastoplastic" and control.attrs["adaptive_threshold"] == threshold
    assert np.array_equal(control.point_mode.values, run.point_mode.values)
    dem_points = read_run(L.adaptive_dem_points(f"t{threshold:g}", "p"), required=DEM_TRAJECTORY_VARIABLES)
    assert_same(dem_points, points, ("strain", "stress", "tangent", "valid", "promoted_at"))
    log = Path(L.log(f"adaptive/t{threshold:g}/p")).read_text()
    assert "promoted to DEM" in log and "particle-steps (trials" in log
    assert Path(L.benchmark(f"adaptive/t{threshold:g}/p")).exists()


@pytest.mark.needs_yade
def test_report_rows_curve_and_mode_map(setup, between, fem_ml_run, fem_dem_run, tmp_path):
    """With adaptive.report the adaptive runs are rows of the speedup and accuracy tables, a curve
    from FEM–ML to FEM–DEM in the speed-vs-error figure, and the mode map: here from the real runs."""
    from granular_multiscale.analysis import figures, products
    from granular_multiscale.data import write_run
    from granular_multiscale.surrogate.dataset import build_dataset_from_sources, write_dataset

    config, _, _ = setup
    threshold, run, _ = between
    labels = {"FEM–DEM": fem_dem_run, "FEM–ML": fem_ml_run, f"adaptive FEM–DEM–ML, threshold {threshold:g}": run}
    files = {label: str(write_run(ds, tmp_path / f"run{k}.h5")) for k, (label, ds) in enumerate(labels.items())}
    train, heldout = build_dataset_from_sources([(files["FEM–DEM"], fem_dem_run)], 0.75, 0,
                                                split=config["surrogate"]["split"],
                                                history_tolerance=config["surrogate"]["history_tolerance"])
    write_dataset(train, tmp_path / "train.h5")
    write_dataset(heldout, tmp_path / "heldout.h5")
    speed = products.make_speedup_outputs(files, tmp_path / "speedup.csv", tmp_path / "speedup.html", path_label="P",
                                          paper_reference=config["analysis"]["paper_reference"], machine="here")
    accuracy = products.make_accuracy_table(files, tmp_path / "train.h5", tmp_path / "heldout.h5",
                                            tmp_path / "accuracy.csv", tmp_path / "accuracy.html", path_label="P")
    adaptive_label = list(labels)[2]
    assert adaptive_label in speed["method"].tolist()
    errors = accuracy.set_index("method")["top_force_max_rel_pct"]
    # DEM at 8 of 16 points takes most of the way from FEM–ML's error to FEM–DEM's 0
    assert errors[adaptive_label] < 0.5 * errors["FEM–ML"]
    curve = ["FEM–ML", adaptive_label, "FEM–DEM"]
    table, _ = products.speed_error_table(tmp_path / "speedup.csv", tmp_path / "accuracy.csv", curve)
    assert table.set_index("label")["curve"].to_dict() == {"FEM–DEM": 2.0, "FEM–ML": 0.0, adaptive_label: 1.0}
    settings = {**config["analysis"], "field_steps": [2, 4, -1]}
    drawn = products.make_speed_vs_error(tmp_path / "speedup.csv", tmp_path / "accuracy.csv", tmp_path / "speed.png",
                                         settings, curve=curve)
    check.check_speed_vs_error(drawn, tmp_path / "speedup.csv", tmp_path / "accuracy.csv")
    for column, points in drawn.items():  # the line joins FEM–ML, the adaptive run and FEM–DEM, in that order
        check.assert_curve(points["curve"], [points[label][0] for label in curve],
                           [points[label][1] for label in curve], f"curve of {column}")
    modes = products.make_mode_map({adaptive_label: files[adaptive_label]}, tmp_path / "modes.png", settings,
                                   path_label="P")
    width = settings["figure_width"]
    check.check_png(tmp_path / "speed.png", products._size(settings, "speed"), products._dpi(settings))
    check.check_png(tmp_path / "modes.png", (width, 0.4 * width), products._dpi(settings))
    # the map's colour: the DEM share of the points at each (x, z), 2 behind each other on this mesh
    columns, share = figures.dem_share_xz(run, STEPS)
    assert len(columns) == 8 and np.isclose(2 * share.sum(), run.point_mode.values[STEPS].sum())
    position = run.gp_position.transpose("gp", "xyz").values
    mode = run.point_mode.transpose("step", "gp").values
    assert list(modes) == [adaptive_label] and list(modes[adaptive_label]) == [2, 4, run.sizes["step"] - 1]
    for step, (columns, share) in modes[adaptive_label].items():
        at = [np.isclose(position[:, 0], x) & np.isclose(position[:, 2], z) for x, z in columns]
        assert len(columns) == 8 and all(a.sum() == 2 for a in at)
        np.testing.assert_array_equal(share, [mode[step, a].mean() for a in at], err_msg=f"step {step}")


@pytest.mark.needs_yade
def test_one_round_of_active_learning(setup, between, fem_dem_run, tmp_path):
    """`snakemake active_learning` with the packing, the networks and the FEM–DEM run in place: the
    adaptive run at adaptive.active_learning.threshold (the run of `between`, bit for bit), its DEM
    points added to the training sources, NNσ and ND trained again, the adaptive run again with them,
    and the table of both rounds with FEM–ML, computed from those run files."""
    from granular_multiscale.analysis.tables import accuracy_row
    from granular_multiscale.data import write_run
    from granular_multiscale.surrogate.dataset import read_dataset

    config, packings, sigma = setup
    threshold, run, points = between
    out = tmp_path / "out"
    L = Layout(out)
    # in the order of their making, so that no rule but those of the round is out of date
    for source, target in ((packings[0], L.packings(1)[0]), (None, L.run("fem_dem", "p")),
                           (sigma, L.model("sigma")), (sigma, L.model("tangent"))):
        target = Path(target)
        target.parent.mkdir(parents=True, exist_ok=True)
        if source is None:
            write_run(fem_dem_run, target)
        else:
            target.write_bytes(open(source, "rb").read())
    config = {**config, "output_dir": str(out),
              "adaptive": {**config["adaptive"], "thresholds": [0.5], "active_learning": {"threshold": threshold}},
              "surrogate": {**config["surrogate"], "tangent": "autodiff"}}
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    rules = ["adaptive", "fem_ml", "dataset_active", "train_sigma_active", "train_tangent_active", "adaptive_active",
             "table_active_learning", "active_learning"]
    snakemake = Path(sys.executable).with_name("snakemake")
    result = subprocess.run([str(snakemake), "-j2", "--configfile", str(tmp_path / "config.yaml"), "--rerun-triggers",
                             "mtime", "--allowed-rules", *rules, "--", "active_learning"], cwd=ROOT,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    label = f"t{threshold:g}"
    first = read_run(L.adaptive(label, "p"))
    assert_same(first, run, SAME + ("point_mode", "promotions"))
    again = read_run(L.adaptive(label, "p", round="active/"))
    assert again.attrs["adaptive_threshold"] == threshold and again.attrs["surrogate_sigma_model"].endswith("active/models/nn_sigma.pt")
    # the round's training data: the pipeline's sources and the first run's DEM points
    sources = np.concatenate([read_dataset(L.dataset(split, round="active/")).source.values
                              for split in ("train", "heldout")])
    assert (sources == L.adaptive_dem_points(label, "p")).sum() == points.sizes["gp"] > 0
    assert (sources == L.run("fem_dem", "p")).sum() == 16
    table = pd.read_csv(L.table("active_learning.csv")).set_index("round")
    assert table.index.tolist() == ["FEM–ML", "first", "after one round"]
    for name, ds in (("first", first), ("after one round", again)):
        row = table.loc[name]
        assert row["promotions"] == int(ds.promotions.sum()) and row["dem_points_final"] == ds.attrs["dem_points_final"]
        assert row["dem_share_of_fem_dem"] == pytest.approx(ds.attrs["dem_particle_steps"]
                                                            / fem_dem_run.attrs["dem_particle_steps"])
        assert row["top_force_max_rel_pct"] == pytest.approx(accuracy_row(fem_dem_run, ds, "", "p")["top_force_max_rel_pct"])
    assert table.loc["first", "promotions"] == points.sizes["gp"] and table.loc["FEM–ML", "dem_particle_steps"] == 0


@pytest.mark.needs_yade
def test_kernel_correction_carries_the_dem_points_residual(setup, fem_ml_run, fem_dem_run):
    """Pass criterion: a quarter of the points as DEM anchors, no promotions. Without correction the
    other points answer with the rough networks (FEM–ML's error); with the kernel correction they add
    the residual their DEM neighbours in input space show, and the top force comes closer to
    FEM–DEM's than without it, at the same DEM work. Threshold ∞ without anchors stays FEM–ML."""
    def top_force_error(run):
        return float(curve_errors(fem_dem_run, run).query("quantity == 'top_force' and phase == 'all'")
                     ["max_error_percent_of_peak"].iloc[0])

    config, packings, sigma = setup
    runs = {}
    for correction, length in (("none", 0.05), ("kernel", 0.05), ("kernel", np.inf)):
        section = {**config["adaptive"], "anchor_fraction": 0.25, "correction": correction,
                   "correction_length": length}
        runs[correction, length] = run_adaptive({**config, "adaptive": section}, "p", np.inf, packings, sigma, None,
                                                "autodiff", n_workers=2)
    errors = {key: top_force_error(run) for key, run in runs.items()}
    print("top-force error, % of the peak:", errors, "FEM–ML", top_force_error(fem_ml_run))
    plain = runs["none", 0.05]
    assert plain.attrs["adaptive_correction"] == "none" and not plain.correction.values.any()
    for key in (("kernel", 0.05), ("kernel", np.inf)):
        run = runs[key]
        assert run.attrs["adaptive_correction"] == "kernel" and run.attrs["adaptive_correction_length"] == key[1]
        assert np.array_equal(run.point_mode.values, plain.point_mode.values)  # the same 4 anchors, nothing promoted
        assert run.correction.values[1:].min() > 0.0
        # measured 17.95 -> 1.06 % (length 0.05) and 2.08 % (infinite length): 0.06x and 0.12x
        assert errors[key] < 0.18 * errors["none", 0.05]
    section = {**config["adaptive"], "correction": "kernel"}
    alone = run_adaptive({**config, "adaptive": section}, "p", np.inf, packings, sigma, None, "autodiff", n_workers=2)
    assert_same(alone, fem_ml_run)


@pytest.mark.needs_yade
def test_a_corrected_points_tangent_holds_its_correction(setup):
    """Pass criterion: 4 of 16 points anchored in DEM, a correction on, after four commits of a
    strain history. At a surrogate point, central differences of the set's stress in that point's
    own strain equal its tangent to 1e-4 of the tangent's largest entry: the kernel (width 0.1, its
    values summing to more than 1 there) and the local kernel (width 0.02, summing to less: not
    normalised). With correction_tangent false the same differences miss the tangent by the
    correction's slope, at least 100 times more (measured 2.4 % and 19 % of its largest entry
    against 2e-7 and 4e-5). Perturbing one point moves no DEM point: its RVE answers the same
    trial from the same converged state."""
    config, packings, sigma = setup
    n, point = 16, 5
    strains = strain_history(n, 5)
    anchors = anchor_points(n, 0.25, 0)
    assert point not in anchors
    misses = {}
    for correction, length in (("kernel", 0.1), ("local_kernel", 0.02)):
        for with_tangent in (True, False):
            surrogate = surrogate_material(config, n, sigma, None, "autodiff")
            dem = DemSubsetMaterialPointSet(n, packings, SETTINGS, n_workers=2)
            material = AdaptiveMaterialPointSet(surrogate, dem, np.inf, 1e5, anchors=anchors, correction=correction,
                                                correction_length=length, correction_tangent=with_tangent)
            with material:
                for eps in strains[:4]:
                    material.evaluate(eps)
                    material.commit(eps)
                trial = strains[4]
                _, tangent = material.evaluate(trial)
                assert material._correction_now > 0.0  # the surrogate points did get a correction
                x = surrogate.trial_scaled_features()
                kernel_sum = np.exp(-((x[point] - x[anchors]) ** 2).sum(-1) / (2 * length**2)).sum()
                assert (kernel_sum > 1) == (correction == "kernel")
                h = 1e-7
                numeric = np.zeros((6, 6))
                for c in range(6):
                    up, down = trial.copy(), trial.copy()
                    up[point, c] += h
                    down[point, c] -= h
                    # tensorial shears in the strain, engineering ones in the tangent's columns
                    numeric[:, c] = ((material.evaluate(up)[0][point] - material.evaluate(down)[0][point])
                                     / (2 * h * ENGINEERING_FACTOR[c]))
            misses[correction, with_tangent] = np.abs(numeric - tangent[point]).max() / np.abs(tangent[point]).max()
    print("largest miss of the tangent, share of its largest entry:", misses)
    for correction in ("kernel", "local_kernel"):
        assert misses[correction, True] < 1e-4
        assert misses[correction, False] > 100 * misses[correction, True]
