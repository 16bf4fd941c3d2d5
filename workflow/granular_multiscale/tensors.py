"""Voigt notation used everywhere in the project.

Components are ordered ``11, 22, 33, 23, 13, 12`` (YADE's xx, yy, zz, yz, xz, xy).

* Strain vectors hold *tensorial* shear components (ε23, not γ23 = 2 ε23); this is what
  every file stores.
* Stress vectors are in Pa, tension positive.
* A tangent ``D`` (6×6) is the Voigt stiffness acting on the *engineering* strain vector
  ``[ε11, ε22, ε33, 2ε23, 2ε13, 2ε12]``: ``dσ = D @ engineering(dε)``. Then
  ``D[I, J] = C[i, j, k, l]`` with (i, j) = pair I and (k, l) = pair J, which is also how
  YADE's ``getStressAndTangent`` and most FE codes store it.
* Its 21 independent entries are the upper triangle, row by row (labels ``TCOMP``).
* A tangent that is not symmetric (the exact Jacobian of a learned stress, autodiff) needs
  all 36 entries, row by row over the Voigt pairs (labels ``TCOMP36``: ``1111, 1122, …,
  1211, …, 1212``; entry I·6 + J is ``D[I, J]``). Whether a run file stores them is decided
  by :func:`tangent_asymmetry` against :data:`SYMMETRY_RTOL` (``data.tangent_variables``).
"""

from __future__ import annotations

import numpy as np

COMP = ("11", "22", "33", "23", "13", "12")
VOIGT_PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))
UPPER = np.triu_indices(6)
TCOMP = tuple(f"{COMP[i]}{COMP[j]}" for i, j in zip(*UPPER))
TCOMP36 = tuple(f"{COMP[i]}{COMP[j]}" for i in range(6) for j in range(6))
ENGINEERING_FACTOR = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])
#: relative asymmetry max|D − Dᵀ| / max|D| (per tangent) up to which a tangent counts as symmetric:
#: round-off of a symmetric computation is ~1e-16, a learned Jacobian's asymmetry ~1e-3 and more
SYMMETRY_RTOL = 1e-10


def tensor_norm(v: np.ndarray) -> np.ndarray:
    """[..., 6] Voigt vector (tensorial shear) -> [...] the Frobenius norm of its tensor (shear counted twice)."""
    return np.sqrt(np.sum(ENGINEERING_FACTOR * np.asarray(v) ** 2, axis=-1))


# index of the Voigt component of tensor entry (i, j)
VOIGT_INDEX = np.empty((3, 3), dtype=int)
for _I, (_i, _j) in enumerate(VOIGT_PAIRS):
    VOIGT_INDEX[_i, _j] = VOIGT_INDEX[_j, _i] = _I


def voigt_to_tensor(v: np.ndarray) -> np.ndarray:
    """[..., 6] -> [..., 3, 3] symmetric tensor (tensorial components)."""
    v = np.asarray(v)
    return v[..., VOIGT_INDEX]


def tensor_to_voigt(t: np.ndarray) -> np.ndarray:
    """[..., 3, 3] -> [..., 6], symmetrising the off-diagonal pairs."""
    t = np.asarray(t)
    sym = 0.5 * (t + np.swapaxes(t, -1, -2))
    return np.stack([sym[..., i, j] for i, j in VOIGT_PAIRS], axis=-1)


def engineering(strain: np.ndarray) -> np.ndarray:
    """Tensorial strain vector -> engineering strain vector (shear doubled)."""
    return np.asarray(strain) * ENGINEERING_FACTOR


def tangent_to_upper(D: np.ndarray) -> np.ndarray:
    """[..., 6, 6] -> [..., 21] upper triangle, row by row."""
    return np.asarray(D)[..., UPPER[0], UPPER[1]]


def tangent_from_upper(u: np.ndarray) -> np.ndarray:
    """[..., 21] -> [..., 6, 6] symmetric matrix."""
    u = np.asarray(u)
    D = np.zeros(u.shape[:-1] + (6, 6), dtype=u.dtype)
    D[..., UPPER[0], UPPER[1]] = u
    D[..., UPPER[1], UPPER[0]] = u
    return D


def tangent_to_full(D: np.ndarray) -> np.ndarray:
    """[..., 6, 6] -> [..., 36], row by row (labels ``TCOMP36``); no entry dropped."""
    D = np.asarray(D)
    return D.reshape(D.shape[:-2] + (36,))


def tangent_from_full(f: np.ndarray) -> np.ndarray:
    """[..., 36] row by row -> [..., 6, 6] (inverse of :func:`tangent_to_full`)."""
    f = np.asarray(f)
    return f.reshape(f.shape[:-1] + (6, 6))


def symmetric_part(D: np.ndarray) -> np.ndarray:
    """[..., 6, 6] -> ½(D + Dᵀ); exactly D where D is exactly symmetric."""
    D = np.asarray(D)
    return 0.5 * (D + np.swapaxes(D, -1, -2))


def tangent_asymmetry(D: np.ndarray) -> float:
    """Largest relative asymmetry max|D − Dᵀ| / max|D| over the tangents [..., 6, 6] (0 for none or all-zero)."""
    D = np.asarray(D, dtype=float)
    if D.size == 0:
        return 0.0
    skew = np.abs(D - np.swapaxes(D, -1, -2)).max(axis=(-2, -1))
    scale = np.abs(D).max(axis=(-2, -1))
    ratio = np.where(scale > 0, skew / np.where(scale > 0, scale, 1.0), np.where(skew > 0, np.inf, 0.0))
    return float(ratio.max())


def tangent_to_tensor4(D: np.ndarray) -> np.ndarray:
    """[..., 6, 6] Voigt stiffness -> [..., 3, 3, 3, 3] with σ_ij = C_ijkl ε_kl."""
    D = np.asarray(D)
    return D[..., VOIGT_INDEX[:, :, None, None], VOIGT_INDEX[None, None, :, :]]


def isotropic_elastic_tangent(youngs_modulus: float, poisson_ratio: float) -> np.ndarray:
    """6×6 Voigt stiffness of an isotropic linear elastic solid."""
    E, nu = youngs_modulus, poisson_ratio
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    D = np.zeros((6, 6))
    D[:3, :3] = lam
    D[np.arange(3), np.arange(3)] += 2 * mu
    D[np.arange(3, 6), np.arange(3, 6)] = mu
    return D
