"""History variables φ1–φ3 of the paper (§2.2.2), numpy and torch.

With ε(k) the converged strain tensor of step k (ε(0) = 0) and the current trial strain
counting as step t, the accumulated absolute strain increment is, component-wise,

    Δε_acc(t) = Σ_{k=1..t} |ε(k) − ε(k−1)|          (six independent components)

and

    φ1 = ‖Δε_acc‖_F = sqrt(Σ_i Δε_ii² + 2 Σ_{i<j} Δε_ij²)   (off-diagonals count twice)
    φ2 = tr Δε_acc = Δε_11 + Δε_22 + Δε_33
    φ3 = Π of the six independent components Δε_11 Δε_22 Δε_33 Δε_23 Δε_13 Δε_12

Strains are tensorial (ε23, not γ23), Voigt order 11, 22, 33, 23, 13, 12.
φ never decreases, so an unload–reload that returns to an earlier strain does not
return to an earlier φ: this is what lets a one-step MLP tell the branches apart.
"""

from __future__ import annotations

import numpy as np

HIST = ("phi1", "phi2", "phi3")
_FROBENIUS_WEIGHT = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])


def accumulate(acc_converged: np.ndarray, strain_converged: np.ndarray, strain: np.ndarray) -> np.ndarray:
    """Δε_acc with `strain` as the current step: acc + |strain − strain_converged|."""
    return acc_converged + np.abs(strain - strain_converged)


def history_variables(acc: np.ndarray) -> np.ndarray:
    """[..., 6] accumulated absolute strain increments -> [..., 3] (φ1, φ2, φ3)."""
    acc = np.asarray(acc, dtype=float)
    phi1 = np.sqrt(np.sum(_FROBENIUS_WEIGHT * acc**2, axis=-1))
    phi2 = acc[..., 0] + acc[..., 1] + acc[..., 2]
    phi3 = np.prod(acc, axis=-1)
    return np.stack([phi1, phi2, phi3], axis=-1)


def accumulated_from_sequence(strain: np.ndarray) -> np.ndarray:
    """[steps, ..., 6] converged strains with strain[0] the step-0 state -> Δε_acc per step."""
    strain = np.asarray(strain, dtype=float)
    inc = np.abs(np.diff(strain, axis=0))
    acc = np.zeros_like(strain)
    acc[1:] = np.cumsum(inc, axis=0)
    return acc


def history_from_sequence(strain: np.ndarray) -> np.ndarray:
    """[steps, ..., 6] converged strains -> [steps, ..., 3] φ1–φ3 at every step."""
    return history_variables(accumulated_from_sequence(strain))


def history_variables_torch(acc):
    """torch version of :func:`history_variables` (same numbers, differentiable, finite gradient at 0)."""
    import torch

    weight = torch.as_tensor(_FROBENIUS_WEIGHT, dtype=acc.dtype, device=acc.device)
    squares = torch.sum(weight * acc**2, dim=-1)
    # sqrt has an infinite slope at 0 (fresh points, step 0): take the subgradient 0 there so
    # an autodiff tangent through φ stays finite; the values are those of the plain sqrt.
    positive = squares > 0
    phi1 = torch.where(positive, torch.sqrt(torch.where(positive, squares, torch.ones_like(squares))), 0.0 * squares)
    phi2 = acc[..., 0] + acc[..., 1] + acc[..., 2]
    phi3 = torch.prod(acc, dim=-1)
    return torch.stack([phi1, phi2, phi3], dim=-1)


def accumulate_torch(acc_converged, strain_converged, strain):
    """torch version of :func:`accumulate`."""
    import torch

    return acc_converged + torch.abs(strain - strain_converged)


def history_jacobian_torch(acc):
    """[..., 6] Δε_acc -> [..., 3, 6] derivatives of (φ1, φ2, φ3) with respect to Δε_acc.

    dφ1/dΔε_i = w_i Δε_i / φ1 (0 at φ1 = 0, the subgradient the autodiff version takes),
    dφ2/dΔε_i = 1 for the normal components, dφ3/dΔε_i = the product of the other five
    (prefix and suffix products: no division by a zero component)."""
    import torch

    weight = torch.as_tensor(_FROBENIUS_WEIGHT, dtype=acc.dtype, device=acc.device)
    phi1 = history_variables_torch(acc)[..., :1]
    d_phi1 = torch.where(phi1 > 0, weight * acc / torch.where(phi1 > 0, phi1, torch.ones_like(phi1)), 0.0 * acc)
    d_phi2 = torch.zeros_like(acc)
    d_phi2[..., :3] = 1.0
    ones = torch.ones_like(acc[..., :1])
    prefix = torch.cumprod(torch.cat([ones, acc[..., :-1]], dim=-1), dim=-1)
    suffix = torch.flip(torch.cumprod(torch.cat([ones, torch.flip(acc, [-1])[..., :-1]], dim=-1), dim=-1), [-1])
    d_phi3 = prefix * suffix
    return torch.stack([d_phi1, d_phi2, d_phi3], dim=-2)
