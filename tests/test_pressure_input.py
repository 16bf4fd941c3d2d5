"""The consolidation pressure p0 as a network input: RVE-path sets of packings consolidated at g·p0,
the dataset's p0 column, the fresh state anchored at any pressure, and FEM–ML giving the networks
the specimen's pressure. The analytic elastoplastic model stands in for the RVEs: its fresh state at
pressure p is exactly −p·1 and its strength grows with p, so what the networks must learn is known."""

import json
import logging
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from granular_multiscale.analysis.problem_surrogate import run_features
from granular_multiscale.config import ConfigError, validate_config
from granular_multiscale.drivers.fem_ml import surrogate_attributes, surrogate_material
from granular_multiscale.drivers.rve_paths import run_rve_paths
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.paths import LoadPath
from granular_multiscale.plan import Plan
from granular_multiscale.surrogate.dataset import (DatasetError, build_dataset_from_sources, consolidation_pressures,
                                                   features, targets)
from granular_multiscale.surrogate.material import SurrogateMaterial
from granular_multiscale.surrogate.models import SurrogateModel, fresh_state_at
from granular_multiscale.surrogate.training import train

ROOT = Path(__file__).resolve().parents[1]

ONE = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
HISTORY = ["phi1", "phi2", "p0"]
# the random walks give the shear stiffness: a set of triaxial paths alone never shears
SETS = {name: {"triaxial": 6, "axisymmetric": 2, "random_walk": 6, "n_steps": 30, "seed_offset": k,
               "consolidation_pressure": g} for k, (name, g) in enumerate((("low", 0.5), ("high", 2.0)))}


def config_with(sets=SETS, **top) -> dict:
    config = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    config["rve_paths"] = {"sets": sets}
    config["surrogate"].update(training_sources=[f"rve_paths:{name}" for name in sets], weak_zone_sources=[],
                               history_variables=HISTORY)
    config.update(reference_material="elastoplastic", **top)
    return validate_config(config)


CONFIG = config_with()
P0 = CONFIG["specimen"]["confining_pressure"]


@pytest.fixture(scope="module")
def sets(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sets")
    return {name: run_rve_paths(CONFIG, name, [], folder / f"{name}.h5", None, 1) for name in SETS}


@pytest.fixture(scope="module")
def data(sets):
    return build_dataset_from_sources(list(sets.items()), 0.75, seed=0)


@pytest.fixture(scope="module")
def networks(data, tmp_path_factory):
    """NNσ with p0 among its inputs, trained for a few seconds on both sets."""
    torch.manual_seed(0)
    model, _, _ = train(*data, "sigma", dict(CONFIG["surrogate"], epochs=60, log_every=1000), seed=0)
    path = tmp_path_factory.mktemp("networks") / "sigma.pt"
    model.save(path)
    return path


def config_at(pressure):
    return config_with(specimen={"confining_pressure": pressure})


def test_a_set_consolidated_at_another_pressure_refers_its_stresses_to_it(sets):
    """Set `high` (g = 2): it starts from −2·p0·1, its triaxial trajectories hold −f·2·p0 across,
    and its file records 2·p0 as the pressure its RVEs were consolidated at."""
    high = sets["high"]
    assert high.attrs["confining_pressure"] == 2 * P0 and sets["low"].attrs["confining_pressure"] == 0.5 * P0
    np.testing.assert_allclose(high.stress.values[0], np.tile(-2 * P0 * ONE, (14, 1)), rtol=1e-12)
    fractions = np.array([p["lateral_stress_fraction"] for p in trajectory_parameters(high) if "lateral_stress_fraction" in p])
    lateral = high.stress.values[1:, high.family.values == "triaxial", :2]
    error = np.abs(lateral + 2 * P0 * fractions[None, :, None]) / (2 * P0 * fractions[None, :, None])
    assert np.median(error) < 2e-3, np.median(error)


def trajectory_parameters(ds):
    return json.loads(ds.attrs["trajectory_parameters"])


def test_the_dataset_holds_p0_per_trajectory_and_names_a_source_without_it(sets, data):
    train_ds, heldout = data
    for ds in (train_ds, heldout):
        expected = np.where(ds.source.values == "low", 0.5 * P0, 2 * P0)
        np.testing.assert_array_equal(consolidation_pressures(ds), expected)
        x = features(ds, HISTORY)
        assert x.shape[1] == 9 and set(np.unique(x[:, -1])) == {0.5 * P0, 2 * P0}
    assert "confining_pressure_Pa" not in train_ds.attrs  # the sources differ: no one training pressure
    assert train_ds.feature_min.sel(feature="p0") == 0.5 * P0 and train_ds.feature_max.sel(feature="p0") == 2 * P0
    silent = sets["low"].copy()
    del silent.attrs["confining_pressure"]
    mixed, _ = build_dataset_from_sources([("high", sets["high"]), ("silent.h5", silent)], 0.75, seed=0)
    assert np.isnan(mixed.feature_min.sel(feature="p0"))
    features(mixed, ["phi1"])  # networks without p0 do not need it
    with pytest.raises(DatasetError, match=r"p0: the training sources \['silent.h5'\] record no confining pressure"):
        features(mixed, HISTORY)


def test_the_fresh_state_is_anchored_at_any_pressure(networks):
    """Zero strain gives −p·1 at the training pressures and between and beyond them (linear in p:
    the consolidated stress is), with no prestrain and no warning."""
    model = SurrogateModel.load(networks)
    assert model.feature_names[-1] == "p0" and model.takes_pressure and model.history == ("phi1", "phi2", "p0")
    assert [s["pressure"] for s in model.initial_state["by_pressure"]] == [0.5 * P0, 2 * P0]
    for pressure in (0.5 * P0, P0, 2 * P0, 3 * P0):
        material = surrogate_material(config_at(pressure), 4, networks, None, "autodiff")
        assert type(material) is SurrogateMaterial and material.consolidation_pressure == pressure
        np.testing.assert_allclose(material.evaluate(np.zeros((4, 6)))[0], np.tile(-pressure * ONE, (4, 1)),
                                   rtol=1e-9, atol=1e-9 * pressure)
        assert surrogate_attributes(material, networks, None)["surrogate_consolidation_pressure_Pa"] == pressure
    halfway = fresh_state_at(model.initial_state["by_pressure"], 1.25 * P0)
    np.testing.assert_allclose(halfway["targets"], -1.25 * P0 * ONE, rtol=1e-12)
    assert halfway["features"][-1] == pytest.approx(1.25 * P0) and not np.any(halfway["features"][:-1])
    with pytest.raises(ValueError, match="take p0"):
        SurrogateMaterial(4, model, tangent="autodiff")
    with pytest.raises(ValueError, match="consolidation pressure"):
        model.initial_offset()


def test_the_networks_answer_for_the_pressure_they_are_given(data, networks):
    """Fed its own p0, each held-out trajectory is predicted better than fed the other set's: the
    networks use the input (the elastoplastic strength is proportional to p)."""
    model = SurrogateModel.load(networks)
    heldout = data[1]
    x, y = features(heldout, HISTORY), targets(heldout, "sigma")
    swapped = x.copy()
    swapped[:, -1] = np.where(x[:, -1] == 2 * P0, 0.5 * P0, 2 * P0)
    own, other = (np.abs(model.predict(z) - y).mean() for z in (x, swapped))
    assert own < 0.5 * other, (own, other)


def test_the_autodiff_tangent_holds_p0_fixed(networks):
    """d(features)/d(strain) has a zero row for p0: the autodiff tangent is the finite-difference one."""
    material = surrogate_material(config_at(1.5 * P0), 2, networks, None, "autodiff")
    strain = np.array([[2e-4, 1e-4, -1e-3, 1e-5, 0.0, 2e-5], [1e-4, 1e-4, -5e-4, 0.0, 1e-5, 0.0]])
    _, tangent = material.evaluate(strain)
    h = 1e-7
    for j in range(6):
        step = np.zeros(6)
        step[j] = h if j < 3 else h / 2  # engineering shear
        plus, minus = material.evaluate(strain + step)[0], material.evaluate(strain - step)[0]
        np.testing.assert_allclose(tangent[:, :, j], (plus - minus) / (2 * h), rtol=1e-4, atol=1e-4 * np.abs(tangent).max())


def test_fem_ml_starts_in_equilibrium_at_a_pressure_between_the_sets(networks, caplog):
    """A specimen at 1.5·p0, which no set was consolidated at: step 0 needs no Newton correction."""
    with caplog.at_level(logging.INFO):
        material = surrogate_material(config_at(1.5 * P0), 8, networks, None, "autodiff")
    assert "networks that take the consolidation pressure p0: 150000 Pa" in caplog.text
    problem = TriaxialProblem(elements=(1, 1, 1), platen="smooth", confining_pressure=1.5 * P0)
    ds = problem.run(material, LoadPath("short", ((3, 3e-3),)), progress=False)
    assert int(ds.newton_iterations.values[0]) == 0 and int(ds.cutbacks.sum()) == 0
    np.testing.assert_allclose(ds.stress.values[0], np.tile(-1.5 * P0 * ONE, (8, 1)), rtol=1e-9, atol=1e-6)
    features_along = run_features(ds.assign_attrs(confining_pressure_Pa=1.5 * P0), ("phi1", "phi2", "p0"))
    assert features_along.shape[-1] == 9 and np.all(features_along[..., -1] == 1.5 * P0)


def test_a_set_at_another_pressure_drives_packings_of_its_own(tmp_path):
    config = config_with(output_dir=str(tmp_path))
    config["reference_material"] = "dem"
    plan = Plan(config)
    assert plan.rve_path_packings("low") == [str(tmp_path / "rve_p0.5" / "packing_0.yade.gz")]
    assert plan.rve_path_packings("high") == [str(tmp_path / "rve_p2" / "packing_0.yade.gz")]
    weak = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    weak["rve_paths"] = {"sets": {"band_weak": {"plane_strain": 2, "packing": "weak_zone", "consolidation_pressure": 2}}}
    weak["surrogate"].update(training_sources=["path1"], weak_zone_sources=["rve_paths:band_weak"])
    with pytest.raises(ConfigError, match=r"'rve_paths.sets.band_weak.consolidation_pressure': 2 needs the specimen"):
        validate_config(weak)
