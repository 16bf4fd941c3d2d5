"""The report's products from files: what each analysis rule script calls.

Every function takes file paths and the config's ``analysis`` section, reads the run files
through ``data.read_run`` (which names the file on any problem), and writes its outputs
atomically. Runs are given as ordered ``{label: file}`` mappings, the reference first. A
figure's function returns the numbers it drew (see ``figures``), a table's the table.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd
import xarray as xr

from ..atomic import atomic_path
from .. import data, integrity
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
    """Mesh Gauss-point ids whose reference-run histories trained / were held out (attrs
    ``train_gp``/``heldout_gp`` of the dataset files; an older file: its ``gp`` coordinate). Both
    empty when only RVE paths trained: then every point of a validation run is unseen."""
    ids = []
    for path, key in ((train_file, "train_gp"), (heldout_file, "heldout_gp")):
        integrity.verify(path, "dataset file")
        with xr.open_dataset(path, engine=data.ENGINE) as ds:
            if key in ds.attrs:
                ids.append(np.atleast_1d(np.asarray(ds.attrs[key], dtype=int)))
            elif "gp" in ds.coords:
                ids.append(np.asarray(ds["gp"].values, dtype=int))
            else:
                raise data.DataFileError(f"dataset file {path} has neither attr '{key}' nor a 'gp' coordinate")
    return ids[0], ids[1]


def specimen_bounds(ds: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
    nodes = ds["node_position"].values
    return nodes.min(axis=0), nodes.max(axis=0)


# --------------------------------------------------------------------------------------


def make_error_map(reference_file, surrogate_file, train_file, heldout_file, out, settings: Mapping, *,
                   path_label: str, reference_label: str, surrogate_label: str) -> pd.DataFrame:
    """The error map; returns its points (``figures.error_map``)."""
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
                       settings: Mapping, *, path_label: str) -> tuple[dict[str, int], dict[str, dict]]:
    """One figure per selected held-out Gauss point; ``outs`` maps point name -> PNG path.
    Returns ({point name: gp}, {point name: the curves its figure drew})."""
    from . import figures

    runs = read_runs(run_files)
    reference = next(iter(runs.values()))
    train_gp, heldout_gp = gauss_point_split(train_file, heldout_file)
    points = stress_strain_points(reference, heldout_gp, settings)
    if set(points) != set(outs):
        raise ValueError(f"stress–strain outputs {sorted(outs)} do not match the selected points {sorted(points)}")
    drawn = {}
    for name, gp in points.items():
        where = selection.DESCRIPTIONS.get(name, "chosen in the config")
        xyz = ", ".join(f"{v:.3f}" for v in reference["gp_position"].sel(gp=gp).values)
        status = "held out" if gp in set(heldout_gp.tolist()) else "TRAINING point"
        drawn[name] = figures.stress_strain(
            runs, gp, outs[name], title=f"{path_label}, Gauss point {gp} ({status}) {where}, at ({xyz}) m",
            figsize=_size(settings, "line"), dpi=_dpi(settings))
    return points, drawn


def make_global_response(run_files: Mapping[str, str], out, settings: Mapping, *, path_label: str) -> dict:
    from . import figures

    runs = read_runs(run_files)
    n_steps = next(iter(runs.values())).sizes["step"]
    marked = selection.resolve_steps(settings.get("field_steps", [4, 16, -1]), n_steps)
    return figures.global_response(runs, out, path_label=path_label, marked_steps=marked,
                                   figsize=_size(settings, "line"), dpi=_dpi(settings))


def make_field_figure(reference_file, surrogate_file, quantity: str, out, settings: Mapping, *,
                      path_label: str, reference_label: str, surrogate_label: str) -> dict:
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


def make_training_curves(curve_files: Mapping[str, str], out, settings: Mapping) -> dict:
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


# -- numbers as people read them (the report's pages print these strings) ---------------


def readable_number(value, digits: int = 3) -> str:
    """``digits`` significant digits in plain notation with thousands separators, never an
    exponent: 0.247 -> '0.247', 563.2 -> '563', 2660.3 -> '2,660', 1.2e5 -> '120,000'."""
    if value is None:
        return "n/a"
    value = float(value)
    if not np.isfinite(value):
        return "n/a"
    if value == 0:
        return "0"
    rounded = float(f"{value:.{digits}g}")
    magnitude = int(np.floor(np.log10(abs(rounded))))
    decimals = max(digits - 1 - magnitude, 0)
    return f"{rounded:,.{decimals}f}"


def readable_ratio(value, digits: int = 3) -> str:
    """A speedup: '2,660×', '0.5×'."""
    text = readable_number(value, digits)
    return text if text == "n/a" else f"{text}×"


def readable_duration(seconds) -> str:
    """A wall time in seconds, with minutes (from 2 min) or hours (from 2 h) beside it:
    0.247 -> '0.247 s', 563.2 -> '563 s (9.4 min)', 1.2e5 -> '120,000 s (33 h)'."""
    if seconds is None or not np.isfinite(float(seconds)) or float(seconds) < 0:
        return "n/a"
    seconds = float(seconds)
    text = f"{readable_number(seconds)} s"
    if seconds >= 7200:
        return f"{text} ({readable_number(seconds / 3600, 2)} h)"
    if seconds >= 120:
        return f"{text} ({readable_number(seconds / 60, 2)} min)"
    return text


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
    "rves": "material points evaluated (RVEs)",
    "dem_particle_steps": "DEM particle-steps",
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
              "Material points evaluated: the Gauss points of the modelled mesh (a quarter of them with "
              "specimen.symmetry quarter), 1 for a reference run with specimen.uniform_field (one point stands "
              "for all). DEM particle-steps: the DEM work of the run (Newton trials and, in an adaptive run, "
              "replays), which unlike the wall time does not depend on the machine or its load. Grey rows: the paper's Table 4 (2000 RVEs of 1000 spheres on the authors' machine), "
              "for reference only. What making the surrogate cost is in the surrogate cost table."),
    )
    return table


def make_speed_vs_error(speedup_csv, accuracy_csv, out, settings: Mapping, curve: Sequence[str] = ()) -> dict:
    """The speed-vs-error figure of :func:`speed_error_table`."""
    from . import figures

    merged, error_columns = speed_error_table(speedup_csv, accuracy_csv, curve)
    return figures.speed_vs_error(merged, out, errors=error_columns, figsize=_size(settings, "speed"), dpi=_dpi(settings))


def speed_error_table(speedup_csv, accuracy_csv, curve: Sequence[str] = ()) -> tuple[pd.DataFrame, dict]:
    """Join the two tables on the method label; the reference gets error 0. `curve`: labels
    joined by a line in that order (FEM–ML, the adaptive runs, FEM–DEM; absent ones skipped),
    column 'curve' (NaN off it). Returns the table and {error column: axis label}."""
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
    merged["curve"] = merged["method"].map({label: k for k, label in enumerate(curve)}).astype(float)
    stopped = merged["completed"].astype(str) == "no"
    merged.loc[stopped, "method"] = [f"{m} (stopped after step {n}; time and error of those steps)"
                                     for m, n in zip(merged.loc[stopped, "method"], merged.loc[stopped, "load_steps"])]
    return merged.rename(columns={"method": "label"}), error_columns


def make_mode_map(files: Mapping[str, str | Path], out, settings: Mapping, *, path_label: str) -> dict:
    """Rule figure_mode_map: which Gauss points ran DEM in each adaptive run, at the field figures'
    steps (analysis.field_steps)."""
    from . import figures

    runs = read_runs(files)
    n_steps = min(ds.sizes["step"] for ds in runs.values())
    steps = selection.resolve_steps(settings.get("field_steps", [4, 16, -1]), n_steps)
    width = float(settings.get("figure_width", 10.0))
    return figures.mode_map(runs, steps, out, title=f"{path_label}: Gauss points answered by their YADE RVE (red) "
                            "or by the surrogate (blue)", figsize=(width, width * (0.1 + 0.3 * len(runs))),
                            dpi=_dpi(settings))


COST_HEADERS = {
    "item": "item",
    "kind": "kind",
    "wall_time": "wall time",
    "wall_time_s": "wall time (s)",
    "wall_time_h": "wall time (h)",
    "runs": "runs of the validation path",
    "source": "read from",
}

# cost items: how each is read (see make_surrogate_cost)
COST_READERS = {
    "run": lambda path: tables.run_wall_time(data.read_run(path)),
    "benchmark": tables.benchmark_seconds,
    "rve_summary": tables.rve_preparation_seconds,
}


def _one_run_times(speedup_csv, reference_label: str, surrogate_label: str) -> tuple[float, float, bool]:
    """Wall times of one reference and one surrogate run of the whole path, from the speedup
    table; a surrogate run that stopped early counts at its time per load step (the speedup's
    measure) times the reference's steps. Returns (t_ref, t_ml, t_ml is such an estimate)."""
    speed = pd.read_csv(speedup_csv)
    this = speed[speed["source"] == "this run"].set_index("method")
    for label in (reference_label, surrogate_label):
        if label not in this.index:
            raise ValueError(f"speedup table {speedup_csv} has no row for {label!r} (rows: {list(this.index)})")
    ref, ml = this.loc[reference_label], this.loc[surrogate_label]
    t_ref, t_ml = float(ref["wall_time_s"]), float(ml["wall_time_s"])
    estimated = str(ml["completed"]) != "yes"
    if estimated:
        t_ml = t_ml / max(int(ml["load_steps"]), 1) * int(ref["load_steps"])
    return t_ref, t_ml, estimated


def make_surrogate_cost(items: Sequence[tuple[str, str, str]], speedup_csv, out_csv, out_html, *,
                        reference_label: str, surrogate_label: str, path_label: str) -> pd.DataFrame:
    """The full cost of an answer: each step that makes the surrogate, their total, one run of
    each method (from the speedup table) and the break-even number of FEM–ML runs.

    ``items``: (what, how to read it, file) with how = 'run' (a run file's wall time, as in the
    speedup table), 'benchmark' (a Snakemake benchmark TSV, column ``s``) or 'rve_summary'
    (``rve/summary.json``)."""
    costs = []
    for what, how, path in items:
        if how not in COST_READERS:
            raise ValueError(f"cost item {what!r}: unknown kind {how!r} (one of {sorted(COST_READERS)})")
        costs.append((what, COST_READERS[how](path), str(path)))
    t_ref, t_ml, estimated = _one_run_times(speedup_csv, reference_label, surrogate_label)
    table, numbers = tables.surrogate_cost_table(costs, reference=(reference_label, t_ref),
                                                 surrogate=(surrogate_label, t_ml), path=path_label)
    tables.write_csv(table, out_csv)
    shown = table.drop(columns=["wall_time_h"])
    shown.insert(2, "wall_time", [readable_duration(t) for t in table["wall_time_s"]])
    files = [str(path) for _, _, path in items]
    if len(files) > 1:  # the HTML names the files below their common folder (the output_dir)
        import os

        top = os.path.commonpath(files)
        shown["source"] = [os.path.relpath(f, top) if f in files else f for f in shown["source"]]
    n = numbers["break_even_runs"]
    verdict = (f"Break-even: from {n} FEM–ML runs on, making the surrogate once and running it N times costs no "
               f"more than N runs of {reference_label}: the smallest N with N·t_ML + cost ≤ N·t_ref, "
               "N = ceil(cost / (t_ref − t_ML))." if n is not None else
               f"{surrogate_label} is not faster than {reference_label} here, so the surrogate never pays back.")
    tables.write_html_table(
        shown, out_html, title=f"The full cost of an answer on {path_label}", headers=COST_HEADERS,
        note=(f"Making the surrogate: every step before the first FEM–ML run, as measured in this workflow run "
              "(run files: the FEM solve's wall time, as in the speedup table; benchmarks: the rule's whole wall "
              "time; RVE preparation: the packings' consolidation time from rve/summary.json). "
              + ("The FEM–ML time is an estimate for the whole path (it stopped early): its time per load step "
                 "times the reference's steps. " if estimated else "")
              + verdict),
    )
    return table


def _cost_numbers(cost_csv) -> dict:
    """The headline's numbers of the surrogate cost table."""
    cost = pd.read_csv(cost_csv)
    total = cost[cost["kind"] == "surrogate cost total"]
    if total.empty:
        raise ValueError(f"surrogate cost table {cost_csv} has no row of kind 'surrogate cost total'")
    breaks = cost[cost["kind"] == "break-even"]
    items = cost[cost["kind"] == "surrogate cost"]
    return {
        "surrogate_cost_s": float(total["wall_time_s"].iloc[0]),
        "surrogate_cost_items": [{"item": str(r.item), "wall_time_s": float(r.wall_time_s)} for r in items.itertuples()],
        "break_even_runs": int(breaks["runs"].iloc[0]) if not breaks.empty else None,
    }


def _reduction_from_config(config: Mapping) -> dict:
    """What a run of this config models (for a headline made without the reference run file)."""
    spec = config["specimen"]
    elements = [int(n) for n in spec["elements"]]
    quarter = spec.get("symmetry", "none") == "quarter"
    mesh = [-(-elements[0] // 2), -(-elements[1] // 2), elements[2]] if quarter else elements
    modelled = 8 * int(np.prod(mesh))
    return {"specimen_elements": elements, "mesh_elements": mesh, "symmetry": spec.get("symmetry", "none"),
            "modelled_fraction": 0.25 if quarter else 1.0, "uniform_field": bool(spec.get("uniform_field", False)),
            "gauss_points_full_specimen": 8 * int(np.prod(elements)), "gauss_points_modelled": modelled,
            "material_points_evaluated": 1 if spec.get("uniform_field", False) else modelled}


def make_headline(speedup_csv, accuracy_csv, out, *, config: Mapping, reference_label: str,
                  surrogate_label: str, ablation_label: str | None, reference_run=None, cost_csv=None,
                  page=None) -> dict:
    """The headline numbers (JSON), and under ``display`` the same numbers written as people read
    them; with ``page``, also the report's headline page there (:func:`headline_page`, HTML).

    ``reference_run``: the reference run file of the validation path; what it modelled (symmetry,
    uniform field, Gauss points of its mesh, material points evaluated) is read from it (without
    it, from the config). ``cost_csv``: the surrogate cost table (:func:`make_surrogate_cost`)."""
    speed = pd.read_csv(speedup_csv)
    accuracy = pd.read_csv(accuracy_csv).set_index("method")
    this = speed[speed["source"] == "this run"].set_index("method")
    def acc(label, column):
        return float(accuracy.loc[label, column]) if label in accuracy.index else None
    elements = list(config["specimen"]["elements"])
    reference = data.read_run(reference_run) if reference_run is not None else None
    reduction = tables.model_reduction(reference) if reference is not None else _reduction_from_config(config)
    headline = {
        "output_dir": config["output_dir"],
        "reference_material": config["reference_material"],
        "reference": reference_label,
        "surrogate": surrogate_label,
        "validation_path": config["validation_path"],
        "training_path": config["training_path"],
        "elements": elements,
        # the full specimen's Gauss points; what ran: gauss_points_modelled, material_points_evaluated
        "gauss_points": int(8 * np.prod(elements)),
        "mesh_elements": reduction["mesh_elements"],
        "symmetry": reduction["symmetry"],
        "modelled_fraction": reduction["modelled_fraction"],
        "uniform_field": reduction["uniform_field"],
        "gauss_points_modelled": reduction["gauss_points_modelled"],
        "material_points_evaluated": reduction["material_points_evaluated"],
        "surrogate_points_evaluated": int(this.loc[surrogate_label, "rves"]),
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
        "surrogate_cost_s": None,
        "surrogate_cost_items": [],
        "break_even_runs": None,
    }
    if cost_csv is not None:
        headline.update(_cost_numbers(cost_csv))
    if reference is not None:
        from .convergence import newton_settings_of

        headline["reference_newton"] = newton_settings_of(reference)
    headline["display"] = headline_display(headline)
    write_json(headline, out)
    if page is not None:
        write_page(headline_page(headline), page)
    return headline


def readable_small(value) -> str:
    """A tolerance or a residual: two digits, no exponent, no trailing zeros (2e-3 -> '0.002')."""
    text = readable_number(value, 2)
    return text.rstrip("0").rstrip(".") if "." in text else text


def headline_display(h: Mapping) -> dict:
    """The headline's numbers as the headline page prints them."""
    def pct(v):
        return None if v is None else f"{readable_number(v)} %"

    def kpa(v):
        return None if v is None else f"{readable_number(v)} kPa"

    n = h.get("break_even_runs")
    newton = h.get("reference_newton") or {}
    convergence = h.get("reference_convergence") or {}
    return {
        "reference_tolerance": readable_small(newton["tolerance"]) if newton else None,
        "reference_residual_max": readable_small(newton["residual_relative_max"]) if newton else None,
        "converged_tolerance": readable_small(convergence["converged_tolerance"]) if convergence else None,
        "speedup": readable_ratio(h["speedup"]),
        "reference_wall_time": readable_duration(h["reference_wall_time_s"]),
        "surrogate_wall_time": readable_duration(h["surrogate_wall_time_s"]),
        "top_force_max_rel_pct": pct(h.get("top_force_max_rel_pct")),
        "stress_mae_heldout_kpa": kpa(h.get("stress_mae_heldout_kpa")),
        "ablation_top_force_max_rel_pct": pct(h.get("ablation_top_force_max_rel_pct")),
        "ablation_stress_mae_heldout_kpa": kpa(h.get("ablation_stress_mae_heldout_kpa")),
        "surrogate_cost": None if h.get("surrogate_cost_s") is None else readable_duration(h["surrogate_cost_s"]),
        "surrogate_cost_items": [f"{item['item']} {readable_duration(item['wall_time_s'])}"
                                 for item in h.get("surrogate_cost_items", [])],
        "break_even_runs": None if n is None else f"{n:,}",
    }


# -- the report's headline pages (category "0 Headline") ---------------------------------
# The report's front page (workflow/report/workflow.rst) is rendered from the config alone;
# the numbers of a run reach the report as these pages, written by the jobs that know them:
# headline_page by rule headline (with tables/headline.json), reference_convergence_page by
# rule tolerance_study (not part of `all`).


def write_page(page: str, out) -> Path:
    with atomic_path(out) as tmp:
        tmp.write_text(page)
    return Path(out)


def _html_page(title: str, sections: Sequence[tuple[str, Sequence[str]]]) -> str:
    """A standalone HTML page (the tables' style): a title, then each section's heading and
    paragraphs (HTML, already escaped)."""
    import html

    from .tables import _HTML_STYLE

    body = [f"<h3>{html.escape(title)}</h3>"]
    for heading, paragraphs in sections:
        body.append(f"<h4>{html.escape(heading)}</h4>")
        body += [f"<p>{p}</p>" if not p.startswith("<ul>") else p for p in paragraphs]
    return (f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
            f"<style>{_HTML_STYLE}\nh4 {{ margin-bottom: 0.3em; }} p, li {{ max-width: 60em; }}</style></head>"
            "<body>\n" + "\n".join(body) + "\n</body></html>\n")


def _plural(n, word: str, plural: str | None = None) -> str:
    return word if n == 1 else (plural or word + "s")


def _own_error_text(convergence: Mapping, *, study: str) -> str:
    """The reference's own error, from a tolerance-study row (convergence.self_consistency)."""
    import html

    limit = convergence.get("converged_tolerance")
    against = f"against a run to {readable_small(limit)}" if limit is not None else "against the converged run"
    return (f"<b>Its own error</b>, measured by {html.escape(study)} (variant "
            f"{html.escape(str(convergence['variant']))} {against}): top force within "
            f"<b>{convergence['top_force_max_pct']:.2f} %</b> of the peak, volumetric strain within "
            f"<b>{convergence['volumetric_strain_max_pct']:.2f} %</b> of its peak magnitude, Gauss-point stress MAE "
            f"{convergence['stress_mae_kpa']:.2f} kPa. Errors of FEM–ML below these are below what the reference "
            "can tell.")


def _solver_text(newton: Mapping) -> str:
    return f"{newton['predictor']} predictor" + (", Anderson mixing" if newton["acceleration"] != "none" else "")


def headline_page(h: Mapping) -> str:
    """The report's headline page (HTML) of a headline as :func:`make_headline` writes it: what
    ran, how converged the reference is, the machine and the headline numbers, in the strings of
    :func:`headline_display`. A part the headline lacks (the reference's Newton record, the cost
    table, an accuracy row, the ablation) is left out or stated as missing."""
    import html

    e = html.escape
    d = headline_display(h)
    dem = h["reference_material"] == "dem"
    path, ref, ml = e(h["validation_path"]), e(h["reference"]), e(h["surrogate"])
    points = "RVE" if dem else "material point"

    m = h["mesh_elements"]
    ran = [f"Read from the reference run of {path}:"]
    if h["symmetry"] == "quarter":
        ran.append(f"<b>quarter symmetry</b> (<code>specimen.symmetry: quarter</code>), a mesh of {m[0]} × {m[1]} × "
                   f"{m[2]} elements with {h['gauss_points_modelled']} of the specimen's {h['gauss_points']} Gauss "
                   "points (forces reported for the full specimen);")
    else:
        ran.append(f"the full specimen, {h['gauss_points_modelled']} Gauss points (no symmetry reduction);")
    n_eval = h["material_points_evaluated"]
    if h["uniform_field"]:
        ran.append(f"<b>uniform field</b> (<code>specimen.uniform_field: true</code>): one material point stands for "
                   f"all {h['gauss_points_modelled']} Gauss points, so the reference evaluated "
                   f"<b>{n_eval} {_plural(n_eval, points)}</b>;")
    else:
        ran.append(f"the reference evaluated <b>{n_eval} {_plural(n_eval, points)}</b>, one per Gauss point "
                   "(no uniform-field reduction);")
    n_ml = h["surrogate_points_evaluated"]
    ran.append(f"FEM–ML evaluated the surrogate at {n_ml} {_plural(n_ml, 'point')}.")
    sections = [("What ran", [" ".join(ran)])]

    newton = h.get("reference_newton")
    if newton:
        convergence = [f"The reference was solved to a relative residual of {d['reference_tolerance']} (largest "
                       f"accepted: {d['reference_residual_max']}; {e(_solver_text(newton))})."]
        if h.get("reference_convergence"):
            convergence.append(_own_error_text(h["reference_convergence"], study="the tolerance study"))
        elif dem:
            # the tolerance study is not part of `all`; the job that writes this page does not
            # depend on it, so its numbers are on their own page, made with the study
            convergence.append(
                "Its own error is measured by the tolerance study, which <code>all</code> does not run: "
                "<code>snakemake -j2 tolerance_study</code>, then <code>snakemake --report … all tolerance_study"
                "</code>; its page <i>Reference convergence</i> in this category states it, the study itself is in "
                "<i>5 Reference</i> (docs/method.md, “How converged is the reference”, has the numbers measured at "
                "the tiny and default scales).")
        else:
            convergence.append("Its own error is not measured by this workflow: the tolerance study measures FEM–DEM "
                               "runs, and this reference is the analytic model.")
    else:
        convergence = ["The reference run does not record its Newton tolerance (a file written before it did)."]
    sections.append(("Reference convergence", convergence))

    machine = h["machine"]
    memory = f"{machine['memory_gib']} GiB memory, " if machine.get("memory_gib") is not None else ""
    sections.append(("Machine", [f"Measured on {machine['cores']} cores of {e(str(machine['cpu']))} "
                                 f"({memory}{e(str(machine['system']))})."]))

    items = [f"<b>Speedup {d['speedup']}</b> for one answer: {ml} took {d['surrogate_wall_time']}, {ref} "
             f"{d['reference_wall_time']} (paper: 24.8 h vs 0.2 h, about 125×)."]
    if d["surrogate_cost"]:
        cost = (f"<b>Making the surrogate took {d['surrogate_cost']}</b>: "
                f"{e('; '.join(d['surrogate_cost_items']))}.")
        n = h.get("break_even_runs")
        if n is not None:
            cost += (f" <b>It pays back from {d['break_even_runs']} FEM–ML {_plural(n, 'run')}</b> of {path} on: the "
                     f"smallest N with N × {d['surrogate_wall_time']} + {d['surrogate_cost']} ≤ N × "
                     f"{d['reference_wall_time']}.")
        else:
            cost += f" <b>It never pays back here</b>: {ml} is not faster than {ref}."
        if not dem:
            cost += (" (The reference is the analytic model, not FEM–DEM: these are the costs of a surrogate of "
                     "that model.)")
        items.append(cost)
    else:
        items.append("The cost of making the surrogate is not in this headline (no surrogate cost table).")
    if not h.get("surrogate_completed", True):
        items.append(f"<b>{ml} stopped after load step {h['surrogate_load_steps']} of {h['reference_load_steps']}</b> "
                     "(Newton did not converge even after cutbacks; its log names the step). The speedup compares "
                     "time per load step; the errors below cover the steps it reached.")
    if h.get("top_force_max_rel_pct") is not None:
        items.append(f"<b>Top-force error {d['top_force_max_rel_pct']}</b> of the peak reference force at worst over "
                     f"the load steps ({ml}).")
    if h.get("stress_mae_heldout_kpa") is not None:
        items.append(f"<b>Held-out stress MAE {d['stress_mae_heldout_kpa']}</b>: mean absolute stress error at the "
                     "Gauss points held out of training, over all steps and components.")
    if h.get("ablation_top_force_max_rel_pct") is not None:
        items.append(f"Without history variables ({e(str(h['ablation']))}): top-force error "
                     f"{d['ablation_top_force_max_rel_pct']}, held-out stress MAE "
                     f"{d['ablation_stress_mae_heldout_kpa']}.")
    sections.append(("Headline numbers", ["<ul>" + "".join(f"<li>{item}</li>" for item in items) + "</ul>"]))
    return _html_page(f"Headline numbers: {h['surrogate']} against {h['reference']} on {h['validation_path']}",
                      sections)


def reference_convergence_page(convergence: Mapping | None, newton: Mapping, *, study_path: str,
                               reference_material: str) -> str:
    """The report's page on the FEM–DEM reference's own error (HTML): the Newton settings FEM–DEM
    runs of this configuration are solved with (``newton``: tolerance, predictor, acceleration)
    and the tolerance-study row solved the same way (``convergence``, from
    ``convergence.self_consistency``; None: no variant of the study was solved so)."""
    import html

    settings = (f"FEM–DEM runs of this configuration are solved to a relative residual of "
                f"{readable_small(newton['tolerance'])} ({html.escape(_solver_text(newton))}; <code>newton</code> with "
                "the overrides of <code>dem.newton</code>).")
    paragraphs = [settings]
    if convergence:
        paragraphs.append(_own_error_text(convergence, study=f"the tolerance study on {study_path}"))
    else:
        paragraphs.append("No variant of the tolerance study (<code>tolerance_study.variants</code>) is solved with "
                          "these settings, so this study does not measure the reference's own error: add such a "
                          "variant.")
    if reference_material != "dem":
        paragraphs.append("This report's reference is the analytic elastoplastic model, not FEM–DEM: these numbers "
                          "are the error a FEM–DEM reference would carry.")
    return _html_page("Reference convergence: the FEM–DEM reference's own error",
                      [("Reference convergence", paragraphs)])


def make_reference_convergence(study_csv, out, *, newton: Mapping, study_path: str,
                               reference_material: str) -> dict | None:
    """Write :func:`reference_convergence_page` for the tolerance study ``study_csv``; returns the
    study's row solved with ``newton`` (None if there is none)."""
    from .convergence import self_consistency

    convergence = self_consistency(study_csv, newton)
    write_page(reference_convergence_page(convergence, newton, study_path=study_path,
                                          reference_material=reference_material), out)
    return convergence


# --------------------------------------------------------------------------------------
# validation per load path and load phase


def make_validation_table(cases: Sequence[tuple[str, str, Mapping[str, str]]], out_csv, out_html, *,
                          reference_label: str) -> pd.DataFrame:
    """The FEM–ML runs of every path against its reference run, per method and load phase
    (``validation.phase_errors``). ``cases``: (path, role, {label: run file}) with the reference
    run first in each mapping; role 'validation path' or 'training path' (grey rows in the HTML:
    the in-sample error)."""
    from . import validation

    parts = []
    for path, role, files in cases:
        labels = list(files)
        reference = data.read_run(files[labels[0]])
        runs = {label: data.read_run(files[label]) for label in labels[1:]}
        try:
            parts.append(validation.phase_errors(reference, runs, path=path, role=role))
        except ValueError as error:  # name the files: the message names the method and the path
            raise ValueError(f"{error} (run files: {', '.join(f'{k}: {v}' for k, v in files.items())})") from error
    table = pd.concat(parts, ignore_index=True)
    tables.write_csv(table, out_csv)
    tables.write_html_table(
        validation.display_table(table), out_html, headers=validation.HEADERS,
        title=f"FEM–ML against {reference_label}, per load path and load phase",
        reference_rows=np.flatnonzero(table["role"].to_numpy() == "training path").tolist(),
        note=("Each cycle of a path is numbered (unloading 1, reloading 1, unloading 2, ...); 'all' is load steps "
              "1..n. Top force: the largest and the mean |F − F_ref| over the phase's steps, in % of the "
              "reference's peak |F| over the path; volumetric strain: the largest |εv − εv_ref| in % of the "
              "reference's peak |εv|; stress MAE: mean |σ − σ_ref| over the phase's steps, the Gauss points "
              "and the six components. A run that stopped early is compared over the steps it reached "
              "('–': a phase it never reached). Grey rows: paths whose reference runs trained the networks "
              "(in-sample error)."),
    )
    return table
