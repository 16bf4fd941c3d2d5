"""History variables of the surrogate's inputs, numpy and torch: φ1–φ3 of the paper (§2.2.2)
and the running strain maxima ψ1, ψ2.

With ε(k) the converged strain tensor of step k (ε(0) = 0) and the current trial strain
counting as step t, the accumulated absolute strain increment is, component-wise,

    Δε_acc(t) = Σ_{k=1..t} |ε(k) − ε(k−1)|          (six independent components)

and

    φ1 = ‖Δε_acc‖_F = sqrt(Σ_i Δε_ii² + 2 Σ_{i<j} Δε_ij²)   (off-diagonals count twice)
    φ2 = tr Δε_acc = Δε_11 + Δε_22 + Δε_33
    φ3 = Π of the six independent components Δε_11 Δε_22 Δε_33 Δε_23 Δε_13 Δε_12

φ never decreases, so an unload–reload that returns to an earlier strain does not return to
an earlier φ: this is what lets a one-step MLP tell the branches apart. But φ grows along any
path and does not say where the last peak was. The running maxima do:

    ψ1(t) = max_{k=0..t} ‖ε(k)‖_F                       (same Frobenius norm as φ1)
    ψ2(t) = max_{k=0..t} ‖ε(k) − (tr ε(k)/3)·1‖_F       (deviatoric strain)

Both are Markovian, ψ(t) = max(ψ(t−1), ‖ε_trial‖): during unloading from a peak ψ stays at the
peak while ‖ε‖ falls, and grows again once the path passes the old peak. Their derivative with
respect to the trial strain is d‖ε‖/dε where the trial norm exceeds the converged maximum and
0 elsewhere (ties included: the maximum is then frozen).

The state a material point carries is therefore (ε_c, Δε_acc,c, ψ_c): the converged strain,
accumulated increment [..., 6] and running maxima [..., 2] ("peak"). ``HIST`` names the five
variables in the order every array here and the ``hist`` coordinate of the run files use.
Strains are tensorial (ε23, not γ23), Voigt order 11, 22, 33, 23, 13, 12.
"""

from __future__ import annotations

import numpy as np

PHI = ("phi1", "phi2", "phi3")
PSI = ("psi1", "psi2")
HIST = PHI + PSI
_FROBENIUS_WEIGHT = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])
_NORMAL = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])


# ------------------------------------------------------------------------- numpy
def accumulate(acc_converged: np.ndarray, strain_converged: np.ndarray, strain: np.ndarray) -> np.ndarray:
    """Δε_acc with `strain` as the current step: acc + |strain − strain_converged|."""
    return acc_converged + np.abs(strain - strain_converged)


def deviator(strain: np.ndarray) -> np.ndarray:
    """[..., 6] strain -> its deviatoric part ε − (tr ε / 3)·1 (Voigt)."""
    strain = np.asarray(strain, dtype=float)
    return strain - strain[..., :3].mean(axis=-1, keepdims=True) * _NORMAL


def strain_norms(strain: np.ndarray) -> np.ndarray:
    """[..., 6] strain -> [..., 2] (‖ε‖_F, ‖dev ε‖_F), off-diagonals counted twice."""
    strain = np.asarray(strain, dtype=float)
    return np.sqrt(np.stack([np.sum(_FROBENIUS_WEIGHT * strain**2, axis=-1),
                             np.sum(_FROBENIUS_WEIGHT * deviator(strain) ** 2, axis=-1)], axis=-1))


def equivalent_shear_strain(strain: np.ndarray) -> np.ndarray:
    """[..., 6] strain -> [...] ε_s = √(2/3 · dev ε : dev ε) (the analysis's too, to the last bit)."""
    return np.sqrt(2.0 / 3.0 * np.sum(_FROBENIUS_WEIGHT * deviator(strain) ** 2, axis=-1))


def running_peak(peak_converged: np.ndarray, strain: np.ndarray) -> np.ndarray:
    """(ψ1, ψ2) with `strain` as the current step: the larger of the converged maxima and its norms."""
    return np.maximum(peak_converged, strain_norms(strain))


def phi_variables(acc: np.ndarray) -> np.ndarray:
    """[..., 6] accumulated absolute strain increments -> [..., 3] (φ1, φ2, φ3)."""
    acc = np.asarray(acc, dtype=float)
    phi1 = np.sqrt(np.sum(_FROBENIUS_WEIGHT * acc**2, axis=-1))
    phi2 = acc[..., 0] + acc[..., 1] + acc[..., 2]
    phi3 = np.prod(acc, axis=-1)
    return np.stack([phi1, phi2, phi3], axis=-1)


def history_variables(acc: np.ndarray, peak: np.ndarray) -> np.ndarray:
    """[..., 6] Δε_acc and [..., 2] running maxima -> [..., 5] the variables of ``HIST``."""
    return np.concatenate([phi_variables(acc), np.asarray(peak, dtype=float)], axis=-1)


def accumulated_from_sequence(strain: np.ndarray) -> np.ndarray:
    """[steps, ..., 6] converged strains with strain[0] the step-0 state -> Δε_acc per step."""
    strain = np.asarray(strain, dtype=float)
    inc = np.abs(np.diff(strain, axis=0))
    acc = np.zeros_like(strain)
    acc[1:] = np.cumsum(inc, axis=0)
    return acc


def peak_from_sequence(strain: np.ndarray) -> np.ndarray:
    """[steps, ..., 6] converged strains -> [steps, ..., 2] (ψ1, ψ2) per step (steps 0..t)."""
    return np.maximum.accumulate(strain_norms(strain), axis=0)


def history_from_sequence(strain: np.ndarray) -> np.ndarray:
    """[steps, ..., 6] converged strains -> [steps, ..., 5] the variables of ``HIST`` at every step."""
    return history_variables(accumulated_from_sequence(strain), peak_from_sequence(strain))


# ------------------------------------------------------------------------- torch
def _sqrt_torch(squares):
    """sqrt with the subgradient 0 at 0 (fresh points, step 0), so that an autodiff tangent
    stays finite; the values are those of the plain sqrt."""
    import torch

    positive = squares > 0
    return torch.where(positive, torch.sqrt(torch.where(positive, squares, torch.ones_like(squares))), 0.0 * squares)


def accumulate_torch(acc_converged, strain_converged, strain):
    """torch version of :func:`accumulate`."""
    import torch

    return acc_converged + torch.abs(strain - strain_converged)


def _weight_torch(like):
    import torch

    return torch.as_tensor(_FROBENIUS_WEIGHT, dtype=like.dtype, device=like.device)


def _strain_and_deviator_torch(strain):
    """[..., 6] strain -> [..., 2, 6] (ε, dev ε): the tensors whose norms are ψ1, ψ2."""
    import torch

    normal = torch.as_tensor(_NORMAL, dtype=strain.dtype, device=strain.device)
    return torch.stack([strain, strain - strain[..., :3].mean(dim=-1, keepdim=True) * normal], dim=-2)


def strain_norms_torch(strain):
    """torch version of :func:`strain_norms` (differentiable, subgradient 0 at a zero strain)."""
    import torch

    return _sqrt_torch(torch.sum(_weight_torch(strain) * _strain_and_deviator_torch(strain) ** 2, dim=-1))


def running_peak_torch(peak_converged, strain):
    """torch version of :func:`running_peak`; the derivative flows to the trial norm only where it
    exceeds the converged maximum (a tie keeps the maximum frozen: derivative 0)."""
    import torch

    norms = strain_norms_torch(strain)
    return torch.where(norms > peak_converged, norms, peak_converged)


def phi_variables_torch(acc):
    """torch version of :func:`phi_variables` (same numbers, differentiable, finite gradient at 0)."""
    import torch

    phi1 = _sqrt_torch(torch.sum(_weight_torch(acc) * acc**2, dim=-1))
    phi2 = acc[..., 0] + acc[..., 1] + acc[..., 2]
    phi3 = torch.prod(acc, dim=-1)
    return torch.stack([phi1, phi2, phi3], dim=-1)


def history_variables_torch(acc, peak):
    """torch version of :func:`history_variables`."""
    import torch

    return torch.cat([phi_variables_torch(acc), peak], dim=-1)


def trial_history_torch(strain, acc_converged, strain_converged, peak_converged):
    """[..., 6] trial strain with the converged state -> [..., 5] the variables of ``HIST`` at the
    trial, differentiable in the trial strain."""
    return history_variables_torch(accumulate_torch(acc_converged, strain_converged, strain),
                                   running_peak_torch(peak_converged, strain))


def phi_jacobian_torch(acc):
    """[..., 6] Δε_acc -> [..., 3, 6] derivatives of (φ1, φ2, φ3) with respect to Δε_acc.

    dφ1/dΔε_i = w_i Δε_i / φ1 (0 at φ1 = 0, the subgradient the autodiff version takes),
    dφ2/dΔε_i = 1 for the normal components, dφ3/dΔε_i = the product of the other five
    (prefix and suffix products: no division by a zero component)."""
    import torch

    phi1 = phi_variables_torch(acc)[..., :1]
    d_phi1 = torch.where(phi1 > 0, _weight_torch(acc) * acc / torch.where(phi1 > 0, phi1, torch.ones_like(phi1)), 0.0 * acc)
    d_phi2 = torch.zeros_like(acc)
    d_phi2[..., :3] = 1.0
    ones = torch.ones_like(acc[..., :1])
    prefix = torch.cumprod(torch.cat([ones, acc[..., :-1]], dim=-1), dim=-1)
    suffix = torch.flip(torch.cumprod(torch.cat([ones, torch.flip(acc, [-1])[..., :-1]], dim=-1), dim=-1), [-1])
    d_phi3 = prefix * suffix
    return torch.stack([d_phi1, d_phi2, d_phi3], dim=-2)


def history_jacobian_torch(strain, acc_converged, strain_converged, peak_converged):
    """[..., 5, 6] derivatives of the variables of ``HIST`` at the trial (:func:`trial_history_torch`)
    with respect to the trial strain (tensorial components).

    dφ/dε = dφ/dΔε_acc · sign(ε − ε_c) (0 where a component did not move); dψ/dε_i = w_i e_i / ‖e‖
    with e = ε for ψ1 and e = dev ε for ψ2 (Σ of the deviator's normal components is 0), where the
    trial norm exceeds the converged maximum, and 0 elsewhere."""
    import torch

    acc = accumulate_torch(acc_converged, strain_converged, strain)
    d_phi = phi_jacobian_torch(acc) * torch.sign(strain - strain_converged)[..., None, :]
    e = _strain_and_deviator_torch(strain)
    norms = strain_norms_torch(strain)[..., None]
    active = norms > peak_converged[..., None]  # > 0 as well: the converged maximum is >= 0
    d_psi = torch.where(active, _weight_torch(strain) * e / torch.where(active, norms, torch.ones_like(norms)), 0.0 * e)
    return torch.cat([d_phi, d_psi], dim=-2)
