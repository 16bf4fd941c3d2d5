"""Calibrate the analytic elastoplastic reference to a triaxial run (FEM–DEM, usually).

The elastoplastic model stands in for the DEM RVE where a known truth is needed. Its
defaults are a least-squares fit to the default-scale FEM–DEM Path1: the Gauss-point mean of
the deviator q = −σ33 + (σ11 + σ22)/2 and of the volumetric strain at every step, reproduced
by one material point in a drained triaxial test under the confining pressure. Writing q
and ε_v out of the same point driver lets a test check the fit on curves of known
parameters, and lets a user recalibrate to another packing:

    python -m granular_multiscale.materials.calibration results/fem_dem/path1.h5 \\
        --check results/fem_dem/path2.h5

prints the fitted parameters as a config section and the fit's RMS errors on both paths.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from ..data import read_run
from .base import MaterialPointSet
from .elastoplastic import DEFAULTS, Elastoplastic

#: parameters the fit moves (the others keep their values: k0 = 0, yield starts at Q = η p)
FITTED = ("youngs_modulus", "poisson_ratio", "friction", "saturated_hardening", "hardening_strain", "kinematic_modulus")
#: weight of the volumetric strain in the residual: 0.1 % of ε_v counts as 10 kPa of q (the two
#: curves then weigh about the same: ε_v spans ~1 %, q ~300 kPa)
VOLUMETRIC_WEIGHT = 1.0e7


def drained_triaxial(material: MaterialPointSet, axial_strain, confining_pressure: float, before_commit=None):
    """One point in a drained triaxial test: ε33 = −axial (compression positive axial strain),
    σ11 = σ22 = −confining_pressure, no shear. The lateral strains are found by Newton with the
    material's own tangent. Returns the deviator q (Pa) and ε_v (tension positive) per step;
    ``before_commit(k)`` lets a caller inspect the converged trial of step k."""
    strain = np.zeros((1, 6))
    q, volumetric = [], []
    for k, axial in enumerate(np.asarray(axial_strain, dtype=float)):
        strain[0, 2] = -axial
        for _ in range(50):
            stress, tangent = material.evaluate(strain)
            residual = stress[0, :2] + confining_pressure
            if np.abs(residual).max() < 1e-7 * confining_pressure:
                break
            strain[0, :2] -= np.linalg.solve(tangent[0, :2, :2], residual)
        else:
            raise RuntimeError(f"drained triaxial point did not converge at step {k} (axial strain {axial:.4g})")
        if before_commit is not None:
            before_commit(k)
        material.commit()
        q.append(-stress[0, 2] - confining_pressure)
        volumetric.append(strain[0, :3].sum())
    return np.array(q), np.array(volumetric)


def mean_triaxial_response(run) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Axial strain, Gauss-point mean deviator q (Pa) and mean ε_v of a run (xarray dataset of
    the data contract)."""
    stress = np.asarray(run["stress"].values)
    strain = np.asarray(run["strain"].values)
    q = (-stress[:, :, 2] + 0.5 * (stress[:, :, 0] + stress[:, :, 1])).mean(axis=1)
    volumetric = strain[:, :, :3].sum(axis=2).mean(axis=1)
    return np.asarray(run["axial_strain"].values), q, volumetric


def model_response(params: dict, axial_strain, confining_pressure: float):
    """q and ε_v of the elastoplastic model with ``params`` (missing keys: DEFAULTS)."""
    full = {**DEFAULTS, **params}
    point = Elastoplastic(1, **full, initial_stress=-confining_pressure * np.array([1.0, 1, 1, 0, 0, 0]))
    return drained_triaxial(point, axial_strain, confining_pressure)


def _to_params(x: np.ndarray) -> dict:
    return {n: float(v) if n == "poisson_ratio" else float(np.exp(v)) for n, v in zip(FITTED, x)}


def _to_vector(params: dict) -> np.ndarray:
    return np.array([params[n] if n == "poisson_ratio" else np.log(params[n]) for n in FITTED])


def rms_errors(params: dict, axial_strain, q, volumetric, confining_pressure: float) -> dict:
    """RMS difference between the model with ``params`` and a triaxial curve (q in Pa, ε_v)."""
    q_m, ev_m = model_response(params, axial_strain, confining_pressure)
    return {
        "rms_q_pa": float(np.sqrt(np.mean((q_m - np.asarray(q)) ** 2))),
        "rms_volumetric": float(np.sqrt(np.mean((ev_m - np.asarray(volumetric)) ** 2))),
    }


def fit_elastoplastic(axial_strain, q, volumetric, confining_pressure: float, start: dict | None = None) -> dict:
    """Least-squares fit of FITTED to a triaxial curve (q in Pa, ε_v). Positive parameters
    are fitted in log space; ν in [0, 0.49]. Returns the parameters and the RMS errors."""
    q, volumetric = np.asarray(q, float), np.asarray(volumetric, float)

    def residual(x):
        try:
            q_m, ev_m = model_response(_to_params(x), axial_strain, confining_pressure)
        except (RuntimeError, ValueError, ArithmeticError):
            return np.full(2 * q.size, 1e6)  # a failing trial counts as a very bad fit
        return np.concatenate([q_m - q, VOLUMETRIC_WEIGHT * (ev_m - volumetric)]) / 1e3

    x0 = _to_vector({**DEFAULTS, **(start or {})})
    lower = np.full(x0.size, -np.inf)
    upper = np.full(x0.size, np.inf)
    lower[FITTED.index("poisson_ratio")], upper[FITTED.index("poisson_ratio")] = 0.0, 0.49
    solution = least_squares(residual, np.clip(x0, lower + 1e-9, upper - 1e-9), bounds=(lower, upper), diff_step=1e-3)
    params = _to_params(solution.x)
    return {"params": params, **rms_errors(params, axial_strain, q, volumetric, confining_pressure)}


def _describe(path: Path, errors: dict) -> str:
    return f"# {path}: RMS q {errors['rms_q_pa'] / 1e3:.2f} kPa, RMS ε_v {100 * errors['rms_volumetric']:.3f} %"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="reference run file (data contract) to fit, e.g. results/fem_dem/path1.h5")
    parser.add_argument("--check", type=Path, action="append", default=[], help="another run file to report the fit's error on")
    args = parser.parse_args(argv)
    run = read_run(args.run)
    if "confining_pressure_Pa" not in run.attrs:
        raise SystemExit(f"{args.run}: attribute 'confining_pressure_Pa' missing (data contract: a triaxial run)")
    pressure = float(run.attrs["confining_pressure_Pa"])
    fit = fit_elastoplastic(*mean_triaxial_response(run), pressure)
    print("elastoplastic:")
    for name in FITTED:
        print(f"  {name}: {fit['params'][name]:.4g}")
    print(_describe(args.run, fit))
    for path in args.check:
        print(_describe(path, rms_errors(fit["params"], *mean_triaxial_response(read_run(path)), pressure)))


if __name__ == "__main__":
    main()
