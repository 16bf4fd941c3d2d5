"""The surrogate on the problems whose field is not uniform (biaxial shear band, strip footing):
every run of a problem against its reference run, point by point (pure numpy, from run files).

    table = comparison_table(reference, {label: run})      one row per run (module text below)
    error_map_figure(reference, {label: run}, out, ...)    where each run's stress is wrong

On a nearly uniform specimen one stress shared by every Gauss point is the answer, so the errors
here are taken where the points differ:

* **zones**: the biaxial test's band points (those of the reference's band at its last step,
  :func:`bands.band_metrics`) against the rest; the footing's points under it (within the footing's
  half-width of its axis and one footing width deep) against the rest;
* **force**: the largest |F − F_ref| over the steps both runs reached, in % of the reference's
  peak, over the whole path, up to the reference's peak and after it;
* **volumetric strain**: the largest |εv − εv_ref| in % of the reference's largest |εv|;
* **stress MAE**: the mean over steps, points and the six components of |σ − σ_ref| (kPa);
* **rank correlation**: per step after the reference's peak (every step where it has none), Spearman's ρ between a run's relative
  ensemble spread and its stress error ‖σ − σ_ref‖ over the Gauss points where the networks answered
  (all in FEM–ML, the surrogate points of an adaptive run); the median over those
  steps (does the spread say *where* the networks are wrong?), and the median of error / spread
  over every step and point (about 1 when the spread is the size of the error);
* **DEM work**: the run's DEM particle-steps (trials and replays) over the reference's, and for an
  adaptive run the share of its DEM points at the end that lie in the band (or under the footing).

Runs are compared step by step: they share the load path, so step k is the same load. A run that
stopped (``completed = 0``) is compared over the steps it reached, and the table says how many.
"""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import xarray as xr  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from ..history import HIST, history_from_sequence  # noqa: E402
from ..novelty import NEIGHBOURS, NOVELTY_QUANTILE, TrainingStates  # noqa: E402,F401  (the scripts' and tests' names)
from . import quantities as qty  # noqa: E402
from .bands import band_metrics  # noqa: E402
from .calibration import spearman  # noqa: E402
from .figures import save_figure  # noqa: E402
from .metrics import stress_norm  # noqa: E402
from .problems import PLANE, gauss_point_cells, load_axis  # noqa: E402


def _values(run: xr.Dataset, name: str) -> np.ndarray:
    return run[name].transpose("step", "gp", ...).values


def zones(reference: xr.Dataset) -> tuple[np.ndarray, str, str]:
    """([n_gp] bool, name of the zone, name of the rest): the band of a biaxial reference, the soil
    under the footing of a footing reference."""
    problem = reference.attrs.get("problem")
    if problem == "footing":
        xz = reference["gp_position"].transpose("gp", "xyz").values[:, PLANE]
        width = float(reference.attrs["footing_width_m"])
        axis = 0.0 if reference.attrs.get("symmetry") == "half" else float(np.mean(xz[:, 0]))
        surface = float(reference["node_position"].values[:, 2].max())
        under = (np.abs(xz[:, 0] - axis) <= 0.5 * width) & (xz[:, 1] >= surface - width)
        return under, "under the footing", "elsewhere"
    band = np.zeros(reference.sizes["gp"], dtype=bool)
    band[band_metrics(reference)["band_gauss_points"]] = True
    return band, "in the band", "outside the band"


def _force(run: xr.Dataset) -> np.ndarray:
    return run["footing_pressure"].values if run.attrs.get("problem") == "footing" else run["load_force"].values


def _largest(error: np.ndarray, scale: float) -> float:
    return float(100 * np.max(np.abs(error)) / scale) if error.size else float("nan")


def stress_errors(reference: xr.Dataset, run: xr.Dataset) -> np.ndarray:
    """[steps both reached, n_gp] ‖σ − σ_ref‖ (Pa)."""
    n = min(reference.sizes["step"], run.sizes["step"])
    return stress_norm(_values(run, "stress")[:n] - _values(reference, "stress")[:n])


def _networks_answered(run: xr.Dataset) -> np.ndarray:
    """[steps, n_gp] where the networks answered (all points of FEM–ML; the surrogate points of an adaptive run)."""
    if "point_mode" in run:
        return run["point_mode"].transpose("step", "gp").values == 0
    return np.ones((run.sizes["step"], run.sizes["gp"]), dtype=bool)


def spread_rank_correlation(reference: xr.Dataset, run: xr.Dataset) -> float:
    """:func:`rank_correlation_after_peak` of the run's relative ensemble spread; NaN without spread."""
    if "stress_spread_relative" not in run or int(run.attrs.get("ensemble_size", 1)) < 2:
        return float("nan")
    return rank_correlation_after_peak(reference, run, run["stress_spread_relative"].transpose("step", "gp").values)


def first_step_after_peak(reference: xr.Dataset) -> int:
    """The first step after the reference's peak force; 1 where the force still rises at the end (the
    footing), so that "after the peak" is every step."""
    peak = int(np.argmax(_force(reference)))
    return peak + 1 if peak + 1 < reference.sizes["step"] else 1


def rank_correlation_after_peak(reference: xr.Dataset, run: xr.Dataset, indicator: np.ndarray) -> float:
    """Median over the steps from :func:`first_step_after_peak` on of Spearman's ρ between
    `indicator` [steps, n_gp] and the run's stress error over the Gauss points where the networks
    answered: does the indicator say *where* the networks are wrong?"""
    errors = stress_errors(reference, run)
    indicator = indicator[: errors.shape[0]]
    answered = _networks_answered(run)[: errors.shape[0]]
    first = first_step_after_peak(reference)
    rho = [spearman(indicator[k][answered[k]], errors[k][answered[k]]) for k in range(first, errors.shape[0])]
    rho = [r for r in rho if np.isfinite(r)]
    return float(np.median(rho)) if rho else float("nan")


def error_over_spread(reference: xr.Dataset, run: xr.Dataset) -> float:
    """Median over every (step ≥ 1, point) of ‖σ − σ_ref‖ / ‖ensemble spread‖: about 1 when the spread
    is the size of the error (calibrated); NaN without spread."""
    if "stress_spread" not in run or int(run.attrs.get("ensemble_size", 1)) < 2:
        return float("nan")
    errors = stress_errors(reference, run)[1:]
    spread = stress_norm(_values(run, "stress_spread")[1: errors.shape[0] + 1])
    positive = (spread > 0) & _networks_answered(run)[1: errors.shape[0] + 1]
    return float(np.median(errors[positive] / spread[positive])) if positive.any() else float("nan")


def comparison_row(reference: xr.Dataset, run: xr.Dataset, zone: np.ndarray, zone_names: tuple[str, str]) -> dict:
    """One row of :func:`comparison_table`."""
    total = reference.sizes["step"]
    n = min(total, run.sizes["step"])
    force, force_ref = _force(run)[:n], _force(reference)
    peak_ref = float(np.max(np.abs(force_ref)))
    peak = int(np.argmax(force_ref))
    error = force - force_ref[:n]
    ev, ev_ref = run["volumetric_strain"].values[:n], reference["volumetric_strain"].values
    stress = np.abs(_values(run, "stress")[:n] - _values(reference, "stress")[:n])
    inside, outside = zone_names
    row = {
        "steps reached": f"{n - 1} of {total - 1}",
        "force: largest error (% of peak)": _largest(error, peak_ref),
        "force: up to the peak (%)": _largest(error[: peak + 1], peak_ref),
        "force: after the peak (%)": _largest(error[peak:], peak_ref),
        "volumetric strain: largest error (% of its peak)": _largest(ev - ev_ref[:n], float(np.max(np.abs(ev_ref)))),
        "stress MAE (kPa)": 1e-3 * float(stress.mean()),
        f"stress MAE {inside} (kPa)": 1e-3 * float(stress[:, zone].mean()),
        f"stress MAE {outside} (kPa)": 1e-3 * float(stress[:, ~zone].mean()),
        "spread–error rank correlation (after the peak)": spread_rank_correlation(reference, run),
        "median error / spread": error_over_spread(reference, run),
    }
    if reference.attrs.get("problem") == "biaxial":
        band, band_ref = band_metrics(run.isel(step=slice(0, n))), band_metrics(reference)
        row.update({
            "band inclination (deg)": band["inclination_deg"],
            "inclination − reference (deg)": band["inclination_deg"] - band_ref["inclination_deg"],
            "band onset: axial strain (%)": 100 * band["onset_load"],
            "onset − reference (% strain)": 100 * (band["onset_load"] - band_ref["onset_load"]),
        })
    dem, dem_ref = float(run.attrs.get("dem_particle_steps", 0.0)), float(reference.attrs.get("dem_particle_steps", 0))
    row["DEM particle-steps (% of the reference's)"] = 100 * dem / dem_ref if dem_ref > 0 else float("nan")
    if "point_mode" in run:
        final = run["point_mode"].transpose("step", "gp").values[-1].astype(bool)
        row["DEM points at the end"] = int(final.sum())
        row[f"DEM points at the end {inside} (%)"] = 100 * float(zone[final].mean()) if final.any() else float("nan")
    row["wall time (s)"] = float(run.attrs.get("time_run_s", float("nan")))
    return row


def comparison_table(reference: xr.Dataset, runs: Mapping[str, xr.Dataset]) -> pd.DataFrame:
    """One row per run (the reference's own row first: its wall time and DEM work), the columns of
    the module text."""
    zone, inside, outside = zones(reference)
    rows = [{"run": label, **comparison_row(reference, run, zone, (inside, outside))} for label, run in runs.items()]
    table = pd.DataFrame(rows)
    table.insert(1, f"Gauss points {inside}", int(zone.sum()))
    return table


def error_map_figure(reference: xr.Dataset, runs: Mapping[str, xr.Dataset], out, *, title: str,
                     deformation_scale: float = 1.0, dpi: int = 120) -> dict:
    """Rows: the runs; columns: the reference's peak and its last step. Each Gauss point's quarter
    of its element (on the reference's deformed mesh) coloured by ‖σ − σ_ref‖ / p0; black dots mark
    the points that answered from their RVE at that step (adaptive runs). Returns what it drew:
    {run label: {step: {"error": [n_gp] the colours, "dem_points": the dotted Gauss points}}}, a
    step the run never reached left out."""
    force = _force(reference)
    steps = sorted({int(np.argmax(force)), reference.sizes["step"] - 1})
    x, xlabel = load_axis(reference)
    p0 = float(reference.attrs["confining_pressure_Pa"])
    errors = {label: stress_errors(reference, run) / p0 for label, run in runs.items()}
    hi = max(float(e.max()) for e in errors.values()) if errors else 1.0
    nodes = reference["node_position"].values[:, PLANE]
    aspect = min(1.6, max(float(np.ptp(nodes[:, 0]) / np.ptp(nodes[:, 1])), 0.5))
    fig, axes = plt.subplots(len(runs), len(steps), figsize=(max(4.0, 2.8 * aspect * len(steps) + 1.6),
                                                             2.4 * len(runs) + 1.0), squeeze=False, layout="constrained")
    cells = None
    drawn = {label: {} for label in runs}
    for row, (label, run) in enumerate(runs.items()):
        for col, step in enumerate(steps):
            ax = axes[row, col]
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_aspect("equal")
            if col == 0:  # also on the row of a run that stopped before the first step shown
                ax.set_ylabel(textwrap.fill(label, 28), fontsize=7)
            if step >= errors[label].shape[0]:
                ax.text(0.5, 0.5, "run stopped\nbefore this step", ha="center", va="center", transform=ax.transAxes,
                        fontsize=8)
                continue
            polygons = gauss_point_cells(reference, step, deformation_scale)
            cells = PolyCollection(polygons, array=errors[label][step], cmap="magma_r", edgecolors="face",
                                   linewidths=0.2)
            cells.set_clim(0.0, max(hi, 1e-12))
            ax.add_collection(cells)
            dem = np.zeros(len(polygons), dtype=bool)
            if "point_mode" in run:
                dem = run["point_mode"].transpose("step", "gp").values[step].astype(bool)
                centres = polygons[dem].mean(axis=1)
                ax.plot(centres[:, 0], centres[:, 1], "k.", markersize=3)
            drawn[label][step] = {"error": errors[label][step], "dem_points": np.flatnonzero(dem)}
            ax.autoscale_view()
            if row == 0:
                ax.set_title(f"step {step}: {xlabel.split(' (')[0]} {x[step]:.2f} %", fontsize=8)
    if cells is not None:
        fig.colorbar(cells, ax=axes.ravel().tolist(), shrink=0.8, label="‖σ − σ_ref‖ / p0")
    fig.suptitle(textwrap.fill(f"{title} (dots: points that answered from their RVE)", 60), fontsize=9)
    save_figure(fig, out, dpi)
    return drawn


# ------------------------------------------------------------------------------ states visited
def _states(run: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
    """([n, 6] stress, [n, 6] strain) of every (step, point) of a run where the state is known (an
    RVE-path set marks the steps after an RVE lost its contacts ``valid`` = False)."""
    stress, strain = _values(run, "stress").reshape(-1, 6), _values(run, "strain").reshape(-1, 6)
    if "valid" in run:
        keep = run["valid"].transpose("step", "gp").values.astype(bool).ravel()
        stress, strain = stress[keep], strain[keep]
    return stress, strain


def state_ranges(runs: Mapping[str, xr.Dataset], confining_pressure: float,
                 training: TrainingStates | None = None, history: tuple[str, ...] = ()) -> pd.DataFrame:
    """One row per run (training sources and validation runs alike): the range of the states its
    material points visited, 1st to 99th percentile over every (step, point): mean stress p/p0,
    deviator q/p0, Lode angle (0° triaxial compression, 30° shear, 60° extension; where q > 0.1 p0),
    rotation of the major principal stress from the vertical (the triaxial loading axis), the
    equivalent shear strain and the volumetric strain. A problem whose states leave the training
    sources' ranges asks the networks to extrapolate. With `training` (the networks' training
    states, their `history` variables), the share of the run's states off the training data: an
    unseen combination of features counts even where each feature is inside its range."""
    rows = []
    for label, run in runs.items():
        stress, strain = _states(run)
        p = qty.mean_stress(stress) / confining_pressure
        q = np.abs(qty.deviatoric_stress(stress)) / confining_pressure
        lode = qty.lode_angle(stress[q > 0.1])
        rotation = qty.principal_axis_rotation(stress[q > 0.1])
        shear, volumetric = 100 * qty.equivalent_shear_strain(strain), 100 * qty.volumetric_strain(strain)

        def spread(v):
            return np.nanpercentile(v, [1, 99]) if np.isfinite(v).any() else (np.nan, np.nan)

        row = {"run": label, "states": int(p.size)}
        if training is not None:
            x = run_features(run, history).reshape(-1, 6 + len(history))
            if "valid" in run:
                x = x[run["valid"].transpose("step", "gp").values.astype(bool).ravel()]
            row[f"off the training data (%, {training.k}-NN)"] = 100 * float(training.off(x).mean())
        for name, values in (("p/p0", p), ("q/p0", q), ("Lode angle (deg)", lode),
                             ("principal-axis rotation (deg)", rotation), ("shear strain ε_s (%)", shear),
                             ("volumetric strain (%)", volumetric)):
            lo, hi = spread(values)
            row[f"{name}: 1 %"], row[f"{name}: 99 %"] = float(lo), float(hi)
        rows.append(row)
    return pd.DataFrame(rows)


# ------------------------------------------------------------------------------ off the training data


def run_features(run: xr.Dataset, history: tuple[str, ...]) -> np.ndarray:
    """[steps, n_gp, 6 + len(history)] the networks' inputs along a run's converged strains: the
    strain and the history variables named (``history.HIST``), accumulated as FEM–ML does, and p0,
    the consolidation pressure, where named: the run's confining pressure, as FEM–ML gives it."""
    strain = _values(run, "strain")
    parts = [strain]
    computed = [h for h in history if h in HIST]
    if computed:
        parts.append(history_from_sequence(strain)[..., [HIST.index(h) for h in computed]])
    if "p0" in history:
        parts.append(np.full((*strain.shape[:-1], 1), float(run.attrs["confining_pressure_Pa"])))
    return np.concatenate(parts, axis=-1) if len(parts) > 1 else strain


