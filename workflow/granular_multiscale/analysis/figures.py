"""Matplotlib figures of the report (the paper's Figs. 8, 10–15 and a speed-vs-error plot).

Every function takes data (xarray Datasets in the data contract, pandas tables) and an
output path, draws on a fixed canvas (``figsize`` inches × ``dpi``, no tight bounding box,
so the PNG size is known in advance), writes the PNG atomically and returns the numbers it
drew, each curve drawn from them: a line figure ``{panel: {curve: (x, y)}}`` (:data:`Curves`),
in the units of its axes; the error map a table of its points; each function says which.

Runs are passed as an ordered ``{label: Dataset}`` mapping whose first entry is the
reference; labels appear verbatim in the legends.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import xarray as xr  # noqa: E402

from ..atomic import atomic_path
from . import quantities as qty  # noqa: E402

# reference first: black solid; then the surrogates, each in its own colour and dash
STYLES = (
    dict(color="black", linestyle="-", linewidth=2.0, marker=None),
    dict(color="tab:blue", linestyle="--", linewidth=1.5, marker="o", markersize=3),
    dict(color="tab:red", linestyle=":", linewidth=1.5, marker="s", markersize=3),
    dict(color="tab:green", linestyle="-.", linewidth=1.2, marker="^", markersize=3),
    dict(color="tab:purple", linestyle="--", linewidth=1.2, marker="v", markersize=3),
    dict(color="tab:brown", linestyle=":", linewidth=1.2, marker="d", markersize=3),
    dict(color="tab:orange", linestyle="-", linewidth=1.2, marker="x", markersize=3),
    dict(color="tab:gray", linestyle="--", linewidth=1.2, marker="+", markersize=4),
)


# what a line figure drew: {panel: {curve label: (x, y)}}, in the units of the panel's axes
Curves = dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]


def style(k: int) -> dict:
    return dict(STYLES[k % len(STYLES)])


def save_figure(fig, out: str | Path, dpi: int) -> Path:
    """Write the PNG atomically (a failed write never leaves a half file) and close the figure."""
    try:
        with atomic_path(out) as tmp:
            fig.savefig(tmp, dpi=dpi, format="png")
    finally:
        plt.close(fig)
    return Path(out)


def _shade_unloading(ax, phase: np.ndarray, x: np.ndarray | None = None) -> None:
    """Grey band over the unloading steps, so the eye finds the reversal."""
    phase = np.asarray(phase)
    x = np.arange(len(phase)) if x is None else np.asarray(x)
    unloading = np.flatnonzero(phase == "unloading")
    if unloading.size:
        ax.axvspan(x[unloading[0] - 1], x[unloading[-1]], color="0.9", zorder=0, label="unloading")


# --------------------------------------------------------------------------------------
# error map (paper Fig. 10)


def _box_edges(ax, lower, upper) -> None:
    corners = np.array([[x, y, z] for x in (lower[0], upper[0]) for y in (lower[1], upper[1]) for z in (lower[2], upper[2])])
    for i in range(8):
        for j in range(i + 1, 8):
            if np.count_nonzero(corners[i] != corners[j]) == 1:
                ax.plot(*corners[[i, j]].T, color="0.6", linewidth=0.6)


def error_map(
    reference: xr.Dataset,
    error_kpa: np.ndarray,
    train_gp,
    heldout_gp,
    out: str | Path,
    *,
    path_label: str,
    surrogate_label: str = "FEM–ML",
    reference_label: str = "reference",
    figsize=(10.0, 5.5),
    dpi: int = 120,
) -> pd.DataFrame:
    """Per-Gauss-point absolute stress error ``error_kpa`` [gp] drawn at the Gauss points of
    ``reference`` in 3D, training ○ vs held-out △ points.

    Returns what it drew: one row per point, columns gp, group ('training' or 'held out'),
    x, y, z (m) and error_kpa (its colour, and its value in the box plot of its group)."""
    position = reference["gp_position"].values
    error_kpa = np.asarray(error_kpa, dtype=float)
    if error_kpa.shape != (len(position),):
        raise ValueError(f"error_kpa has shape {error_kpa.shape}, expected ({len(position)},)")
    if not np.all(np.isfinite(error_kpa)):
        bad = np.flatnonzero(~np.isfinite(error_kpa))
        raise ValueError(f"non-finite stress error at Gauss points {bad[:10].tolist()}")
    train_gp = np.asarray(train_gp, dtype=int)
    heldout_gp = np.asarray(heldout_gp, dtype=int)
    lower = reference["node_position"].values.min(axis=0)
    upper = reference["node_position"].values.max(axis=0)

    groups = (("training", train_gp, "o"), ("held out", heldout_gp, "^"))
    gp = np.concatenate([idx for _, idx, _ in groups])
    group = np.repeat([name for name, _, _ in groups], [idx.size for _, idx, _ in groups])
    drawn = pd.DataFrame({"gp": gp, "group": group, "x": position[gp, 0], "y": position[gp, 1], "z": position[gp, 2],
                          "error_kpa": error_kpa[gp]})
    points = {name: drawn[drawn["group"] == name] for name, _, _ in groups}

    fig = plt.figure(figsize=figsize)
    ax = fig.add_axes([0.0, 0.0, 0.58, 0.9], projection="3d")
    norm = matplotlib.colors.Normalize(vmin=0.0, vmax=max(float(error_kpa.max()), 1e-12))
    cmap = plt.get_cmap("viridis")
    for name, _, marker in groups:
        rows = points[name]
        if len(rows):
            ax.scatter(*rows[["x", "y", "z"]].to_numpy().T, c=rows["error_kpa"].to_numpy(), cmap=cmap, norm=norm,
                       marker=marker, s=46 if marker == "^" else 30, edgecolors="k", linewidths=0.4,
                       depthshade=False, label=f"{name} ({len(rows)})")
    _box_edges(ax, lower, upper)
    ax.set_box_aspect(upper - lower, zoom=0.82)
    for pane in (ax.xaxis, ax.yaxis, ax.zaxis):
        pane.set_pane_color((1.0, 1.0, 1.0, 0.0))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.view_init(elev=18, azim=-55)
    # legend markers in grey: their colour in the plot is the error, not the group
    handles = [matplotlib.lines.Line2D([], [], linestyle="", marker=m, markersize=7, markerfacecolor="0.75",
                                       markeredgecolor="k", label=f"{name} ({idx.size})")
               for idx, m, name in ((train_gp, "o", "training"), (heldout_gp, "^", "held out"))]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(0.02, 0.98), fontsize=8, title="Gauss points",
              title_fontsize=8)
    cax = fig.add_axes([0.6, 0.15, 0.015, 0.65])
    bar = fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap), cax=cax)
    bar.set_label("mean |σ error| (kPa)")

    side = fig.add_axes([0.75, 0.15, 0.22, 0.65])
    values = [points[name]["error_kpa"].to_numpy() for name, _, _ in groups]
    side.boxplot(values, tick_labels=["training", "held out"], widths=0.5, showfliers=False)
    for k, (g, marker) in enumerate(zip(values, ("o", "^")), start=1):
        jitter = np.linspace(-0.12, 0.12, g.size) if g.size > 1 else np.zeros(g.size)
        side.scatter(k + jitter, g, c=g, cmap=cmap, norm=norm, marker=marker, s=14, edgecolors="k", linewidths=0.3)
    side.set_ylabel("mean |σ error| (kPa)")
    side.set_ylim(bottom=0.0)
    side.set_title("per Gauss point", fontsize=9)
    fig.suptitle(
        f"{path_label}: stress error of {surrogate_label} vs {reference_label}\n"
        "mean over load steps and the six components",
        fontsize=10,
    )
    save_figure(fig, out, dpi)
    return drawn


# --------------------------------------------------------------------------------------
# stress–strain at one Gauss point (paper Figs. 11–13)


def stress_strain(
    runs: Mapping[str, xr.Dataset],
    gp: int,
    out: str | Path,
    *,
    title: str,
    figsize=(10.0, 4.2),
    dpi: int = 120,
) -> Curves:
    """q and volumetric strain against the local axial strain −ε33 at Gauss point ``gp``.

    Returns what it drew: panels 'q_kpa' and 'volumetric_strain_pct', one curve per run
    (x: −ε33 in %)."""
    fig, (ax_q, ax_v) = plt.subplots(1, 2, figsize=figsize)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.13, top=0.86, wspace=0.28)
    drawn: Curves = {"q_kpa": {}, "volumetric_strain_pct": {}}
    for k, (label, ds) in enumerate(runs.items()):
        strain = ds["strain"].sel(gp=gp).transpose("step", "comp").values
        stress = ds["stress"].sel(gp=gp).transpose("step", "comp").values
        ea = 100 * qty.local_axial_strain(strain)
        drawn["q_kpa"][label] = (ea, 1e-3 * qty.deviatoric_stress(stress))
        drawn["volumetric_strain_pct"][label] = (ea, 100 * qty.volumetric_strain(strain))
        s = style(k)
        ax_q.plot(*drawn["q_kpa"][label], label=label, **s)
        ax_v.plot(*drawn["volumetric_strain_pct"][label], label=label, **s)
    ax_q.set_xlabel("local axial strain −ε33 (%)")
    ax_q.set_ylabel("deviatoric stress q (kPa)")
    ax_v.set_xlabel("local axial strain −ε33 (%)")
    ax_v.set_ylabel("volumetric strain tr ε (%), dilation +")
    for ax in (ax_q, ax_v):
        ax.grid(alpha=0.3)
    ax_q.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    save_figure(fig, out, dpi)
    return drawn


# --------------------------------------------------------------------------------------
# top force and volumetric strain per load step (paper Figs. 14d, 15d)


def global_response(
    runs: Mapping[str, xr.Dataset],
    out: str | Path,
    *,
    path_label: str,
    marked_steps=(),
    figsize=(10.0, 4.2),
    dpi: int = 120,
) -> Curves:
    """Top force (compression positive, kN) and specimen volumetric strain against load step.

    Returns what it drew: panels 'top_force_kn' and 'volumetric_strain_pct', one curve per run."""
    fig, (ax_f, ax_v) = plt.subplots(1, 2, figsize=figsize)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.13, top=0.88, wspace=0.28)
    reference = next(iter(runs.values()))
    for ax in (ax_f, ax_v):
        _shade_unloading(ax, reference["phase"].values, reference["step"].values)
        for step in marked_steps:
            ax.axvline(step, color="0.5", linewidth=0.8, linestyle="--")
    drawn: Curves = {"top_force_kn": {}, "volumetric_strain_pct": {}}
    for k, (label, ds) in enumerate(runs.items()):
        drawn["top_force_kn"][label] = (ds["step"].values, -1e-3 * ds["top_force"].values)
        drawn["volumetric_strain_pct"][label] = (ds["step"].values, 100 * ds["volumetric_strain"].values)
        s = style(k)
        ax_f.plot(*drawn["top_force_kn"][label], label=label, **s)
        ax_v.plot(*drawn["volumetric_strain_pct"][label], label=label, **s)
    ax_f.set_ylabel("top force, compression + (kN)")
    ax_v.set_ylabel("volumetric strain (%), dilation +")
    for ax in (ax_f, ax_v):
        ax.set_xlabel("load step")
        ax.grid(alpha=0.3)
    ax_f.legend(fontsize=8, loc="lower right")  # the force rises to the right: that corner is free
    note = ""
    if len(marked_steps):
        note = "\ndashed lines: steps " + ", ".join(str(s) for s in marked_steps) + " of the field figures"
    fig.suptitle(f"{path_label}: top force and volumetric strain{note}", fontsize=10)
    save_figure(fig, out, dpi)
    return drawn


# --------------------------------------------------------------------------------------
# training curves (paper Fig. 8)


def training_curves(
    curves: Mapping[str, pd.DataFrame],
    out: str | Path,
    *,
    loss_name: str = "MAE",
    figsize=(10.0, 4.2),
    dpi: int = 120,
) -> Curves:
    """One panel per network; each curve table has columns epoch, train_loss, heldout_loss and,
    for an ensemble, member (one curve per member, the first drawn solid, the others faint).

    ``curves`` keys are 'panel title|series label' (e.g. 'NNσ|with history'); series in the
    same panel share its axes.

    Returns what it drew: per panel title, the curves (epoch, loss) under their legend labels
    ('training (with history)', 'held out (with history)'; 'training', 'held out' without a
    series label), an ensemble's with ', member <m>' added.
    """
    panels: dict[str, list[tuple[str, pd.DataFrame]]] = {}
    for key, table in curves.items():
        panel, _, series = key.partition("|")
        missing = {"epoch", "train_loss", "heldout_loss"} - set(table.columns)
        if missing:
            raise ValueError(f"training curve '{key}' lacks columns {sorted(missing)}")
        panels.setdefault(panel, []).append((series, table))
    fig, axes = plt.subplots(1, len(panels), figsize=figsize, squeeze=False)
    # 0.8 inch on the left for the y label, whatever the width (the training rules draw 6-inch panels)
    fig.subplots_adjust(left=0.8 / figsize[0], right=0.98, bottom=0.13, top=0.85, wspace=0.25)
    drawn: Curves = {}
    for ax, (panel, series_list) in zip(axes[0], panels.items()):
        drawn[panel] = {}
        for k, (series, table) in enumerate(series_list):
            colour = style(k + 1)["color"]
            members = list(table.groupby("member")) if "member" in table else [(0, table)]
            if len(members) > 1:
                series = f"{series}, " if series else ""
                series += f"{len(members)} members"
            suffix = f" ({series})" if series else ""
            for m, (member, rows) in enumerate(members):
                alpha = 0.35 if m else 1.0  # members after the first: faint and unlabelled
                for line, column, dash in (("training", "train_loss", "-"), ("held out", "heldout_loss", "--")):
                    name = f"{line}{suffix}" + (f", member {member}" if len(members) > 1 else "")
                    drawn[panel][name] = (rows["epoch"].to_numpy(), rows[column].to_numpy())
                    ax.plot(*drawn[panel][name], color=colour, linestyle=dash, alpha=alpha,
                            label=None if m else f"{line}{suffix}")
        ax.set_yscale("log")
        ax.set_xlabel("epoch")
        ax.set_ylabel(f"{loss_name} loss (scaled targets)")
        ax.set_title(panel)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.suptitle("Training and held-out loss per epoch", fontsize=10)
    save_figure(fig, out, dpi)
    return drawn


# --------------------------------------------------------------------------------------
# speed vs error


def speed_vs_error(
    table: pd.DataFrame,
    out: str | Path,
    *,
    errors: Mapping[str, str],
    figsize=(10.0, 4.5),
    dpi: int = 120,
) -> Curves:
    """Wall time (log axis) against error to the reference, one point per run.

    ``table`` has a 'label' and a 'wall_time_s' column and one column per entry of
    ``errors`` ({column: axis label}); one panel per error measure. An optional 'curve' column
    (a number, NaN off the curve) joins its rows in that order by a line: FEM–ML, the adaptive
    runs from the highest threshold to the lowest, FEM–DEM.

    Returns what it drew: per error column, each run's point (error, wall time in s) under its
    label, and the line through the curve's points under 'curve' when there is one.
    """
    fig, axes = plt.subplots(1, len(errors), figsize=figsize, squeeze=False)
    fig.subplots_adjust(left=0.09, right=0.98, bottom=0.13, top=0.88, wspace=0.25)
    on_curve = table.dropna(subset=["curve"]).sort_values("curve") if "curve" in table else table.iloc[:0]
    drawn: Curves = {}
    for ax, (column, axis_label) in zip(axes[0], errors.items()):
        drawn[column] = {}
        if len(on_curve) > 1:
            drawn[column]["curve"] = (on_curve[column].to_numpy(), on_curve["wall_time_s"].to_numpy())
            ax.plot(*drawn[column]["curve"], color="0.5", linewidth=1.0, zorder=2,
                    label="adaptive FEM–DEM–ML, threshold from ∞ (FEM–ML) to 0 (FEM–DEM)")
        for k, row in enumerate(table.itertuples(index=False)):
            s = style(k)
            drawn[column][row.label] = (getattr(row, column), row.wall_time_s)
            ax.scatter(*drawn[column][row.label], color=s["color"], marker=s["marker"] or "*",
                       s=120 if k == 0 else 60, edgecolors="k", linewidths=0.5, zorder=3, label=row.label)
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
        ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel(axis_label)
        ax.set_ylabel("wall time of the run (s)")
        ax.grid(alpha=0.3, which="both")
        lo, hi = ax.get_xlim()
        ax.set_xlim(min(lo, 0.0) - 0.02 * (hi - lo), hi + 0.1 * (hi - lo))
        wt = table["wall_time_s"].to_numpy(dtype=float)
        ax.set_ylim(wt.min() / 3, wt.max() * 3)
        if np.log10(wt.max() / wt.min()) < 1.0:
            # less than a decade between the runs: label the minor ticks as well
            ax.yaxis.set_minor_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
            ax.tick_params(axis="y", which="minor", labelsize=7)
    # below the panels: inside, the long labels of partial runs would hide points and ticks
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=2, frameon=False)
    fig.subplots_adjust(bottom=0.13 + 0.045 * ((len(labels) + 1) // 2))
    fig.suptitle("Speed vs error: each point one run on this machine (reference at error 0)", fontsize=10)
    save_figure(fig, out, dpi)
    return drawn


# --------------------------------------------------------------------------------------
# adaptive runs: which Gauss points ran DEM


def dem_share_xz(ds: xr.Dataset, step: int) -> tuple[np.ndarray, np.ndarray]:
    """[m, 2] the distinct (x, z) of the Gauss points and [m] the share of the points at each
    (those behind each other along y) in DEM mode at `step`."""
    position = ds["gp_position"].transpose("gp", "xyz").values
    columns, where = np.unique(np.round(position[:, [0, 2]], 9), axis=0, return_inverse=True)
    where = where.ravel()
    mode = ds["point_mode"].transpose("step", "gp").values[step].astype(float)
    return columns, np.bincount(where, weights=mode, minlength=len(columns)) / np.bincount(where)


def mode_map(runs: Mapping[str, xr.Dataset], steps: list[int], out: str | Path, *, title: str,
             figsize=(10.0, 6.0), dpi: int = 120) -> dict[str, dict[int, tuple[np.ndarray, np.ndarray]]]:
    """One row per adaptive run, one column per load step: the Gauss points in the x–z plane,
    coloured by the share of the points at that (x, z) (the points behind each other along y)
    that answered from their YADE RVE at that step (``point_mode``).

    Returns what it drew: {run label: {step: ([m, 2] the (x, z) of the points, [m] their share)}}."""
    labels = list(runs)
    fig, axes = plt.subplots(len(labels), len(steps), figsize=figsize, squeeze=False, sharex=True, sharey=True)
    height = fig.get_size_inches()[1]  # room in inches: the title above, two-line panel titles, x labels
    fig.subplots_adjust(left=0.08, right=0.88, bottom=0.45 / height, top=1 - 0.8 / height, wspace=0.08,
                        hspace=0.6 * len(labels) / max(height - 1.25, 0.5))
    image = None
    drawn: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
    for row, label in zip(axes, labels):
        ds = runs[label]
        drawn[label] = {}
        for ax, step in zip(row, steps):
            columns, share = dem_share_xz(ds, step)
            drawn[label][step] = (columns, share)
            mode = ds["point_mode"].transpose("step", "gp").values[step]
            image = ax.scatter(columns[:, 0], columns[:, 1], c=share, cmap="coolwarm", vmin=0.0, vmax=1.0, s=40,
                               edgecolors="k", linewidths=0.3)
            ax.set_title(f"{label}\nstep {step}: {int(mode.sum())} of {mode.size} in DEM", fontsize=8)
            if "specimen_size_m" in ds.attrs:  # the whole specimen (the quarter's points sit in its corner)
                size = np.asarray(ds.attrs["specimen_size_m"], dtype=float)
                ax.set_xlim(0.0, size[0])
                ax.set_ylim(0.0, size[2])
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("x (m)", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("z (m)", fontsize=8)
    bar = fig.add_axes([0.90, 0.15, 0.015, 0.65])
    fig.colorbar(image, cax=bar).set_label("share of the points (along y) in DEM mode", fontsize=8)
    fig.suptitle(title, fontsize=10)
    save_figure(fig, out, dpi)
    return drawn


def plot_losses(losses: dict[str, pd.DataFrame], path, loss_name: str = "MAE") -> Curves:
    """Training and held-out loss per epoch of one or more networks (panel per key), log scale.
    Returns what it drew (:func:`training_curves`): {network: {'training' | 'held out': (epoch, loss)}}."""
    return training_curves({f"{label}|": df for label, df in losses.items()}, path, loss_name=loss_name,
                           figsize=(6.0 * len(losses), 4.0))
