"""Accuracy of a run against the reference run of the same load path and mesh.

Definitions (all stresses in Pa, tension positive; ‖·‖ is the tensor norm of a Voigt stress,
shear components counted twice):

* per-Gauss-point stress MAE of component c: mean over steps of |σ_c − σ_c,ref|;
* relative stress error of a (step, point): ‖σ − σ_ref‖ / ‖σ_ref‖ (the reference stress is
  never near zero: the specimen is confined);
* curve errors of a per-step quantity q (top force, volumetric strain), over all steps and
  over each load phase: max and RMS of |q − q_ref|; the same in % of max|q_ref| over the
  path ("of peak"); and the pointwise relative error |q − q_ref| / |q_ref| at steps where
  |q_ref| is at least 1 % of its peak (where it crosses zero a pointwise ratio means nothing);
* Newton iterations per step of every run side by side.

A FEM–ML run that stopped before the end of its path (attribute ``completed = 0``, see
``drivers.fem_ml``) is compared over the steps it reached; every table says so
(``completed``, ``steps_compared``).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd
import xarray as xr

from ..tensors import COMP, tensor_norm

CURVE_QUANTITIES = ("top_force", "volumetric_strain")
PHASE_ORDER = ("loading", "unloading", "reloading")


def stress_norm(stress: np.ndarray) -> np.ndarray:
    return tensor_norm(stress)


def is_partial(run: xr.Dataset) -> bool:
    """A run that stopped before the end of its load path (FEM–ML attribute completed = 0)."""
    return int(run.attrs.get("completed", 1)) == 0


def common_steps(reference: xr.Dataset, run: xr.Dataset, label: str = "run") -> xr.Dataset:
    """The reference restricted to the steps ``run`` shares with it, after checking that the two
    are comparable (same mesh, same load path; a partial run may stop early). Raises naming
    ``label`` and what differs."""
    n_ref, n_run = reference.sizes["step"], run.sizes["step"]
    if n_run != n_ref and not (is_partial(run) and n_run < n_ref):
        raise ValueError(f"{label}: {n_run} steps, the reference has {n_ref}")
    reference = reference.isel(step=slice(0, n_run))
    # the load schedule: the triaxial specimen's and the biaxial test's axial strain, the footing's settlement
    schedule = next((name for name in ("axial_strain", "load_displacement") if name in reference and name in run), None)
    if schedule is None:
        raise ValueError(f"{label}: no load schedule (axial_strain or load_displacement) shared with the reference")
    if not np.allclose(reference[schedule].values, run[schedule].values, rtol=1e-9, atol=1e-12):
        raise ValueError(f"{label}: {schedule.replace('_', ' ')} schedule differs from the reference (another load path?)")
    if "gp" in reference.dims and reference.sizes["gp"] != run.sizes.get("gp", -1):
        raise ValueError(f"{label}: {run.sizes.get('gp')} Gauss points, the reference has {reference.sizes['gp']}")
    if "gp_position" in reference and "gp_position" in run:
        if not np.allclose(reference["gp_position"].values, run["gp_position"].values, atol=1e-9):
            raise ValueError(f"{label}: Gauss-point positions differ from the reference (another mesh?)")
    return reference


def steps_reached(run: xr.Dataset) -> int:
    """Load steps a run reached (step 0, the initial state, not counted)."""
    return int(run.sizes["step"]) - 1


def _stress_pair(reference: xr.Dataset, run: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
    ref = reference["stress"].transpose("step", "gp", "comp").values
    val = run["stress"].transpose("step", "gp", "comp").values
    return ref, val


def split_labels(n_gp: int, train_gp, heldout_gp) -> np.ndarray:
    labels = np.full(n_gp, "none", dtype=object)
    labels[np.asarray(train_gp, dtype=int)] = "train"
    labels[np.asarray(heldout_gp, dtype=int)] = "heldout"
    return labels


def stress_error_by_gp(reference: xr.Dataset, run: xr.Dataset, train_gp, heldout_gp) -> pd.DataFrame:
    """One row per Gauss point: split, MAE per component (Pa), mean relative error and its max over steps."""
    reference = common_steps(reference, run)
    ref, val = _stress_pair(reference, run)
    mae = np.mean(np.abs(val - ref), axis=0)  # [gp, 6]
    rel = stress_norm(val - ref) / stress_norm(ref)  # [step, gp]
    table = pd.DataFrame({"gp": reference["gp"].values, "split": split_labels(ref.shape[1], train_gp, heldout_gp)})
    for j, c in enumerate(COMP):
        table[f"mae_{c}_pa"] = mae[:, j]
    table["mae_mean_pa"] = mae.mean(axis=1)
    table["relative_error_mean"] = rel.mean(axis=0)
    table["relative_error_max"] = rel.max(axis=0)
    if "gp_position" in reference:
        for j, axis in enumerate("xyz"):
            table[axis] = reference["gp_position"].values[:, j]
    return table


def stress_error_summary(reference: xr.Dataset, run: xr.Dataset, train_gp, heldout_gp) -> pd.DataFrame:
    """Rows heldout / train / all: MAE per component (Pa) over (step, point), relative errors."""
    reference = common_steps(reference, run)
    ref, val = _stress_pair(reference, run)
    labels = split_labels(ref.shape[1], train_gp, heldout_gp)
    rows = []
    for split in ("heldout", "train", "all"):
        pick = np.ones(ref.shape[1], bool) if split == "all" else labels == split
        if not pick.any():
            continue
        err = np.abs(val[:, pick] - ref[:, pick])
        rel = stress_norm(val[:, pick] - ref[:, pick]) / stress_norm(ref[:, pick])
        row = {"split": split, "n_gp": int(pick.sum())}
        row.update({f"mae_{c}_pa": float(err[..., j].mean()) for j, c in enumerate(COMP)})
        row["mae_mean_pa"] = float(err.mean())
        row["relative_error_mean"] = float(rel.mean())
        row["relative_error_p95"] = float(np.percentile(rel, 95))
        row["relative_error_max"] = float(rel.max())
        rows.append(row)
    return pd.DataFrame(rows)


def _curve_row(q: np.ndarray, q_ref: np.ndarray, peak: float) -> dict:
    err = np.abs(q - q_ref)
    significant = np.abs(q_ref) >= 0.01 * peak
    rel = err[significant] / np.abs(q_ref[significant]) if significant.any() else np.array([np.nan])
    return {
        "n_steps": int(q.size),
        "max_abs_error": float(err.max()),
        "rms_abs_error": float(np.sqrt(np.mean(err**2))),
        "max_error_percent_of_peak": float(100 * err.max() / peak) if peak > 0 else np.nan,
        "rms_error_percent_of_peak": float(100 * np.sqrt(np.mean(err**2)) / peak) if peak > 0 else np.nan,
        "max_relative_error_percent": float(100 * np.max(rel)),
        "rms_relative_error_percent": float(100 * np.sqrt(np.mean(rel**2))),
        "steps_below_1pct_of_peak": int((~significant).sum()),
    }


def curve_errors(reference: xr.Dataset, run: xr.Dataset) -> pd.DataFrame:
    """Rows (quantity, phase) with phase 'all' and every load phase after step 0."""
    reference = common_steps(reference, run)
    phase = reference["phase"].values.astype(str) if "phase" in reference else np.full(reference.sizes["step"], "all")
    rows = []
    for name in CURVE_QUANTITIES:
        q_ref = reference[name].values.astype(float)
        q = run[name].values.astype(float)
        peak = float(np.abs(q_ref).max())
        units = reference[name].attrs.get("units", "")
        groups = [("all", np.ones_like(q_ref, bool))] + [(p, phase == p) for p in PHASE_ORDER if (phase == p).any()]
        for label, pick in groups:
            rows.append({"quantity": name, "units": units, "phase": label, **_curve_row(q[pick], q_ref[pick], peak)})
    return pd.DataFrame(rows)


def newton_iterations(runs: Mapping[str, xr.Dataset]) -> pd.DataFrame:
    """Newton iterations (and cutbacks) per step, one column per run; runs share the schedule of
    the first. A run that stopped early (attribute completed = 0) has empty cells after its last step."""
    first = next(iter(runs.values()))
    n = first.sizes["step"]
    table = pd.DataFrame({"step": first["step"].values, "axial_strain": first["axial_strain"].values})
    if "phase" in first:
        table["phase"] = first["phase"].values.astype(str)
    for label, ds in runs.items():
        m = ds.sizes["step"]
        if m > n or not np.allclose(ds["axial_strain"].values, first["axial_strain"].values[:m], atol=1e-12):
            raise ValueError(f"{label}: axial strain schedule differs from the first run's")
        for name, column in (("newton_iterations", "iterations"), ("cutbacks", "cutbacks")):
            if name in ds:
                values = np.full(n, np.nan)
                values[:m] = ds[name].values
                table[f"{column}_{label}"] = pd.array(values, dtype="Int64") if m == n else values
    return table


def out_of_range(runs: Mapping[str, xr.Dataset]) -> pd.DataFrame:
    """Per run: steps with inputs outside the training range, the most points at one step, the largest excess."""
    rows = []
    for label, ds in runs.items():
        if "out_of_range_points" not in ds:
            continue
        points = ds["out_of_range_points"].values
        rows.append(
            {
                "run": label,
                "method": ds.attrs.get("method", ""),
                "steps_with_out_of_range_inputs": int((points > 0).sum()),
                "max_points_out_of_range": int(np.nanmax(points)) if points.size else 0,
                "n_gp": int(ds.sizes["gp"]),
                "max_excess_of_training_range": float(np.nanmax(ds["out_of_range_excess"].values)),
            }
        )
    return pd.DataFrame(rows, columns=["run", "method", "steps_with_out_of_range_inputs", "max_points_out_of_range",
                                       "n_gp", "max_excess_of_training_range"])


def compare(reference: xr.Dataset, run: xr.Dataset, train_gp, heldout_gp, /, **labels) -> dict[str, pd.DataFrame]:
    """All tables of one (reference, run) pair, each with the given label columns prepended."""

    def tag(df: pd.DataFrame) -> pd.DataFrame:
        for i, (k, v) in enumerate(labels.items()):
            df.insert(i, k, v)
        return df

    # a run that stopped early is compared over the steps it reached, and says so
    labels = dict(labels, completed=int(not is_partial(run)), steps_compared=int(run.sizes["step"]))
    return {
        "stress_error_by_gp": tag(stress_error_by_gp(reference, run, train_gp, heldout_gp)),
        "stress_error": tag(stress_error_summary(reference, run, train_gp, heldout_gp)),
        "curve_errors": tag(curve_errors(reference, run)),
    }
