"""IsotropicPrestrain: a material set consolidated at p0 taken by an isotropic strain to another
confining pressure (the analytic elastoplastic set, whose answer is known), and the FEM–ML wiring
that puts networks trained at p0 on a specimen at another pressure (surrogate.other_pressure)."""

import logging

import numpy as np
import pytest
import torch

from granular_multiscale.config import validate_config
from granular_multiscale.drivers.fem_ml import (at_specimen_pressure, spread_variables, surrogate_attributes,
                                                surrogate_material)
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.materials import make_material
from granular_multiscale.materials.elastoplastic import Elastoplastic
from granular_multiscale.materials.wrappers import IsotropicPrestrain
from granular_multiscale.paths import LoadPath, load_paths_from_config
from granular_multiscale.surrogate.dataset import build_dataset
from granular_multiscale.surrogate.material import SurrogateMaterial
from granular_multiscale.surrogate.models import SurrogateModel
from granular_multiscale.surrogate.synthetic import material_point_run, triaxial_strain_paths
from granular_multiscale.surrogate.training import train

CONFIG = validate_config({"reference_material": "elastoplastic"})
P0 = CONFIG["specimen"]["confining_pressure"]
ONE = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])


def elastoplastic(n=3, initial_stress="consolidated"):
    return Elastoplastic.from_config(n, CONFIG, initial_stress=initial_stress)


def mean_stress(stress):
    return -stress[:, :3].sum(axis=1) / 3.0


class Counted(Elastoplastic):
    """The elastoplastic set counting its evaluations and commits."""

    evaluations = commits = 0

    def evaluate(self, strain, need_tangent=True):
        self.evaluations += 1
        return super().evaluate(strain, need_tangent)

    def commit(self, strain=None):
        self.commits += 1
        super().commit(strain)


# ------------------------------------------------------------------------------ the wrapper
@pytest.mark.parametrize("pressure", [3.0e4, 5.0e4, 3.0e5, 4.0e5])
def test_zero_strain_gives_the_target_pressure_reached_by_an_isotropic_strain(pressure):
    """The inner set's mean stress at e0·1 is the target within 1e-6 of it; e0 is the elastic one,
    (p0 − p)/(3K) per component (isotropic loading is elastic in this model); zero strain then gives
    −p·1 to round-off, with the inner tangent at e0. Only trial evaluations find it: one commit."""
    inner = make_material("elastoplastic", 3, CONFIG)
    counted = Counted.from_config(3, CONFIG)
    for material in (inner, counted):
        wrapped = IsotropicPrestrain(material, pressure)
        e0 = wrapped.prestrain[:, 0]
        np.testing.assert_array_equal(wrapped.prestrain, e0[:, None] * ONE)
        assert np.all(np.sign(e0) == np.sign(P0 - pressure))  # compression (e < 0) to a higher pressure
        np.testing.assert_allclose(e0, (P0 - pressure) / (3 * material.bulk), rtol=1e-5)
        inner_stress, inner_tangent = material.evaluate(wrapped.prestrain)
        assert np.abs(mean_stress(inner_stress) - pressure).max() <= 1e-6 * pressure
        stress, tangent = wrapped.evaluate(np.zeros((3, 6)))
        np.testing.assert_allclose(stress, np.tile(-pressure * ONE, (3, 1)), rtol=1e-14, atol=0)
        np.testing.assert_array_equal(tangent, inner_tangent)
        assert wrapped.offset_norm < 1e-6 * pressure  # an isotropic fresh state: nothing but the search tolerance
    assert counted.commits == 1 and counted.evaluations > 3


def test_later_evaluations_are_the_inner_ones_from_the_prestrain_plus_the_offset():
    """A fresh state that is not isotropic (point 1) leaves its deviatoric stress in the offset;
    every later evaluation is the inner set's at e0·1 + ε plus that constant, the tangent the inner
    one, through commits and into plasticity, as an inner set driven from e0 by hand gives it."""
    sigma0 = np.array([-P0 * ONE, [-0.95 * P0, -1.0 * P0, -1.05 * P0, 2.0e3, -1.0e3, 0.0]])
    pressure = 2.0e5
    wrapped = IsotropicPrestrain(elastoplastic(2, sigma0), pressure)
    e0 = wrapped.prestrain
    by_hand = elastoplastic(2, sigma0)
    start, _ = by_hand.evaluate(e0)
    by_hand.commit()
    np.testing.assert_allclose(wrapped.offset, -pressure * ONE - start, rtol=0, atol=0)
    deviator = start + mean_stress(start)[:, None] * ONE
    np.testing.assert_allclose(wrapped.offset + deviator, 0.0, atol=1e-6 * pressure)
    assert wrapped.offset_norm == pytest.approx(np.sqrt((deviator[1] ** 2 * [1, 1, 1, 2, 2, 2]).sum()), rel=1e-6)
    np.testing.assert_allclose(wrapped.evaluate(np.zeros((2, 6)))[0], np.tile(-pressure * ONE, (2, 1)),
                               rtol=1e-14, atol=1e-9)
    # a triaxial compression to 3 %, far into plasticity, with an unloading step
    plastic = []
    for axial in (-0.002, -0.01, -0.03, -0.028):
        strain = np.tile([-0.3 * axial, -0.3 * axial, axial, 0.0, 0.0, 0.0], (2, 1))
        stress, tangent = wrapped.evaluate(strain)
        expected, expected_tangent = by_hand.evaluate(e0 + strain)
        np.testing.assert_array_equal(stress, expected + wrapped.offset)
        np.testing.assert_array_equal(tangent, expected_tangent)
        wrapped.commit(strain)
        by_hand.commit()
        plastic.append(wrapped.step_info()["plastic_fraction"])  # delegated to the inner set
    assert plastic[2] == 1.0 and plastic[3] == 0.0


def test_state_round_trips_and_refuses_another_pressure():
    wrapped = IsotropicPrestrain(elastoplastic(), 3.0e5)
    for axial in (-0.004, -0.012):
        wrapped.evaluate(np.tile([0.0, 0.0, axial, 0.0, 0.0, 0.0], (3, 1)))
        wrapped.commit()
    state = wrapped.get_state()
    probe = np.tile([0.001, 0.001, -0.015, 0.0, 0.0, 0.0], (3, 1))
    expected = wrapped.evaluate(probe)
    resumed = IsotropicPrestrain(elastoplastic(), 3.0e5)
    resumed.set_state(state)
    for got, want in zip(resumed.evaluate(probe), expected):
        np.testing.assert_array_equal(got, want)
    assert resumed.checkpoint_key() == {"inner": {}, "isotropic_prestrain_pressure": 3.0e5}
    with pytest.raises(ValueError, match="prestrained to 300000.0 Pa, this run's to 50000.0 Pa"):
        IsotropicPrestrain(elastoplastic(), 5.0e4).set_state(state)


def test_a_pressure_out_of_reach_is_an_error_that_names_it():
    """The elastoplastic set reaches 0.96 MPa at e = −0.05; 10 MPa is out of reach. 1 kPa is not:
    the growing steps overshoot it into tension, past the cone's apex, where the model raises, and
    smaller steps find it."""
    with pytest.raises(ValueError, match=r"target pressure 1e\+07 Pa .* cannot be brought to that confining pressure"):
        IsotropicPrestrain(elastoplastic(), 1.0e7)
    with pytest.raises(ValueError, match="positive"):
        IsotropicPrestrain(elastoplastic(), -1.0e5)
    low = IsotropicPrestrain(elastoplastic(), 1.0e3)
    assert mean_stress(low.evaluate(np.zeros((3, 6)))[0]) == pytest.approx(1.0e3, rel=1e-12)


# ------------------------------------------------------------------------------ FEM–ML wiring
@pytest.fixture(scope="module")
def networks(tmp_path_factory):
    """NNσ trained for a few seconds on elastoplastic triaxial histories at p0, whose sources record
    p0: its mean stress along an isotropic strain rises monotonically from about 70 to 190 kPa."""
    path = load_paths_from_config(CONFIG)["path1"]
    run = material_point_run(elastoplastic(12), triaxial_strain_paths(path, 12, seed=2), path)
    run.attrs["confining_pressure_Pa"] = P0
    train_ds, heldout_ds = build_dataset(run, 0.75, seed=0)
    assert train_ds.attrs["confining_pressure_Pa"] == P0
    torch.manual_seed(0)
    model, _, _ = train(train_ds, heldout_ds, "sigma", dict(CONFIG["surrogate"], epochs=30, log_every=1000), seed=0)
    folder = tmp_path_factory.mktemp("networks")
    model.save(folder / "sigma.pt")
    model.training.pop("confining_pressure_Pa")  # as a model file written before the record
    model.save(folder / "old.pt")
    return folder


def config_at(pressure, other_pressure):
    return validate_config({"reference_material": "elastoplastic", "specimen": {"confining_pressure": pressure},
                            "surrogate": {"other_pressure": other_pressure}})


def test_training_records_the_pressure_of_its_sources(networks):
    assert SurrogateModel.load(networks / "sigma.pt").training_pressure == P0
    old = SurrogateModel.load(networks / "old.pt")
    assert "confining_pressure_Pa" not in old.training and old.training_pressure is None
    old.config = {"specimen": {"confining_pressure": 5.0e4}}  # a pipeline's file: the config it was trained under
    assert old.training_pressure == 5.0e4


def test_fem_ml_prestrains_the_networks_to_another_pressure_without_the_solver_knowing(networks, caplog):
    """isotropic_prestrain at 150 kPa: the networks are wrapped, zero strain gives −150 kPa·1, and a
    FEM–ML triaxial run starts in equilibrium with its confining traction (step 0 needs no Newton
    correction), its ensemble-spread record one entry per solver commit, its file saying how it was
    prestrained. offset, or the training pressure, leaves the networks as they are."""
    sigma = networks / "sigma.pt"
    material = surrogate_material(config_at(1.5e5, "isotropic_prestrain"), 8, sigma, None, "autodiff")
    assert isinstance(material, IsotropicPrestrain) and isinstance(material.inner, SurrogateMaterial)
    np.testing.assert_allclose(material.evaluate(np.zeros((8, 6)))[0], np.tile(-1.5e5 * ONE, (8, 1)), rtol=1e-12, atol=1e-6)
    assert material.prestrain[0, 0] < 0  # (a network this brief is far off isotropic: offset ~50 kPa, deviatoric)
    problem = TriaxialProblem(elements=(1, 1, 1), platen="smooth", confining_pressure=1.5e5)
    ds = problem.run(material, LoadPath("short", ((3, 3e-3),)), progress=False)
    assert int(ds.newton_iterations.values[0]) == 0 and int(ds.cutbacks.sum()) == 0
    np.testing.assert_allclose(ds.stress.values[0], np.tile(-1.5e5 * ONE, (8, 1)), rtol=1e-10, atol=1e-6)
    assert ds.sizes["step"] == 4 and ds.attrs["method"] == "fem_ml_autodiff"
    spread = spread_variables(material, ds)["stress_spread"]
    assert spread.shape[0] == ds.sizes["step"]
    attributes = surrogate_attributes(material, sigma, None)
    assert attributes["surrogate_training_pressure_Pa"] == P0
    assert attributes["surrogate_prestrain_pressure_Pa"] == 1.5e5
    assert attributes["surrogate_prestrain"] == pytest.approx(material.prestrain[0, 0])
    assert attributes["surrogate_prestrain_offset_Pa"] == material.offset_norm

    with caplog.at_level(logging.WARNING):
        as_trained = surrogate_material(config_at(1.5e5, "offset"), 8, sigma, None, "autodiff")
    assert type(as_trained) is SurrogateMaterial
    assert "trained at a confining pressure of 100000 Pa on a specimen at 150000 Pa" in caplog.text
    at_training_pressure = surrogate_material(config_at(P0, "isotropic_prestrain"), 8, sigma, None, "autodiff")
    assert type(at_training_pressure) is SurrogateMaterial
    np.testing.assert_allclose(as_trained.evaluate(np.zeros((8, 6)))[0], np.tile(-P0 * ONE, (8, 1)), atol=1e-6)


def test_a_model_that_does_not_know_its_pressure_is_taken_at_the_specimens(networks, caplog):
    old = SurrogateMaterial(4, SurrogateModel.load(networks / "old.pt"), tangent="autodiff")
    with caplog.at_level(logging.WARNING):
        assert at_specimen_pressure(old, 1.5e5, "isotropic_prestrain") is old
    assert "records no confining pressure of its training RVEs" in caplog.text
    with pytest.raises(ValueError, match="'surrogate.other_pressure'"):
        at_specimen_pressure(old, 1.5e5, "rescale")
