"""Tables of the report: speedup (the paper's Table 4 layout), accuracy, headline numbers.

Run times are those recorded in the run files (the sum of the per-step wall times of the
FEM solve, RVE preparation excluded, as the paper's Table 4 times the FEM–DEM run itself);
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

from ..paths import LoadPath

SPEEDUP_COLUMNS = (
    "source",
    "method",
    "path",
    "load_steps",
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
    """Wall time of the FEM run in s: the sum of the per-step times (step 0 is the initial state)."""
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
    """One row of the speedup table for a run file."""
    phases = phase_labels(ds)
    steps = int(ds.sizes["step"]) - 1
    iterations = np.asarray(ds["newton_iterations"].values, dtype=float)
    wall = run_wall_time(ds)
    return {
        "source": source,
        "method": method,
        "path": path,
        "load_steps": steps,
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
    """Rows of :func:`describe_run`, the first being the reference; speedup = t_ref / t_method.

    The paper's rows (``paper_reference``, see the config's ``analysis.paper_reference``)
    are appended after this run's rows."""
    if not rows:
        raise ValueError("speedup table needs at least the reference run")
    t_ref = rows[0]["wall_time_s"]
    table = []
    for row in rows:
        row = dict(row)
        row["speedup"] = t_ref / row["wall_time_s"] if row["wall_time_s"] > 0 else float("nan")
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


def write_csv(table: pd.DataFrame, out: str | Path, float_format: str = "%.6g") -> Path:
    """CSV written atomically (temporary name, then rename)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    table.to_csv(tmp, index=False, float_format=float_format)
    os.replace(tmp, out)
    return out
