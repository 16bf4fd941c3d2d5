"""Figures and tables of the problems beyond the triaxial specimen (plane-strain biaxial test,
strip footing): what the report shows of each, from run files in the data contract.

    response_figure({label: run}, out, ...)        load–displacement (and volumetric strain)
    field_figure(run, quantities, steps, out, ...) Gauss-point fields on the deformed mesh
    band_table(runs, angles, ...)                  band metrics beside the RVE's Coulomb and Roscoe angles
    footing_table(runs, angles, ...)               limit pressure beside q0·N_q; the states the RVEs saw
    angles_table(element_runs)                     φ and ψ of one RVE, triaxial and plane strain
    mesh_table({mesh: run})                        the post-peak branch and the band against the mesh

Field maps draw every Gauss point as the quarter of its element around it (the element split
at its centre and edge midpoints), so a band one element wide stays visible.
"""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import xarray as xr  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from . import quantities as qty  # noqa: E402
from .angles import arthur_angle, bearing_capacity_factor, coulomb_angle, element_angles, roscoe_angle  # noqa: E402
from .bands import band_metrics  # noqa: E402
from .figures import save_figure, style  # noqa: E402
from .selection import resolve_steps  # noqa: E402

#: the axes (x, z) of the plane-strain problems' plane
PLANE = [0, 2]
#: name -> (label, unit, per-Gauss-point values of a run at a step)
FIELDS = {
    "shear_strain": ("equivalent shear strain ε_s", "%",
                     lambda ds, k: 100 * qty.equivalent_shear_strain(_gp(ds, "strain", k))),
    "volumetric_strain": ("volumetric strain (dilation +)", "%",
                          lambda ds, k: 100 * qty.volumetric_strain(_gp(ds, "strain", k))),
    "mean_stress": ("mean stress p / p0", "1",
                    lambda ds, k: qty.mean_stress(_gp(ds, "stress", k)) / float(ds.attrs["confining_pressure_Pa"])),
    "deviatoric_stress": ("deviatoric stress q", "kPa",
                          lambda ds, k: 1e-3 * np.abs(qty.deviatoric_stress(_gp(ds, "stress", k)))),
}


def _gp(ds: xr.Dataset, name: str, step: int) -> np.ndarray:
    return ds[name].isel(step=step).transpose("gp", "comp").values


def load_axis(ds: xr.Dataset) -> tuple[np.ndarray, str]:
    """(x values, axis label) of a problem's load: axial strain in % or settlement over width in %."""
    if ds.attrs.get("problem") == "footing":
        return 100 * ds["settlement_ratio"].values, "settlement s/B (%)"
    return 100 * ds["axial_strain"].values, "axial strain (%)"


def force_axis(ds: xr.Dataset) -> tuple[np.ndarray, str]:
    """(y values, label) of the force–displacement curve: footing pressure in kPa, else the platen force in kN/m."""
    if ds.attrs.get("problem") == "footing":
        return 1e-3 * ds["footing_pressure"].values, "footing pressure (kPa)"
    return 1e-3 * ds["load_force"].values, "platen force (kN per m, compression +)"


# ------------------------------------------------------------------------------ figures
def response_figure(runs: Mapping[str, xr.Dataset], out, *, title: str, figsize=(10.0, 4.0), dpi: int = 120) -> dict:
    """Force–displacement (left) and volumetric strain (right) of each run against its load.
    Returns what it drew: {"force" | "volumetric strain": {run label: (load, value)}}."""
    fig, (left, right) = plt.subplots(1, 2, figsize=figsize)
    drawn = {"force": {}, "volumetric strain": {}}
    for k, (label, ds) in enumerate(runs.items()):
        x, xlabel = load_axis(ds)
        y, ylabel = force_axis(ds)
        st = style(k)
        drawn["force"][label] = (x, y)
        drawn["volumetric strain"][label] = (x, 100 * ds["volumetric_strain"].values)
        left.plot(*drawn["force"][label], label=label, **st)
        right.plot(*drawn["volumetric strain"][label], label=label, **st)
        left.set_xlabel(xlabel)
        right.set_xlabel(xlabel)
        left.set_ylabel(ylabel)
    right.set_ylabel("volumetric strain (%, dilation +)")
    for ax in (left, right):
        ax.grid(alpha=0.3)
    left.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.14, top=0.88, wspace=0.28)
    save_figure(fig, out, dpi)
    return drawn


def gauss_point_cells(ds: xr.Dataset, step: int, scale: float = 1.0) -> np.ndarray:
    """[n_gp, 4, 2] the quarter of its element around each Gauss point, on the deformed mesh."""
    nodes = ds["node_position"].values[:, PLANE]
    moved = nodes + scale * ds["displacement"].isel(step=step).transpose("node", "xyz").values[:, PLANE]
    elements = ds["element_vertices"].transpose("element", "vertex").values.astype(int)
    gp = ds["gp_position"].transpose("gp", "xyz").values[:, PLANE]
    per = gp.shape[0] // elements.shape[0]
    cells = np.empty((gp.shape[0], 4, 2))
    for e, vertices in enumerate(elements):
        v, w = nodes[vertices], moved[vertices]  # undeformed (to match points), deformed (to draw)
        centre_v, centre_w = v.mean(axis=0), w.mean(axis=0)
        mid_w = 0.5 * (w + np.roll(w, -1, axis=0))
        quarters = [np.array([w[k], mid_w[k], centre_w, mid_w[k - 1]]) for k in range(4)]
        corners_v = [0.5 * (v[k] + centre_v) for k in range(4)]  # the quarters' centres, undeformed
        for q in range(per):
            point = gp[e * per + q]
            k = int(np.argmin([np.linalg.norm(point - c) for c in corners_v]))
            cells[e * per + q] = quarters[k]
    return cells


def field_figure(run: xr.Dataset, quantities: Sequence[str], steps: Sequence[int], out, *, title: str,
                 deformation_scale: float = 1.0, figsize=None, dpi: int = 120) -> Path:
    """Rows: load steps; columns: quantities of :data:`FIELDS`, each Gauss point's quarter coloured."""
    steps = resolve_steps(list(steps), run.sizes["step"])
    x, xlabel = load_axis(run)
    nodes = run["node_position"].values[:, PLANE]
    width, height = np.ptp(nodes[:, 0]), np.ptp(nodes[:, 1])
    ncols = len(quantities)
    if figsize is None:
        panel = 3.2
        figsize = (panel * ncols * min(1.6, max(width / height, 0.5)) + 1.2, panel * len(steps) + 0.8)
    fig, axes = plt.subplots(len(steps), ncols, figsize=figsize, squeeze=False)
    for col, name in enumerate(quantities):
        label, unit, values = FIELDS[name]
        per_step = [values(run, k) for k in steps]
        lo = min(float(v.min()) for v in per_step)
        hi = max(float(v.max()) for v in per_step)
        if hi - lo < 1e-12 * max(abs(hi), 1.0):
            hi = lo + 1e-12 * max(abs(hi), 1.0)
        signed = lo < 0 < hi and name == "volumetric_strain"
        if signed:
            lo, hi = -max(-lo, hi), max(-lo, hi)
        cmap = "RdBu_r" if signed else "viridis"
        for row, (step, v) in enumerate(zip(steps, per_step)):
            ax = axes[row, col]
            cells = PolyCollection(gauss_point_cells(run, step, deformation_scale), array=v, cmap=cmap,
                                   edgecolors="face", linewidths=0.2)
            cells.set_clim(lo, hi)
            ax.add_collection(cells)
            ax.autoscale_view()
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            if row == 0:
                ax.set_title(textwrap.fill(f"{label} ({unit})", 24), fontsize=8)
            if col == 0:
                ax.set_ylabel(f"step {step}: {xlabel.split(' (')[0]} {x[step]:.2f} %", fontsize=8)
            if row == len(steps) - 1:
                fig.colorbar(cells, ax=axes[:, col].tolist(), orientation="horizontal", fraction=0.04, pad=0.02)
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, out, dpi)


# ------------------------------------------------------------------------------ tables
def angles_table(element_runs: Mapping[str, xr.Dataset]) -> pd.DataFrame:
    """One row per element test (triaxial, plane strain) of one RVE: φ, ψ and their strains."""
    rows = []
    for label, run in element_runs.items():
        a = element_angles(run)
        rows.append({
            "test": label,
            "peak friction angle φ (deg)": a["peak_friction_deg"],
            "axial strain at peak (%)": 100 * a["peak_axial_strain"],
            "peak deviator σ1−σ3 (kPa)": 1e-3 * a["peak_deviator_Pa"],
            "dilatancy angle at peak ψ (deg)": a["dilatancy_at_peak_deg"],
            "largest dilatancy angle (deg)": a["max_dilatancy_deg"],
            "mobilised friction at the end (deg)": a["final_friction_deg"],
            "final axial strain (%)": 100 * a["final_axial_strain"],
            "Coulomb 45+φ/2 (deg)": coulomb_angle(a["peak_friction_deg"]),
            "Roscoe 45+ψ/2 (deg)": roscoe_angle(a["dilatancy_at_peak_deg"]),
            "Arthur 45+(φ+ψ)/4 (deg)": arthur_angle(a["peak_friction_deg"], a["dilatancy_at_peak_deg"]),
            "N_q(φ)": bearing_capacity_factor(a["peak_friction_deg"]),
        })
    return pd.DataFrame(rows)


def plane_strain_angles(angles: pd.DataFrame) -> pd.Series:
    """The plane-strain row of :func:`angles_table`."""
    rows = angles[angles["test"].str.contains("plane strain")]
    if rows.empty:
        raise ValueError("the angles table has no plane-strain element test")
    return rows.iloc[0]


def band_table(runs: Mapping[str, xr.Dataset], angles: pd.DataFrame | None, grain_diameter: float) -> pd.DataFrame:
    """Band metrics of each biaxial run, beside the plane-strain RVE's Coulomb and Roscoe angles."""
    ps = plane_strain_angles(angles) if angles is not None else None
    rows = []
    for label, run in runs.items():
        m = band_metrics(run)
        element = float(run.attrs["specimen_size_m"][0]) / int(run.attrs["specimen_elements"][0])
        row = {
            "run": label,
            "mesh": "x".join(str(int(v)) for v in run.attrs["specimen_elements"]),
            "Gauss points": m["gauss_points"],
            "band onset: axial strain (%)": 100 * m["onset_load"],
            "inclination to σ3 (deg)": m["inclination_deg"],
            "width (mm)": 1e3 * m["width_m"],
            "width / element size": m["width_m"] / element,
            "width / mean grain diameter": m["width_m"] / grain_diameter,
            "band / mean shear strain at the end": m["band_ratio"],
            "band points": m["band_points"],
            "peak force (kN/m)": 1e-3 * float(run["load_force"].max()),
            "axial strain at peak (%)": 100 * float(run["axial_strain"].values[int(np.argmax(run["load_force"].values))]),
            "force at the end / peak": float(run["load_force"].values[-1] / run["load_force"].max()),
        }
        if ps is not None:
            roscoe, coulomb = float(ps["Roscoe 45+ψ/2 (deg)"]), float(ps["Coulomb 45+φ/2 (deg)"])
            row.update({
                "Roscoe 45+ψ/2 (deg)": roscoe,
                "Arthur (deg)": float(ps["Arthur 45+(φ+ψ)/4 (deg)"]),
                "Coulomb 45+φ/2 (deg)": coulomb,
                "between Roscoe and Coulomb": bool(min(roscoe, coulomb) <= m["inclination_deg"] <= max(roscoe, coulomb)),
            })
        rows.append(row)
    return pd.DataFrame(rows)


def footing_table(runs: Mapping[str, xr.Dataset], angles: pd.DataFrame | None) -> pd.DataFrame:
    """Per footing run: pressure at the end and its largest, beside q0·N_q(φ) of the plane-strain
    RVE; the range of mean stress and shear strain the RVEs saw."""
    ps = plane_strain_angles(angles) if angles is not None else None
    rows = []
    for label, run in runs.items():
        q = run["footing_pressure"].values
        q0 = float(run.attrs["surcharge_Pa"])
        stress = run["stress"].transpose("step", "gp", "comp").values
        p = qty.mean_stress(stress) / q0
        shear = qty.equivalent_shear_strain(run["strain"].transpose("step", "gp", "comp").values)
        where = np.unravel_index(int(np.argmax(p)), p.shape)
        row = {
            "run": label,
            "settlement at the end s/B (%)": 100 * float(run["settlement_ratio"].values[-1]),
            "pressure at the end (kPa)": 1e-3 * float(q[-1]),
            "largest pressure (kPa)": 1e-3 * float(q.max()),
            "largest pressure / q0": float(q.max() / q0),
            "pressure gain over the last 20 % of the settlement (%)": _late_gain(run["settlement_ratio"].values, q),
            "mean stress p/p0: smallest": float(p.min()),
            "mean stress p/p0: largest": float(p.max()),
            "largest p at (x, z) m": f"({run['gp_position'].values[where[1], 0]:.3f}, "
                                     f"{run['gp_position'].values[where[1], 2]:.3f})",
            "largest shear strain ε_s (%)": 100 * float(shear.max()),
            "Gauss points": int(run.sizes["gp"]),
        }
        if ps is not None:
            nq = float(ps["N_q(φ)"])
            row.update({"plane-strain φ (deg)": float(ps["peak friction angle φ (deg)"]), "N_q(φ)": nq,
                        "q0·N_q (kPa)": 1e-3 * q0 * nq, "largest pressure / (q0·N_q)": float(q.max() / (q0 * nq))})
        rows.append(row)
    return pd.DataFrame(rows)


def _late_gain(settlement: np.ndarray, pressure: np.ndarray) -> float:
    """Pressure gained over the last 20 % of the settlement, in % of the final pressure (a limit
    load is reached when this is small)."""
    late = settlement >= 0.8 * settlement[-1]
    first = int(np.flatnonzero(late)[0])
    return float(100 * (pressure[-1] - pressure[first]) / pressure[-1])


def mesh_table(runs: Mapping[str, xr.Dataset]) -> pd.DataFrame:
    """The biaxial runs of several meshes side by side, against the finest (the most Gauss points)."""
    rows = {label: band_table({label: run}, None, 1.0).iloc[0] for label, run in runs.items()}
    finest = max(runs, key=lambda k: runs[k].sizes["gp"])
    ref = runs[finest]
    out = []
    for label, run in runs.items():
        steps = min(run.sizes["step"], ref.sizes["step"])
        f, f_ref = run["load_force"].values[:steps], ref["load_force"].values[:steps]
        peak = int(np.argmax(f_ref))
        pre, post = slice(0, peak + 1), slice(peak, steps)
        r = rows[label]
        out.append({
            "mesh": r["mesh"], "Gauss points": r["Gauss points"], "element": str(run.attrs.get("element", "")),
            "peak force (kN/m)": r["peak force (kN/m)"], "force at the end / peak": r["force at the end / peak"],
            f"largest force difference to {rows[finest]['mesh']} before its peak (% of peak)":
                100 * float(np.max(np.abs(f[pre] - f_ref[pre])) / f_ref.max()),
            f"largest force difference to {rows[finest]['mesh']} after its peak (% of peak)":
                100 * float(np.max(np.abs(f[post] - f_ref[post])) / f_ref.max()),
            "band onset (%)": r["band onset: axial strain (%)"], "inclination (deg)": r["inclination to σ3 (deg)"],
            "width (mm)": r["width (mm)"], "band / mean shear strain": r["band / mean shear strain at the end"],
        })
    return pd.DataFrame(out)


def read_table(path) -> pd.DataFrame:
    """A table this module wrote (CSV)."""
    return pd.read_csv(path)
