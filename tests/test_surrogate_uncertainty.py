"""The uncertainty a FEM–ML run reports: the ensemble spread per Gauss point and
step in the run file, its checkpoint round trip and Gauss-point mapping, the out-of-range
margin of the strain features, and the calibration table and figure.

The networks are trained here in seconds on a synthetic material-point run of the
elastoplastic model (surrogate/synthetic.py): two NNσ from different seeds (an ensemble of 2),
and member 0 alone as the one-network model. Rough, but real networks."""

import logging
import warnings

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import KilledAfterCommits
from PIL import Image

from granular_multiscale.analysis import calibration
from granular_multiscale.config import validate_config
from granular_multiscale.data import read_run, write_run
from granular_multiscale.drivers.fem_ml import fem_ml_config, run_fem_ml, spread_variables
from granular_multiscale.drivers.reference import run_fem_reference
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.history import PHI, phi_variables
from granular_multiscale.materials.elastoplastic import Elastoplastic
from granular_multiscale.paths import load_paths_from_config
from granular_multiscale.surrogate.dataset import build_dataset
from granular_multiscale.surrogate.material import SurrogateMaterial, relative_spread, spread_floor
from granular_multiscale.surrogate.models import SurrogateModel
from granular_multiscale.surrogate.synthetic import material_point_run, triaxial_strain_paths
from granular_multiscale.surrogate.training import heldout_spread_scale, train
from granular_multiscale.tensors import voigt_to_tensor

# loading, unloading, reloading on the 1×1×2 mesh of config/tiny.yaml (16 Gauss points), rough platens
SHORT = {"segments": [[6, 0.006], [3, 0.003], [6, 0.012]]}
CONFIG = validate_config({
    "reference_material": "elastoplastic",
    "specimen": {"elements": [1, 1, 2]},
    "load_paths": {**validate_config({})["load_paths"], "short": SHORT},
    "surrogate": {"history_variables": ["phi1", "phi2"]},
})
FAST = dict(CONFIG["surrogate"], epochs=150, learning_rate=5e-3, batch_size=256, ensemble_size=2)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """{K: NNσ model file} for an ensemble of 2 and for its member 0 alone."""
    torch.set_num_threads(1)
    path = load_paths_from_config(CONFIG)["path1"]
    run = material_point_run(Elastoplastic.from_config(12, CONFIG), triaxial_strain_paths(path, 12, seed=2), path)
    sigma, _, _ = train(*build_dataset(run, 0.75, seed=0), "sigma", FAST, seed=0, config=CONFIG)
    assert sigma.ensemble_size == 2
    folder = tmp_path_factory.mktemp("models")
    sigma.save(folder / "k2.pt")
    one = SurrogateModel(sigma.members[0], sigma.kind, sigma.feature_names, sigma.target_names, sigma.architecture,
                         sigma.config, sigma.training, sigma.initial_state)
    one.save(folder / "k1.pt")
    return {2: folder / "k2.pt", 1: folder / "k1.pt"}


def fem_ml(model_file, config=CONFIG, **kwargs):
    return run_fem_ml(config, "short", model_file, None, "autodiff", progress=False, **kwargs)


@pytest.fixture(scope="module")
def runs(models, tmp_path_factory):
    """{K: FEM–ML run of the short path}, and the elastoplastic reference run."""
    folder = tmp_path_factory.mktemp("runs")
    out = {k: fem_ml(models[k]) for k in (1, 2)}
    out["reference"] = run_fem_reference(CONFIG, "short", str(folder / "reference.h5"))
    return out


def tensor_norm(v):
    return np.linalg.norm(voigt_to_tensor(v), axis=(-2, -1))


# -- the spread in the run file ----------------------------------------------------------------
def test_spread_columns_exist_finite_and_non_negative(runs):
    for k in (1, 2):
        ds = runs[k]
        assert ds.attrs["ensemble_size"] == k and ds.attrs["completed"] == 1
        assert ds.stress_spread.dims == ("step", "gp", "comp") and ds.stress_spread.shape == (16, 16, 6)
        assert ds.stress_spread_relative.dims == ("step", "gp") and ds.stress_spread_relative.shape == (16, 16)
        assert ds.stress_spread.attrs["units"] == "Pa" and ds.stress_spread.attrs["ensemble_size"] == k
        for name in ("stress_spread", "stress_spread_relative"):
            assert np.isfinite(ds[name].values).all() and (ds[name].values >= 0).all(), (k, name)
    # one network: exactly 0; two: 0 at the fresh state (each member anchored there), then real spread
    assert not runs[1].stress_spread.values.any() and not runs[1].stress_spread_relative.values.any()
    spread = runs[2].stress_spread.values
    assert np.abs(spread[0]).max() < 1e-6  # Pa, against stresses of 1e5
    assert (tensor_norm(spread[1:]) > 1.0).all()  # Pa, every later (step, point)


def test_spread_is_the_std_of_the_members_recomputed_from_the_run_file(runs, models):
    """At a few (step, gp): each member of the model file, anchored by its own offset, evaluated at the
    converged strain and φ recomputed from the file's strain history; their population std is the spread,
    their mean the run's stress, and the relative spread is ‖std‖ / max(‖σ‖, √3·p0)."""
    ds = runs[2]
    assert int(ds.cutbacks.sum()) == 0  # one commit per load step: the history below is the material's
    model = SurrogateModel.load(models[2])
    strain = ds.strain.transpose("step", "gp", "comp").values
    acc = np.cumsum(np.abs(np.diff(strain, axis=0, prepend=0.0)), axis=0)  # Δε_acc from the fresh state
    phi = phi_variables(acc)[..., [PHI.index(h) for h in model.history]]
    x0 = np.asarray(model.initial_state["features"])[None]
    target0 = np.asarray(model.initial_state["targets"])
    p0 = ds.attrs["confining_pressure_Pa"]
    for step, gp in ((1, 0), (7, 5), (9, 11), (15, 15)):
        x = np.concatenate([strain[step, gp], phi[step, gp]])[None]
        members = []
        for net in model.members:
            with torch.no_grad():
                at = lambda v: net(torch.as_tensor(v, dtype=torch.float64)).numpy()[0]  # noqa: E731
                members.append(at(x) + target0 - at(x0))
        members = np.array(members)
        np.testing.assert_allclose(ds.stress_spread.values[step, gp], members.std(axis=0), rtol=1e-7,
                                   atol=1e-9 * np.abs(members).max(), err_msg=f"step {step}, gp {gp}")
        np.testing.assert_allclose(ds.stress.values[step, gp], members.mean(axis=0), rtol=1e-9)
        expected = tensor_norm(members.std(axis=0)) / max(tensor_norm(members.mean(axis=0)), np.sqrt(3) * p0)
        assert ds.stress_spread_relative.values[step, gp] == pytest.approx(expected, rel=1e-7)
    assert spread_floor(1e5) == pytest.approx(173205.08, rel=1e-8)
    # below the floor the indicator divides by √3·p0: a spread of p0 in σ11 alone at zero stress -> 1/√3
    assert relative_spread(np.array([1e5, 0, 0, 0, 0, 0]), np.zeros(6), 1e5) == pytest.approx(1 / np.sqrt(3))


def test_spread_written_and_read_back(runs, tmp_path):
    back = read_run(write_run(runs[2], tmp_path / "fem_ml.h5", CONFIG))
    np.testing.assert_array_equal(back.stress_spread.values, runs[2].stress_spread.values)
    assert back.attrs["ensemble_size"] == 2 and back.stress_spread_relative.attrs["floor_Pa"] == spread_floor(1e5)


class KilledAfter(KilledAfterCommits, SurrogateMaterial):
    pass


def test_spread_survives_checkpoint_and_resume(runs, models, tmp_path, caplog):
    """Killed after step 6 by the solver's own checkpointing, then run_fem_ml resumes from the
    checkpoint: the spread of steps 0-6 comes from the checkpoint and equals the uninterrupted run's."""
    checkpoint = tmp_path / "short.ckpt"
    config = fem_ml_config(CONFIG)
    problem = TriaxialProblem.from_config(config)
    killed = KilledAfter(problem.n_material_points, SurrogateModel.load(models[2]), tangent="autodiff", commits=7)
    with pytest.raises(KeyboardInterrupt):
        problem.run(killed, load_paths_from_config(config)["short"], checkpoint=checkpoint, progress=False)
    assert checkpoint.exists()
    with caplog.at_level(logging.INFO):
        resumed = fem_ml(models[2], checkpoint=checkpoint)
    assert "resuming from checkpoint" in caplog.text and "after step 6" in caplog.text
    full = runs[2]
    np.testing.assert_allclose(resumed.stress_spread.values, full.stress_spread.values, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(resumed.stress_spread_relative.values, full.stress_spread_relative.values, rtol=1e-12)
    # a checkpoint without the spread record cannot be resumed (the solver sets it aside)
    state = killed.get_state()
    del state["stress_spread"]
    with pytest.raises(ValueError, match=r"7 committed states at 16 points holds an ensemble-spread record "
                                         r"of shape \(0, 16, 6\)"):
        SurrogateMaterial(problem.n_material_points, SurrogateModel.load(models[2]), tangent="autodiff").set_state(state)


def test_uniform_field_spread_has_the_run_gauss_points(models):
    """Under specimen.uniform_field one material point is evaluated; its spread stands for all 16
    Gauss points and equals that of the run evaluating every point (smooth platens: a uniform field)."""
    smooth = {**CONFIG["specimen"], "platen": "smooth"}
    every = fem_ml(models[2], validate_config({**CONFIG, "specimen": smooth}))
    one = fem_ml(models[2], validate_config({**CONFIG, "specimen": {**smooth, "uniform_field": True}}))
    assert (one.attrs["material_points"], every.attrs["material_points"]) == (1, 16)
    assert one.stress_spread.shape == every.stress_spread.shape == (16, 16, 6)
    np.testing.assert_array_equal(one.stress_spread.values, np.broadcast_to(one.stress_spread.values[:, :1],
                                                                           one.stress_spread.shape))
    np.testing.assert_allclose(one.stress_spread.values, every.stress_spread.values, rtol=1e-6, atol=1e-6)
    assert one.stress_spread.values[1:].min() > 0


def test_spread_per_step_is_that_of_the_last_commit_of_the_step(runs, models):
    """With cutbacks a load step commits several sub-steps: the run file takes the last one of each
    step. Record: a spread per commit [1, 2, 3, 4, 5, 6]; cutbacks [0, 2, 0] -> commits 1 | 2 3 4 | 5."""
    material = SurrogateMaterial(16, SurrogateModel.load(models[2]), tangent="autodiff")
    material._spread = [np.full((16, 6), float(c)) for c in range(1, 7)]
    ds = runs[2].isel(step=slice(0, 3)).copy()
    ds["cutbacks"] = ("step", np.array([0, 2, 0]))
    ds.attrs["completed"] = 0  # a run that stopped during step 3: its sub-step 6 is not in the file
    assert spread_variables(material, ds)["stress_spread"].values[:, 0, 0].tolist() == [1.0, 4.0, 5.0]
    ds.attrs["completed"] = 1
    with pytest.raises(RuntimeError, match="recorded 6 committed states.*make 5"):
        spread_variables(material, ds)


# -- out of range: the strains share one span ----------------------------------------------------
def symmetric_mesh_model(tmp_path):
    """An (untrained) NNσ whose training range has ε12 = ±4e-18 (zero on a symmetric mesh), the other
    strains spanning up to 4.5 %, φ1 in [0, 1] and φ2 in [0, 0.01]."""
    x_min = np.array([0.0, 0.0, -0.045, -0.004, -0.004, -4e-18, 0.0, 0.0])
    x_max = np.array([0.02, 0.02, 0.0, 0.004, 0.004, 4e-18, 1.0, 0.01])
    scaling = {"x_min": x_min, "x_max": x_max, "y_min": np.full(6, -3e5), "y_max": np.full(6, 0.0)}
    model = SurrogateModel.create("sigma", ("phi1", "phi2"), scaling, CONFIG["surrogate"])
    model.save(tmp_path / "symmetric.pt")
    return SurrogateModel.load(tmp_path / "symmetric.pt")


@pytest.mark.parametrize("strain, flagged, excess", [
    # ε12 = 1e-4: within 1 % of the strains' 4.5 % span (the former rule: 1e13 ranges of its own ±4e-18 out)
    ([0.002, 0.002, -0.006, 0.0, 0.0, 1e-4], 0, 0.0),
    # ε12 = 1e-3: out by (1e-3 − 4e-18 − 0.01·0.045 − 1e-9·0.045) / 0.045 strain ranges
    ([0.002, 0.002, -0.006, 0.0, 0.0, 1e-3], 1, (1e-3 - 4e-18 - 4.5e-4 - 4.5e-11) / 0.045),
    # φ2 = |ε11| + |ε22| + |ε33| = 0.0103: φ keeps its own span, out by (0.0103 − 0.0101 − 1e-11) / 0.01
    ([0.002, 0.002, -0.0063, 0.0, 0.0, 0.0], 1, (0.0103 - 0.0101 - 1e-11) / 0.01),
])
def test_out_of_range_margin_of_the_strains_is_their_shared_span(tmp_path, strain, flagged, excess):
    model = symmetric_mesh_model(tmp_path)
    material = SurrogateMaterial(1, model, tangent="autodiff", out_of_range_tolerance=0.01, anchor_initial_state=False)
    material.evaluate(np.array([strain]))
    material.commit()
    info = material.step_info()
    assert info["out_of_range_points"] == flagged
    assert info["out_of_range_excess"] == pytest.approx(excess, rel=1e-6, abs=1e-15)


# -- calibration ---------------------------------------------------------------------------------
def test_calibration_of_a_constructed_pair_error_twice_the_spread(runs, tmp_path):
    """Reference = the FEM–ML stress minus 2 × its spread, component by component: the realised error
    is 2 × the spread at every (step, point), so every decile has median error / spread 2, median
    error 2 × median spread, and the rank correlation is 1."""
    run = runs[2]
    reference = run.copy()
    reference["stress"] = run.stress - 2.0 * run.stress_spread
    files = {name: write_run(ds, tmp_path / f"{name}.h5", CONFIG) for name, ds in (("ml", run), ("ref", reference))}
    out = {k: tmp_path / f"calibration.{k}" for k in ("png", "csv", "html")}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no log-of-zero or empty-slice warnings
        _, drawn = calibration.make_calibration(files["ml"], files["ref"], out["png"], out["csv"], out["html"], {},
                                                path_label="Short", reference_label="constructed",
                                                surrogate_label="FEM–ML")
    table = pd.read_csv(out["csv"])
    deciles, everything = table.iloc[:-1], table.iloc[-1]
    assert list(deciles.decile) == [str(d) for d in range(1, 11)] and everything.decile == "all"
    assert deciles["count"].tolist() == [24] * 10 and everything["count"] == 240  # 15 load steps × 16 points
    # the CSV's 10 digits, and σ − (σ − 2s) is 2s to round-off of σ (1e5 Pa) only
    np.testing.assert_allclose(deciles.median_error_over_spread, 2.0, rtol=1e-8)
    np.testing.assert_allclose(deciles.median_error_kpa, 2.0 * deciles.median_spread_kpa, rtol=1e-8)
    np.testing.assert_allclose(deciles.p90_error_kpa, 2.0 * np.array([np.percentile(
        np.sort(calibration.calibration_points(run, reference).spread_kpa)[24 * d:24 * (d + 1)], 90)
        for d in range(10)]), rtol=1e-8)
    assert (np.diff(deciles.median_spread_kpa) > 0).all()
    # 1 up to the order within pairs of mirror-image points, whose spreads agree to round-off
    assert everything.spearman_spread_error == pytest.approx(1.0, abs=1e-5)
    # the figure: every (step >= 1, point) pair at (spread, error = 2 spread), the deciles of the table,
    # and per step the median and 90th percentile of both over the points
    spread = tensor_norm(run.stress_spread.values[1:]) / 1e3  # [step, gp], kPa
    x, y = drawn["error_vs_spread"]["pairs"]
    np.testing.assert_allclose(x, spread.ravel(), rtol=5e-16)  # measured 3.6e-16: another order of the sum
    np.testing.assert_allclose(y, 2.0 * x, rtol=1.2e-14)  # measured 7.8e-15: the round-off of σ
    for label, column in (("median error per spread decile", "median_error_kpa"),
                          ("90th percentile per decile", "p90_error_kpa")):
        deciles_x, deciles_y = drawn["error_vs_spread"][label]
        # the CSV's 10 digits: measured 1.5e-10 and 4.6e-10
        np.testing.assert_allclose(deciles_x, deciles.median_spread_kpa, rtol=7e-10)
        np.testing.assert_allclose(deciles_y, deciles[column], rtol=7e-10)
    steps = run.step.values[1:]
    for label, values in (("spread, median", np.median(spread, axis=1)),
                          ("spread, 90th percentile", np.percentile(spread, 90, axis=1)),
                          ("error, median", 2.0 * np.median(spread, axis=1)),
                          ("error, 90th percentile", 2.0 * np.percentile(spread, 90, axis=1))):
        np.testing.assert_array_equal(drawn["per_step"][label][0], steps)
        np.testing.assert_allclose(drawn["per_step"][label][1], values, rtol=4e-15, err_msg=label)  # measured 2.7e-15
    with Image.open(out["png"]) as image:
        assert image.size == (1200, 504)  # 10 x 4.2 inches at 120 dpi
    html = out["html"].read_text()
    assert "ensemble of 2 members" in html and "Spearman" in html


def test_calibration_points_and_deciles_by_hand():
    """Spreads 1..100 kPa in σ11 alone (norm = the value), errors twice that: decile d holds
    10(d−1)+1 .. 10d, median 10(d−1) + 5.5 kPa."""
    points = pd.DataFrame({"step": np.repeat(np.arange(1, 11), 10), "gp": np.tile(np.arange(10), 10),
                           "phase": "loading", "spread_kpa": np.arange(100, 0, -1.0)})
    points["relative_spread"] = points.spread_kpa / 173.2
    points["error_kpa"] = 2 * points.spread_kpa
    table = calibration.calibration_table(points)
    np.testing.assert_allclose(table.median_spread_kpa[:10], 10 * np.arange(10) + 5.5)
    np.testing.assert_allclose(table.spread_min_kpa[:10], 10 * np.arange(10) + 1)
    last = table.iloc[-1]
    assert (last["count"], last.median_spread_kpa, last.median_error_kpa) == (100, 50.5, 101.0)
    assert last.p90_error_kpa == pytest.approx(2 * 90.1)
    assert last.spearman_spread_error == pytest.approx(1.0) and last.spearman_relative_spread_error == pytest.approx(1.0)
    # an error that falls as the spread grows: ρ = −1
    points["error_kpa"] = 1.0 / points.spread_kpa
    assert calibration.calibration_table(points).iloc[-1].spearman_spread_error == pytest.approx(-1.0)
    steps = calibration.step_summary(points.assign(error_kpa=2 * points.spread_kpa))
    assert steps.step.tolist() == list(range(1, 11)) and steps.median_error_kpa[0] == pytest.approx(2 * 95.5)


def test_calibration_with_one_network_says_the_spread_is_empty(runs, tmp_path):
    """K = 1 against the real elastoplastic reference: the figure builds without warnings and says the
    ensemble has one member; the table has only the row "all", with the error statistics and no ρ."""
    files = {name: write_run(ds, tmp_path / f"{name}.h5", CONFIG) for name, ds in
             (("ml", runs[1]), ("ref", runs["reference"]))}
    out = {k: tmp_path / f"calibration.{k}" for k in ("png", "csv", "html")}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        table, drawn = calibration.make_calibration(files["ml"], files["ref"], out["png"], out["csv"], out["html"],
                                                    {"dpi": 80}, path_label="Short", reference_label="elastoplastic",
                                                    surrogate_label="FEM–ML")
    assert list(table.decile) == ["all"] and table["count"].iloc[0] == 240
    assert np.isnan(table.spearman_spread_error.iloc[0]) and np.isnan(table.median_error_over_spread.iloc[0])
    error = tensor_norm(runs[1].stress.values[1:] - runs["reference"].stress.values[1:]) / 1e3
    assert table.median_error_kpa.iloc[0] == pytest.approx(np.median(error), rel=1e-12)
    assert table.median_error_kpa.iloc[0] > 0.1  # kPa: rough networks, a real error
    assert "ensemble of 1 member: the spread is 0 and carries no information" in out["html"].read_text()
    # the figure: no pairs (no spread), the error's median and 90th percentile over the points per step
    assert drawn["error_vs_spread"] == {} and list(drawn["per_step"]) == ["error, median", "error, 90th percentile"]
    for label, values in (("error, median", np.median(error, axis=1)),
                          ("error, 90th percentile", np.percentile(error, 90, axis=1))):
        np.testing.assert_array_equal(drawn["per_step"][label][0], runs[1].step.values[1:])
        # measured 2.2e-16, and 4.1e-16 with networks that differ from those by round-off
        np.testing.assert_allclose(drawn["per_step"][label][1], values, rtol=1e-15, err_msg=label)
    with Image.open(out["png"]) as image:
        assert image.size == (800, 336)  # 10 x 4.2 inches at 80 dpi


def test_calibration_names_a_run_without_spread(runs):
    old = runs[2].drop_vars(["stress_spread", "stress_spread_relative"])
    with pytest.raises(calibration.CalibrationError, match="old.h5 has no 'stress_spread'.*rule fem_ml"):
        calibration.calibration_points(old, runs["reference"], label="old.h5")


# ------------------------------------------------------------------ the spread's scale on held-out data


@pytest.fixture(scope="module")
def heldout():
    """The held-out side of the dataset the models fixture trained on (the same run, split and seed)."""
    path = load_paths_from_config(CONFIG)["path1"]
    run = material_point_run(Elastoplastic.from_config(12, CONFIG), triaxial_strain_paths(path, 12, seed=2), path)
    return build_dataset(run, 0.75, seed=0)[1]


def test_heldout_spread_scale_is_what_the_material_reports_along_the_heldout_histories(models, heldout):
    """The scale recomputed independently: the surrogate material (as FEM–ML runs it) driven along each
    held-out trajectory's strain history, committing every step, gives the stress and the spread of
    each (step ≥ 1, trajectory); the median of their error over spread is the scale."""
    model = SurrogateModel.load(models[2])
    scale = heldout_spread_scale(model, heldout)
    strain, stress = heldout.strain.transpose("step", "gp", "comp").values, heldout.stress.transpose("step", "gp", "comp").values
    material = SurrogateMaterial(heldout.sizes["gp"], model, tangent="autodiff")
    errors = []
    for step in range(1, heldout.sizes["step"]):
        sigma, _ = material.evaluate(strain[step], need_tangent=False)
        material.commit()
        errors.append(tensor_norm(sigma - stress[step]))
    spread = tensor_norm(material.stress_spread)
    ratio = np.asarray(errors) / spread
    assert heldout.valid.values.all() and scale["pairs"] == ratio.size == (heldout.sizes["step"] - 1) * heldout.sizes["gp"]
    assert scale["trajectories"] == heldout.sizes["gp"] == 3  # a quarter of the 12 trajectories
    assert scale["scale"] == pytest.approx(np.median(ratio), rel=1e-9)
    assert scale["p10_error_over_spread"] == pytest.approx(np.percentile(ratio, 10), rel=1e-9)
    assert scale["scale"] > 1.0  # members trained on the same data agree more than they are right
    one = heldout_spread_scale(SurrogateModel.load(models[1]), heldout)
    assert one["pairs"] == 0 and np.isnan(one["scale"])  # one network: no spread to scale


def test_calibration_against_the_scaled_spread_of_a_constructed_pair(runs, tmp_path):
    """Error = 2 × spread at every point, scale 2 at half of the points and 4 at the others: error /
    (scale × spread) is 1 and 0.5 there, the figure draws error = 3 × spread (the points' median
    scale), and a scale table without the specimen's row, or scales for other points, are refused."""
    run = runs[2]
    reference = run.copy()
    reference["stress"] = run.stress - 2.0 * run.stress_spread
    scales = np.where(np.arange(run.sizes["gp"]) < 8, 2.0, 4.0)
    points = calibration.calibration_points(run, reference, spread_scale=scales)
    ratio = points.error_kpa / points.scaled_spread_kpa
    np.testing.assert_allclose(ratio[points.gp < 8], 1.0, rtol=1e-8)
    np.testing.assert_allclose(ratio[points.gp >= 8], 0.5, rtol=1e-8)
    assert calibration.calibration_table(points).iloc[-1].median_error_over_scaled_spread == pytest.approx(0.75)
    files = {name: write_run(ds, tmp_path / f"{name}.h5", CONFIG) for name, ds in (("ml", run), ("ref", reference))}
    out = {k: tmp_path / f"calibration.{k}" for k in ("png", "csv", "html")}
    table, drawn = calibration.make_calibration(files["ml"], files["ref"], out["png"], out["csv"], out["html"], {},
                                                path_label="Short", reference_label="constructed",
                                                surrogate_label="FEM–ML", spread_scales={"specimen": 2.0})
    np.testing.assert_allclose(table.median_error_over_scaled_spread, 1.0, rtol=1e-8)
    x, y = drawn["error_vs_spread"]["error = 2.00 × spread (the held-out trajectories' scale)"]
    np.testing.assert_allclose(y, 2.0 * x)
    assert "median error / (scale × spread)" in out["html"].read_text()
    with pytest.raises(calibration.CalibrationError, match="short.h5: \\(3,\\) spread scales for its 16 Gauss points"):
        calibration.calibration_points(run, reference, label="short.h5", spread_scale=np.ones(3))
    pd.DataFrame({"networks": ["weak_zone"], "scale": [3.0]}).to_csv(tmp_path / "scales.csv", index=False)
    with pytest.raises(calibration.CalibrationError, match="scales.csv: not a spread-scale table.*'specimen'"):
        calibration.read_spread_scales(tmp_path / "scales.csv")


def test_the_weak_zone_points_get_the_weak_zone_networks_scale(runs):
    """A run that names the weak zone's networks: the points within the zone's radius (x–z plane) take
    the row 'weak_zone', the others the specimen's; without that row the run is refused by name."""
    run = runs[2].copy()
    xz = run.gp_position.transpose("gp", "xyz").values[:, [0, 2]]
    centre = xz[5]
    radius = 0.5 * np.sort(np.linalg.norm(xz - centre, axis=1))[1]  # holds point 5 (and its twins) only
    run.attrs.update({"surrogate_weak_zone_sigma_model": "weak.pt", "weak_zone_center_m": centre.tolist(),
                      "weak_zone_radius_m": radius})
    scales = calibration.point_spread_scales(run, {"specimen": 2.0, "weak_zone": 5.0})
    inside = np.linalg.norm(xz - centre, axis=1) <= radius
    assert inside[5] and inside.sum() < run.sizes["gp"]
    np.testing.assert_array_equal(scales, np.where(inside, 5.0, 2.0))
    with pytest.raises(calibration.CalibrationError, match="run.h5 has the weak zone's networks.*'weak_zone'"):
        calibration.point_spread_scales(run, {"specimen": 2.0}, label="run.h5")
    np.testing.assert_array_equal(calibration.point_spread_scales(runs[2], {"specimen": 2.0}), 2.0)
