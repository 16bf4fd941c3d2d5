"""SurrogateMaterial: batched evaluation, history on commit only, tangents vs finite differences,
out-of-range inputs counted, state round trip."""

import logging

import numpy as np
import pytest
import torch

from granular_multiscale.config import validate_config
import pickle

from granular_multiscale.history import accumulate, history_variables, phi_variables, strain_norms
from granular_multiscale.materials.base import MaterialPointError
from granular_multiscale.materials.elastic import LinearElastic
from granular_multiscale.materials.elastoplastic import Elastoplastic
from granular_multiscale.paths import load_paths_from_config
from granular_multiscale.surrogate.dataset import build_dataset, scaling
from granular_multiscale.surrogate.material import SurrogateMaterial, method_name
from granular_multiscale.surrogate.models import SurrogateModel
from granular_multiscale.surrogate.synthetic import material_point_run, triaxial_strain_paths
from granular_multiscale.surrogate.training import initial_state, train
from granular_multiscale.tensors import ENGINEERING_FACTOR, isotropic_elastic_tangent, tangent_from_upper

CONFIG = validate_config({"reference_material": "elastoplastic"})


@pytest.fixture(scope="module")
def data():
    path = load_paths_from_config(CONFIG)["path1"]
    run = material_point_run(Elastoplastic.from_config(12, CONFIG), triaxial_strain_paths(path, 12, seed=2), path)
    return build_dataset(run, 0.75, seed=0)


def untrained(data, kind, use_history=True, seed=0, activation="tanh"):
    """A randomly initialised network with the dataset's scaling, reloaded in float64 like a real model."""
    torch.manual_seed(seed)
    settings = dict(CONFIG["surrogate"], activation=activation)
    model = SurrogateModel.create(kind, use_history, scaling(data[0], kind, use_history), settings)
    model.initial_state = initial_state(data[0], kind, use_history)
    return model


@pytest.fixture(scope="module")
def models(data, tmp_path_factory):
    folder = tmp_path_factory.mktemp("models")
    untrained(data, "sigma").save(folder / "s.pt")
    untrained(data, "tangent").save(folder / "d.pt")
    return SurrogateModel.load(folder / "s.pt"), SurrogateModel.load(folder / "d.pt")


def state_with_history(n, seed=0):
    """A converged strain after some loading, its accumulated increment, and a nearby trial strain."""
    rng = np.random.default_rng(seed)
    strain_c = np.array([0.003, 0.0028, -0.008, 0.0002, -0.0001, 0.00015]) + rng.normal(scale=5e-4, size=(n, 6))
    acc_c = np.abs(strain_c) * 1.3 + 1e-4
    trial = strain_c + rng.normal(scale=4e-4, size=(n, 6))
    return strain_c, acc_c, trial


def finite_difference_tangent(material, strain, h=1e-7):
    """Central differences of the material's stress wrt the ENGINEERING strain (the solver's convention)."""
    n = strain.shape[0]
    fd = np.empty((n, 6, 6))
    for J in range(6):
        d = np.zeros(6)
        d[J] = h / ENGINEERING_FACTOR[J]  # engineering increment h = tensorial increment h / factor
        plus, _ = material.evaluate(strain + d, need_tangent=False)
        minus, _ = material.evaluate(strain - d, need_tangent=False)
        fd[:, :, J] = (plus - minus) / (2 * h)
    return fd


def test_method_names():
    assert method_name("nn") == "fem_ml_nn"
    assert method_name("autodiff", use_history=False) == "fem_ml_nohist_autodiff"


def test_stress_is_the_network_at_strain_and_trial_history(models):
    sigma, nd = models
    strain_c, acc_c, trial = state_with_history(7)
    mat = SurrogateMaterial(7, sigma, nd, tangent="nn")
    mat.set_state({"strain": strain_c, "accumulated": acc_c})
    stress, D = mat.evaluate(trial)
    phi = phi_variables(accumulate(acc_c, strain_c, trial))
    x = np.concatenate([trial, phi], axis=1)
    np.testing.assert_allclose(stress, sigma.predict(x) + sigma.initial_offset(), rtol=1e-12)
    # nn tangent: ND's 21 outputs in Pa, reassembled into the symmetric matrix
    np.testing.assert_allclose(D, tangent_from_upper(nd.predict(x) + nd.initial_offset()), rtol=1e-12)
    raw = SurrogateMaterial(7, sigma, nd, tangent="nn", anchor_initial_state=False)
    raw.set_state({"strain": strain_c, "accumulated": acc_c})
    np.testing.assert_allclose(raw.evaluate(trial)[0], sigma.predict(x), rtol=1e-12)
    np.testing.assert_array_equal(D, np.swapaxes(D, 1, 2))
    assert mat.method == "fem_ml_nn"


def test_anchored_networks_reproduce_the_fresh_state(models, data):
    """Zero strain and history give the consolidated stress and tangent of the data, exactly."""
    sigma, nd = models
    fresh = data[0].isel(step=0)
    stress, D = SurrogateMaterial(3, sigma, nd, tangent="nn").evaluate(np.zeros((3, 6)))
    # exact up to round-off: the network's answer at zero, evaluated in another batch than when the
    # offset was fixed, may differ in its last bit, which leaves ~1e-12 Pa where the stress is 0
    np.testing.assert_allclose(stress, np.tile(fresh.stress.values.mean(axis=0), (3, 1)), rtol=1e-12, atol=1e-12 * 1e5)
    np.testing.assert_allclose(stress[0], [-1e5, -1e5, -1e5, 0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(D[0], tangent_from_upper(fresh.tangent.values.mean(axis=0)), rtol=1e-10, atol=1e-3)
    raw, _ = SurrogateMaterial(3, sigma, nd, anchor_initial_state=False).evaluate(np.zeros((3, 6)))
    assert np.abs(raw - stress).max() > 1e3  # an untrained network is far off: the anchor did the work
    # the offset is a constant: the autodiff tangent is the same with and without it
    strain_c, acc_c, trial = state_with_history(3, seed=5)
    tangents = []
    for anchor in (True, False):
        m = SurrogateMaterial(3, sigma, tangent="autodiff", anchor_initial_state=anchor)
        m.set_state({"strain": strain_c, "accumulated": acc_c})
        tangents.append(m.evaluate(trial)[1])
    np.testing.assert_allclose(tangents[0], tangents[1], rtol=1e-12)


def test_batched_evaluation_has_no_cross_talk(models):
    sigma, nd = models
    strain_c, acc_c, trial = state_with_history(9, seed=1)
    for tangent in ("nn", "autodiff"):
        batch = SurrogateMaterial(9, sigma, nd, tangent=tangent)
        batch.set_state({"strain": strain_c, "accumulated": acc_c})
        s_all, D_all = batch.evaluate(trial)
        for i in (0, 4, 8):
            one = SurrogateMaterial(1, sigma, nd, tangent=tangent)
            one.set_state({"strain": strain_c[i : i + 1], "accumulated": acc_c[i : i + 1]})
            s1, D1 = one.evaluate(trial[i : i + 1])
            np.testing.assert_allclose(s1[0], s_all[i], rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(D1[0], D_all[i], rtol=1e-10, atol=1e-6)


def test_history_advances_on_commit_only(models):
    sigma, nd = models
    mat = SurrogateMaterial(3, sigma, nd)
    loaded = np.tile([0.002, 0.002, -0.006, 0.0, 0.0, 0.0], (3, 1))
    first, _ = mat.evaluate(loaded)
    again, _ = mat.evaluate(0.5 * loaded)  # another trial of the same step
    repeat, _ = mat.evaluate(loaded)
    np.testing.assert_array_equal(first, repeat)  # trials do not accumulate
    np.testing.assert_array_equal(mat.history, 0.0)
    mat.commit()  # the last trial (loaded) is converged now
    np.testing.assert_allclose(mat.history, history_variables(np.abs(loaded), strain_norms(loaded)))
    # unload back to zero strain: same strain as the fresh state, different stress (the history differs)
    unloaded, _ = mat.evaluate(np.zeros((3, 6)))
    fresh = SurrogateMaterial(3, sigma, nd).evaluate(np.zeros((3, 6)))[0]
    assert np.abs(unloaded - fresh).max() > 1.0  # Pa
    mat.commit()
    # φ grew by the unloading increment, ψ stayed at the peak (the loaded strain's norms)
    np.testing.assert_allclose(mat.history, history_variables(2 * np.abs(loaded), strain_norms(loaded)))
    with pytest.raises(RuntimeError, match="before evaluate"):
        mat.commit()


def test_autodiff_tangent_matches_finite_differences(models):
    """Exact Jacobian including dφ/dε; columns act on engineering shear strain."""
    sigma, _ = models
    strain_c, acc_c, trial = state_with_history(5, seed=2)
    mat = SurrogateMaterial(5, sigma, tangent="autodiff")
    mat.set_state({"strain": strain_c, "accumulated": acc_c})
    _, D = mat.evaluate(trial)
    fd = finite_difference_tangent(mat, trial)
    scale = np.abs(fd).max()
    np.testing.assert_allclose(D, fd, atol=1e-6 * scale)
    # the chain rule through φ1–φ3 matters: freezing the history changes the tangent a lot
    frozen = SurrogateMaterial(5, sigma, tangent="autodiff")
    frozen_fd = np.empty_like(fd)
    phi = phi_variables(accumulate(acc_c, strain_c, trial))
    for J in range(6):
        d = np.zeros(6)
        d[J] = 1e-7 / ENGINEERING_FACTOR[J]
        xp = np.concatenate([trial + d, phi], 1)
        xm = np.concatenate([trial - d, phi], 1)
        frozen_fd[:, :, J] = (sigma.predict(xp) - sigma.predict(xm)) / 2e-7
    assert np.abs(frozen_fd - D).max() > 1e-3 * scale
    assert frozen.method == "fem_ml_autodiff"


@pytest.mark.parametrize("activation", ["tanh", "gelu", "silu", "softplus", "elu", "sigmoid"])
def test_forward_mode_tangent_equals_torch_func_jacobian(data, activation):
    """The hand-written forward mode (one batched pass) is the Jacobian torch.func computes."""
    from torch.func import jacrev, vmap

    sigma = untrained(data, "sigma", seed=4, activation=activation)
    sigma.network.to(torch.float64).requires_grad_(False)
    strain_c, acc_c, trial = state_with_history(6, seed=6)
    trial[0, 4] = strain_c[0, 4]  # a component with no increment: the kink of |ε − ε_c|
    mat = SurrogateMaterial(6, sigma, tangent="autodiff")
    mat.set_state({"strain": strain_c, "accumulated": acc_c})
    stress, D = mat.evaluate(trial)
    args = [torch.from_numpy(a) for a in (trial, acc_c, strain_c, mat.get_state()["peak"])]
    jac, reference = vmap(jacrev(mat._stress_with_aux, has_aux=True))(*args)
    np.testing.assert_allclose(stress, reference.numpy(), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(D, jac.numpy() / ENGINEERING_FACTOR, rtol=1e-9, atol=1e-9 * np.abs(D).max())


def test_ensemble_autodiff_tangent_matches_finite_differences(data):
    """The ensemble's stress is its members' mean; its tangent is the exact Jacobian of that mean."""
    from granular_multiscale.surrogate.models import EnsembleMLP

    members = [untrained(data, "sigma", seed=s) for s in (7, 8, 9)]
    ensemble = untrained(data, "sigma", seed=7)
    ensemble.network = EnsembleMLP([m.network for m in members]).to(torch.float64)
    strain_c, acc_c, trial = state_with_history(5, seed=3)
    stresses = []
    for model in members + [ensemble]:
        mat = SurrogateMaterial(5, model, tangent="autodiff", anchor_initial_state=False)
        mat.set_state({"strain": strain_c, "accumulated": acc_c})
        stresses.append(mat.evaluate(trial)[0])
    np.testing.assert_allclose(stresses[-1], np.mean(stresses[:-1], axis=0), rtol=1e-12)
    _, D = mat.evaluate(trial)
    fd = finite_difference_tangent(mat, trial)
    np.testing.assert_allclose(D, fd, atol=1e-6 * np.abs(fd).max())


def test_autodiff_tangent_at_fresh_state(models):
    """At Δε_acc = 0, the kinks of |·| and of the norm in φ, the tangent is finite and is the
    central difference there: a step ±h changes |Δε| alike both ways, so the history terms
    cancel, as autodiff's subgradient 0 of |·| and of the norm says."""
    sigma, _ = models
    mat = SurrogateMaterial(4, sigma, tangent="autodiff")
    fresh = np.zeros((4, 6))
    stress, D = mat.evaluate(fresh)
    assert np.isfinite(D).all() and np.isfinite(stress).all()
    fd = finite_difference_tangent(mat, fresh)
    assert np.abs(D).max() > 0
    np.testing.assert_allclose(D, fd, atol=1e-6 * np.abs(fd).max())


def test_autodiff_without_history_matches_finite_differences(data):
    sigma = untrained(data, "sigma", use_history=False, seed=3)
    mat = SurrogateMaterial(4, sigma, tangent="autodiff")
    assert mat.method == "fem_ml_nohist_autodiff"
    _, _, trial = state_with_history(4, seed=3)
    _, D = mat.evaluate(trial)
    fd = finite_difference_tangent(mat, trial)
    np.testing.assert_allclose(D, fd, atol=1e-6 * np.abs(fd).max())


@pytest.mark.slow
def test_trained_nd_agrees_with_finite_differences_of_trained_nn_sigma():
    """Train NNσ and ND on a linear elastic response: ND (nn tangent) must match the finite-difference
    tangent of NNσ wrt engineering strain, and both the exact elastic stiffness. A factor-2 slip in the
    shear convention (tensorial vs engineering) would miss by 50 % on the shear diagonal."""
    n = 48
    # space-filling strains (the elastic response has no history), so that NNσ's slopes are learnt
    strain = np.random.default_rng(5).uniform(-0.005, 0.005, size=(21, n, 6))
    strain[0] = 0.0
    elastic = LinearElastic(n, 5.0e7, 0.25, initial_stress=[-1e5, -1e5, -1e5, 0, 0, 0])
    train_ds, heldout_ds = build_dataset(material_point_run(elastic, strain), 0.75, seed=0)
    settings = dict(CONFIG["surrogate"], epochs=150, learning_rate=3e-3, loss="mse", log_every=1000)
    sigma, _, _ = train(train_ds, heldout_ds, "sigma", settings, seed=0, use_history=False)
    nd, _, _ = train(train_ds, heldout_ds, "tangent", settings, seed=0, use_history=False)
    mat = SurrogateMaterial(6, sigma, nd, tangent="nn")
    probe = strain[12, :6]
    _, D_nn = mat.evaluate(probe)
    fd = finite_difference_tangent(mat, probe, h=1e-6)
    D_exact = isotropic_elastic_tangent(5.0e7, 0.25)
    scale = np.abs(D_exact).max()
    assert np.abs(D_nn - D_exact).max() < 1e-3 * scale  # a constant target: ND learns it closely
    assert np.abs(fd - D_exact).max() < 0.1 * scale
    assert np.abs(fd - D_nn).max() < 0.1 * scale
    # shear diagonal = μ = E / (2 (1 + ν)) = 20 MPa on engineering strain (40 MPa if the convention slipped)
    assert D_exact[3, 3] == pytest.approx(2e7)
    assert np.all(np.abs(np.diagonal(fd, axis1=1, axis2=2)[:, 3:] / 2e7 - 1) < 0.2)


def test_out_of_range_inputs_are_counted_and_logged(models, caplog):
    sigma, nd = models
    x_max = sigma.network.x_max.numpy()
    mat = SurrogateMaterial(5, sigma, nd, out_of_range_tolerance=0.0, logger=logging.getLogger("oor"))
    inside = np.tile(0.5 * (sigma.network.x_min.numpy() + x_max)[:6], (5, 1))
    mat.evaluate(inside)
    mat.commit()
    assert mat.step_info()["out_of_range_points"] == 0
    beyond = inside.copy()
    beyond[[1, 3], 2] = 3 * x_max[2] - 2 * sigma.network.x_min.numpy()[2]  # ε33 two ranges past the max
    with caplog.at_level(logging.WARNING, logger="oor"):
        mat.evaluate(beyond)
        mat.commit()
    info = mat.step_info()
    assert info["out_of_range_points"] == 2
    assert info["out_of_range_excess"] == pytest.approx(2.0, rel=1e-6)
    assert "2 of 5 Gauss points" in caplog.text and "strain_33" in caplog.text
    # a tolerance of the whole excess lets the step pass as in range... for strain; φ grew too
    lenient = SurrogateMaterial(5, sigma, nd, out_of_range_tolerance=10.0)
    lenient.evaluate(beyond)
    lenient.commit()
    assert lenient.step_info()["out_of_range_points"] == 0


def test_state_roundtrip_and_errors(models):
    sigma, nd = models
    strain_c, acc_c, trial = state_with_history(4, seed=4)
    a = SurrogateMaterial(4, sigma, nd)
    a.set_state({"strain": strain_c, "accumulated": acc_c})
    a.evaluate(trial)
    a.commit()
    b = SurrogateMaterial(4, sigma, nd)
    b.set_state(a.get_state())
    probe = trial * 1.1
    np.testing.assert_array_equal(a.evaluate(probe)[0], b.evaluate(probe)[0])
    with pytest.raises(ValueError, match="state for 4 points"):
        SurrogateMaterial(3, sigma, nd).set_state(a.get_state())
    with pytest.raises(ValueError, match="needs the ND model"):
        SurrogateMaterial(4, sigma, None, tangent="nn")
    with pytest.raises(ValueError, match="surrogate.tangent"):
        SurrogateMaterial(4, sigma, nd, tangent="secant")
    with pytest.raises(ValueError, match="NNσ"):
        SurrogateMaterial(4, nd, nd)
    bad = trial.copy()
    bad[2, 1] = np.nan
    with pytest.raises(MaterialPointError, match=r"Gauss points \[2\]"):
        a.evaluate(bad)


WITH_PSI = ["phi1", "phi2", "psi1"]


def test_autodiff_tangent_with_psi_matches_finite_differences(data):
    """NNσ(ε, φ1, φ2, ψ1): the exact Jacobian includes dψ1/dε where the trial strain passes the
    converged maximum (loading further) and not where ψ1 is frozen (unloading)."""
    sigma = untrained(data, "sigma", use_history=WITH_PSI, seed=11)
    assert sigma.feature_names[6:] == ("phi1", "phi2", "psi1")
    strain_c, acc_c, _ = state_with_history(5, seed=8)
    noise = np.random.default_rng(9).normal(scale=1e-4, size=(5, 6))
    cases = {"active": (strain_norms(strain_c), 1.05 * strain_c + noise),   # ‖ε‖ 5 % past the peak
             "frozen": (1.3 * strain_norms(strain_c), 0.97 * strain_c + noise)}  # unloading below it
    tangents = {}
    for name, (peak_c, trial) in cases.items():
        mat = SurrogateMaterial(5, sigma, tangent="autodiff")
        mat.set_state({"strain": strain_c, "accumulated": acc_c, "peak": peak_c})
        above = strain_norms(trial)[:, 0] > peak_c[:, 0]
        assert above.all() if name == "active" else not above.any()
        _, D = mat.evaluate(trial)
        fd = finite_difference_tangent(mat, trial)
        np.testing.assert_allclose(D, fd, atol=1e-6 * np.abs(fd).max(), err_msg=name)
        tangents[name] = D
    # the chain rule through ψ1 matters: at the same trial strain and (to 1e-12) the same ψ1,
    # a maximum just above the trial norm freezes ψ1 and changes the tangent
    peak_c, trial = cases["active"]
    for frozen in (False, True):
        mat = SurrogateMaterial(5, sigma, tangent="autodiff")
        mat.set_state({"strain": strain_c, "accumulated": acc_c,
                       "peak": strain_norms(trial) * (1 + 1e-12) if frozen else peak_c})
        tangents[frozen] = mat.evaluate(trial)[1]
    np.testing.assert_array_equal(tangents[False], tangents["active"])
    assert np.abs(tangents[True] - tangents[False]).max() > 1e-3 * np.abs(tangents[False]).max()


def test_checkpoint_resume_with_psi_is_bit_identical(data):
    """A load–unload–reload sequence, checkpointed (pickled state) while unloading below the peak:
    the resumed material gives the same stresses and tangents to the bit; without the running
    maxima in the state (taken at the current strain) it would not."""
    sigma = untrained(data, "sigma", use_history=WITH_PSI, seed=12)
    direction = np.array([0.002, 0.002, -0.006, 0.0003, -0.0001, 0.0002])
    scales = [0.5, 1.0, 0.6, 0.3, 0.7, 1.2, 1.5]  # load, unload, reload past the peak
    strains = [np.outer(np.linspace(0.9, 1.1, 3), s * direction) for s in scales]
    whole = SurrogateMaterial(3, sigma, tangent="autodiff")
    resumed = None
    out = {"whole": [], "resumed": []}
    for k, strain in enumerate(strains):
        if k == 3:  # checkpoint after committing the first unloading step
            saved = pickle.loads(pickle.dumps(whole.get_state()))
            np.testing.assert_allclose(saved["peak"], strain_norms(strains[1]), rtol=1e-15)  # the peak, not the current strain
            resumed = SurrogateMaterial(3, sigma, tangent="autodiff")
            resumed.set_state(saved)
            forgetful = SurrogateMaterial(3, sigma, tangent="autodiff")
            forgetful.set_state({key: v for key, v in saved.items() if key != "peak"})
            assert np.abs(forgetful.evaluate(strain)[0] - whole.evaluate(strain)[0]).max() > 1.0  # Pa
        for name, mat in (("whole", whole), ("resumed", resumed)):
            if mat is not None:
                out[name].append(mat.evaluate(strain))
                mat.commit()
    for (s_w, D_w), (s_r, D_r) in zip(out["whole"][3:], out["resumed"]):
        np.testing.assert_array_equal(s_w, s_r)
        np.testing.assert_array_equal(D_w, D_r)
    np.testing.assert_array_equal(whole.history, resumed.history)
    np.testing.assert_allclose(whole.history[:, 3:], strain_norms(strains[-1]), rtol=1e-15)  # the new peak
    with pytest.raises(ValueError, match="running maximum"):
        resumed.set_state(dict(saved, peak=0.5 * saved["peak"]))


def test_fem_ml_run_file_holds_the_autodiff_tangent_whole(models, tmp_path):
    """The autodiff tangent (NNσ's exact Jacobian) is not symmetric; the run file must give
    back the tangent the solver had at every converged state, all 36 entries, not its upper triangle."""
    from granular_multiscale.data import read_run, run_tangent, write_run
    from granular_multiscale.fem.triaxial import TriaxialProblem
    from granular_multiscale.paths import LoadPath
    from granular_multiscale.tensors import tangent_to_upper

    sigma, _ = models
    problem = TriaxialProblem(elements=(1, 1, 1), platen="smooth")
    ds = problem.run(SurrogateMaterial(problem.n_gauss_points, sigma, tangent="autodiff"),
                     LoadPath("short", ((3, 3e-4),)), progress=False)
    back = read_run(write_run(ds, tmp_path / "fem_ml.h5"))
    assert back.attrs["method"] == "fem_ml_autodiff" and back.attrs["tangent_symmetric"] == 0
    assert int(back.cutbacks.sum()) == 0  # so the replay below commits the same states
    full = run_tangent(back)
    np.testing.assert_array_equal(back.tangent_full.values, ds.tangent_full.values)  # the file round trip is exact
    # ... and it is the solver's tangent: replay the converged strains through a fresh material
    replay = SurrogateMaterial(problem.n_gauss_points, sigma, tangent="autodiff")
    for k in range(back.sizes["step"]):
        _, D = replay.evaluate(back.strain.values[k])
        replay.commit()
        np.testing.assert_allclose(full[k], D, rtol=1e-12, atol=1e-12 * np.abs(D).max(), err_msg=f"step {k}")
    lower_lost = np.abs(full - np.swapaxes(full, -1, -2)).max()
    assert lower_lost > 1e-3 * np.abs(full).max()  # the 21 upper entries alone would not give it back
    np.testing.assert_allclose(back.tangent.values, tangent_to_upper(0.5 * (full + np.swapaxes(full, -1, -2))),
                               rtol=1e-15, atol=0)


def test_an_unseen_combination_inside_the_box_is_off_the_training_data(data, tmp_path, caplog):
    """Triaxial training data: the lateral strain is largest where the axial compression is. A state
    with that lateral strain and no axial strain is inside every feature's training range (the box
    lets it pass) but far from every training state: off_training_points counts it, with a warning,
    and the model file carries the training sample it is measured against. (Networks without history
    variables: their inputs are the strains alone, so a training strain is a training state.)"""
    from granular_multiscale.novelty import sample_states
    from granular_multiscale.surrogate.dataset import features

    model = untrained(data, "sigma", use_history=False)
    model.training_states = sample_states(features(data[0], ()), 20_000, seed=0)
    model.save(tmp_path / "s.pt")
    sigma = SurrogateModel.load(tmp_path / "s.pt")
    np.testing.assert_array_equal(sigma.training_states, model.training_states)
    mat = SurrogateMaterial(2, sigma, tangent="autodiff", logger=logging.getLogger("novel"))
    strain = data[0]["strain"].values.reshape(-1, 6)
    seen = strain[np.argmin(strain[:, 2])]  # the most compressed training state, its lateral strain largest
    unseen = seen.copy()
    unseen[2] = 0.0  # the same lateral strain without the axial compression
    with caplog.at_level(logging.WARNING, logger="novel"):
        mat.evaluate(np.stack([seen, unseen]))
        mat.commit()
    info = mat.step_info()
    assert info["out_of_range_points"] == 0  # inside the box
    assert info["off_training_points"] == 1  # the unseen combination only
    assert "1 of 2 Gauss points off the training data" in caplog.text and "first points [1]" in caplog.text
    without_sample = untrained(data, "sigma", use_history=False)
    assert without_sample.training_states is None
    box_only = SurrogateMaterial(2, without_sample, tangent="autodiff")
    box_only.evaluate(np.stack([seen, unseen]))
    box_only.commit()
    assert "off_training_points" not in box_only.step_info()  # a model file without the sample: the box alone


def test_zoned_networks_answer_each_point_with_its_zones_networks(data):
    """FEM–ML's weak zone: each point gets its zone's networks, exactly as they answer alone; the
    spread is gathered per point and the out-of-range points counted over both zones."""
    from granular_multiscale.materials.wrappers import ZonedSurrogate

    zones = np.array([0, 1, 0, 1, 1])
    specimen, weak = untrained(data, "sigma", seed=3), untrained(data, "sigma", seed=4)
    zoned = ZonedSurrogate([SurrogateMaterial(2, specimen, tangent="autodiff"), SurrogateMaterial(3, weak, tangent="autodiff")], zones)
    _, _, trial = state_with_history(5, seed=5)
    stress, tangent = zoned.evaluate(trial)
    for model, idx in ((specimen, zones == 0), (weak, zones == 1)):
        alone = SurrogateMaterial(int(idx.sum()), model, tangent="autodiff")
        s, t = alone.evaluate(trial[idx])
        np.testing.assert_array_equal(stress[idx], s)
        np.testing.assert_array_equal(tangent[idx], t)
    assert not np.allclose(stress[0], stress[1])  # another network, another answer
    zoned.commit()
    assert zoned.stress_spread.shape == (1, 5, 6)  # one network per model: zeros, one record per commit
    assert zoned.ensemble_size == 1 and zoned.sigma_model is specimen  # what the run file records
    # ε33 two ranges past the training maximum at one point of each zone: two points out in all
    x_min, x_max = specimen.network.x_min.numpy()[2], specimen.network.x_max.numpy()[2]
    beyond = trial.copy()
    beyond[[0, 1], 2] = 3 * x_max - 2 * x_min
    zoned.evaluate(beyond)
    zoned.commit()
    assert zoned.step_info()["out_of_range_points"] == 2
    assert zoned.stress_spread.shape == (2, 5, 6)


def test_zoned_networks_must_be_ensembles_of_one_size(data):
    from granular_multiscale.materials.wrappers import ZonedSurrogate
    from granular_multiscale.surrogate.models import EnsembleMLP

    pair = untrained(data, "sigma", seed=7)
    pair.network = EnsembleMLP([untrained(data, "sigma", seed=s).network for s in (7, 8)]).to(torch.float64)
    with pytest.raises(ValueError, match=r"ensembles of one size .*\[1, 2\]"):
        ZonedSurrogate([SurrogateMaterial(1, untrained(data, "sigma"), tangent="autodiff"),
                        SurrogateMaterial(1, pair, tangent="autodiff")], [0, 1])
