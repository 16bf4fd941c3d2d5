"""Scalar quantities drawn in the figures, from the stored Voigt vectors.

Stored conventions (see ``tensors``): stress in Pa, tension positive; strain tensorial,
tension positive; Voigt order 11, 22, 33, 23, 13, 12; axis 3 (z) is axial.

Plotting conventions, chosen so a triaxial compression test reads the way soil mechanics
draws it:

* deviatoric stress ``q = sqrt(3 J2)``, signed positive when the axial stress is more
  compressive than the mean lateral stress (``(σ11 + σ22)/2 − σ33 > 0``) — in triaxial
  compression q = σ_axial − σ_radial, compression positive, and an unloading that reaches
  extension shows as negative q instead of folding back;
* mean stress ``p = −tr σ / 3`` (compression positive);
* local axial strain ``−ε33`` (compression positive, as ``axial_strain`` in the files);
* volumetric strain ``tr ε`` (tension/dilation positive, as ``volumetric_strain`` in the files);
* equivalent shear strain ``ε_s = sqrt(2/3 e:e)``, ``e = ε − tr ε / 3 I`` (off-diagonal
  entries count twice); for uniaxial isochoric straining it equals the axial strain.
"""

from __future__ import annotations

import numpy as np

from ..history import equivalent_shear_strain  # noqa: F401 (the analysis's quantities)
from ..tensors import voigt_to_tensor

_SHEAR_WEIGHT = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])


def _deviator(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    mean = v[..., :3].mean(axis=-1, keepdims=True)
    dev = v.copy()
    dev[..., :3] -= mean
    return dev


def mean_stress(stress: np.ndarray) -> np.ndarray:
    """p = −tr σ / 3, compression positive; [..., 6] -> [...]."""
    return -np.asarray(stress, dtype=float)[..., :3].mean(axis=-1)


def deviatoric_stress(stress: np.ndarray) -> np.ndarray:
    """Signed q = ±sqrt(3 J2); positive when the axial (33) stress is the most compressive."""
    s = _deviator(stress)
    j2 = 0.5 * np.sum(_SHEAR_WEIGHT * s**2, axis=-1)
    stress = np.asarray(stress, dtype=float)
    sign = np.where(0.5 * (stress[..., 0] + stress[..., 1]) - stress[..., 2] >= 0.0, 1.0, -1.0)
    return sign * np.sqrt(3.0 * j2)


def volumetric_strain(strain: np.ndarray) -> np.ndarray:
    """tr ε, tension (dilation) positive; [..., 6] -> [...]."""
    return np.asarray(strain, dtype=float)[..., :3].sum(axis=-1)


def local_axial_strain(strain: np.ndarray) -> np.ndarray:
    """−ε33, compression positive; [..., 6] -> [...]."""
    return -np.asarray(strain, dtype=float)[..., 2]


def lode_angle(stress: np.ndarray) -> np.ndarray:
    """Lode angle θ in degrees, [..., 6] -> [...]: 0° in triaxial compression (one principal stress
    more compressive than two equal others, σ tension positive), 60° in triaxial extension, 30°
    in pure shear (the intermediate stress halfway), from cos 3θ = −(3√3/2) J3 / J2^(3/2); NaN
    where the stress is isotropic."""
    s = voigt_to_tensor(_deviator(stress))
    j2 = 0.5 * np.einsum("...ij,...ij->...", s, s)
    j3 = np.linalg.det(s)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.clip(-1.5 * np.sqrt(3.0) * j3 / j2**1.5, -1.0, 1.0)
    return np.where(j2 > 0, np.degrees(np.arccos(c)) / 3.0, np.nan)


def principal_axis_rotation(stress: np.ndarray, axis=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Angle in degrees between the most compressive principal stress direction and `axis` (the
    vertical, the triaxial specimen's loading axis), [..., 6] -> [...] in [0°, 90°]."""
    _, vectors = np.linalg.eigh(voigt_to_tensor(np.asarray(stress, dtype=float)))
    major = vectors[..., :, 0]  # eigh sorts ascending: the first is the most compressive (tension +)
    return np.degrees(np.arccos(np.clip(np.abs(major @ np.asarray(axis, dtype=float)), 0.0, 1.0)))
