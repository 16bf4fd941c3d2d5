"""Calibration of the ensemble spread: does the spread FEM–ML reports say how wrong it is?

For a FEM–ML run (with the ensemble spread of ``drivers.fem_ml``) and the reference run of the
same load path and mesh, per load step and Gauss point:

* predicted: the spread ‖stress_spread‖ (kPa) and the relative indicator
  ``stress_spread_relative`` (‖std‖ / max(‖σ‖, √3·p0));
* realised: the error ‖σ_ML − σ_ref‖ (kPa);

with the tensor norm of ``metrics.stress_norm`` (shear counted twice). Step 0, the
consolidated state, is left out: the anchored networks reproduce it exactly by construction
(spread and error both 0 to round-off), so it says nothing about calibration.

A spread is calibrated when the error is about as large (the y = x line of the figure) and
ranks with it (Spearman ρ near 1). With an ensemble of one network the spread is 0 and carries
no information: table, figure and title say so and show the error alone.

The members agree more than they are right: trained on the same data, they share much of their
error. ``surrogate.training.heldout_spread_scale`` measures by how much, on whole trajectories the
training never saw (the dataset's held-out side, the networks fed their strain histories, no FEM):
the median error / spread there is the spread's *scale*, one number per network pair (rule
``table_spread_scale``, :func:`write_spread_scale`). The calibration of a run then also gives
error / (scale × spread): about 1 where the run's points are as far from the training as the
held-out trajectories, above 1 where they are farther (the problems); the scale is fitted on data
independent of the run it is judged on.

    points = calibration_points(run, reference)      # one row per (step ≥ 1, Gauss point)
    calibration_table(points)                        # per spread decile, then the row "all"
    steps = step_summary(points)                     # per step: median and 90th percentile
    make_calibration(run_file, reference_file, png, csv, html, settings, ...)   # the rule's products
    write_spread_scale(rows, csv, html)              # the rule's table of the scales
    point_spread_scales(run, read_spread_scales(csv))   # [n_gp] each point's scale (the weak zone's own)
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd
import xarray as xr

from .. import data, integrity
from . import metrics, tables
from .products import legend_label

N_BINS = 10
#: phases shaded in the figure's path panel
SHADED_PHASES = {"unloading": "0.88", "reloading": "0.95"}


class CalibrationError(ValueError):
    """The runs cannot be compared for calibration; the message names the file."""


def ensemble_size(run: xr.Dataset) -> int:
    return int(run.attrs.get("ensemble_size", run["stress_spread"].attrs.get("ensemble_size", 1)))


def calibration_points(run: xr.Dataset, reference: xr.Dataset, label: str = "FEM–ML run",
                       spread_scale: np.ndarray | None = None) -> pd.DataFrame:
    """One row per (load step ≥ 1, Gauss point): step, gp, phase, spread_kpa, relative_spread, error_kpa;
    with ``spread_scale`` ([n_gp], :func:`point_spread_scales`) also scaled_spread_kpa, the spread times
    its point's scale."""
    for name in ("stress_spread", "stress_spread_relative"):
        if name not in run:
            raise CalibrationError(f"{label} has no '{name}' (written before FEM–ML recorded the ensemble spread: "
                                   "run rule fem_ml again)")
    reference = metrics.common_steps(reference, run, label=label)
    ref = reference["stress"].transpose("step", "gp", "comp").values
    val = run["stress"].transpose("step", "gp", "comp").values
    spread = run["stress_spread"].transpose("step", "gp", "comp").values
    relative = run["stress_spread_relative"].transpose("step", "gp").values
    n_steps, n_gp = relative.shape
    step, gp = np.meshgrid(run["step"].values, run["gp"].values, indexing="ij")
    phase = np.broadcast_to(tables.phase_labels(run)[:, None], (n_steps, n_gp))
    points = pd.DataFrame({
        "step": step.ravel(), "gp": gp.ravel(), "phase": phase.ravel(),
        "spread_kpa": 1e-3 * metrics.stress_norm(spread).ravel(),
        "relative_spread": relative.ravel(),
        "error_kpa": 1e-3 * metrics.stress_norm(val - ref).ravel(),
    })
    if spread_scale is not None:
        scale = np.asarray(spread_scale, dtype=float)
        if scale.shape != (n_gp,):
            raise CalibrationError(f"{label}: {scale.shape} spread scales for its {n_gp} Gauss points")
        points["scaled_spread_kpa"] = points.spread_kpa * np.tile(scale, n_steps)
    bad = points[~np.isfinite(points[["spread_kpa", "relative_spread", "error_kpa"]]).all(axis=1)]
    if len(bad):
        raise CalibrationError(f"{label}: non-finite spread or error at (step, Gauss point) "
                               f"{list(zip(bad.step, bad.gp))[:5]}")
    return points[points.step >= 1].reset_index(drop=True)


def spread_deciles(spread: np.ndarray, n_bins: int = N_BINS) -> np.ndarray:
    """1..n_bins per point: its spread's rank in equal-count bins (ties broken by order, so every
    bin holds n/n_bins points even when spreads repeat, e.g. a uniform field)."""
    order = np.argsort(spread, kind="stable")
    rank = np.empty(len(spread), dtype=int)
    rank[order] = np.arange(len(spread))
    return rank * n_bins // max(len(spread), 1) + 1


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman rank correlation (average ranks for ties); NaN when either side is constant."""
    rx, ry = pd.Series(x).rank().to_numpy(), pd.Series(y).rank().to_numpy()
    if len(x) < 2 or np.ptp(rx) == 0 or np.ptp(ry) == 0:
        return float("nan")
    return float(np.corrcoef(rx, ry)[0, 1])


def _row(label, pick: pd.DataFrame) -> dict:
    spread, error = pick.spread_kpa.to_numpy(), pick.error_kpa.to_numpy()
    positive = spread > 0
    row = {
        "decile": label,
        "count": int(len(pick)),
        "spread_min_kpa": float(spread.min()),
        "spread_max_kpa": float(spread.max()),
        "median_spread_kpa": float(np.median(spread)),
        "median_relative_spread": float(np.median(pick.relative_spread)),
        "median_error_kpa": float(np.median(error)),
        "p90_error_kpa": float(np.percentile(error, 90)),
        "median_error_over_spread": float(np.median(error[positive] / spread[positive])) if positive.any() else np.nan,
    }
    if "scaled_spread_kpa" in pick:
        scaled = pick.scaled_spread_kpa.to_numpy()
        row["median_error_over_scaled_spread"] = (float(np.median(error[positive] / scaled[positive]))
                                                  if positive.any() else np.nan)
    return row


def calibration_table(points: pd.DataFrame, n_bins: int = N_BINS) -> pd.DataFrame:
    """Per spread decile (1 = smallest spreads): count, spread range and median (kPa), median
    relative spread, median and 90th-percentile error (kPa), median error/spread; then the row
    "all" with the Spearman rank correlations of the error with ‖std‖ and with the relative
    spread. Without spread (one network) only the row "all"."""
    if points.empty:
        raise CalibrationError("no (step, Gauss point) to calibrate: the run has no load step after step 0")
    rows = []
    if (points.spread_kpa > 0).any():
        deciles = spread_deciles(points.spread_kpa.to_numpy(), n_bins)
        rows = [_row(str(d), points[deciles == d]) for d in range(1, n_bins + 1) if (deciles == d).any()]
    everything = _row("all", points)
    everything["spearman_spread_error"] = spearman(points.spread_kpa.to_numpy(), points.error_kpa.to_numpy())
    everything["spearman_relative_spread_error"] = spearman(points.relative_spread.to_numpy(),
                                                            points.error_kpa.to_numpy())
    return pd.DataFrame([*rows, everything])


def step_summary(points: pd.DataFrame) -> pd.DataFrame:
    """Per load step: phase, and median and 90th percentile over the Gauss points of spread and error (kPa)."""
    grouped = points.groupby("step", sort=True)
    return pd.DataFrame({
        "phase": grouped.phase.first(),
        "median_spread_kpa": grouped.spread_kpa.median(),
        "p90_spread_kpa": grouped.spread_kpa.quantile(0.9),
        "median_error_kpa": grouped.error_kpa.median(),
        "p90_error_kpa": grouped.error_kpa.quantile(0.9),
    }).reset_index()


def point_spread_scales(run: xr.Dataset, scales: Mapping[str, float], label: str = "FEM–ML run") -> np.ndarray:
    """[n_gp] each point's spread scale (``scales``: network round -> scale, the rows of rule
    ``table_spread_scale``): the weak zone's networks' at the points inside the weak zone of a run
    that names them (``surrogate_weak_zone_sigma_model``; the zone as the biaxial test draws it, a
    circle in the x–z plane), the specimen's elsewhere."""
    out = np.full(run.sizes["gp"], float(scales["specimen"]))
    if run.attrs.get("surrogate_weak_zone_sigma_model"):
        if "weak_zone" not in scales:
            raise CalibrationError(f"{label} has the weak zone's networks, the spread scales have no row 'weak_zone'")
        xz = run["gp_position"].transpose("gp", "xyz").values[:, [0, 2]]
        centre = np.asarray(run.attrs["weak_zone_center_m"], dtype=float)
        out[np.linalg.norm(xz - centre, axis=1) <= float(run.attrs["weak_zone_radius_m"])] = float(scales["weak_zone"])
    return out


def ensemble_note(k: int) -> str:
    """The figure title's word on the ensemble."""
    if k == 1:
        return "ensemble of 1 member: the spread is 0 and carries no information"
    return f"ensemble of {k} members"


# --------------------------------------------------------------------------------------
# the figure


def _shade_phases(ax, steps: np.ndarray, phases: np.ndarray) -> None:
    """Grey bands over each run of unloading / reloading steps (from the step before: the reversal)."""
    shown = set()
    for phase, colour in SHADED_PHASES.items():
        idx = np.flatnonzero(phases == phase)
        if not idx.size:
            continue
        runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
        for run in runs:
            ax.axvspan(steps[run[0]] - 1, steps[run[-1]], color=colour, zorder=0,
                       label=None if phase in shown else phase)
            shown.add(phase)


def calibration_figure(points: pd.DataFrame, table: pd.DataFrame, steps: pd.DataFrame, out: str | Path, *,
                       k: int, title: str, figsize=(10.0, 4.2), dpi: int = 120) -> dict:
    """Left: error against spread (kPa, log axes, hexbin of the (step, point) pairs), the y = x line and
    the median and 90th-percentile error per spread decile. Right: per load step, median and 90th
    percentile over the Gauss points of spread and error, unloading/reloading shaded.

    Returns what it drew (``figures.Curves``): panel 'error_vs_spread' with the hexbin's pairs under
    'pairs' and the decile curves (empty without a positive spread), panel 'per_step' with the
    curves against the load step, each under its legend label."""
    from . import figures

    plt = figures.plt
    fig, (ax_c, ax_p) = plt.subplots(1, 2, figsize=figsize)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.13, top=0.84, wspace=0.25)
    drawn: figures.Curves = {"error_vs_spread": {}, "per_step": {}}
    plotted = points[(points.spread_kpa > 0) & (points.error_kpa > 0)]
    if len(plotted):
        x, y = plotted.spread_kpa.to_numpy(), plotted.error_kpa.to_numpy()
        drawn["error_vs_spread"]["pairs"] = (x, y)
        ax_c.hexbin(x, y, xscale="log", yscale="log", gridsize=30, mincnt=1, cmap="Blues", bins="log", linewidths=0.2)
        lo, hi = min(x.min(), y.min()) / 1.5, max(x.max(), y.max()) * 1.5
        ax_c.plot([lo, hi], [lo, hi], color="black", linewidth=1.0, label="error = spread")
        if "scaled_spread_kpa" in points:
            scale = float(np.median(points.scaled_spread_kpa[points.spread_kpa > 0] /
                                    points.spread_kpa[points.spread_kpa > 0]))
            if np.isfinite(scale):
                label = f"error = {scale:.2f} × spread (the held-out trajectories' scale)"
                drawn["error_vs_spread"][label] = (np.array([lo, hi]), scale * np.array([lo, hi]))
                ax_c.plot(*drawn["error_vs_spread"][label], color="black", linewidth=1.0, linestyle=":", label=label)
        bins = table[table.decile != "all"]
        for column, fmt, alpha, label in (("median_error_kpa", "o-", 1.0, "median error per spread decile"),
                                          ("p90_error_kpa", "v--", 0.7, "90th percentile per decile")):
            drawn["error_vs_spread"][label] = (bins.median_spread_kpa.to_numpy(), bins[column].to_numpy())
            ax_c.plot(*drawn["error_vs_spread"][label], fmt, color="tab:red", markersize=4, alpha=alpha, label=label)
        ax_c.set_xlim(lo, hi)
        ax_c.set_ylim(lo, hi)
        left_out = len(points) - len(plotted)
        note = f"{len(plotted)} (step, point) pairs" + (f"; {left_out} with zero spread or error left out"
                                                        if left_out else "")
        everything = table.iloc[-1]
        scaled = (f"; error / scaled spread {everything.median_error_over_scaled_spread:.2f}"
                  if "median_error_over_scaled_spread" in table else "")
        ax_c.set_title(f"{note}; Spearman ρ = {float(everything.spearman_spread_error):.2f}{scaled}", fontsize=8)
        ax_c.legend(fontsize=7, loc="upper left")
    else:
        ax_c.set_xticks([])
        ax_c.set_yticks([])
        ax_c.text(0.5, 0.5, "no spread to plot:\none network (surrogate.ensemble_size = 1)" if k == 1 else
                  "no (step, point) with positive spread and error", ha="center", va="center",
                  transform=ax_c.transAxes, fontsize=10)
    ax_c.set_xlabel("predicted spread ‖std of NNσ members‖ (kPa)")
    ax_c.set_ylabel("realised error ‖σ_ML − σ_ref‖ (kPa)")
    ax_c.grid(alpha=0.3, which="both")

    step = steps.step.to_numpy()
    _shade_phases(ax_p, step, steps.phase.to_numpy())
    curves = [("error, median", "median_error_kpa", "tab:red", "-"),
              ("error, 90th percentile", "p90_error_kpa", "tab:red", "--")]
    if k > 1:
        curves += [("spread, median", "median_spread_kpa", "tab:blue", "-"),
                   ("spread, 90th percentile", "p90_spread_kpa", "tab:blue", "--")]
    for label, column, colour, dash in curves:
        drawn["per_step"][label] = (step, steps[column].to_numpy())
        ax_p.plot(*drawn["per_step"][label], color=colour, linestyle=dash, label=label)
    ax_p.set_xlabel("load step")
    ax_p.set_ylabel("kPa, over the Gauss points")
    ax_p.set_ylim(bottom=0.0)
    ax_p.grid(alpha=0.3)
    ax_p.legend(fontsize=7, loc="upper left")
    fig.suptitle(f"{title}\n{ensemble_note(k)}", fontsize=10)
    figures.save_figure(fig, out, dpi)
    return drawn


# --------------------------------------------------------------------------------------
# the rule's products from files

HEADERS = {
    "decile": "spread decile",
    "count": "(step, point) pairs",
    "spread_min_kpa": "spread from (kPa)",
    "spread_max_kpa": "spread to (kPa)",
    "median_spread_kpa": "median spread (kPa)",
    "median_relative_spread": "median relative spread",
    "median_error_kpa": "median error (kPa)",
    "p90_error_kpa": "90th pct. error (kPa)",
    "median_error_over_spread": "median error / spread",
    "median_error_over_scaled_spread": "median error / (scale × spread)",
    "spearman_spread_error": "Spearman ρ (spread, error)",
    "spearman_relative_spread_error": "Spearman ρ (relative spread, error)",
}


def make_calibration(run_file, reference_file, out_png, out_csv, out_html, settings: Mapping, *,
                     path_label: str, reference_label: str, surrogate_label: str,
                     spread_scales: Mapping[str, float] | None = None) -> tuple[pd.DataFrame, dict]:
    """Figure, CSV and HTML table of the spread's calibration; returns the table and what the
    figure drew (:func:`calibration_figure`). With ``spread_scales`` (network round -> scale, rule
    ``table_spread_scale``) also against the scaled spread (:func:`point_spread_scales`)."""
    run = data.read_run(run_file)
    reference = data.read_run(reference_file)
    label = f"{run_file} (against {reference_file})"
    scales = None if spread_scales is None else point_spread_scales(run, spread_scales, label)
    points = calibration_points(run, reference, label=label, spread_scale=scales)
    k = ensemble_size(run)
    table = calibration_table(points)
    title = (f"{path_label}: ensemble spread of {legend_label(surrogate_label, run)} vs its error against "
             f"{reference_label}")
    width = float(settings.get("figure_width", 10.0))
    drawn = calibration_figure(points, table, step_summary(points), out_png, k=k, title=title,
                               figsize=(width, 0.42 * width), dpi=int(settings.get("dpi", 120)))
    tables.write_csv(table, out_csv)
    note = (f"{ensemble_note(k)}. Spread: the norm of the standard deviation over the members of each stress "
            "component at the converged strain; error: the norm of the stress difference from the reference; "
            f"per (load step >= 1, Gauss point), {len(points)} pairs; deciles of equal count by spread."
            + (" Scale: the median error / spread of the networks on their held-out trajectories (table "
               "spread_scale), the weak zone's networks' own at its points." if scales is not None else ""))
    tables.write_html_table(table, out_html, title=title, note=note, headers=HEADERS, digits=3)
    return table, drawn


SCALE_HEADERS = {
    "networks": "networks",
    "model": "NNσ model file",
    "heldout_trajectories": "held-out trajectories",
    "pairs": "(step, trajectory) samples",
    "scale": "scale: median error / spread",
    "p10_error_over_spread": "10th pct. error / spread",
    "p90_error_over_spread": "90th pct. error / spread",
}


def write_spread_scale(rows: list[dict], out_csv, out_html) -> pd.DataFrame:
    """Rule table_spread_scale: one row per network pair (networks, model, then what
    ``surrogate.training.heldout_spread_scale`` returns) as a CSV and an HTML table; returns the table."""
    table = pd.DataFrame(rows).rename(columns={"trajectories": "heldout_trajectories"})[list(SCALE_HEADERS)]
    tables.write_csv(table, out_csv)
    note = ("Each network pair's NNσ ensemble fed the strain histories of its held-out trajectories (whole "
            "trajectories the training never saw), per (step >= 1, trajectory): the realised error over the "
            "members' spread. Its median scales the spread in the calibration tables and figures; NaN for one "
            "network (no spread).")
    tables.write_html_table(table, out_html, title="The ensemble spread's scale on held-out trajectories",
                            note=note, headers=SCALE_HEADERS, digits=3)
    return table


def read_spread_scales(path) -> dict[str, float]:
    """{network round: scale} from a table of :func:`write_spread_scale`."""
    integrity.verify(path, "spread-scale table")
    table = pd.read_csv(path)
    missing = {"networks", "scale"} - set(table.columns)
    if missing or "specimen" not in set(table.networks):
        raise CalibrationError(f"{path}: not a spread-scale table (needs columns networks, scale and the row "
                               "'specimen'; rule table_spread_scale writes it)")
    return dict(zip(table.networks, table.scale.astype(float)))
