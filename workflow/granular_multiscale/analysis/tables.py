"""Tables of the report: speedup (the paper's Table 4 layout), accuracy, headline numbers.

Run times are those recorded in the run files (the solver's load-step loop, RVE preparation
and file writing excluded, as the paper's Table 4 times the FEM–DEM run itself);
speedups are the reference run's wall time over the method's, both measured on this
machine in the same workflow run. The paper's own figures are a separate, labelled row.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd
import xarray as xr

from .. import integrity
from ..atomic import atomic_path
from ..paths import LoadPath
from . import metrics

SPEEDUP_COLUMNS = (
    "source",
    "method",
    "path",
    "load_steps",
    "completed",
    "unloading_step",
    "reloading_step",
    "rves",
    "dem_particle_steps",
    "wall_time_s",
    "wall_time_h",
    "newton_iterations",
    "newton_per_step",
    "speedup",
)


def run_wall_time(ds: xr.Dataset) -> float:
    """Wall time of the FEM run in s: the solver's whole load-step loop (attr ``time_run_s``),
    else the sum of the per-step times (step 0, the initial state, included)."""
    if "time_run_s" in ds.attrs:
        total = float(ds.attrs["time_run_s"])
        if not np.isfinite(total) or total < 0:
            raise ValueError(f"attr time_run_s is {total}")
        return total
    wall = np.asarray(ds["wall_time"].values, dtype=float)
    if not np.all(np.isfinite(wall)) or np.any(wall < 0):
        raise ValueError("wall_time holds negative or non-finite values")
    return float(wall.sum())


def phase_labels(ds: xr.Dataset) -> np.ndarray:
    """Per-step phase labels; from the file, or from the axial-strain increments if absent."""
    if "phase" in ds:
        return np.asarray(ds["phase"].values).astype(str)
    inc = np.diff(np.asarray(ds["axial_strain"].values, dtype=float))
    labels, unloaded = ["initial"], False
    for d in inc:
        unloaded |= bool(d < 0)
        labels.append("unloading" if d < 0 else ("reloading" if unloaded else "loading"))
    return np.asarray(labels)


def first_step(phases: np.ndarray, label: str) -> int | None:
    idx = np.flatnonzero(phases == label)
    return int(idx[0]) if idx.size else None


# files written before the attr ``material_points``: methods whose driver built a material set of
# one point per Gauss point even under ``specimen.uniform_field`` (drivers.fem_ml); the
# reference drivers (drivers.fem_dem, drivers.reference) built problem.n_material_points
ALL_POINT_METHOD_PREFIXES = ("fem_ml",)


def material_points_evaluated(ds: xr.Dataset) -> int:
    """Material points the run evaluated (RVEs that ran, for FEM–DEM): the run file's attr
    ``material_points`` (the solver records it); in an older file, 1 for a ``uniform_field`` run of a reference driver
    (one point stands for every Gauss point); else the Gauss points of the modelled mesh
    (``gp``, already reduced by ``symmetry: quarter``)."""
    if "material_points" in ds.attrs:
        return int(ds.attrs["material_points"])
    uniform = bool(int(ds.attrs.get("uniform_field", 0)))
    if uniform and not str(ds.attrs.get("method", "")).startswith(ALL_POINT_METHOD_PREFIXES):
        return 1
    return int(ds.sizes["gp"])


def model_reduction(ds: xr.Dataset) -> dict:
    """What of the specimen a run modelled, from its attrs (older files without them: the full
    specimen): elements of the specimen and of the mesh, symmetry, modelled fraction, uniform
    field, Gauss points of the full specimen and of the modelled mesh, material points evaluated."""
    per_element = int(ds.attrs.get("gauss_points_per_element", 8))
    gp_modelled = int(ds.sizes["gp"])
    specimen = ds.attrs.get("specimen_elements")
    specimen = [int(n) for n in np.atleast_1d(specimen)] if specimen is not None else None
    mesh = ds.attrs.get("mesh_elements")
    mesh = [int(n) for n in np.atleast_1d(mesh)] if mesh is not None else specimen
    symmetry = str(ds.attrs.get("symmetry", "none"))
    return {
        "specimen_elements": specimen,
        "mesh_elements": mesh,
        "symmetry": symmetry,
        "modelled_fraction": float(ds.attrs.get("modelled_fraction", 1.0)),
        "uniform_field": bool(int(ds.attrs.get("uniform_field", 0))),
        "gauss_points_full_specimen": per_element * int(np.prod(specimen)) if specimen else gp_modelled,
        "gauss_points_modelled": gp_modelled,
        "material_points_evaluated": material_points_evaluated(ds),
    }


def describe_run(ds: xr.Dataset, method: str, path: str, source: str = "this run") -> dict:
    """One row of the speedup table for a run file (``load_steps``: the steps it reached;
    ``completed``: "no" for a FEM–ML run that stopped early, see ``metrics.is_partial``;
    ``rves``: the material points it evaluated, see :func:`material_points_evaluated`)."""
    phases = phase_labels(ds)
    steps = metrics.steps_reached(ds)
    iterations = np.asarray(ds["newton_iterations"].values, dtype=float)
    wall = run_wall_time(ds)
    return {
        "source": source,
        "method": method,
        "path": path,
        "load_steps": steps,
        "completed": "no" if metrics.is_partial(ds) else "yes",
        "unloading_step": first_step(phases, "unloading"),
        "reloading_step": first_step(phases, "reloading"),
        "rves": material_points_evaluated(ds),
        # DEM work in particle-steps (trials and replays): machine-independent, unlike the wall time
        "dem_particle_steps": float(ds.attrs.get("dem_particle_steps", 0.0)),
        "wall_time_s": wall,
        "wall_time_h": wall / 3600.0,
        "newton_iterations": int(iterations[1:].sum()),
        "newton_per_step": float(iterations[1:].mean()) if steps else float("nan"),
    }


def paper_rows(reference: Mapping) -> list[dict]:
    """The paper's Table 4 (FEM–DEM vs FEM–ML on Path2) as two labelled rows."""
    source = reference.get("source", "paper (Qu et al., Table 4)")
    common = {
        "source": source,
        "path": reference["path"],
        "load_steps": reference["load_steps"],
        "completed": "yes",
        "unloading_step": reference["unloading_step"],
        "reloading_step": reference["reloading_step"],
        "rves": reference["rves"],
        "dem_particle_steps": None,
        "newton_iterations": None,
        "newton_per_step": None,
    }
    h_ref, h_ml = float(reference["reference_hours"]), float(reference["surrogate_hours"])
    return [
        {**common, "method": reference["reference_method"], "wall_time_s": 3600 * h_ref, "wall_time_h": h_ref, "speedup": 1.0},
        {**common, "method": reference["surrogate_method"], "wall_time_s": 3600 * h_ml, "wall_time_h": h_ml,
         "speedup": float(reference.get("speedup", h_ref / h_ml))},
    ]


def speedup_table(rows: Sequence[dict], paper_reference: Mapping | None = None) -> pd.DataFrame:
    """Rows of :func:`describe_run`, the first being the reference; speedup = wall time per load
    step of the reference / that of the row: the whole-run ratio t_ref / t_method when both ran
    every step, and still a fair ratio for a run that stopped early.

    The paper's rows (``paper_reference``, see the config's ``analysis.paper_reference``)
    are appended after this run's rows."""
    if not rows:
        raise ValueError("speedup table needs at least the reference run")
    def per_step(row):
        return row["wall_time_s"] / max(row["load_steps"], 1)

    t_ref = per_step(rows[0])
    table = []
    for row in rows:
        row = dict(row)
        row["speedup"] = t_ref / per_step(row) if row["wall_time_s"] > 0 else float("nan")
        table.append(row)
    if paper_reference:
        table.extend(paper_rows(paper_reference))
    return pd.DataFrame(table, columns=list(SPEEDUP_COLUMNS))


def machine_description() -> dict:
    """Cores, CPU model and memory of this machine, for the report's 'measured on' line."""
    model = platform.processor() or platform.machine()
    memory_gib = None
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemTotal"):
                    memory_gib = round(int(line.split()[1]) / 2**20, 1)
                    break
    except OSError:
        pass
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count()
    return {"cores": cores, "cpu": model, "memory_gib": memory_gib, "system": f"{platform.system()} {platform.release()}"}


def load_path_summary(path: LoadPath) -> dict:
    phases = path.phase()
    return {
        "load_steps": path.n_steps,
        "unloading_step": first_step(phases, "unloading"),
        "reloading_step": first_step(phases, "reloading"),
    }


def write_csv(table: pd.DataFrame, out: str | Path, float_format: str = "%.10g") -> Path:
    """CSV written atomically (temporary name, then rename)."""
    with atomic_path(out) as tmp:
        table.to_csv(tmp, index=False, float_format=float_format)
    return Path(out)


# --------------------------------------------------------------------------------------
# the full cost of an answer: what making the surrogate cost, and when it pays back


def benchmark_seconds(path: str | Path) -> float:
    """Wall seconds of a rule from its Snakemake benchmark file (TSV, column ``s``; the mean
    when the benchmark repeated the rule)."""
    try:
        table = pd.read_csv(path, sep="\t")
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as error:
        raise ValueError(f"benchmark file {path}: {error}") from error
    if "s" not in table.columns or table.empty:
        raise ValueError(f"benchmark file {path} has no column 's' (wall seconds) or no row; columns {list(table.columns)}")
    seconds = pd.to_numeric(table["s"], errors="coerce").to_numpy(dtype=float)
    if not np.all(np.isfinite(seconds)) or np.any(seconds < 0):
        raise ValueError(f"benchmark file {path}: column 's' holds {seconds.tolist()}, not wall seconds")
    return float(seconds.mean())


def rve_preparation_seconds(summary_file: str | Path) -> float:
    """Consolidation wall time of the RVE packings from ``rve/summary.json`` (summed over the
    packings: exact for one packing, an upper bound when several ran side by side)."""
    import json

    integrity.verify(summary_file, "RVE summary")
    try:
        summary = json.loads(Path(summary_file).read_text())
        times = [float(p["wall_time"]) for p in summary["packings"]]
    except (OSError, ValueError) as error:
        raise ValueError(f"RVE summary {summary_file}: {error}") from error
    except (KeyError, TypeError) as error:
        raise ValueError(f"RVE summary {summary_file} lacks 'packings' with a 'wall_time' each ({error!r})") from error
    if not times or not all(np.isfinite(t) and t >= 0 for t in times):
        raise ValueError(f"RVE summary {summary_file}: packing wall times {times}")
    return float(sum(times))


def break_even_runs(cost_s: float, reference_s: float, surrogate_s: float) -> int | None:
    """The smallest number N >= 1 of answers for which making the surrogate once and running it
    N times costs no more than N reference runs: N·t_surrogate + cost <= N·t_reference, i.e.
    ceil(cost / (t_reference − t_surrogate)). None when the surrogate run is not faster (it never
    pays back)."""
    import math

    cost_s, reference_s, surrogate_s = float(cost_s), float(reference_s), float(surrogate_s)
    if not all(np.isfinite(v) and v >= 0 for v in (cost_s, reference_s, surrogate_s)):
        raise ValueError(f"break-even needs finite times >= 0: cost {cost_s}, reference {reference_s}, "
                         f"surrogate {surrogate_s}")
    saving = reference_s - surrogate_s
    if saving <= 0:
        return None
    n = max(math.ceil(cost_s / saving), 1)
    # the ratio's round-off must not cost one run: take N − 1 when it already satisfies the inequality
    if n > 1 and (n - 1) * surrogate_s + cost_s <= (n - 1) * reference_s:
        n -= 1
    return n


COST_COLUMNS = ("item", "kind", "wall_time_s", "wall_time_h", "runs", "source")


def surrogate_cost_table(items: Sequence[tuple[str, float, str]], *, reference: tuple[str, float],
                         surrogate: tuple[str, float], path: str) -> tuple[pd.DataFrame, dict]:
    """The cost of making the surrogate and when it pays back.

    ``items``: (what, wall seconds, where it was read) of each step that makes the surrogate;
    ``reference`` / ``surrogate``: (label, wall seconds) of one run of the validation path
    ``path`` each. Rows: the items (kind ``surrogate cost``), their total, the two runs (kind
    ``one answer``), and at the break-even number N of FEM–ML runs (``runs``) the time of N
    answers either way (kind ``break-even``). Returns the table and its numbers."""
    if not items:
        raise ValueError("surrogate cost table needs at least one cost item")
    rows = [{"item": what, "kind": "surrogate cost", "wall_time_s": float(t), "runs": None, "source": source}
            for what, t, source in items]
    total = float(sum(r["wall_time_s"] for r in rows))
    rows.append({"item": "total: making the surrogate", "kind": "surrogate cost total", "wall_time_s": total,
                 "runs": None, "source": ""})
    (ref_label, t_ref), (ml_label, t_ml) = reference, surrogate
    rows.append({"item": f"one {ref_label} run of {path}", "kind": "one answer", "wall_time_s": float(t_ref),
                 "runs": 1, "source": "speedup table"})
    rows.append({"item": f"one {ml_label} run of {path}", "kind": "one answer", "wall_time_s": float(t_ml),
                 "runs": 1, "source": "speedup table"})
    n = break_even_runs(total, t_ref, t_ml)
    if n is not None:
        rows.append({"item": f"{n} answers by {ml_label}, making the surrogate included", "kind": "break-even",
                     "wall_time_s": n * float(t_ml) + total, "runs": n, "source": ""})
        rows.append({"item": f"{n} answers by {ref_label}", "kind": "break-even", "wall_time_s": n * float(t_ref),
                     "runs": n, "source": ""})
    table = pd.DataFrame(rows)
    table["wall_time_h"] = table["wall_time_s"] / 3600.0
    table["runs"] = pd.Series([r["runs"] for r in rows], dtype=object)
    numbers = {"surrogate_cost_s": total, "break_even_runs": n, "reference_wall_time_s": float(t_ref),
               "surrogate_wall_time_s": float(t_ml),
               "cost_items": [{"item": what, "wall_time_s": float(t)} for what, t, _ in items]}
    return table[list(COST_COLUMNS)], numbers


# --------------------------------------------------------------------------------------
# accuracy of one run against the reference


ACCURACY_COLUMNS = (
    "method",
    "path",
    "load_steps_compared",
    "stress_mae_heldout_kpa",
    "stress_mae_train_kpa",
    "stress_mae_all_kpa",
    "top_force_max_rel_pct",
    "top_force_rms_rel_pct",
    "volumetric_strain_max_abs_pct",
    "newton_per_step",
)


def accuracy_row(reference: xr.Dataset, run: xr.Dataset, method: str, path: str,
                 train_gp=None, heldout_gp=None) -> dict:
    """Errors of ``run`` against ``reference`` (same mesh and path), by the definitions of
    ``analysis.metrics`` (the FEM–ML stage's metrics), gathered into one row.

    A run that stopped early (``metrics.is_partial``) is compared over the steps it reached
    (``load_steps_compared``). Stress MAE: mean |σ − σ_ref| over steps, the six components and the Gauss points of each
    group (kPa). Top-force errors in % of the largest reference top force (max_k |F_ref|), so
    the near-zero force at the end of unloading does not blow them up.
    """
    train_gp = np.asarray([] if train_gp is None else train_gp, dtype=int)
    heldout_gp = np.asarray([] if heldout_gp is None else heldout_gp, dtype=int)
    stress = metrics.stress_error_summary(reference, run, train_gp, heldout_gp).set_index("split")

    def mae_kpa(split):
        return float(stress.loc[split, "mae_mean_pa"]) * 1e-3 if split in stress.index else float("nan")

    curves = metrics.curve_errors(reference, run).set_index(["quantity", "phase"])
    force = curves.loc[("top_force", "all")]
    volume = curves.loc[("volumetric_strain", "all")]
    iterations = np.asarray(run["newton_iterations"].values, dtype=float)[1:]
    return {
        "method": method,
        "path": path,
        "load_steps_compared": metrics.steps_reached(run),
        "stress_mae_heldout_kpa": mae_kpa("heldout"),
        "stress_mae_train_kpa": mae_kpa("train"),
        "stress_mae_all_kpa": mae_kpa("all"),
        "top_force_max_rel_pct": float(force["max_error_percent_of_peak"]),
        "top_force_rms_rel_pct": float(force["rms_error_percent_of_peak"]),
        "volumetric_strain_max_abs_pct": 100 * float(volume["max_abs_error"]),
        "newton_per_step": float(iterations.mean()) if iterations.size else float("nan"),
    }


# --------------------------------------------------------------------------------------
# HTML rendering (the report shows HTML inline; CSV is offered as a download)

_HTML_STYLE = """
body { font-family: sans-serif; font-size: 14px; margin: 1em; }
table { border-collapse: collapse; }
th, td { border: 1px solid #bbb; padding: 4px 8px; text-align: right; }
th { background: #eee; }
td:first-child, td:nth-child(2), th:first-child, th:nth-child(2) { text-align: left; }
tr.reference td { color: #555; font-style: italic; background: #f7f7f7; }
p.note { color: #444; max-width: 60em; }
"""


def _cell(value, digits: int) -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "–"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if v != 0 and (abs(v) >= 1e5 or abs(v) < 1e-3):
            return f"{v:.{digits}e}"
        return f"{v:.{digits}g}" if abs(v) < 10 ** digits else f"{v:.0f}"
    return str(value)


def write_html_table(table: pd.DataFrame, out: str | Path, *, title: str, note: str = "",
                     headers: Mapping[str, str] | None = None, reference_rows=None, digits: int = 4) -> Path:
    """A small standalone HTML page with the table (rows in ``reference_rows`` greyed)."""
    import html

    headers = headers or {}
    reference_rows = set(reference_rows or [])
    head = "".join(f"<th>{html.escape(headers.get(c, c))}</th>" for c in table.columns)
    body = []
    for i, row in enumerate(table.itertuples(index=False)):
        cls = ' class="reference"' if i in reference_rows else ""
        cells = "".join(f"<td>{html.escape(_cell(v, digits))}</td>" for v in row)
        body.append(f"<tr{cls}>{cells}</tr>")
    page = (
        f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
        f"<style>{_HTML_STYLE}</style></head><body>\n<h3>{html.escape(title)}</h3>\n"
        f"<table><thead><tr>{head}</tr></thead><tbody>\n" + "\n".join(body) + "\n</tbody></table>\n"
        + (f"<p class=\"note\">{html.escape(note)}</p>\n" if note else "")
        + "</body></html>\n"
    )
    with atomic_path(out) as tmp:
        tmp.write_text(page)
    return Path(out)


def active_learning_table(rounds: Mapping[str, Mapping[str, xr.Dataset]],
                          references: Mapping[str, xr.Dataset] | None = None,
                          fem_ml: Mapping[str, xr.Dataset] | None = None) -> pd.DataFrame:
    """One row per (load path, round) of the active-learning round (``adaptive.active_learning``):
    rounds {round name: {path: adaptive run}} at the same threshold, the first with the pipeline's
    networks, the next trained again with the DEM answers of the first's promoted points.

    Columns: promotions (points promoted during the run; anchors not counted), DEM points at the
    end, share of the point-steps in DEM mode, DEM particle-steps (trials + replays) and, with a
    FEM–DEM reference of the path, their share of the reference's and the top-force error in %
    of its peak (largest over the steps, as ``accuracy_row``). FEM–ML runs with the pipeline's
    networks, where given, add a row "FEM–ML" per path (no DEM), the end the curve starts from."""
    references, fem_ml = references or {}, fem_ml or {}
    rows = []
    for path in dict.fromkeys(p for runs in rounds.values() for p in runs):
        reference = references.get(path)
        ref_steps = float(reference.attrs["dem_particle_steps"]) if reference is not None else float("nan")

        def errors(run):
            if reference is None:
                return float("nan"), float("nan")
            row = accuracy_row(reference, run, "", path)
            return row["top_force_max_rel_pct"], row["stress_mae_all_kpa"]

        if path in fem_ml:
            force, mae = errors(fem_ml[path])
            rows.append({"path": path, "round": "FEM–ML", "threshold": float("inf"), "promotions": 0,
                         "dem_points_final": 0, "dem_point_fraction": 0.0, "dem_particle_steps": 0.0,
                         "dem_share_of_fem_dem": 0.0, "top_force_max_rel_pct": force, "stress_mae_all_kpa": mae,
                         "wall_time_s": run_wall_time(fem_ml[path])})
        for name, runs in rounds.items():
            if path not in runs:
                continue
            run = runs[path]
            steps = float(run.attrs["dem_particle_steps"])
            force, mae = errors(run)
            rows.append({
                "path": path, "round": name, "threshold": float(run.attrs["adaptive_threshold"]),
                "promotions": int(run["promotions"].sum()), "dem_points_final": int(run.attrs["dem_points_final"]),
                "dem_point_fraction": float(run.attrs["dem_point_fraction"]), "dem_particle_steps": steps,
                "dem_share_of_fem_dem": steps / ref_steps, "top_force_max_rel_pct": force,
                "stress_mae_all_kpa": mae, "wall_time_s": run_wall_time(run),
            })
    return pd.DataFrame(rows)
