"""History variables φ1–φ3 (paper §2.2.2) and the running strain maxima ψ1, ψ2: hand-computed values,
load–unload–reload, numpy == torch, derivatives wrt the trial strain."""

import numpy as np
import pytest
import torch

from granular_multiscale.history import (
    HIST,
    accumulate,
    accumulate_torch,
    accumulated_from_sequence,
    history_from_sequence,
    history_jacobian_torch,
    history_variables,
    peak_from_sequence,
    phi_jacobian_torch,
    phi_variables,
    phi_variables_torch,
    running_peak,
    strain_norms,
    trial_history_torch,
)

MILLI = 1e-3
# One Gauss point, Voigt order 11, 22, 33, 23, 13, 12, tensorial shear.
# Steps: 0 fresh, 1 load, 2 load further, 3 unload back to the strain of step 1, 4 reload to step 2.
STEP1 = np.array([1.0, 1.0, -4.0, 0.5, -0.2, 0.1]) * MILLI
STEP2 = np.array([2.0, 1.5, -8.0, 1.0, -0.4, 0.3]) * MILLI
SEQUENCE = np.stack([np.zeros(6), STEP1, STEP2, STEP1, STEP2])

# Δε_acc by hand: |STEP1|, then + |STEP2 − STEP1| = (1, .5, 4, .5, .2, .2) mm/m at each later step
ACC_BY_HAND = np.array(
    [
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [1.0, 1.0, 4.0, 0.5, 0.2, 0.1],
        [2.0, 1.5, 8.0, 1.0, 0.4, 0.3],
        [3.0, 2.0, 12.0, 1.5, 0.6, 0.5],
        [4.0, 2.5, 16.0, 2.0, 0.8, 0.7],
    ]
) * MILLI

# φ1² = Σ diag² + 2 Σ offdiag², φ2 = Σ diag, φ3 = Π of the six components (all in mm/m first)
PHI_BY_HAND = np.array(
    [
        [0.0, 0.0, 0.0],
        [np.sqrt(1 + 1 + 16 + 2 * (0.25 + 0.04 + 0.01)) * MILLI, 6.0 * MILLI, 1 * 1 * 4 * 0.5 * 0.2 * 0.1 * MILLI**6],
        [np.sqrt(4 + 2.25 + 64 + 2 * (1 + 0.16 + 0.09)) * MILLI, 11.5 * MILLI, 2 * 1.5 * 8 * 1 * 0.4 * 0.3 * MILLI**6],
        [np.sqrt(9 + 4 + 144 + 2 * (2.25 + 0.36 + 0.25)) * MILLI, 17.0 * MILLI, 32.4 * MILLI**6],
        [np.sqrt(16 + 6.25 + 256 + 2 * (4 + 0.64 + 0.49)) * MILLI, 22.5 * MILLI, 4 * 2.5 * 16 * 2 * 0.8 * 0.7 * MILLI**6],
    ]
)


def test_names():
    assert HIST == ("phi1", "phi2", "phi3", "psi1", "psi2")


def test_accumulated_increment_by_hand():
    np.testing.assert_allclose(accumulated_from_sequence(SEQUENCE), ACC_BY_HAND, rtol=1e-12, atol=1e-18)


def test_history_variables_by_hand():
    np.testing.assert_allclose(history_from_sequence(SEQUENCE)[:, :3], PHI_BY_HAND, rtol=1e-12, atol=1e-30)
    # the hand values themselves: φ1 at step 1 is sqrt(18.6) mm/m, φ3 at step 3 is 3.24e-17
    assert PHI_BY_HAND[1, 0] == pytest.approx(4.312771730569565e-3, rel=1e-12)
    assert PHI_BY_HAND[3, 2] == pytest.approx(3.24e-17, rel=1e-12)


def test_unload_reload_returns_strain_but_not_history():
    phi = history_from_sequence(SEQUENCE)[:, :3]
    # the strain of step 3 equals that of step 1, and step 4 equals step 2 ...
    np.testing.assert_array_equal(SEQUENCE[3], SEQUENCE[1])
    np.testing.assert_array_equal(SEQUENCE[4], SEQUENCE[2])
    # ... but every history variable is strictly larger: the branches are told apart
    assert np.all(phi[3] > phi[1])
    assert np.all(phi[4] > phi[2])
    # φ2 grows by the trace of |Δε| of the unload step (1 + 0.5 + 4 mm/m), not by the signed trace
    assert phi[3, 1] - phi[2, 1] == pytest.approx(5.5 * MILLI, rel=1e-12)


def test_incremental_accumulate_matches_sequence():
    """The surrogate advances Δε_acc one committed step at a time; that must equal the sequence form."""
    rng = np.random.default_rng(3)
    strains = np.cumsum(rng.normal(scale=1e-3, size=(12, 5, 6)), axis=0)
    strains[0] = 0.0
    acc, peak = np.zeros((5, 6)), np.zeros((5, 2))
    for k in range(1, 12):
        acc = accumulate(acc, strains[k - 1], strains[k])
        peak = running_peak(peak, strains[k])
        np.testing.assert_allclose(history_variables(acc, peak), history_from_sequence(strains)[k], rtol=1e-12)


def test_history_is_monotone_and_vectorised():
    rng = np.random.default_rng(0)
    strains = np.cumsum(rng.normal(scale=1e-3, size=(30, 7, 6)), axis=0)
    phi = history_from_sequence(strains)
    assert phi.shape == (30, 7, 5)
    assert np.all(np.diff(phi, axis=0) >= 0)
    # each Gauss point alone gives the same numbers as the batch
    for gp in range(7):
        np.testing.assert_array_equal(history_from_sequence(strains[:, gp]), phi[:, gp])


def test_frobenius_weight_counts_offdiagonals_twice():
    acc = np.zeros(6)
    acc[3] = 3.0  # ε23 alone: the 3×3 tensor has 3 at (2,3) and (3,2)
    tensor = np.zeros((3, 3))
    tensor[1, 2] = tensor[2, 1] = 3.0
    assert phi_variables(acc)[0] == pytest.approx(np.linalg.norm(tensor, "fro"), rel=1e-15)
    assert strain_norms(acc)[0] == pytest.approx(np.linalg.norm(tensor, "fro"), rel=1e-15)


def test_numpy_equals_torch():
    rng = np.random.default_rng(1)
    acc_conv = np.abs(rng.normal(scale=1e-2, size=(50, 6)))
    strain_conv = rng.normal(scale=1e-2, size=(50, 6))
    strain = strain_conv + rng.normal(scale=1e-3, size=(50, 6))
    acc_np = accumulate(acc_conv, strain_conv, strain)
    acc_t = accumulate_torch(torch.tensor(acc_conv), torch.tensor(strain_conv), torch.tensor(strain))
    np.testing.assert_allclose(acc_t.numpy(), acc_np, rtol=1e-15)
    np.testing.assert_allclose(phi_variables_torch(acc_t).numpy(), phi_variables(acc_np), rtol=1e-13)
    np.testing.assert_allclose(
        phi_variables_torch(torch.tensor(ACC_BY_HAND)).numpy(), PHI_BY_HAND, rtol=1e-12, atol=1e-30
    )
    # the trial history with the running maxima: some trials above the converged maxima, some below
    peak_conv = strain_norms(strain_conv) * rng.uniform(0.9, 1.1, size=(50, 1))
    expected = history_variables(acc_np, running_peak(peak_conv, strain))
    trial = trial_history_torch(*(torch.tensor(a) for a in (strain, acc_conv, strain_conv, peak_conv))).numpy()
    np.testing.assert_allclose(trial, expected, rtol=1e-13)
    above = strain_norms(strain) > peak_conv
    assert above.any() and (~above).any()


def test_torch_gradient_finite_at_fresh_state():
    """At Δε_acc = 0 the sqrt in φ1 has no derivative; the torch version must give 0, not NaN."""
    acc = torch.zeros(4, 6, dtype=torch.float64, requires_grad=True)
    phi_variables_torch(acc).sum().backward()
    assert torch.isfinite(acc.grad).all()
    # dφ2/dΔε_ii = 1 survives; the φ1 and φ3 contributions are 0 at the origin
    np.testing.assert_array_equal(acc.grad.numpy(), np.tile([1.0, 1, 1, 0, 0, 0], (4, 1)))


def test_torch_gradient_matches_finite_difference():
    rng = np.random.default_rng(2)
    acc0 = np.abs(rng.normal(scale=1e-2, size=6)) + 1e-3
    jac = torch.autograd.functional.jacobian(phi_variables_torch, torch.tensor(acc0)).numpy()
    h = 1e-7
    fd = np.stack(
        [(phi_variables(acc0 + h * e) - phi_variables(acc0 - h * e)) / (2 * h) for e in np.eye(6)], axis=1
    )
    np.testing.assert_allclose(jac, fd, rtol=1e-6, atol=1e-14)


def test_history_jacobian_matches_autograd():
    rng = np.random.default_rng(5)
    acc = np.abs(rng.normal(scale=1e-2, size=(8, 6)))
    acc[2, 4] = 0.0  # a zero component: φ3's derivative along it is the product of the other five
    acc[3] = 0.0  # fresh point: subgradient 0 for φ1
    acc_t = torch.tensor(acc)
    jac = torch.func.vmap(torch.func.jacrev(phi_variables_torch))(acc_t).numpy()
    np.testing.assert_allclose(phi_jacobian_torch(acc_t).numpy(), jac, rtol=1e-12, atol=1e-30)
    assert phi_jacobian_torch(acc_t)[2, 2, 4] == pytest.approx(np.prod(np.delete(acc[2], 4)), rel=1e-12)


# ψ on a load–unload–reload path along one direction D (tensorial; ‖D‖_F = √22, ‖dev D‖_F = √19):
# steps 0..6 at ε = s·D mm/m with s = 0, 1, 2, 1, 0.5, 1.5, 3 (load, unload, reload past the peak)
DIRECTION = np.array([1.0, 0.0, -4.0, 1.5, 0.0, 0.5])
SCALES = np.array([0.0, 1.0, 2.0, 1.0, 0.5, 1.5, 3.0])
PSI_PATH = SCALES[:, None] * DIRECTION * MILLI


def test_direction_norms_by_hand():
    # ‖D‖² = 1 + 0 + 16 + 2 (1.5² + 0² + 0.5²) = 22
    # dev D = D − (−1)·(1, 1, 1, 0, 0, 0) = (2, 1, −3, 1.5, 0, 0.5): 4 + 1 + 9 + 4.5 + 0.5 = 19
    np.testing.assert_allclose(strain_norms(DIRECTION), [np.sqrt(22.0), np.sqrt(19.0)], rtol=1e-15)


def test_psi_is_the_running_maximum_by_hand():
    psi = peak_from_sequence(PSI_PATH)
    # the largest s so far: 0, 1, 2, 2 (unloading), 2, 2 (reloading below the old peak), 3 (past it)
    np.testing.assert_allclose(psi, np.outer([0, 1, 2, 2, 2, 2, 3], [np.sqrt(22.0), np.sqrt(19.0)]) * MILLI, rtol=1e-14)
    history = history_from_sequence(PSI_PATH)
    np.testing.assert_array_equal(history[:, 3:], psi)
    # at the same strain (s = 1, steps 1 and 3) ψ says how far the path went before: the peak s = 2
    np.testing.assert_array_equal(PSI_PATH[1], PSI_PATH[3])
    np.testing.assert_allclose(history[3, 3:] / history[1, 3:], 2.0, rtol=1e-14)
    # the Markov step: ψ(t) = max(ψ(t−1), ‖ε(t)‖) reproduces the sequence form, trial by trial
    peak = np.zeros(2)
    for k in range(1, len(SCALES)):
        peak = running_peak(peak, PSI_PATH[k])
        np.testing.assert_array_equal(peak, psi[k])


def _trial_args(strain, strain_c, acc_c, peak_c):
    return [torch.tensor(a, dtype=torch.float64) for a in (strain, acc_c, strain_c, peak_c)]


def test_history_jacobian_matches_autograd_and_finite_differences():
    """d(φ, ψ)/dε_trial: ψ active where the trial norm exceeds the converged maximum, frozen (0) elsewhere."""
    rng = np.random.default_rng(7)
    strain_c = rng.normal(scale=2e-3, size=(6, 6))
    acc_c = np.abs(strain_c) * 1.5 + 1e-4
    strain = strain_c + rng.normal(scale=3e-4, size=(6, 6))
    norms = strain_norms(strain)
    peak_c = norms * np.array([[0.9], [1.2], [0.9], [1.2], [0.9], [1.2]])  # even rows above, odd rows below
    peak_c[4] = [norms[4, 0] * 0.9, norms[4, 1] * 1.2]  # ψ1 active, ψ2 frozen at one point
    args = _trial_args(strain, strain_c, acc_c, peak_c)
    analytic = history_jacobian_torch(*args).numpy()
    auto = torch.func.vmap(torch.func.jacrev(trial_history_torch))(*args).numpy()
    np.testing.assert_allclose(analytic, auto, rtol=1e-12, atol=1e-30)
    h = 1e-9
    fd = np.stack([(history_variables(accumulate(acc_c, strain_c, strain + h * e), running_peak(peak_c, strain + h * e))
                    - history_variables(accumulate(acc_c, strain_c, strain - h * e), running_peak(peak_c, strain - h * e)))
                   / (2 * h) for e in np.eye(6)], axis=-1)
    np.testing.assert_allclose(analytic[:, 3:], fd[:, 3:], rtol=1e-6, atol=1e-9)
    # active: dψ1/dε = w ε / ‖ε‖ (w = 2 on the shears), dψ2/dε = w dev ε / ‖dev ε‖; frozen: 0
    w = np.array([1.0, 1, 1, 2, 2, 2])
    dev = strain - strain[:, :3].mean(axis=1, keepdims=True) * np.array([1.0, 1, 1, 0, 0, 0])
    np.testing.assert_allclose(analytic[0, 3], w * strain[0] / norms[0, 0], rtol=1e-12)
    np.testing.assert_allclose(analytic[0, 4], w * dev[0] / norms[0, 1], rtol=1e-12)
    np.testing.assert_array_equal(analytic[1, 3:], 0.0)
    assert np.abs(analytic[4, 3]).max() > 0 and np.all(analytic[4, 4] == 0.0)
    # φ rows: the chain rule dφ/dΔε_acc · sign(ε − ε_c)
    sign = np.sign(strain - strain_c)
    np.testing.assert_allclose(analytic[:, :3], phi_jacobian_torch(torch.tensor(accumulate(acc_c, strain_c, strain))).numpy()
                               * sign[:, None, :], rtol=1e-12, atol=1e-30)


def test_history_jacobian_finite_at_zero_strain():
    """A fresh point at zero trial strain: the norms' sqrt kink gives the subgradient 0, not NaN."""
    zeros = np.zeros((2, 6))
    args = _trial_args(zeros, zeros, zeros, np.zeros((2, 2)))
    np.testing.assert_array_equal(history_jacobian_torch(*args).numpy()[:, 3:], 0.0)
    assert torch.isfinite(torch.func.vmap(torch.func.jacrev(trial_history_torch))(*args)).all()
