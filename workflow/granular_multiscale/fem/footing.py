"""Strip footing in plane strain: a rigid, rough footing of width B pushed into a granular
layer under a surcharge, by default on half of the domain (the symmetry plane through the
footing's centre).

    problem = FootingProblem.from_config(config)     # config section ``footing``

Geometry. The x–z plane (y out of plane, plane strain as in ``biaxial.py``): x horizontal, z
vertical with the free surface at z = 0 and the layer down to z = −depth. ``symmetry: half`` meshes x in [0, half_width] (x = 0 the symmetry plane through
the footing's centre, the footing on 0 ≤ x ≤ B/2); ``symmetry: none`` meshes the whole domain
x in [−half_width, half_width]. The mesh is graded: ``footing_elements`` equal elements under
the half footing, then sizes growing geometrically to the far side and downwards
(``elements`` = [along x for the half, down]).

Boundary conditions:

* footing nodes (surface, |x| ≤ B/2): u_z = −(s/B) · B from the load path (s/B: the settlement
  over the footing width), u_x = 0 (rough);
* free surface outside the footing: the surcharge q0 = p0 (``specimen.confining_pressure``),
  so the initial state −p0·1 of the consolidated RVEs is in equilibrium everywhere at zero
  displacement;
* bottom (z = −depth): fixed; far side(s): rollers (u_x = 0); symmetry plane: u_x = 0.

Recorded per step, beyond every problem's variables: ``settlement_ratio`` (s/B) and
``footing_pressure`` (mean contact pressure of the whole footing, compression positive: the
footing reaction per metre, × 2 with the half domain, over B; it starts at q0).
"""

from __future__ import annotations

import numpy as np

from .assembly import GaussPointOperators
from .biaxial import ProblemConfigError, check_compression_path, plane_element, plane_pair
from .mesh import boundary_facets_where, graded_axis, nodes_where, rectangle_mesh
from .newton import Converged, NewtonSettings
from .problem import BoundaryValueProblem

SYMMETRIES = ("half", "none")


class FootingProblem(BoundaryValueProblem):
    name = "footing"
    config_section = "footing"
    load_label = "settlement/B"
    load_measure = "settlement over footing width s/B (downwards positive)"
    loaded_boundary = "footing"
    domain_name = "modelled domain"
    #: the largest settlement a load path may reach, in footing widths
    MAX_SETTLEMENT = 1.0
    OBSERVABLES = {
        "settlement_ratio": ("1", "footing settlement over its width s/B (downwards positive)"),
        "footing_pressure": ("Pa", "mean contact pressure of the footing, compression positive: the reaction of "
                                   "the whole footing per metre over its width B"),
    }

    def __init__(self, width: float = 0.1, domain=(0.5, 0.3), elements=(8, 6), footing_elements: int = 2,
                 element: str = "quad8", confining_pressure: float = 1.0e5, newton: NewtonSettings | None = None,
                 symmetry: str = "half"):
        section = self.config_section
        if symmetry not in SYMMETRIES:
            raise ProblemConfigError(f"config key '{section}.symmetry': {symmetry!r} does not fit the footing; it "
                                     f"takes {list(SYMMETRIES)} (half: the symmetry plane through its centre)")
        self.symmetry = symmetry
        self.width = float(width)
        self.domain = plane_pair(section, "domain", domain)
        self.elements = plane_pair(section, "elements", elements, integer=True)
        self.element = plane_element(section, element)
        self.footing_elements = int(footing_elements)
        half, depth = self.domain
        if not self.width > 0:
            raise ProblemConfigError(f"config key '{section}.width': must be > 0 m, got {width}")
        if self.width / 2 >= half:
            raise ProblemConfigError(
                f"config key '{section}.width': a footing {self.width:g} m wide does not fit a domain that reaches "
                f"{half:g} m from its centre ({section}.domain[0]); the footing must be narrower than the domain")
        if not 1 <= self.footing_elements < self.elements[0]:
            raise ProblemConfigError(f"config key '{section}.footing_elements': must be in [1, {section}.elements[0] "
                                     f"- 1 = {self.elements[0] - 1}], got {footing_elements}")
        if not confining_pressure > 0:
            raise ProblemConfigError(f"config key 'specimen.confining_pressure' must be > 0, got {confining_pressure}")
        b = self.width / 2
        h = b / self.footing_elements
        x_half = np.concatenate([np.linspace(0.0, b, self.footing_elements + 1)[:-1],
                                 graded_axis(b, half, self.elements[0] - self.footing_elements, h)])
        y_nodes = -graded_axis(0.0, depth, self.elements[1], h)[::-1]
        x_nodes = x_half if symmetry == "half" else np.concatenate([-x_half[:0:-1], x_half])
        mesh = rectangle_mesh(x_nodes, y_nodes)
        ops = GaussPointOperators(mesh, self.element)
        self.ops = ops
        x = ops.mesh_node_positions  # the mesh's (x, y) are the body's (x, z)
        scale = max(half, depth)
        tol = 1e-9 * scale
        surface = nodes_where(x, 1, 0.0, scale)
        self.footing_nodes = surface[np.abs(x[surface, 0]) <= b + tol]
        far = [nodes_where(x, 0, half, scale)] + ([nodes_where(x, 0, -half, scale)] if symmetry == "none" else [])
        bottom = nodes_where(x, 1, -depth, scale)
        surcharge = boundary_facets_where(mesh, lambda p: (np.abs(p[1]) < tol) & (np.abs(p[0]) > b + tol))
        f_ext = ops.pressure_load(surcharge, confining_pressure)
        dofs = ops.node_dofs
        fixed = [dofs(bottom, 0), dofs(bottom, 1), *(dofs(f, 0) for f in far), dofs(self.footing_nodes, 0)]
        if symmetry == "half":
            fixed.append(dofs(nodes_where(x, 0, 0.0, scale), 0))
        self._set_up(ops, f_ext, fixed, dofs(self.footing_nodes, 1), self.width, confining_pressure, newton,
                     force_factor=2.0 if symmetry == "half" else 1.0)
        self.mesh_elements = (len(x_nodes) - 1, self.elements[1])

    @classmethod
    def from_config(cls, config: dict) -> "FootingProblem":
        section = config[cls.config_section]
        return cls(width=section["width"], domain=section["domain"], elements=section["elements"],
                   footing_elements=section["footing_elements"], element=section["element"],
                   confining_pressure=config["specimen"]["confining_pressure"],
                   newton=NewtonSettings.from_config(config), symmetry=section["symmetry"])

    # -- what the footing reports ------------------------------------------------------------
    def check_load_path(self, load_path) -> None:
        check_compression_path(self.config_section, load_path, self.MAX_SETTLEMENT)

    def observables(self, load: float, result: Converged) -> dict[str, float]:
        return {"settlement_ratio": load, **self.force_observables(self.load_force(result.residual))}

    def force_observables(self, load_force: float) -> dict[str, float]:
        return {"footing_pressure": load_force / self.width}

    def load_force_meaning(self) -> dict[str, str]:
        half = " (x 2: the half domain models half of it)" if self.symmetry == "half" else ""
        return {"units": "N/m", "description": "reaction of the whole footing per metre of thickness, compression "
                                               f"positive{half}"}

    def definition(self) -> dict:
        return {"problem": self.name, "width": self.width, "domain": self.domain, "elements": self.elements,
                "footing_elements": self.footing_elements, "element": self.element,
                "confining_pressure": self.confining_pressure, "symmetry": self.symmetry}

    def attributes(self) -> dict:
        return {
            "footing_width_m": self.width,
            "domain_m": list(self.domain),
            "specimen_elements": list(self.elements),
            "mesh_elements": list(self.mesh_elements),
            "footing_elements": self.footing_elements,
            "symmetry": self.symmetry,
            "surcharge_Pa": self.confining_pressure,
            "force_units": "N per metre of thickness (plane strain)",
        }
