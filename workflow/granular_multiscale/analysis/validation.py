"""Validation per load path and load phase: FEM–ML runs against the reference run of their path.

For one load path (a validation path the networks never saw, or a training path: the in-sample
error), each method (FEM–ML with history variables, the no-history ablation, ...) and each load
phase with its cycle numbered (initial, loading, unloading 1, reloading 1, unloading 2, ...;
``paths.number_cycles``), plus 'all' (load steps 1..n, the initial state left out):

* ``steps`` of ``steps_in_phase``: the phase's steps the run reached, of the reference's;
* top force: max and mean over the phase's steps of |F − F_ref|, in % of the reference's peak
  |F| over the whole path (so the near-zero force at the end of an unloading does not blow a
  ratio up);
* volumetric strain: max |εv − εv_ref| over the phase's steps, in % of the reference's peak
  |εv| over the whole path;
* stress MAE: mean of |σ − σ_ref| over the phase's steps, the Gauss points and the six
  components (kPa).

A run that stopped before the end of its path (``metrics.is_partial``) is compared over the
steps it reached and says so (``completed``, ``load_steps_reached`` of ``load_steps``); a phase
it never reached has 0 steps and no errors (NaN).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd
import xarray as xr

from ..paths import number_cycles
from . import metrics, tables

COLUMNS = (
    "path",
    "role",
    "method",
    "phase",
    "steps",
    "steps_in_phase",
    "completed",
    "load_steps_reached",
    "load_steps",
    "top_force_max_pct",
    "top_force_mean_pct",
    "volumetric_strain_max_pct",
    "stress_mae_kpa",
)
ROLES = ("validation path", "training path")


def _percent_of(error: np.ndarray, peak: float) -> np.ndarray:
    return 100.0 * error / peak if peak > 0 else np.full_like(error, np.nan)


def _over(steps: np.ndarray, values: np.ndarray, reduce) -> float:
    """``reduce`` of the values at the chosen steps; NaN when none was reached."""
    return float(reduce(values[steps])) if steps.any() else np.nan


def phase_groups(reference: xr.Dataset) -> list[tuple[str, np.ndarray]]:
    """(phase label, step mask) over the reference's steps: each cycle-numbered phase in the
    order the path meets it, then 'all' (every load step, step 0 excluded)."""
    phases = number_cycles(tables.phase_labels(reference))
    groups = [(label, phases == label) for label in dict.fromkeys(phases)]
    return groups + [("all", np.arange(phases.size) >= 1)]


def phase_errors(reference: xr.Dataset, runs: Mapping[str, xr.Dataset], *, path: str,
                 role: str = "validation path") -> pd.DataFrame:
    """One row per method × phase (columns :data:`COLUMNS`) of the runs ``{method: run}``
    against ``reference``, all of load path ``path``; ``role``: one of :data:`ROLES`."""
    if role not in ROLES:
        raise ValueError(f"role {role!r} of path {path}: expected one of {ROLES}")
    groups = phase_groups(reference)
    n_steps = reference.sizes["step"]
    force_ref = reference["top_force"].values.astype(float)
    volume_ref = reference["volumetric_strain"].values.astype(float)
    peak_force, peak_volume = float(np.abs(force_ref).max()), float(np.abs(volume_ref).max())
    rows = []
    for method, run in runs.items():
        shared = metrics.common_steps(reference, run, label=f"{method} on {path}")  # the steps it reached
        m = shared.sizes["step"]
        force = _percent_of(np.abs(run["top_force"].values - force_ref[:m]), peak_force)
        volume = _percent_of(np.abs(run["volumetric_strain"].values - volume_ref[:m]), peak_volume)
        stress_error = run["stress"] - shared["stress"]  # aligned by the labelled step, gp, comp
        stress_kpa = 1e-3 * np.abs(stress_error).mean(dim=("gp", "comp")).values  # per step
        for phase, pick in groups:
            reached = pick[:m]
            rows.append({
                "path": path,
                "role": role,
                "method": method,
                "phase": phase,
                "steps": int(reached.sum()),
                "steps_in_phase": int(pick.sum()),
                "completed": "no" if metrics.is_partial(run) else "yes",
                "load_steps_reached": metrics.steps_reached(run),
                "load_steps": n_steps - 1,
                "top_force_max_pct": _over(reached, force, np.max),
                "top_force_mean_pct": _over(reached, force, np.mean),
                "volumetric_strain_max_pct": _over(reached, volume, np.max),
                "stress_mae_kpa": _over(reached, stress_kpa, np.mean),
            })
    return pd.DataFrame(rows, columns=list(COLUMNS))


# -- the table as people read it -----------------------------------------------------------

HEADERS = {
    "path": "load path",
    "role": "role",
    "method": "method",
    "phase": "load phase",
    "steps": "load steps compared",
    "completed": "completed",
    "top_force_max_pct": "top force, max error (% of peak)",
    "top_force_mean_pct": "top force, mean error (% of peak)",
    "volumetric_strain_max_pct": "vol. strain, max error (% of peak)",
    "stress_mae_kpa": "Gauss-point stress MAE (kPa)",
}


def _two_decimals(value) -> str:
    return "–" if value is None or not np.isfinite(value) else f"{value:.2f}"


def display_table(table: pd.DataFrame) -> pd.DataFrame:
    """The table with readable cells: errors to two decimals ('–' where a phase was not reached),
    steps as 'k of n', and a run that stopped early as 'no: stopped after step k of n'."""
    shown = table[["path", "role", "method", "phase"]].copy()
    shown["steps"] = [f"{k} of {n}" for k, n in zip(table["steps"], table["steps_in_phase"])]
    shown["completed"] = ["yes" if done == "yes" else f"no: stopped after step {k} of {n}"
                          for done, k, n in zip(table["completed"], table["load_steps_reached"], table["load_steps"])]
    for column in ("top_force_max_pct", "top_force_mean_pct", "volumetric_strain_max_pct", "stress_mae_kpa"):
        shown[column] = [_two_decimals(v) for v in table[column]]
    return shown
