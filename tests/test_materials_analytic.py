"""The two analytic material-point sets: linear elastic and the Drucker–Prager reference model."""

import numpy as np
import pytest
import yaml

from granular_multiscale.config import validate_config
from granular_multiscale.data import write_run
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.materials import Elastoplastic, LinearElastic, MaterialPointError, calibration, make_material
from granular_multiscale.materials.elastoplastic import DEFAULTS, REVERSE_YIELDING, SOFTENING
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


# -- softening and non-associated, decaying dilatancy -------------------------------------

OFF = {"softening": 0.0, "softening_strain": 0.2, "dilatancy": None, "dilatancy_strain": np.inf}


def plane_strain_compression(material, axial_strain, lateral_stress=-P0):
    """One point in plane-strain compression: ε_yy = −axial, ε_zz = 0, no shear, σ_xx held at
    `lateral_stress` by Newton on ε_xx. Returns the deviator σ_xx − σ_yy (Pa) and ε_v per step."""
    strain = np.zeros((1, 6))
    deviator, volumetric = [], []
    for k, axial in enumerate(np.asarray(axial_strain, dtype=float)):
        strain[0, 1] = -axial
        for _ in range(30):
            stress, tangent = material.evaluate(strain)
            residual = stress[0, 0] - lateral_stress
            if abs(residual) < 1e-8 * P0:
                break
            strain[0, 0] -= residual / tangent[0, 0, 0]
        else:
            raise RuntimeError(f"plane-strain point did not converge at step {k} (axial strain {axial:.4g})")
        material.commit()
        deviator.append(stress[0, 0] - stress[0, 1])
        volumetric.append(strain[0, 0] + strain[0, 1])
    return np.array(deviator), np.array(volumetric)


@pytest.mark.parametrize("params", [DEFAULTS, REVERSE_YIELDING], ids=["defaults", "reverse_yielding"])
def test_new_options_at_their_off_values_reproduce_the_model_bit_for_bit(params):
    rng = np.random.default_rng(3)
    a = Elastoplastic(6, **params, initial_stress=ISOTROPIC)
    b = Elastoplastic(6, **{**params, **OFF}, initial_stress=ISOTROPIC)
    c = Elastoplastic(6, **{**params, "dilatancy": params["friction"]}, initial_stress=ISOTROPIC)  # β0 = η given
    # random 3D paths with loading, a reversal and reloading
    strain = np.zeros((6, 6))
    direction = rng.normal(scale=4e-4, size=(6, 6)) + np.array([2e-4, 2e-4, -1.5e-3, 0, 0, 0])
    n_plastic = 0
    for k in range(30):
        strain = strain + (-1.0 if 12 <= k < 18 else 1.0) * direction
        sa, Da = a.evaluate(strain)
        sb, Db = b.evaluate(strain)
        sc, Dc = c.evaluate(strain)
        np.testing.assert_array_equal(sa, sb)
        np.testing.assert_array_equal(Da, Db)
        # the non-associated code path with β = η gives the same model (to round-off)
        np.testing.assert_allclose(sc, sa, rtol=1e-12, atol=1e-12 * P0)
        np.testing.assert_allclose(Dc, Da, rtol=0, atol=1e-12 * np.abs(Da).max())
        n_plastic += a._last_plastic.sum()
        for m in (a, b, c):
            m.commit()
    assert n_plastic > 60
    assert a.get_state()["kappa"].min() > 3e-3
    # the drained triaxial load-unload-reload path too
    axial = np.concatenate(
        [np.linspace(0, 0.009, 10), np.linspace(0.009, 0.003, 7)[1:], np.linspace(0.003, 0.02, 10)[1:]]
    )
    qa, eva = drained_triaxial(Elastoplastic(1, **params, initial_stress=ISOTROPIC), axial)
    qb, evb = drained_triaxial(Elastoplastic(1, **{**params, **OFF}, initial_stress=ISOTROPIC), axial)
    np.testing.assert_array_equal(qa, qb)
    np.testing.assert_array_equal(eva, evb)
    assert qa[-1] > 1e5
    # from_config with the keys absent or at their off values
    config = {"elastoplastic": dict(params), "specimen": {"confining_pressure": P0}}
    config_off = {"elastoplastic": {**params, **OFF}, "specimen": {"confining_pressure": P0}}
    strain = np.tile([1e-3, 1e-3, -6e-3, 2e-4, 0, 0], (2, 1))
    stress, tangent = Elastoplastic.from_config(2, config).evaluate(strain)
    stress_off, tangent_off = Elastoplastic.from_config(2, config_off).evaluate(strain)
    np.testing.assert_array_equal(stress, stress_off)
    np.testing.assert_array_equal(tangent, tangent_off)


def _states_on_the_yield_surface(m, kappa, rng):
    """Converged states at plastic strains `kappa` [n]: stress on the yield surface at p = 150
    kPa around a random back-stress, and a loading trial strain (outward, plus noise) from there."""
    n = kappa.size
    p = 1.5e5

    def unit_deviator(x):
        x = x - x[:, :3].mean(axis=1, keepdims=True) * np.array([1.0, 1, 1, 0, 0, 0])
        return x / np.sqrt(np.sum(np.array([1, 1, 1, 2, 2, 2]) * x**2, axis=1))[:, None]

    n_hat = unit_deviator(np.array([0.4, 0.3, -0.7, 0.1, -0.05, 0.08]) + rng.normal(scale=0.05, size=(n, 6)))
    alpha = 0.1 * m.kinematic * np.sqrt(2 / 3) * kappa[:, None] * unit_deviator(rng.normal(size=(n, 6)))
    radius = (m.friction * p + m.hardening(kappa)[0]) / np.sqrt(1.5)
    stress = alpha + radius[:, None] * n_hat - p * np.array([1.0, 1, 1, 0, 0, 0])
    m.set_state({"strain": np.zeros((n, 6)), "stress": stress, "back_stress": alpha, "kappa": kappa})
    assert np.abs(m.yield_function(stress, alpha, kappa)).max() < 1e-6
    # tensorial strain increment: deviatoric loading along n̂ (≈ 0.15 % of shear) plus noise
    return 1.5e-3 * n_hat + rng.normal(scale=1e-4, size=(n, 6))


@pytest.mark.parametrize(
    "params",
    [SOFTENING, {**SOFTENING, "dilatancy": 0.9, "dilatancy_strain": np.inf, "kinematic_modulus": 1.0e6}],
    ids=["softening_preset", "beta_above_eta_constant"],
)
def test_non_associated_softening_tangent_matches_finite_differences(params):
    rng = np.random.default_rng(5)
    m = Elastoplastic(8, **params, initial_stress=ISOTROPIC)
    a = (m.k_inf - m.k0) / m.kappa_ref
    c = m.k_soft / m.kappa_soft
    kappa_peak = np.log(a / c) / (1 / m.kappa_ref - 1 / m.kappa_soft)  # k'(κ) = 0
    assert abs(m.hardening(np.array([kappa_peak]))[1][0]) < 1e-6 * a
    # hardening (twice), at the peak of k, softening (twice), β decayed (three; for the preset
    # β/β0 = 0.05, 0.013, 0.002)
    kappa = np.array([0.0, 0.003, kappa_peak, 0.02, 0.04, 0.09, 0.13, 0.19])
    strain = _states_on_the_yield_surface(m, kappa, rng)
    stress, D = m.evaluate(strain)
    assert m._last_plastic.all(), "every point must be loaded plastically"
    slope = m.hardening(m._trial["kappa"])[1]
    assert slope[:2].min() > 0 and slope[3:].max() < 0  # hardening, then softening
    D_fd = fd_tangent(m, strain)
    np.testing.assert_allclose(D, D_fd, rtol=0, atol=1e-5 * np.abs(D).max())

    # the return: on the yield surface, plastic volumetric strain β(κ_n) Δλ with β explicit
    stress, _ = m.evaluate(strain)  # (again: the differences evaluated other trials)
    trial = m._trial
    assert np.abs(m.yield_function(stress, trial["back_stress"], trial["kappa"])).max() < 1e-6 * P0
    dlam = trial["kappa"] - kappa
    assert dlam.min() > 1e-5
    stress_trial = m.get_state()["stress"] + (m.elastic_tangent @ (strain * ENGINEERING_FACTOR).T).T
    dp = -(stress - stress_trial)[:, :3].mean(axis=1)  # p − p_tr = K β Δλ
    np.testing.assert_allclose(dp / (m.bulk * dlam), m.dilatancy(kappa), rtol=1e-9)

    # β ≠ η: the consistent tangent is not symmetric, D − Dᵀ = −K (β − η) √6 G (1⊗n̂ − n̂⊗1) / h
    beta = m.dilatancy(kappa)
    assert np.all(np.abs(beta - m.friction) > 0.09)
    asymmetry = np.abs(D - np.swapaxes(D, 1, 2)).max(axis=(1, 2)) / np.abs(D).max(axis=(1, 2))
    assert asymmetry.min() > 1e-3
    xi = stress_trial - m.get_state()["back_stress"]
    xi[:, :3] -= xi[:, :3].mean(axis=1, keepdims=True)
    n_hat = xi / np.sqrt(np.sum(np.array([1, 1, 1, 2, 2, 2]) * xi**2, axis=1))[:, None]
    one = np.array([1.0, 1, 1, 0, 0, 0])
    h = 3 * m.shear + m.kinematic + m.bulk * m.friction * beta + slope
    skew = (m.bulk * (beta - m.friction) * np.sqrt(6) * m.shear / h)[:, None, None] * (
        one[None, :, None] * n_hat[:, None, :] - n_hat[:, :, None] * one[None, None, :]
    )
    np.testing.assert_allclose(D - np.swapaxes(D, 1, 2), -skew, rtol=0, atol=1e-9 * np.abs(D).max())


def test_return_mapping_converges_with_steep_softening_and_large_steps():
    """A brittle set (k' down to −1.5e7 Pa against 3G = 1.9e7 Pa; r concave where k'' > 0) under
    large random steps: the safeguarded Newton converges and every return lands on the yield surface."""
    rng = np.random.default_rng(1)
    brittle = {**SOFTENING, "saturated_hardening": 3e5, "hardening_strain": 5e-4, "softening": 2.9e5,
               "softening_strain": 0.015, "dilatancy": 0.0}
    m = Elastoplastic(200, **brittle, initial_stress=ISOTROPIC)
    assert m.min_hardening_slope() < -0.75 * 3 * m.shear
    strain = np.zeros((200, 6))
    for _ in range(12):
        noise = rng.normal(scale=3e-3, size=(200, 6)) * [0.3, 0.3, 0.3, 1, 1, 1]
        strain = strain + noise + [2e-3, 2e-3, -8e-3, 0, 0, 0]
        stress, _ = m.evaluate(strain)
        trial = m._trial
        f = m.yield_function(stress, trial["back_stress"], trial["kappa"])
        assert np.abs(f[m._last_plastic]).max() < 1e-6 * P0
        assert m._last_plastic.sum() > 100
        m.commit()
    assert m.get_state()["kappa"].max() > 0.05  # well into the softening branch


def test_softening_preset_peaks_and_softens_to_a_critical_state_in_plane_strain():
    axial = np.linspace(0, 0.10, 201)  # 0.05 % steps
    q, ev = plane_strain_compression(Elastoplastic(1, **SOFTENING, initial_stress=ISOTROPIC), axial)
    peak = np.argmax(q)
    print(f"peak {100 * axial[peak]:.2f} % q {q[peak] / 1e3:.1f} kPa; "
          f"at 10 %: q {q[-1] / 1e3:.1f} kPa, ε_v {100 * ev[-1]:.3f} %")
    assert 0.015 <= axial[peak] <= 0.035
    assert 200e3 < q[peak] < 350e3
    assert q[-1] <= 0.8 * q[peak]  # measured 0.77
    assert np.all(np.diff(q[peak:]) < 0)  # softens monotonically after the peak
    rate = np.gradient(ev, axial)
    assert np.abs(rate[axial >= 0.08]).max() < 0.2 * np.abs(rate).max()  # towards constant volume
    assert ev[-1] > ev[peak] + 5e-3  # dilates after the peak (measured: -1.37 % -> -0.39 %)
    # the strength stays positive over the range reached
    m = Elastoplastic(1, **SOFTENING)
    assert m.hardening(np.linspace(0, 1.0, 1001))[0].min() >= 0


def test_min_hardening_slope_is_the_minimum_over_kappa():
    kappa = np.linspace(0, 0.5, 200001)
    interior = {**SOFTENING, "hardening_strain": 0.001, "softening": 5e4, "softening_strain": 0.05}
    for params in [SOFTENING, interior, DEFAULTS]:
        m = Elastoplastic(1, **params)
        assert m.min_hardening_slope() == pytest.approx(min(m.hardening(kappa)[1].min(), 0.0), rel=1e-6, abs=1e-9)
    # an interior minimum (k' starts positive, turns negative, then decays to 0)
    m = Elastoplastic(1, **interior)
    assert m.hardening(np.zeros(1))[1][0] > 0 > m.min_hardening_slope()


def test_softening_and_dilatancy_reject_bad_parameters():
    with pytest.raises(ValueError, match=r"elastoplastic\.softening: invalid value -1"):
        Elastoplastic(1, softening=-1.0)
    with pytest.raises(ValueError, match=r"elastoplastic\.softening_strain: invalid value 0\.0"):
        Elastoplastic(1, softening=1e4, softening_strain=0.0)
    with pytest.raises(ValueError, match=r"elastoplastic\.dilatancy: invalid value -0\.1"):
        Elastoplastic(1, dilatancy=-0.1)
    with pytest.raises(ValueError, match=r"elastoplastic\.dilatancy_strain: invalid value -1"):
        Elastoplastic(1, dilatancy=0.3, dilatancy_strain=-1.0)
    with pytest.raises(ValueError, match=r"elastoplastic\.dilatancy_strain: invalid value 0"):
        Elastoplastic(1, dilatancy_strain=0)
    # h = 3G + H_k + K η β + k'(κ) ≤ 0 somewhere: a softening slope k_s/κs beyond the elastic shear
    with pytest.raises(ValueError, match=r"elastoplastic\.softening: .* ≤ 0"):
        Elastoplastic(1, softening=1e6, softening_strain=1e-3)
    # at the margin: no isotropic hardening, k' = −k_s/κs at κ = 0; accepted while β = β0 = η
    # holds K η² in h, rejected once β may decay to 0 (finite κd)
    E, nu = DEFAULTS["youngs_modulus"], DEFAULTS["poisson_ratio"]
    eta, Hk = DEFAULTS["friction"], DEFAULTS["kinematic_modulus"]
    G, K = E / (2 * (1 + nu)), E / (3 * (1 - 2 * nu))
    slope = 3 * G + Hk + 0.5 * K * eta**2  # between 3G + H_k and 3G + H_k + K η²
    margin = {"saturated_hardening": 0.0, "softening": slope * 0.01, "softening_strain": 0.01}
    Elastoplastic(1, **margin)
    with pytest.raises(ValueError, match=r"elastoplastic\.softening"):
        Elastoplastic(1, **margin, dilatancy_strain=0.1)
    # a residual strength below k0 (even negative) is allowed: the yield stress η p + k stays positive
    m = Elastoplastic(1, initial_hardening=2e4, saturated_hardening=5e4, softening=8e4, softening_strain=0.05)
    assert m.hardening(np.array([10.0]))[0][0] == pytest.approx(-3e4)
