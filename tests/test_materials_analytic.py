"""The two analytic material-point sets: linear elastic and the Drucker–Prager reference model."""

import numpy as np
import pytest
import yaml

from granular_multiscale.config import validate_config
from granular_multiscale.data import write_run
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.materials import Elastoplastic, LinearElastic, MaterialPointError, calibration, make_material
from granular_multiscale.materials.elastoplastic import DEFAULTS, REVERSE_YIELDING
from granular_multiscale.paths import LoadPath
from granular_multiscale.tensors import ENGINEERING_FACTOR, isotropic_elastic_tangent

P0 = 1.0e5
ISOTROPIC = -P0 * np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])


def fd_tangent(material, strain, h=1e-8):
    """Central differences of the stress w.r.t. the engineering strain (no commit)."""
    n = strain.shape[0]
    D = np.zeros((n, 6, 6))
    for j in range(6):
        e = np.zeros(6)
        e[j] = h / ENGINEERING_FACTOR[j]  # engineering perturbation h
        plus, _ = material.evaluate(strain + e, need_tangent=False)
        minus, _ = material.evaluate(strain - e, need_tangent=False)
        D[:, :, j] = (plus - minus) / (2 * h)
    return D


def drained_triaxial(material, axial_path, before_commit=None):
    return calibration.drained_triaxial(material, axial_path, P0, before_commit=before_commit)


def test_linear_elastic_stress_and_tangent():
    m = LinearElastic(3, 5e7, 0.25, initial_stress=ISOTROPIC)
    strain = np.array([[0, 0, -1e-3, 0, 0, 0], [1e-4, 2e-4, 3e-4, 1e-4, 0, 0], [0] * 6], float)
    stress, D = m.evaluate(strain)
    lam, mu = 2e7, 2e7  # E = 5e7, ν = 0.25
    assert stress[0] == pytest.approx([-P0 - lam * 1e-3, -P0 - lam * 1e-3, -P0 - (lam + 2 * mu) * 1e-3, 0, 0, 0])
    assert stress[1, 3] == pytest.approx(2 * mu * 1e-4)  # σ23 = 2μ ε23
    assert stress[2] == pytest.approx(ISOTROPIC)
    np.testing.assert_allclose(D[1], isotropic_elastic_tangent(5e7, 0.25))


def test_linear_elastic_rejects_bad_parameters():
    with pytest.raises(ValueError, match="poisson_ratio"):
        LinearElastic(1, 5e7, 0.5)
    with pytest.raises(ValueError, match=r"initial_stress must be \[6\] or \[2, 6\]"):
        LinearElastic(2, 5e7, 0.2, initial_stress=np.zeros(5))


def test_elastoplastic_elastic_at_initial_state_and_small_strain():
    m = Elastoplastic(2, initial_stress=ISOTROPIC)
    E, nu = DEFAULTS["youngs_modulus"], DEFAULTS["poisson_ratio"]
    stress, D = m.evaluate(np.zeros((2, 6)))
    np.testing.assert_allclose(stress, np.tile(ISOTROPIC, (2, 1)))
    np.testing.assert_allclose(D[0], isotropic_elastic_tangent(E, nu), rtol=1e-12)
    # an isotropic compression never yields (the cone's axis is the hydrostat)
    stress, _ = m.evaluate(np.tile([-1e-3, -1e-3, -1e-3, 0, 0, 0], (2, 1)))
    bulk = E / (3 * (1 - 2 * nu))
    assert stress[0, :3] == pytest.approx(-P0 - 3 * bulk * 1e-3 * np.ones(3))


@pytest.mark.parametrize("params", [DEFAULTS, REVERSE_YIELDING], ids=["defaults", "reverse_yielding"])
def test_elastoplastic_consistent_tangent_matches_finite_differences(params):
    rng = np.random.default_rng(1)
    m = Elastoplastic(8, **params, initial_stress=ISOTROPIC)
    # a loaded, hardened state with back-stress, then general trial strains from it
    load = np.array([2e-3, 1.5e-3, -1.2e-2, 4e-4, -3e-4, 2e-4])
    m.evaluate(np.tile(load, (8, 1)))
    m.commit()
    # mostly further loading (plastic), some unloading (elastic)
    strain = m.get_state()["strain"] + 0.1 * load + rng.normal(scale=1.5e-3, size=(8, 6))
    _, D = m.evaluate(strain)
    plastic = m._last_plastic
    assert plastic.sum() >= 4, "the check must cover plastic points"
    D_fd = fd_tangent(m, strain)
    np.testing.assert_allclose(D, D_fd, rtol=0, atol=1e-5 * np.abs(D).max())
    # associated flow with constant friction: the consistent tangent is symmetric
    np.testing.assert_allclose(D, np.swapaxes(D, 1, 2), atol=1e-8 * np.abs(D).max())


def test_elastoplastic_return_lands_on_the_yield_surface():
    m = Elastoplastic(1, initial_stress=ISOTROPIC)
    strain = np.array([[3e-3, 3e-3, -1e-2, 0, 1e-3, 0]])
    stress, _ = m.evaluate(strain)
    trial = m._trial
    f = m.yield_function(stress, trial["back_stress"], trial["kappa"])
    assert trial["kappa"][0] > 1e-3
    assert abs(f[0]) < 1e-6  # Pa, on a scale of 1e5 Pa


def test_elastoplastic_evaluate_is_repeatable_and_commit_is_explicit():
    m = Elastoplastic(1, initial_stress=ISOTROPIC)
    strain = np.array([[2e-3, 2e-3, -8e-3, 0, 0, 0]])
    s1, D1 = m.evaluate(strain)
    m.evaluate(2 * strain)  # another trial in between must not change anything
    s2, D2 = m.evaluate(strain)
    np.testing.assert_array_equal(s1, s2)
    np.testing.assert_array_equal(D1, D2)
    assert m.get_state()["kappa"][0] == 0.0  # nothing committed yet
    m.commit()
    assert m.get_state()["kappa"][0] > 0.0


def test_elastoplastic_state_round_trip():
    a = Elastoplastic(2, initial_stress=ISOTROPIC)
    a.evaluate(np.tile([2e-3, 2e-3, -8e-3, 0, 0, 0], (2, 1)))
    a.commit()
    b = Elastoplastic(2, initial_stress=ISOTROPIC)
    b.set_state(a.get_state())
    strain = np.tile([1e-3, 1e-3, -4e-3, 1e-4, 0, 0], (2, 1))
    np.testing.assert_array_equal(a.evaluate(strain)[0], b.evaluate(strain)[0])


def test_elastoplastic_defaults_look_like_the_dem_specimen():
    """Defaults (fitted to the default-scale FEM–DEM Path1, see calibration.py): about 16 MPa
    initial axial stiffness, deviator ~140 kPa at 1 % and ~300 kPa at 4.5 %, contraction then
    dilation, and Path2's unloading (0.9 % -> 0.3 %) stays in compression and elastic."""
    axial = np.linspace(0, 0.045, 91)
    q, ev = drained_triaxial(Elastoplastic(1, initial_stress=ISOTROPIC), axial)
    initial_modulus = q[1] / axial[1]
    assert 1.2e7 < initial_modulus < 2.2e7
    assert 120e3 < q[20] < 170e3  # 1 % axial strain
    assert 260e3 < q[-1] < 340e3  # 4.5 %
    assert np.all(np.diff(q) > 0)  # hardening, no softening (keeps the FE problem well posed)
    assert ev.min() < -0.005 and ev[-1] > ev.min() + 0.005  # contraction first, dilation later (tension positive)

    m = Elastoplastic(1, initial_stress=ISOTROPIC)
    plastic = []
    path2 = np.concatenate([np.linspace(0, 0.009, 10), np.linspace(0.009, 0.003, 7)[1:]])
    q2, _ = drained_triaxial(m, path2, before_commit=lambda k: plastic.append(bool(m._last_plastic[0])))
    assert q2[-1] > 0.15 * q2[9]  # still in compression at 0.3 %
    assert not any(plastic[10:]) and all(plastic[6:10])  # yields while loading, unloads elastically


def test_hysteresis_loop_with_reverse_yielding():
    load = np.linspace(0, 0.009, 10)
    unload = np.linspace(0.009, 0.003, 7)[1:]
    reload = np.linspace(0.003, 0.009, 7)[1:]
    axial = np.concatenate([load, unload, reload])
    m = Elastoplastic(1, **REVERSE_YIELDING, initial_stress=ISOTROPIC)
    plastic_on_unloading = []

    def record_unloading_plasticity(k):
        if 10 <= k < 16:
            plastic_on_unloading.append(bool(m._last_plastic[0]))

    q, _ = drained_triaxial(m, axial, before_commit=record_unloading_plasticity)
    assert any(plastic_on_unloading), "unloading must yield in reverse"
    cycle = slice(9, 22)  # 0.9 % -> 0.3 % -> 0.9 %, closed in axial strain
    area = np.sum(0.5 * (q[cycle][1:] + q[cycle][:-1]) * np.diff(axial[cycle]))
    print(f"loop area {area:.1f} J/m3")
    assert area > 100.0  # J/m³, dissipated per cycle (the elastic model gives 0)
    # the same cycle on the elastic model closes with zero area
    e = LinearElastic(1, 5e7, 0.25, initial_stress=ISOTROPIC)
    qe, _ = drained_triaxial(e, axial)
    assert abs(np.sum(0.5 * (qe[cycle][1:] + qe[cycle][:-1]) * np.diff(axial[cycle]))) < 1e-6


def test_calibration_recovers_the_parameters_of_a_known_curve():
    """Fitting the model's own triaxial curve (load, unload, reload) from the defaults as the
    start gives back the parameters that made it."""
    truth = dict(youngs_modulus=2.2e7, poisson_ratio=0.15, friction=0.45, saturated_hardening=1.0e5,
                 hardening_strain=0.005, kinematic_modulus=3.0e6)
    axial = LoadPath("p", ((10, 0.01), (5, 0.004), (20, 0.03))).axial_strain()
    q, ev = calibration.model_response(truth, axial, P0)
    fit = calibration.fit_elastoplastic(axial, q, ev, P0)
    for name, value in truth.items():
        assert fit["params"][name] == pytest.approx(value, rel=2e-3), name
    assert fit["rms_q_pa"] < 1.0 and fit["rms_volumetric"] < 1e-7


def test_elastoplastic_apex_raises_material_point_error():
    m = Elastoplastic(3, initial_stress=ISOTROPIC)
    strain = np.zeros((3, 6))
    strain[1] = [3e-2, 3e-2, 3e-2, 0, 0, 2e-3]  # strong volumetric extension: beyond the apex
    with pytest.raises(MaterialPointError, match=r"Gauss points \[1\]"):
        m.evaluate(strain)


def test_elastoplastic_rejects_bad_parameters_and_initial_state():
    with pytest.raises(ValueError, match="saturated_hardening"):
        Elastoplastic(1, initial_hardening=2e5, saturated_hardening=1e5)
    with pytest.raises(ValueError, match="outside the yield surface"):
        Elastoplastic(1, initial_stress=[-1e5, -1e5, -4e5, 0, 0, 0])


def test_make_material_from_config():
    config = validate_config({"elastoplastic": {"friction": 0.3}, "specimen": {"confining_pressure": 5e4}})
    m = make_material("elastoplastic", 4, config)
    assert m.friction == 0.3
    np.testing.assert_allclose(m.evaluate(np.zeros((4, 6)))[0][0], [-5e4, -5e4, -5e4, 0, 0, 0])
    e = make_material("linear_elastic", 4, config)
    assert e.youngs_modulus == config["linear_elastic"]["youngs_modulus"]
    with pytest.raises(ValueError, match="unknown material-point set 'dm'"):
        make_material("dm", 4, config)


def test_calibration_command_fits_a_run_file_of_the_model_itself(tmp_path, capsys):
    """The command on a smooth-platen FE run of the defaults (a homogeneous specimen: every
    Gauss point is the drained triaxial point) prints the defaults back and an RMS of ~0."""
    problem = TriaxialProblem(size=(0.5, 0.5, 1.0), elements=(1, 1, 2), platen="smooth")
    path = LoadPath("p", ((8, 0.008), (4, 0.003), (12, 0.02)))
    run = problem.run(Elastoplastic(problem.n_gauss_points, initial_stress=problem.initial_stress), path,
                      progress=False)
    write_run(run, tmp_path / "run.h5")
    calibration.main([str(tmp_path / "run.h5")])
    printed = yaml.safe_load("\n".join(line for line in capsys.readouterr().out.splitlines() if not line.startswith("#")))
    for name in calibration.FITTED:
        assert printed["elastoplastic"][name] == pytest.approx(DEFAULTS[name], rel=2e-3), name
