"""Conventional triaxial test on a box-shaped specimen of trilinear hexahedra.

    problem = TriaxialProblem.from_config(config)
    problem.n_gauss_points, problem.gp_positions          # [n_gp, 3]; gp = element * 8 + q
    ds = problem.run(material, load_path, checkpoint=None, logger=None, progress=True)
    granular_multiscale.data.write_run(ds, path, config)

One problem of the problem layer (``problem.py``: step loop, cutbacks, checkpoint, recorder);
this module adds the mesh, the boundary conditions and the observables.

Boundary conditions (z is the axial direction, specimen [0, Lx]×[0, Ly]×[0, H]):

* bottom face: uz = 0; rough platen: also ux = uy = 0; smooth platen: only the node at
  the origin (ux = uy = 0) and the node at (Lx, 0, 0) (uy = 0) are pinned against rigid
  motion, so a homogeneous material deforms homogeneously;
* top face: uz = −axial_strain · H following the load path (axial strain compression
  positive); rough platen: also ux = uy = 0;
* four lateral faces: the constant confining pressure p0 as a traction −p0·n;
* the material points start from the consolidated stress −p0·1, which is in equilibrium
  with the confinement at zero displacement (step 0 solves and records this state).

Quarter symmetry (``specimen.symmetry: quarter``): only the quarter x ≥ Lx/2, y ≥ Ly/2 is
meshed, in the full specimen's coordinates (so Gauss-point and node positions compare
directly with a full run), with ceil(nx/2)×ceil(ny/2)×nz elements — exactly the full mesh's
elements there when nx and ny are even, 4× fewer Gauss points. The cut planes carry the
symmetry conditions u_x = 0 on x = Lx/2 and u_y = 0 on y = Ly/2; the confinement acts on
the two outer lateral faces; with smooth platens these conditions already remove the
rigid-body motions (no pins). ``top_force`` is reported for the FULL specimen (4 × the
quarter's reaction), and ``volumetric_strain`` is the quarter's, which equals the full
specimen's for a symmetric field. Valid when the specimen, its material and its loading
are symmetric about both planes (docs/method.md, "Quarter symmetry").

Uniform field (``specimen.uniform_field: true``, smooth platens only): the run takes a
material set of ONE point (:attr:`TriaxialProblem.n_material_points`) and broadcasts its
answer (``materials.wrappers.UniformField``); a trial field that is not homogeneous stops the
run with an error naming the Gauss points. A set of all points is accepted too (with a
warning that it does the work of every point).

Tangent repair (``newton.tangent_repair``): the run wraps whatever material set it gets in
``materials.wrappers.TangentRepair``; the run file records the repaired tangents and per step
``tangent_non_spd_points`` / ``tangent_repaired_points``.

Recorded per step (data contract, see ``granular_multiscale.data``): what every problem
records, and ``axial_strain`` (the load path's value, compression positive) and ``top_force``
(tension positive, = ∫σzz over the top face = the platen reaction; ``load_force`` is −top_force).
"""

from __future__ import annotations

import numpy as np

from .assembly import GaussPointOperators
from .mesh import box_mesh, face_nodes, lateral_facets
from .newton import Converged, NewtonSettings
from .problem import BoundaryValueProblem

SYMMETRIES = ("none", "quarter")


class TriaxialProblem(BoundaryValueProblem):
    name = "triaxial"
    config_section = "specimen"
    load_label = "axial strain"
    load_measure = "axial strain (compression positive): top displacement / specimen height"
    loaded_boundary = "top platen"
    domain_name = "specimen"
    OBSERVABLES = {
        "axial_strain": ("1", "prescribed axial strain, compression positive (top uz = -axial_strain * H)"),
        "top_force": ("N", "axial platen reaction of the full specimen, tension positive (= integral of sigma_zz "
                           "over the top face)"),
    }

    def __init__(
        self,
        size=(0.5, 0.5, 1.0),
        elements=(2, 2, 4),
        confining_pressure: float = 1.0e5,
        platen: str = "rough",
        newton: NewtonSettings | None = None,
        symmetry: str = "none",
        uniform_field: bool = False,
    ):
        if platen not in ("rough", "smooth"):
            raise ValueError(f"specimen.platen must be 'rough' or 'smooth', got {platen!r}")
        if not confining_pressure > 0:
            raise ValueError(f"specimen.confining_pressure must be > 0, got {confining_pressure}")
        if symmetry not in SYMMETRIES:
            raise ValueError(f"specimen.symmetry must be one of {SYMMETRIES}, got {symmetry!r}")
        if uniform_field and platen != "smooth":
            raise ValueError("config key 'specimen.uniform_field': a uniform field needs specimen.platen 'smooth' "
                             "(rough platens restrain the ends, so the field is never homogeneous)")
        self.size = tuple(float(v) for v in size)
        self.elements = tuple(int(v) for v in elements)
        self.platen = platen
        self.symmetry = symmetry

        if symmetry == "quarter":
            # the quarter x >= Lx/2, y >= Ly/2, in the full specimen's coordinates
            model_size = (self.size[0] / 2, self.size[1] / 2, self.size[2])
            origin = (self.size[0] / 2, self.size[1] / 2, 0.0)
            self.mesh_elements = (-(-self.elements[0] // 2), -(-self.elements[1] // 2), self.elements[2])
            force_factor = 4.0
        else:
            model_size, origin = self.size, (0.0, 0.0, 0.0)
            self.mesh_elements = self.elements
            force_factor = 1.0
        mesh = box_mesh(model_size, self.mesh_elements, origin)
        ops = GaussPointOperators(mesh)
        self.faces = face_nodes(mesh, self.size)
        self.height = self.size[2]
        self.top_area = self.size[0] * self.size[1]
        self.volume = self.top_area * self.height
        loaded = ("xmax", "ymax") if symmetry == "quarter" else ("xmin", "xmax", "ymin", "ymax")
        f_ext = ops.pressure_load(lateral_facets(mesh, self.size, loaded), confining_pressure)

        dofs = ops.node_dofs
        bottom, top = self.faces["bottom"], self.faces["top"]
        fixed = [dofs(bottom, 2)]
        if platen == "rough":
            fixed += [dofs(bottom, 0), dofs(bottom, 1), dofs(top, 0), dofs(top, 1)]
        self.ops = ops
        if symmetry == "quarter":
            fixed += [dofs(self.faces["xmin"], 0), dofs(self.faces["ymin"], 1)]  # the two cut planes
        elif platen == "smooth":
            origin = self._node_at((0.0, 0.0, 0.0))
            x_corner = self._node_at((self.size[0], 0.0, 0.0))
            fixed += [dofs(origin, 0), dofs(origin, 1), dofs(x_corner, 1)]
        self.top_dofs = dofs(top, 2)  # axial displacement prescribed by the load path
        self._set_up(ops, f_ext, fixed, self.top_dofs, self.height, confining_pressure, newton, uniform_field,
                     force_factor)

    @classmethod
    def from_config(cls, config: dict) -> "TriaxialProblem":
        spec = config["specimen"]
        return cls(
            size=spec["size"],
            elements=spec["elements"],
            confining_pressure=spec["confining_pressure"],
            platen=spec["platen"],
            newton=NewtonSettings.from_config(config),
            symmetry=spec.get("symmetry", "none"),
            uniform_field=bool(spec.get("uniform_field", False)),
        )

    # -- what the triaxial test reports ------------------------------------------------------
    def observables(self, load: float, result: Converged) -> dict[str, float]:
        return {"axial_strain": load, **self.force_observables(self.load_force(result.residual))}

    def force_observables(self, load_force: float) -> dict[str, float]:
        """top_force: the platen reaction of the full specimen in N, tension positive (Σ over the top
        nodes of (f_int − f_ext)_z, × 4 with quarter symmetry): −load_force."""
        return {"top_force": -load_force}

    def definition(self) -> dict:
        return {
            "size": self.size,
            "elements": self.elements,
            "confining_pressure": self.confining_pressure,
            "platen": self.platen,
            "symmetry": self.symmetry,
            "uniform_field": self.uniform_field,
        }

    def attributes(self) -> dict:
        return {
            "specimen_size_m": list(self.size),
            "specimen_elements": list(self.elements),
            "platen": self.platen,
            "symmetry": self.symmetry,
            "mesh_elements": list(self.mesh_elements),
        }

    def observable_meanings(self) -> dict[str, tuple[str, str]]:
        meanings = dict(self.OBSERVABLES)
        if self.symmetry == "quarter":
            units, description = meanings["top_force"]
            meanings["top_force"] = (units, description + "; quarter symmetry: 4 x the modelled quarter's reaction")
        return meanings

    def load_force_meaning(self) -> dict[str, str]:
        quarter = "; quarter symmetry: 4 x the modelled quarter's reaction" if self.symmetry == "quarter" else ""
        return {"units": "N", "description": "axial platen reaction of the full specimen, compression positive "
                                             f"(= -top_force){quarter}"}
