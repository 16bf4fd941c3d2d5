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


def describe_run(ds: xr.Dataset, method: str, path: str, source: str = "this run") -> dict:
    """One row of the speedup table for a run file (``load_steps``: the steps it reached;
    ``completed``: "no" for a FEM–ML run that stopped early, see ``metrics.is_partial``)."""
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
        "rves": int(ds.sizes["gp"]),
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
