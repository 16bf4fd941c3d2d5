"""Fields on the specimen: the mesh as a VTK grid, off-screen renderings, VTU export.

The run files store node positions in scikit-fem's node order, the elements' vertices
(``element_vertices``) and Gauss-point values with gp = element * k + q (k = 8 for hexahedra,
4 for quadrilaterals). A triaxial run written before the files held ``element_vertices`` has
its connectivity rebuilt from the node positions (a tensor-product grid, checked against
them); hexahedra are passed to VTK in VTK's vertex order (bottom quad, then top quad),
quadrilaterals (plane strain, in the x–z plane) as they are.

Gauss-point values are shown as cell averages (mean of the element's points), nodal
displacement as point data; the mesh is drawn deformed by the run's own displacement.
"""

from __future__ import annotations

import os
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import xarray as xr
from skfem import MeshHex

from .. import vtk_order

# Before pyvista: where YADE is loaded, pip's VTK must be loaded deep-bound or it binds to
# YADE's VTK 9.1 and segfaults (ImportError if that already happened; docs/environment.md).
vtk_order.before_vtk_import()
import pyvista as pv  # noqa: E402

from . import quantities as qty
from .selection import resolve_steps

# scikit-fem's local hex vertex order -> VTK_HEXAHEDRON order (skfem.io.meshio uses the same)
SKFEM_TO_VTK_HEX = np.array([0, 3, 6, 2, 1, 5, 7, 4])


class MeshMismatchError(ValueError):
    """Node positions of a run are not the tensor-product hex mesh the figures assume."""


def hex_elements(node_position: np.ndarray) -> np.ndarray:
    """Element connectivity [n_elements, 8] (scikit-fem order) rebuilt from node positions.

    Raises :class:`MeshMismatchError` if the nodes are not those of
    ``MeshHex.init_tensor(unique x, unique y, unique z)`` in the same order.
    """
    node_position = np.asarray(node_position, dtype=float)
    scale = max(float(np.ptp(node_position)), 1e-300)
    axes = []
    for k in range(3):
        values = np.sort(node_position[:, k])
        keep = np.r_[True, np.diff(values) > 1e-9 * scale]
        axes.append(values[keep])
    mesh = MeshHex.init_tensor(*axes)
    if mesh.p.shape[1] != len(node_position) or not np.allclose(mesh.p.T, node_position, atol=1e-9 * scale):
        raise MeshMismatchError(
            f"node_position ({len(node_position)} nodes) is not the scikit-fem tensor-product hex mesh "
            f"with {[len(a) - 1 for a in axes]} elements in its node order"
        )
    return mesh.t.T.copy()


def run_elements(ds: xr.Dataset) -> np.ndarray:
    """Element vertices [n_elements, 8 or 4] of a run: its ``element_vertices``, or (a triaxial run
    written before the files held them) the hex mesh rebuilt from the node positions."""
    if "element_vertices" in ds:
        return ds["element_vertices"].transpose("element", "vertex").values.astype(np.int64)
    return hex_elements(ds["node_position"].values)


def vtk_grid(node_position: np.ndarray, elements: np.ndarray) -> pv.UnstructuredGrid:
    """Undeformed grid of hexahedra [n_elements, 8] or quadrilaterals [n_elements, 4] (vertex
    nodes in scikit-fem's local order; a quadratic quadrilateral is drawn by its vertices)."""
    elements = np.asarray(elements, dtype=np.int64)
    if elements.shape[1] == 8:
        cells = np.hstack([np.full((len(elements), 1), 8), elements[:, SKFEM_TO_VTK_HEX]]).ravel()
        kind = pv.CellType.HEXAHEDRON
    elif elements.shape[1] == 4:  # scikit-fem's quadrilaterals run counter-clockwise, as VTK_QUAD
        cells = np.hstack([np.full((len(elements), 1), 4), elements]).ravel()
        kind = pv.CellType.QUAD
    else:
        raise ValueError(f"elements of {elements.shape[1]} vertices are neither hexahedra nor quadrilaterals")
    cell_types = np.full(len(elements), kind, dtype=np.uint8)
    return pv.UnstructuredGrid(cells, cell_types, np.asarray(node_position, dtype=float))


def cell_average(gp_values: np.ndarray, n_elements: int) -> np.ndarray:
    """[n_gp, ...] Gauss-point values -> [n_elements, ...] element means (gp = element*k + q, k
    points per element)."""
    gp_values = np.asarray(gp_values)
    per_element, rest = divmod(gp_values.shape[0], n_elements)
    if rest or per_element not in (4, 8):
        raise ValueError(f"{gp_values.shape[0]} Gauss points for {n_elements} elements (expected 8 or 4 each)")
    return gp_values.reshape((n_elements, per_element) + gp_values.shape[1:]).mean(axis=1)


# --------------------------------------------------------------------------------------
# the quantities of the field figures


@dataclass(frozen=True)
class FieldQuantity:
    name: str
    label: str  # colour-bar label
    unit: str
    location: str  # "point" (nodal) or "cell" (element mean of Gauss-point values)
    values: Callable[[xr.Dataset, int], np.ndarray]  # (run, step) -> values at nodes or Gauss points
    magnitude: Callable[[xr.Dataset, int], float]  # (run, step) -> size of the whole tensor/vector field


def _axial_displacement_mm(ds: xr.Dataset, step: int) -> np.ndarray:
    return 1e3 * ds["displacement"].sel(step=step, xyz="z").values


def _shear_strain_pct(ds: xr.Dataset, step: int) -> np.ndarray:
    return 100 * qty.equivalent_shear_strain(ds["strain"].sel(step=step).transpose("gp", "comp").values)


def _sigma23_kpa(ds: xr.Dataset, step: int) -> np.ndarray:
    return 1e-3 * ds["stress"].sel(step=step, comp="23").values


def _max_displacement_mm(ds: xr.Dataset, step: int) -> float:
    return 1e3 * float(np.max(np.abs(ds["displacement"].sel(step=step).values)))


def _max_shear_strain_pct(ds: xr.Dataset, step: int) -> float:
    return float(np.max(_shear_strain_pct(ds, step)))


def _max_stress_kpa(ds: xr.Dataset, step: int) -> float:
    return 1e-3 * float(np.max(np.abs(ds["stress"].sel(step=step).values)))


FIELD_QUANTITIES: dict[str, FieldQuantity] = {
    q.name: q
    for q in (
        FieldQuantity("axial_displacement", "axial displacement u_z", "mm", "point", _axial_displacement_mm,
                      _max_displacement_mm),
        FieldQuantity("shear_strain", "equivalent shear strain ε_s", "%", "cell", _shear_strain_pct,
                      _max_shear_strain_pct),
        FieldQuantity("sigma23", "shear stress σ23", "kPa", "cell", _sigma23_kpa, _max_stress_kpa),
    )
}


def field_on_mesh(ds: xr.Dataset, quantity: str, step: int, n_elements: int) -> np.ndarray:
    """Values of ``quantity`` at step ``step`` at the nodes or per element."""
    q = FIELD_QUANTITIES[quantity]
    values = q.values(ds, step)
    return values if q.location == "point" else cell_average(values, n_elements)


# --------------------------------------------------------------------------------------
# off-screen rendering


def deformed_grid(ds: xr.Dataset, elements: np.ndarray, step: int, scale: float = 1.0) -> pv.UnstructuredGrid:
    points = ds["node_position"].values + scale * ds["displacement"].sel(step=step).transpose("node", "xyz").values
    return vtk_grid(points, elements)


class PanelRenderer:
    """One off-screen pyvista plotter reused for every panel of a figure (same camera)."""

    def __init__(self, window_size=(420, 620)):
        self.plotter = pv.Plotter(off_screen=True, window_size=list(window_size))
        self.plotter.set_background("white")
        self.camera = None

    def render(self, grid: pv.UnstructuredGrid, values: np.ndarray, location: str, clim, cmap: str) -> np.ndarray:
        grid = grid.copy()
        if location == "point":
            grid.point_data["value"] = values
        else:
            grid.cell_data["value"] = values
        p = self.plotter
        p.clear_actors()
        p.add_mesh(grid, scalars="value", preference=location, clim=list(clim), cmap=cmap,
                   show_edges=True, edge_color="black", line_width=1, show_scalar_bar=False,
                   lighting=False)
        if self.camera is None:
            p.view_isometric()
            p.camera.azimuth = -20
            p.camera.zoom(1.3)
            self.camera = p.camera.copy()
        else:
            p.camera = self.camera.copy()
        return np.asarray(p.screenshot(return_img=True))

    def close(self) -> None:
        self.plotter.close()


#: values below this fraction of the field's magnitude are round-off (e.g. σ23 ~ 1e-13 kPa
#: on a symmetric mesh) and must not be stretched over a whole colour map
NOISE_FRACTION = 1e-6


def _limits(*arrays: np.ndarray, symmetric: bool, floor: float) -> tuple[float, float]:
    """Colour limits: ±max|v| if symmetric, else the data range extended to include 0, so a
    nearly uniform field is not stretched over the whole colour map (a 0.5 % difference
    between two runs would otherwise read as opposite ends of the scale). Never narrower
    than ``floor``."""
    values = np.concatenate([np.ravel(a) for a in arrays])
    floor = max(float(floor), 1e-300)
    if symmetric:
        m = max(float(np.max(np.abs(values))), floor)
        return -m, m
    vmin, vmax = float(values.min()), float(values.max())
    lo, hi = min(vmin, 0.0), max(vmax, 0.0)
    if hi - lo < floor:
        lo, hi = (0.0, floor) if vmin >= 0 else (-floor, 0.0) if vmax <= 0 else (-floor, floor)
    return lo, hi


def field_comparison(
    reference: xr.Dataset,
    surrogate: xr.Dataset,
    quantity: str,
    steps,
    out: str | Path,
    *,
    labels=("reference", "FEM–ML"),
    title: str = "",
    deformation_scale: float = 1.0,
    figsize=(10.0, 11.0),
    dpi: int = 120,
    window_size=(420, 620),
) -> dict[int, dict[str, np.ndarray]]:
    """Rows: load steps; columns: reference | surrogate | surrogate − reference.

    Reference and surrogate share one colour scale per row (diverging and symmetric about 0
    when the field changes sign); the difference has its own symmetric scale. Each mesh is
    drawn deformed by its own displacement; the difference on the reference's.

    Returns what it drew: {step: {'reference' | 'surrogate' | 'difference': the values at the
    nodes or per element}}; a step the surrogate run did not reach has the reference only.
    """
    import matplotlib.pyplot as plt

    from .figures import save_figure

    q = FIELD_QUANTITIES[quantity]
    elements = run_elements(reference)
    n_el = len(elements)
    steps = resolve_steps(steps, reference.sizes["step"])
    # a surrogate run that stopped early (metrics.is_partial) has no fields after its last step
    last_surrogate_step = surrogate.sizes["step"] - 1
    renderer = PanelRenderer(window_size)
    fig, axes = plt.subplots(len(steps), 3, figsize=figsize, squeeze=False)
    fig.subplots_adjust(left=0.03, right=0.93, bottom=0.01, top=0.9, wspace=0.35, hspace=0.08)
    drawn: dict[int, dict[str, np.ndarray]] = {}
    try:
        for row, step in enumerate(steps):
            if step > last_surrogate_step:
                drawn[step] = {"reference": _reference_only_row(fig, axes[row], renderer, reference, elements, quantity,
                                                                step, deformation_scale, labels, row == 0,
                                                                last_surrogate_step)}
                continue
            ref_v = field_on_mesh(reference, quantity, step, n_el)
            sur_v = field_on_mesh(surrogate, quantity, step, n_el)
            diff = sur_v - ref_v
            drawn[step] = {"reference": ref_v, "surrogate": sur_v, "difference": diff}
            floor = NOISE_FRACTION * max(q.magnitude(reference, step), q.magnitude(surrogate, step))
            signed = bool(min(ref_v.min(), sur_v.min()) < -floor and max(ref_v.max(), sur_v.max()) > floor)
            clim = _limits(ref_v, sur_v, symmetric=signed, floor=floor)
            cmap = "coolwarm" if signed else "viridis"
            dlim = _limits(diff, symmetric=True, floor=floor)
            panels = (
                (reference, ref_v, clim, cmap, labels[0]),
                (surrogate, sur_v, clim, cmap, labels[1]),
                (reference, diff, dlim, "RdBu_r", f"{labels[1]} − {labels[0]}"),
            )
            for col, (ds, values, lim, cm, name) in enumerate(panels):
                image = renderer.render(deformed_grid(ds, elements, step, deformation_scale), values, q.location, lim, cm)
                ax = axes[row, col]
                ax.imshow(image)
                if float(np.max(np.abs(values))) < floor:
                    ax.text(0.5, 0.01, "zero to round-off", transform=ax.transAxes, ha="center", va="bottom",
                            fontsize=8, color="0.3")
                ax.set_xticks([])
                ax.set_yticks([])
                for spine in ax.spines.values():
                    spine.set_visible(False)
                if row == 0:
                    ax.set_title(textwrap.fill(name, 26), fontsize=9)
                if col == 0:
                    ax.set_ylabel(f"step {step}", fontsize=10)
                if col in (1, 2):
                    mappable = plt.cm.ScalarMappable(norm=plt.Normalize(*lim), cmap=cm)
                    bar = fig.colorbar(mappable, ax=ax, fraction=0.06, pad=0.02)
                    bar.ax.tick_params(labelsize=7)
                    bar.set_label(f"{q.label} ({q.unit})" if col == 1 else f"difference ({q.unit})", fontsize=8)
    finally:
        renderer.close()
    fig.suptitle(title or f"{q.label} on the deformed mesh (displacement ×{deformation_scale:g})", fontsize=11)
    save_figure(fig, out, dpi)
    return drawn


def _reference_only_row(fig, axes, renderer, reference, elements, quantity, step, deformation_scale, labels,
                        first_row, last_surrogate_step) -> np.ndarray:
    """A row at a step the surrogate run did not reach: the reference field, and say so. Returns
    the values drawn."""
    import matplotlib.pyplot as plt

    q = FIELD_QUANTITIES[quantity]
    values = field_on_mesh(reference, quantity, step, len(elements))
    floor = NOISE_FRACTION * q.magnitude(reference, step)
    signed = bool(values.min() < -floor and values.max() > floor)
    lim = _limits(values, symmetric=signed, floor=floor)
    cmap = "coolwarm" if signed else "viridis"
    axes[0].imshow(renderer.render(deformed_grid(reference, elements, step, deformation_scale), values, q.location,
                                   lim, cmap))
    mappable = plt.cm.ScalarMappable(norm=plt.Normalize(*lim), cmap=cmap)
    fig.colorbar(mappable, ax=axes[0], fraction=0.06, pad=0.02).ax.tick_params(labelsize=7)
    for ax in axes[1:]:
        ax.text(0.5, 0.5, f"not reached:\nthe run stopped\nafter step {last_surrogate_step}", transform=ax.transAxes,
                ha="center", va="center", fontsize=9, color="0.3")
    for col, ax in enumerate(axes):
        ax.set_xticks([])
        ax.set_yticks([])
        for spine in ax.spines.values():
            spine.set_visible(False)
        if first_row:
            name = labels[0] if col == 0 else labels[1] if col == 1 else f"{labels[1]} − {labels[0]}"
            ax.set_title(textwrap.fill(name, 26), fontsize=9)
    axes[0].set_ylabel(f"step {step}", fontsize=10)
    return values


# --------------------------------------------------------------------------------------
# VTU export for ParaView


def step_grid(ds: xr.Dataset, elements: np.ndarray, step: int) -> pv.UnstructuredGrid:
    """Undeformed grid of one step: nodal displacement (warp by vector in ParaView), element
    means of stress (Pa, one array per Voigt component), strain, q, p and ε_s."""
    grid = vtk_grid(ds["node_position"].values, elements)
    n_el = len(elements)
    grid.point_data["displacement"] = ds["displacement"].sel(step=step).transpose("node", "xyz").values
    stress = ds["stress"].sel(step=step).transpose("gp", "comp").values
    strain = ds["strain"].sel(step=step).transpose("gp", "comp").values
    for k, comp in enumerate(ds["comp"].values):
        grid.cell_data[f"stress_{comp}"] = cell_average(stress[:, k], n_el)
        grid.cell_data[f"strain_{comp}"] = cell_average(strain[:, k], n_el)
    grid.cell_data["deviatoric_stress_q"] = cell_average(qty.deviatoric_stress(stress), n_el)
    grid.cell_data["mean_stress_p"] = cell_average(qty.mean_stress(stress), n_el)
    grid.cell_data["equivalent_shear_strain"] = cell_average(qty.equivalent_shear_strain(strain), n_el)
    grid.cell_data["volumetric_strain"] = cell_average(qty.volumetric_strain(strain), n_el)
    return grid


def write_vtu_series(ds: xr.Dataset, directory: str | Path, stem: str) -> Path:
    """One ``{stem}_{step:04d}.vtu`` per step and a ``{stem}.pvd`` collection (time = step).

    The folder is filled under a temporary name and renamed at the end, so a failure never
    leaves a partial series."""
    directory = Path(directory)
    tmp = directory.with_name(f".{directory.name}.tmp")
    if tmp.exists():
        for f in tmp.iterdir():
            f.unlink()
    tmp.mkdir(parents=True, exist_ok=True)
    elements = run_elements(ds)
    entries = []
    for step in ds["step"].values.tolist():
        name = f"{stem}_{step:04d}.vtu"
        step_grid(ds, elements, step).save(tmp / name, binary=True)
        entries.append(f'    <DataSet timestep="{step}" group="" part="0" file="{name}"/>')
    (tmp / f"{stem}.pvd").write_text(
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
        "  <Collection>\n" + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n"
    )
    if directory.exists():
        for f in directory.iterdir():
            f.unlink()
        directory.rmdir()
    os.replace(tmp, directory)
    return directory
