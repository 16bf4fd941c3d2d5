"""The report's products from files: what each analysis rule script calls.

Every function takes file paths and the config's ``analysis`` section, reads the run files
through ``data.read_run`` (which names the file on any problem), and writes its outputs
atomically. Runs are given as ordered ``{label: file}`` mappings, the reference first.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd
import xarray as xr

from ..atomic import atomic_path
from .. import data
from . import metrics, selection, tables

# figures (matplotlib) and fields (pyvista/VTK) are imported where they are used: the table
# rules then start in a fraction of the time.

# height / width of each kind of figure
ASPECT = {"line": 0.42, "error_map": 0.55, "speed": 0.45, "field_row": 0.36}


def _size(settings: Mapping, kind: str, rows: int = 1) -> tuple[float, float]:
    width = float(settings.get("figure_width", 10.0))
    if kind == "field_row":
        return width, width * (ASPECT[kind] * rows + 0.06)
    return width, width * ASPECT[kind]


def _dpi(settings: Mapping) -> int:
    return int(settings.get("dpi", 120))


def legend_label(label: str, ds: xr.Dataset) -> str:
    """The run's label, saying where a run that stopped early stopped."""
    return f"{label} (stopped after step {metrics.steps_reached(ds)})" if metrics.is_partial(ds) else label


def read_runs(files: Mapping[str, str | Path]) -> dict[str, xr.Dataset]:
    """{legend label: run} in the given order (the reference first)."""
    runs = {label: data.read_run(path) for label, path in files.items()}
    return {legend_label(label, ds): ds for label, ds in runs.items()}


def gauss_point_split(train_file: str | Path, heldout_file: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Training and held-out Gauss-point ids from the dataset files (their ``gp`` coordinate)."""
    ids = []
    for path in (train_file, heldout_file):
        with xr.open_dataset(path, engine=data.ENGINE) as ds:
            if "gp" not in ds.coords:
                raise data.DataFileError(f"dataset file {path} has no 'gp' coordinate")
            ids.append(np.asarray(ds["gp"].values, dtype=int))
    return ids[0], ids[1]


def specimen_bounds(ds: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
    nodes = ds["node_position"].values
    return nodes.min(axis=0), nodes.max(axis=0)


# --------------------------------------------------------------------------------------


def make_error_map(reference_file, surrogate_file, train_file, heldout_file, out, settings: Mapping, *,
                   path_label: str, reference_label: str, surrogate_label: str) -> Path:
    from . import figures

    reference = data.read_run(reference_file)
    surrogate = data.read_run(surrogate_file)
    metrics.common_steps(reference, surrogate, label=f"{surrogate_file} (against {reference_file})")
    train_gp, heldout_gp = gauss_point_split(train_file, heldout_file)
    by_gp = metrics.stress_error_by_gp(reference, surrogate, train_gp, heldout_gp)
    error_kpa = 1e-3 * by_gp["mae_mean_pa"].to_numpy()
    return figures.error_map(reference, error_kpa, train_gp, heldout_gp, out, path_label=path_label,
                             reference_label=reference_label, surrogate_label=legend_label(surrogate_label, surrogate),
                             figsize=_size(settings, "error_map"), dpi=_dpi(settings))


def stress_strain_points(reference: xr.Dataset, heldout_gp, settings: Mapping) -> dict[str, int]:
    """{name: gp} of the stress–strain figures: explicit indices if configured, else the rule."""
    explicit = list(settings.get("stress_strain_gauss_points") or [])
    n_gp = reference.sizes["gp"]
    if explicit:
        bad = [g for g in explicit if not 0 <= g < n_gp]
        if bad:
            raise ValueError(f"config key 'analysis.stress_strain_gauss_points': {bad} outside 0..{n_gp - 1}")
        return {f"gp{g}": int(g) for g in explicit}
    lower, upper = specimen_bounds(reference)
    chosen = selection.select_gauss_points(reference["gp_position"].values, heldout_gp, lower, upper)
    names = settings.get("stress_strain_points") or list(selection.ANCHORS)
    return {name: chosen[name] for name in names}


def make_stress_strain(run_files: Mapping[str, str], train_file, heldout_file, outs: Mapping[str, str],
                       settings: Mapping, *, path_label: str) -> dict[str, int]:
    """One figure per selected held-out Gauss point; ``outs`` maps point name -> PNG path."""
    from . import figures

    runs = read_runs(run_files)
    reference = next(iter(runs.values()))
    train_gp, heldout_gp = gauss_point_split(train_file, heldout_file)
    points = stress_strain_points(reference, heldout_gp, settings)
    if set(points) != set(outs):
        raise ValueError(f"stress–strain outputs {sorted(outs)} do not match the selected points {sorted(points)}")
    for name, gp in points.items():
        where = selection.DESCRIPTIONS.get(name, "chosen in the config")
        xyz = ", ".join(f"{v:.3f}" for v in reference["gp_position"].sel(gp=gp).values)
        status = "held out" if gp in set(heldout_gp.tolist()) else "TRAINING point"
        figures.stress_strain(runs, gp, outs[name], title=f"{path_label}, Gauss point {gp} ({status}) {where}, at ({xyz}) m",
                              figsize=_size(settings, "line"), dpi=_dpi(settings))
    return points


def make_global_response(run_files: Mapping[str, str], out, settings: Mapping, *, path_label: str) -> Path:
    from . import figures

    runs = read_runs(run_files)
    n_steps = next(iter(runs.values())).sizes["step"]
    marked = selection.resolve_steps(settings.get("field_steps", [4, 16, -1]), n_steps)
    return figures.global_response(runs, out, path_label=path_label, marked_steps=marked,
                                   figsize=_size(settings, "line"), dpi=_dpi(settings))


def make_field_figure(reference_file, surrogate_file, quantity: str, out, settings: Mapping, *,
                      path_label: str, reference_label: str, surrogate_label: str) -> Path:
    from . import fields

    reference = data.read_run(reference_file)
    surrogate = data.read_run(surrogate_file)
    metrics.common_steps(reference, surrogate, label=f"{surrogate_file} (against {reference_file})")
    steps = settings.get("field_steps", [4, 16, -1])
    q = fields.FIELD_QUANTITIES[quantity]
    scale = float(settings.get("deformation_scale", 1.0))
    return fields.field_comparison(
        reference, surrogate, quantity, steps, out, labels=(reference_label, legend_label(surrogate_label, surrogate)),
        title=f"{path_label}: {q.label} ({q.unit}) on the deformed mesh (displacement ×{scale:g})",
        deformation_scale=scale, figsize=_size(settings, "field_row", rows=len(steps)), dpi=_dpi(settings),
        window_size=tuple(settings.get("panel_pixels", (420, 620))),
    )


def make_vtk(run_file, out_dir, stem: str) -> Path:
    from . import fields

    return fields.write_vtu_series(data.read_run(run_file), out_dir, stem)


def make_training_curves(curve_files: Mapping[str, str], out, settings: Mapping) -> Path:
    """``curve_files`` keys are 'panel|series' (see ``figures.training_curves``)."""
    from . import figures

    curves = {}
    for key, path in curve_files.items():
        try:
            curves[key] = pd.read_csv(path)
        except (OSError, pd.errors.ParserError) as error:
            raise data.DataFileError(f"training curve file {path}: {error}") from error
    return figures.training_curves(curves, out, figsize=_size(settings, "line"), dpi=_dpi(settings))


# --------------------------------------------------------------------------------------
# tables


def make_speedup_table(run_files: Mapping[str, str], out, *, path_label: str, paper_reference: Mapping | None) -> pd.DataFrame:
    rows = [tables.describe_run(data.read_run(f), label, path_label) for label, f in run_files.items()]
    table = tables.speedup_table(rows, paper_reference)
    tables.write_csv(table, out)
    return table


def write_json(payload: Mapping, out) -> Path:
    with atomic_path(out) as tmp:
        tmp.write_text(json.dumps(payload, indent=2, default=_json_default) + "\n")
    return Path(out)


def _json_default(value):
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    raise TypeError(f"not JSON serialisable: {type(value)}")


def fmt(value, digits: int = 3) -> str:
    """Short human number for the report text."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "n/a"
    return f"{value:.{digits}g}"


def make_accuracy_table(run_files: Mapping[str, str], train_file, heldout_file, out_csv, out_html, *,
                        path_label: str) -> pd.DataFrame:
    """One row per run after the first (the reference) in ``run_files``."""
    labels = list(run_files)
    reference = data.read_run(run_files[labels[0]])
    train_gp, heldout_gp = gauss_point_split(train_file, heldout_file)
    rows = []
    for label in labels[1:]:
        run = data.read_run(run_files[label])
        metrics.common_steps(reference, run, label=f"{run_files[label]} (against {run_files[labels[0]]})")
        rows.append(tables.accuracy_row(reference, run, label, path_label, train_gp, heldout_gp))
    table = pd.DataFrame(rows, columns=list(tables.ACCURACY_COLUMNS))
    tables.write_csv(table, out_csv)
    tables.write_html_table(
        table, out_html, title=f"Accuracy against {labels[0]} on {path_label}",
        headers=ACCURACY_HEADERS,
        note=("A run that stopped before the end of the path is compared over the load steps it reached. "
              "Stress MAE: mean |σ − σ_ref| over load steps 1..n and the six components, per group of Gauss "
              f"points ({len(heldout_gp)} held out, {len(train_gp)} training). Top-force errors relative to the "
              "largest reference top force. Volumetric strain: largest absolute difference over the steps."),
    )
    return table


ACCURACY_HEADERS = {
    "method": "method",
    "path": "path",
    "load_steps_compared": "load steps compared",
    "stress_mae_heldout_kpa": "stress MAE held-out GPs (kPa)",
    "stress_mae_train_kpa": "stress MAE training GPs (kPa)",
    "stress_mae_all_kpa": "stress MAE all GPs (kPa)",
    "top_force_max_rel_pct": "top force max error (%)",
    "top_force_rms_rel_pct": "top force RMS error (%)",
    "volumetric_strain_max_abs_pct": "vol. strain max error (% points)",
    "newton_per_step": "Newton iterations / step",
}

SPEEDUP_HEADERS = {
    "source": "source",
    "method": "method",
    "path": "loading path",
    "load_steps": "total load steps",
    "completed": "completed",
    "unloading_step": "unloading step",
    "reloading_step": "reloading step",
    "rves": "number of RVEs / Gauss points",
    "wall_time_s": "time (s)",
    "wall_time_h": "time (h)",
    "newton_iterations": "Newton iterations",
    "newton_per_step": "Newton iterations / step",
    "speedup": "speedup",
}


def make_speedup_outputs(run_files: Mapping[str, str], out_csv, out_html, *, path_label: str,
                         paper_reference: Mapping | None, machine: str) -> pd.DataFrame:
    table = make_speedup_table(run_files, out_csv, path_label=path_label, paper_reference=paper_reference)
    n_run = len(run_files)
    tables.write_html_table(
        table, out_html, title=f"Speedup on {path_label} (paper Table 4 layout)", headers=SPEEDUP_HEADERS,
        reference_rows=range(n_run, len(table)),
        note=(f"Rows from this run measured on {machine}: wall time of the FEM solve (load-step loop) read "
              f"from each run file; speedup = time per load step of {next(iter(run_files))} / that of the row "
              "(the whole-run ratio when both ran every step; a run with completed = no stopped early). "
              "Grey rows: the paper's Table 4 (2000 RVEs of 1000 spheres on the authors' machine), for reference only."),
    )
    return table


def make_speed_vs_error(speedup_csv, accuracy_csv, out, settings: Mapping) -> Path:
    """Join the two tables on the method label; the reference gets error 0."""
    from . import figures

    speed = pd.read_csv(speedup_csv)
    speed = speed[speed["source"] == "this run"]
    accuracy = pd.read_csv(accuracy_csv)
    merged = speed[["method", "wall_time_s", "load_steps", "completed"]].merge(accuracy, on="method", how="left")
    reference = speed["method"].iloc[0]
    error_columns = {"stress_mae_all_kpa": "stress MAE over all Gauss points (kPa)",
                     "top_force_max_rel_pct": "top-force max error (% of peak)"}
    for column in error_columns:
        merged.loc[merged["method"] == reference, column] = 0.0
    missing = merged[merged[list(error_columns)].isna().any(axis=1)]["method"].tolist()
    if missing:
        raise ValueError(f"no accuracy row for {missing} in {accuracy_csv}")
    stopped = merged["completed"].astype(str) == "no"
    merged.loc[stopped, "method"] = [f"{m} (stopped after step {n}; time and error of those steps)"
                                     for m, n in zip(merged.loc[stopped, "method"], merged.loc[stopped, "load_steps"])]
    merged = merged.rename(columns={"method": "label"})
    return figures.speed_vs_error(merged, out, errors=error_columns, figsize=_size(settings, "speed"), dpi=_dpi(settings))


def make_headline(speedup_csv, accuracy_csv, out, *, config: Mapping, reference_label: str,
                  surrogate_label: str, ablation_label: str | None) -> dict:
    """The numbers the report's front page states (JSON)."""
    speed = pd.read_csv(speedup_csv)
    accuracy = pd.read_csv(accuracy_csv).set_index("method")
    this = speed[speed["source"] == "this run"].set_index("method")
    def acc(label, column):
        return float(accuracy.loc[label, column]) if label in accuracy.index else None
    elements = list(config["specimen"]["elements"])
    headline = {
        "output_dir": config["output_dir"],
        "reference_material": config["reference_material"],
        "reference": reference_label,
        "surrogate": surrogate_label,
        "validation_path": config["validation_path"],
        "training_path": config["training_path"],
        "elements": elements,
        "gauss_points": int(8 * np.prod(elements)),
        "n_spheres": config["dem"]["n_spheres"] if config["reference_material"] == "dem" else None,
        "machine": tables.machine_description(),
        "reference_wall_time_s": float(this.loc[reference_label, "wall_time_s"]),
        "surrogate_wall_time_s": float(this.loc[surrogate_label, "wall_time_s"]),
        "speedup": float(this.loc[surrogate_label, "speedup"]),
        "surrogate_completed": str(this.loc[surrogate_label, "completed"]) == "yes",
        "surrogate_load_steps": int(this.loc[surrogate_label, "load_steps"]),
        "reference_load_steps": int(this.loc[reference_label, "load_steps"]),
        "top_force_max_rel_pct": acc(surrogate_label, "top_force_max_rel_pct"),
        "stress_mae_heldout_kpa": acc(surrogate_label, "stress_mae_heldout_kpa"),
        "ablation": ablation_label,
        "ablation_top_force_max_rel_pct": acc(ablation_label, "top_force_max_rel_pct") if ablation_label else None,
        "ablation_stress_mae_heldout_kpa": acc(ablation_label, "stress_mae_heldout_kpa") if ablation_label else None,
    }
    write_json(headline, out)
    return headline
