"""Plane-strain biaxial compression: a W × H specimen (H = 2W in the defaults) between smooth
rigid platens, confined laterally by p0, the top pushed down along a load path until a shear
band forms.

    problem = BiaxialProblem.from_config(config)     # config section ``biaxial``
    problem.zones()                                   # [n_gp] 1 inside the weak zone, else 0

Geometry and constraint. The specimen lies in the x–z plane, x horizontal in [0, W], z vertical
in [0, H] as in the triaxial specimen, meshed with quadrilaterals (``element``: quad8 by
default, see ``assembly.py``). Plane strain: every Gauss point gets ε_yy = γ_xy = γ_yz = 0 (y out
of plane), one 3D RVE per in-plane Gauss point, whose axial direction is z as in the triaxial
test. Forces are per metre of thickness.

Boundary conditions:

* bottom platen (z = 0): u_z = 0; smooth, so u_x is free except at the node at the origin
  (u_x = 0: no rigid-body motion);
* top platen (z = H): u_z = −axial_strain · H from the load path (smooth: u_x free);
* lateral faces (x = 0, x = W): the confining pressure p0 as a traction −p0·n;
* the material points start from the consolidated stress −p0·1, in equilibrium with the
  confinement at zero displacement (step 0 records that state).

No symmetry reduction: a band breaks the specimen's symmetry, so the full specimen is meshed.

Localisation trigger (``weak_zone``): the Gauss points inside a circle (centre [x, z], radius in m)
belong to zone 1, the others to zone 0 (:meth:`zones`); the driver gives zone 1 a weaker
material (DEM: the packing restored to a lower interparticle friction; the analytic model: a
lower friction). A weak zone that holds no Gauss point is an error naming the key.

Recorded per step, beyond every problem's variables: ``axial_strain`` (compression positive),
``top_force`` (platen reaction per metre, tension positive; ``load_force`` = −top_force) and
``lateral_strain`` (mean horizontal strain, (u_x(W) − u_x(0))/W averaged over the height,
tension positive).
"""

from __future__ import annotations

import numpy as np

from .assembly import ELEMENTS, GaussPointOperators
from .mesh import boundary_facets_where, nodes_where, rectangle_mesh
from .newton import Converged, NewtonSettings
from .problem import BoundaryValueProblem


class ProblemConfigError(ValueError):
    """A problem's settings do not fit the problem; the message names the config key."""


def plane_element(section: str, element: str) -> str:
    """The element name of a plane-strain problem, or ProblemConfigError naming ``<section>.element``."""
    if element not in ELEMENTS or ELEMENTS[element][1] != 2:
        planar = sorted(k for k, v in ELEMENTS.items() if v[1] == 2)
        raise ProblemConfigError(f"config key '{section}.element': {element!r} is not a plane-strain element "
                                 f"(plane strain takes {planar}; hex8 is the triaxial specimen's)")
    return element


def plane_pair(section: str, key: str, value, integer: bool = False) -> tuple:
    """Two positive numbers [x, z] of a plane-strain setting, or ProblemConfigError naming the key."""
    values = list(value) if isinstance(value, (list, tuple)) else [value]
    if len(values) != 2:
        raise ProblemConfigError(f"config key '{section}.{key}': plane strain takes two values [x, z], got "
                                 f"{values} (three values are a 3D specimen's: section 'specimen')")
    cast = int if integer else float
    out = tuple(cast(v) for v in values)
    if any(v <= 0 for v in out):
        raise ProblemConfigError(f"config key '{section}.{key}': values must be positive, got {values}")
    return out


def check_compression_path(section: str, load_path, upper: float) -> None:
    """A plane-strain problem's load path stays in [0, upper] (its platen or footing only pushes)."""
    values = load_path.axial_strain()
    if values.min() < 0 or values.max() > upper:
        raise ProblemConfigError(
            f"config key '{section}.load_paths.{load_path.name}.segments': the path reaches "
            f"[{values.min():.4g}, {values.max():.4g}]; this problem's load must stay in [0, {upper:g}] "
            "(a rigid platen or footing pushes, it cannot pull on a granular body)")


class BiaxialProblem(BoundaryValueProblem):
    name = "biaxial"
    config_section = "biaxial"
    load_label = "axial strain"
    load_measure = "axial strain (compression positive): top displacement / specimen height"
    loaded_boundary = "top platen"
    domain_name = "specimen"
    #: the largest axial strain a load path may reach
    MAX_AXIAL_STRAIN = 0.5
    OBSERVABLES = {
        "axial_strain": ("1", "prescribed axial strain, compression positive (top uz = -axial_strain * H)"),
        "top_force": ("N/m", "platen reaction per metre of thickness, tension positive (= integral of sigma_zz "
                             "over the top face)"),
        "lateral_strain": ("1", "mean horizontal strain (u_x(W) - u_x(0)) / W over the height, tension positive"),
    }

    def __init__(self, size=(0.05, 0.1), elements=(4, 8), element: str = "quad8", confining_pressure: float = 1.0e5,
                 newton: NewtonSettings | None = None, uniform_field: bool = False, weak_zone: dict | None = None):
        section = self.config_section
        self.size = plane_pair(section, "size", size)
        self.elements = plane_pair(section, "elements", elements, integer=True)
        self.element = plane_element(section, element)
        self.mesh_elements = self.elements
        if not confining_pressure > 0:
            raise ProblemConfigError(f"config key 'specimen.confining_pressure' must be > 0, got {confining_pressure}")
        W, H = self.size
        mesh = rectangle_mesh(np.linspace(0.0, W, self.elements[0] + 1), np.linspace(0.0, H, self.elements[1] + 1))
        ops = GaussPointOperators(mesh, self.element)
        self.ops = ops
        x = ops.mesh_node_positions  # the mesh's (x, y) are the body's (x, z)
        scale = max(W, H)
        self.faces = {
            "bottom": nodes_where(x, 1, 0.0, scale), "top": nodes_where(x, 1, H, scale),
            "left": nodes_where(x, 0, 0.0, scale), "right": nodes_where(x, 0, W, scale),
        }
        lateral = boundary_facets_where(mesh, lambda p: (np.abs(p[0]) < 1e-9 * scale) | (np.abs(p[0] - W) < 1e-9 * scale))
        f_ext = ops.pressure_load(lateral, confining_pressure)
        dofs = ops.node_dofs
        origin = self._node_at((0.0, 0.0))
        fixed = [dofs(self.faces["bottom"], 1), dofs(origin, 0)]
        self.top_dofs = dofs(self.faces["top"], 1)
        self._set_up(ops, f_ext, fixed, self.top_dofs, H, confining_pressure, newton, uniform_field)
        self.weak_zone = self._check_weak_zone(weak_zone)
        if self.uniform_field and self.weak_zone is not None:
            raise ProblemConfigError(f"config key '{section}.uniform_field': a weak zone makes the field "
                                     f"non-uniform; set {section}.weak_zone to null or uniform_field to false")

    @classmethod
    def from_config(cls, config: dict) -> "BiaxialProblem":
        section = config[cls.config_section]
        return cls(size=section["size"], elements=section["elements"], element=section["element"],
                   confining_pressure=config["specimen"]["confining_pressure"],
                   newton=NewtonSettings.from_config(config), uniform_field=bool(section["uniform_field"]),
                   weak_zone=section.get("weak_zone"))

    # -- the weak zone ----------------------------------------------------------------------
    def _check_weak_zone(self, zone: dict | None) -> dict | None:
        if zone is None:
            return None
        key = f"config key '{self.config_section}.weak_zone'"
        centre = np.asarray(zone.get("center", ()), dtype=float)
        radius = float(zone.get("radius", 0.0))
        if centre.shape != (2,) or not radius > 0:
            raise ProblemConfigError(f"{key}: needs center [x, z] (m) and a radius > 0 (m), got {zone}")
        W, H = self.size
        if not (0 <= centre[0] <= W and 0 <= centre[1] <= H):
            raise ProblemConfigError(f"{key}: center {centre.tolist()} lies outside the specimen [0, {W:g}] x "
                                     f"[0, {H:g}] m")
        inside = self._inside(centre, radius)
        if not inside.any():
            d = np.linalg.norm(self._gp_positions[:, [0, 2]] - centre, axis=1).min()
            raise ProblemConfigError(f"{key}: no Gauss point lies within {radius:g} m of {centre.tolist()} (the "
                                     f"nearest is {d:.3g} m away); enlarge the radius")
        return {"center": centre.tolist(), "radius": radius, "gauss_points": int(inside.sum())}

    def _inside(self, centre: np.ndarray, radius: float) -> np.ndarray:
        return np.linalg.norm(self._gp_positions[:, [0, 2]] - centre, axis=1) <= radius

    def zones(self) -> np.ndarray:
        """[n_material_points] material zone of each point: 1 inside the weak zone, 0 elsewhere."""
        if self.weak_zone is None:
            return super().zones()
        return self._inside(np.asarray(self.weak_zone["center"]), self.weak_zone["radius"]).astype(int)

    # -- what the biaxial test reports ---------------------------------------------------------
    def check_load_path(self, load_path) -> None:
        check_compression_path(self.config_section, load_path, self.MAX_AXIAL_STRAIN)

    def observables(self, load: float, result: Converged) -> dict[str, float]:
        u = result.u
        ux = self.ops.node_dofs
        lateral = float(np.mean(u[ux(self.faces["right"], 0)]) - np.mean(u[ux(self.faces["left"], 0)])) / self.size[0]
        return {"axial_strain": load, **self.force_observables(self.load_force(result.residual)),
                "lateral_strain": lateral}

    def force_observables(self, load_force: float) -> dict[str, float]:
        return {"top_force": -load_force}

    def load_force_meaning(self) -> dict[str, str]:
        return {"units": "N/m", "description": "platen reaction per metre of thickness, compression positive "
                                               "(= -top_force)"}

    def definition(self) -> dict:
        return {"problem": self.name, "size": self.size, "elements": self.elements, "element": self.element,
                "confining_pressure": self.confining_pressure, "uniform_field": self.uniform_field,
                "weak_zone": self.weak_zone}

    def attributes(self) -> dict:
        zone = self.weak_zone
        return {
            "specimen_size_m": list(self.size),
            "specimen_elements": list(self.elements),
            "mesh_elements": list(self.mesh_elements),
            "platen": "smooth",
            "symmetry": "none",
            "weak_zone_center_m": zone["center"] if zone else [],
            "weak_zone_radius_m": zone["radius"] if zone else 0.0,
            "weak_zone_gauss_points": zone["gauss_points"] if zone else 0,
            "force_units": "N per metre of thickness (plane strain)",
        }
