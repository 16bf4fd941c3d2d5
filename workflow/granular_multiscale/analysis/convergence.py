"""The reference's own numerical error: FEM–DEM runs of one path at several Newton settings
(tolerance, predictor, acceleration) against the tightest of them, with the DEM cost of each.

    table = tolerance_table({name: run}, settings={name: overrides}, converged=name)
    tolerance_figure(table, out)

Every run uses the same packing, mesh and path, so what differs is only where Newton stopped:
each step's stresses are exact DEM responses to its strains, and the out-of-balance force
left at the accepted iterate (``residual_relative`` ≤ tolerance) is the only approximation. The
errors are those of the run against the converged one, by the definitions the accuracy table
uses (``metrics.curve_errors``): top force in % of the converged run's peak, volumetric strain in
% of its peak magnitude, Gauss-point stress MAE in kPa. The cost is the DEM work per load step:
RVE evaluations (predictor included) and particle-steps.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd
import xarray as xr

from . import metrics

COLUMNS = (
    "variant",
    "tolerance",
    "predictor",
    "acceleration",
    "load_steps",
    "evaluations_per_step",
    "corrections_per_step",
    "particle_steps_per_step",
    "cutbacks",
    "residual_relative_max",
    "wall_time_s",
    "top_force_max_pct",
    "top_force_rms_pct",
    "volumetric_strain_max_pct",
    "stress_mae_kpa",
    "cost_ratio",
)


def cost_per_step(run: xr.Dataset) -> dict:
    """DEM work per load step (step 0, the consolidated state, excluded)."""
    steps = slice(1, None)
    evaluations = np.asarray(run["material_evaluations"].values[steps], dtype=float)
    row = {
        "load_steps": int(evaluations.size),
        "evaluations_per_step": float(evaluations.mean()),
        "corrections_per_step": float(np.asarray(run["newton_iterations"].values[steps], dtype=float).mean()),
        "cutbacks": int(run["cutbacks"].values.sum()),
        "wall_time_s": float(run.attrs.get("time_run_s", np.nan)),
    }
    if "particle_steps" in run:
        row["particle_steps_per_step"] = float(np.asarray(run["particle_steps"].values[steps], dtype=float).mean())
    else:
        row["particle_steps_per_step"] = np.nan
    if "residual_relative" in run:
        row["residual_relative_max"] = float(np.nanmax(run["residual_relative"].values))
    else:  # files written before residual_relative existed
        norms = run["residual_norm"].values
        last = np.array([r[np.isfinite(r)][-1] for r in norms])
        row["residual_relative_max"] = float(np.max(last / run["residual_reference"].values))
    return row


def errors_against(converged: xr.Dataset, run: xr.Dataset, label: str) -> dict:
    """Top-force, volumetric-strain and stress differences of ``run`` from ``converged``."""
    metrics.common_steps(converged, run, label=label)
    if run.sizes["step"] != converged.sizes["step"]:
        raise ValueError(f"{label}: {run.sizes['step']} steps, the converged run {converged.sizes['step']}")
    curves = metrics.curve_errors(converged, run).set_index(["quantity", "phase"])
    volume = converged["volumetric_strain"].values
    stress_error = np.abs(run["stress"].values[1:] - converged["stress"].values[1:])
    return {
        "top_force_max_pct": float(curves.loc[("top_force", "all"), "max_error_percent_of_peak"]),
        "top_force_rms_pct": float(curves.loc[("top_force", "all"), "rms_error_percent_of_peak"]),
        "volumetric_strain_max_pct": float(100 * np.abs(run["volumetric_strain"].values - volume).max()
                                           / np.abs(volume).max()),
        "stress_mae_kpa": float(1e-3 * stress_error.mean()),
    }


def tolerance_table(runs: Mapping[str, xr.Dataset], settings: Mapping[str, Mapping], converged: str,
                    baseline: str | None = None) -> pd.DataFrame:
    """One row per run, sorted by solver and tolerance. ``settings``: each run's Newton settings
    (tolerance, predictor, acceleration); ``converged``: the run taken as the converged limit;
    ``cost_ratio``: DEM evaluations per step over those of ``baseline`` (e.g. the old default)."""
    if converged not in runs:
        raise KeyError(f"config key 'tolerance_study.converged': {converged!r} is not one of the variants {sorted(runs)}")
    if baseline is not None and baseline not in runs:
        raise KeyError(f"config key 'tolerance_study.baseline': {baseline!r} is not one of the variants {sorted(runs)}")
    limit = runs[converged]
    rows = []
    for name, run in runs.items():
        s = settings[name]
        row = {"variant": name, "tolerance": float(s["tolerance"]), "predictor": s["predictor"],
               "acceleration": s["acceleration"], **cost_per_step(run), **errors_against(limit, run, name)}
        rows.append(row)
    table = pd.DataFrame(rows)
    reference = table.set_index("variant").loc[baseline or converged, "evaluations_per_step"]
    table["cost_ratio"] = table["evaluations_per_step"] / reference
    table = table.sort_values(["predictor", "acceleration", "tolerance"], ascending=[True, True, False])
    return table[list(COLUMNS)].reset_index(drop=True)


def newton_settings_of(run: xr.Dataset) -> dict | None:
    """The Newton settings a run was solved with and the largest relative residual it accepted
    (None for a file that does not record its tolerance)."""
    if "newton_tolerance" not in run.attrs:
        return None
    predictor, acceleration = run.attrs.get("newton_predictor"), run.attrs.get("newton_acceleration")
    if predictor is None or acceleration is None:
        # a file written before these attributes: the Newton section of the config stored with
        # it (a FEM–DEM run's with the dem.newton overrides)
        from ..data import run_config

        config = run_config(run) or {}
        newton = dict(config.get("newton", {}))
        if run.attrs.get("method") == "dem":
            newton.update(config.get("dem", {}).get("newton", {}))
        predictor, acceleration = newton.get("predictor", "tangent"), newton.get("acceleration", "none")
    return {
        "tolerance": float(run.attrs["newton_tolerance"]),
        "predictor": str(predictor),
        "acceleration": str(acceleration),
        "residual_relative_max": cost_per_step(run)["residual_relative_max"],
    }


def self_consistency(study_csv: str | Path, newton: Mapping) -> dict | None:
    """The tolerance-study row solved with the same Newton settings as ``newton`` (a run's, see
    :func:`newton_settings_of`): its differences from the converged variant. None when there is
    no study table or no such row."""
    path = Path(study_csv)
    if not path.is_file():
        return None
    table = pd.read_csv(path)
    same = table[np.isclose(table["tolerance"], newton["tolerance"], rtol=1e-9)
                 & (table["predictor"] == newton["predictor"]) & (table["acceleration"] == newton["acceleration"])]
    if same.empty:
        return None
    row = same.iloc[0]
    converged = table.loc[table["top_force_max_pct"].eq(0) & table["stress_mae_kpa"].eq(0)]
    return {
        "variant": str(row["variant"]),
        "converged_tolerance": float(converged["tolerance"].min()) if not converged.empty else None,
        "top_force_max_pct": float(row["top_force_max_pct"]),
        "volumetric_strain_max_pct": float(row["volumetric_strain_max_pct"]),
        "stress_mae_kpa": float(row["stress_mae_kpa"]),
        "evaluations_per_step": float(row["evaluations_per_step"]),
        "file": str(path),
    }


def solver_label(predictor: str, acceleration: str) -> str:
    return f"{predictor} predictor" + (", Anderson" if acceleration != "none" else "")


def tolerance_figure(table: pd.DataFrame, out: str | Path, converged: str, *, title: str,
                     figsize=(10.0, 3.6), dpi: int = 120) -> Path:
    """Three panels against the tolerance: top-force and volumetric-strain difference from the
    converged run, and DEM evaluations per load step; one line per solver."""
    from .figures import plt, save_figure, style

    fig, axes = plt.subplots(1, 3, figsize=figsize)
    panels = (("top_force_max_pct", "top force, max difference (% of peak)"),
              ("volumetric_strain_max_pct", "volumetric strain, max difference\n(% of peak magnitude)"),
              ("evaluations_per_step", "DEM evaluations per load step"))
    others = table[table["variant"] != converged]
    for k, ((predictor, acceleration), group) in enumerate(others.groupby(["predictor", "acceleration"], sort=True)):
        st = style(k + 1)
        st["linestyle"] = "-"
        for ax, (column, _) in zip(axes, panels):
            ax.plot(group["tolerance"], group[column], label=solver_label(predictor, acceleration), **st)
    limit = table[table["variant"] == converged].iloc[0]
    axes[2].plot([limit["tolerance"]], [limit["evaluations_per_step"]], "k*", markersize=10,
                 label=f"converged run ({limit['variant']})")
    for ax, (column, label) in zip(axes, panels):
        ax.set_xscale("log")
        ax.invert_xaxis()  # tighter to the right
        ax.set_xlabel("Newton tolerance (relative residual)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_yscale("log")
    axes[1].set_yscale("log")
    # upper right of the first panel is free: the differences fall to the right
    handles = [h for ax in axes for h in ax.get_legend_handles_labels()[0]]
    labels = [lab for ax in axes for lab in ax.get_legend_handles_labels()[1]]
    unique = dict(zip(labels, handles))
    axes[0].legend(unique.values(), unique.keys(), fontsize=8, loc="upper right")
    fig.suptitle(title, fontsize=10)
    fig.subplots_adjust(left=0.07, right=0.99, bottom=0.17, top=0.88, wspace=0.38)
    return save_figure(fig, out, dpi)


HEADERS = {
    "variant": "variant",
    "tolerance": "tolerance",
    "predictor": "predictor",
    "acceleration": "acceleration",
    "load_steps": "load steps",
    "evaluations_per_step": "DEM evaluations / step",
    "corrections_per_step": "Newton corrections / step",
    "particle_steps_per_step": "particle-steps / step",
    "cutbacks": "cutbacks",
    "residual_relative_max": "largest accepted residual",
    "wall_time_s": "time (s)",
    "top_force_max_pct": "top force max diff. (% of peak)",
    "top_force_rms_pct": "top force RMS diff. (% of peak)",
    "volumetric_strain_max_pct": "vol. strain max diff. (% of peak)",
    "stress_mae_kpa": "stress MAE (kPa)",
    "cost_ratio": "DEM evaluations / baseline's",
}


def make_tolerance_study(run_files: Mapping[str, str | Path], variants: Mapping[str, Mapping], converged: str,
                         baseline: str, out_csv, out_html, out_figure, *, path_label: str,
                         settings: Mapping | None = None) -> pd.DataFrame:
    """The rule's products from the run files ({variant: file}); returns the table."""
    from .. import data
    from . import tables

    runs = {name: data.read_run(path) for name, path in run_files.items()}
    table = tolerance_table(runs, variants, converged, baseline)
    tables.write_csv(table, out_csv)
    limit = table.set_index("variant").loc[converged]
    tables.write_html_table(
        table, out_html, title=f"FEM–DEM reference on {path_label}: Newton tolerance study", headers=HEADERS,
        reference_rows=[int(np.flatnonzero(table["variant"] == converged)[0])],
        note=(f"Every run: the same packing, mesh and path; only the Newton settings differ. Differences "
              f"are from the converged variant {converged} (grey; tolerance {limit['tolerance']:g}, its largest "
              f"accepted relative residual {limit['residual_relative_max']:.2g}). DEM evaluations per step include "
              f"the one after the predictor; the cost ratio is relative to {baseline}."),
    )
    settings = settings or {}
    width = float(settings.get("figure_width", 10.0))
    tolerance_figure(table, out_figure, converged, title=f"{path_label}: FEM–DEM against its converged run "
                     f"({converged})", figsize=(width, 0.36 * width), dpi=int(settings.get("dpi", 120)))
    return table
