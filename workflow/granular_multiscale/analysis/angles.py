"""Friction and dilatancy angles of one RVE from a uniform-field element test, and the
classical numbers they give: the Coulomb and Roscoe band inclinations and the bearing
capacity factor N_q.

    angles = element_angles(run)     # a uniform-field triaxial or plane-strain run

Principal stresses and strains compression positive: σ1, ε1 axial (z), σ3, ε3 lateral (x; in
plane strain y is the out-of-plane direction). Mobilised friction sin φ = (σ1 − σ3)/(σ1 + σ3); the peak friction angle
is its largest value over the run. Dilatancy from the strain increments of a step (total
strains; near the peak the elastic part is small), dε_v = dε1 + 2 dε3 (triaxial) or
dε1 + dε3 (plane strain, ε2 = 0):

    plane strain   sin ψ = −dε_v / (dε1 − dε3)
    triaxial       sin ψ = −dε_v / (2 dε1 − dε_v)

(Mohr–Coulomb flow with the potential's angle ψ; triaxial compression on the corner of two
planes). ψ at the peak is the angle of the steps on either side of the peak stress; ψ_max the
largest over the run.

    Coulomb θ = 45° + φ/2,   Roscoe θ = 45° + ψ/2,   Arthur θ = 45° + (φ + ψ)/4
    N_q = exp(π tan φ) tan²(45° + φ/2)       (Prandtl–Reissner, rough or smooth footing)
"""

from __future__ import annotations

import numpy as np
import xarray as xr

#: (axial, lateral) Voigt components of the element tests (z axial in both)
AXES = {"triaxial": (2, 0), "biaxial": (2, 0)}


def element_angles(run: xr.Dataset) -> dict:
    """Peak friction angle, dilatancy at the peak and its maximum (degrees) of a uniform-field
    triaxial or biaxial run, and where they occur."""
    problem = str(run.attrs.get("problem", "triaxial"))
    if problem not in AXES:
        raise ValueError(f"element angles need a triaxial or biaxial run, got problem {problem!r}")
    axial, lateral = AXES[problem]
    stress = -run["stress"].transpose("step", "gp", "comp").values.mean(axis=1)  # compression positive
    strain = -run["strain"].transpose("step", "gp", "comp").values.mean(axis=1)
    s1, s3 = stress[:, axial], stress[:, lateral]
    sin_phi = (s1 - s3) / (s1 + s3)
    peak = int(np.argmax(sin_phi))
    d1, d3 = np.diff(strain[:, axial]), np.diff(strain[:, lateral])
    if problem == "biaxial":
        dv = d1 + d3
        sin_psi = -dv / (d1 - d3)
    else:
        dv = d1 + 2 * d3
        sin_psi = -dv / (2 * d1 - dv)
    loading = d1 > 0
    psi = np.degrees(np.arcsin(np.clip(np.where(loading, sin_psi, np.nan), -1, 1)))
    around = psi[max(peak - 1, 0): peak + 1]  # the increments into and out of the peak step
    load = run["axial_strain"].values
    return {
        "problem": problem,
        "peak_friction_deg": float(np.degrees(np.arcsin(sin_phi[peak]))),
        "peak_axial_strain": float(load[peak]),
        "peak_deviator_Pa": float(s1[peak] - s3[peak]),
        "dilatancy_at_peak_deg": float(np.nanmean(around)) if np.isfinite(around).any() else float("nan"),
        "max_dilatancy_deg": float(np.nanmax(psi)),
        "max_dilatancy_axial_strain": float(load[1:][int(np.nanargmax(psi))]),
        "final_friction_deg": float(np.degrees(np.arcsin(sin_phi[-1]))),
        "final_axial_strain": float(load[-1]),
    }


def coulomb_angle(phi_deg: float) -> float:
    return 45.0 + phi_deg / 2.0


def roscoe_angle(psi_deg: float) -> float:
    return 45.0 + psi_deg / 2.0


def arthur_angle(phi_deg: float, psi_deg: float) -> float:
    return 45.0 + (phi_deg + psi_deg) / 4.0


def bearing_capacity_factor(phi_deg: float) -> float:
    """N_q = exp(π tan φ) tan²(45° + φ/2)."""
    phi = np.radians(phi_deg)
    return float(np.exp(np.pi * np.tan(phi)) * np.tan(np.pi / 4 + phi / 2) ** 2)
