"""Gauss-point operators of a small-strain discretisation: trilinear hexahedra in 3D, or
quadrilaterals in plane strain.

The basis (shape function gradients, Jacobians, quadrature weights, dof numbering) comes
from scikit-fem (:data:`ELEMENTS`):

* ``hex8``: ``ElementVector(ElementHex1())`` with 2×2×2 Gauss points (the triaxial specimen);
* ``quad8``: ``ElementVector(ElementQuadS2())``, 8-node serendipity quadrilaterals with 2×2
  Gauss points (reduced integration: no volumetric locking under the nearly isochoric flow of
  a shear band; the element of YADE's FEMxDEM examples);
* ``quad4``: ``ElementVector(ElementQuad1())``, bilinear quadrilaterals with full 2×2 Gauss
  integration (locks under isochoric flow; kept to measure that, docs/problems.md).

Plane strain: the 2D mesh's coordinates (x, y) are the body's x (horizontal) and z (vertical,
as in the triaxial specimen), and every Gauss point receives the full 6-component strain with
ε_yy = γ_xy = γ_yz = 0 (y out of plane), so the material-point sets are the same as in 3D (one
3D RVE per in-plane Gauss point) and see their axial direction where the triaxial specimen
puts it; positions and displacements are written as (x, 0, z); forces are per metre of
thickness.
Residual and stiffness are then assembled here with numpy batched products and a
precomputed scatter into a fixed CSR pattern, not with ``BilinearForm``: the tangent is a
different 6×6 matrix at every Gauss point and changes every Newton iteration; a
``BilinearForm`` with that per-point coefficient evaluates the form's 36 products for all
24×24 basis pairs in Python-level loops and rebuilds the COO triplets on every call
(bench/bench_fem.py at the paper mesh: about 260 ms against 1.3 ms here, same matrix to
1e-16; tests/test_fem_core.py checks the equality too). The operators below are computed
once per mesh:

    B[e, q, :, i]  engineering-strain operator: ε_eng(e, q) = B[e, q] @ u[dofs[e]]
    dV[e, q]       quadrature weight × Jacobian determinant

so that   f_int = Σ_eq dV Bᵀ σ    and    K = Σ_eq dV Bᵀ D B.

Gauss point index = element * points_per_element + quadrature index (the order of ``basis.dx``).
Nodes are the mesh's vertices, then (quadratic elements) the mid-side nodes of its facets;
``node_positions`` and ``nodal`` follow that order.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from skfem import Basis, ElementHex1, ElementQuad1, ElementQuadS2, ElementVector, FacetBasis, LinearForm
from skfem.helpers import dot

from ..tensors import ENGINEERING_FACTOR

GAUSS_ORDER = 3  # scikit-fem intorder giving the 2-point Gauss rule per direction
POINTS_PER_ELEMENT = 8  # of the hexahedra of the triaxial specimen

#: element name -> (scikit-fem scalar element, spatial dimension, Gauss points per element)
ELEMENTS = {
    "hex8": (ElementHex1, 3, 8),
    "quad8": (ElementQuadS2, 2, 4),
    "quad4": (ElementQuad1, 2, 4),
}


def vector_basis(mesh, element: str = "hex8") -> Basis:
    if element not in ELEMENTS:
        raise ValueError(f"unknown element {element!r}; known: {sorted(ELEMENTS)}")
    scalar, dim, points = ELEMENTS[element]
    if mesh.dim() != dim:
        raise ValueError(f"element {element!r} needs a {dim}D mesh, got a {mesh.dim()}D one")
    basis = Basis(mesh, ElementVector(scalar()), intorder=GAUSS_ORDER)
    if basis.X.shape[1] != points:
        raise RuntimeError(f"expected {points} Gauss points per element, scikit-fem gave {basis.X.shape[1]}")
    return basis


def strain_operator(basis: Basis) -> np.ndarray:
    """B[e, q, 6, n_local] mapping element dofs to the engineering strain (Voigt 11,22,33,23,13,12).

    A 2D basis is the x–z plane of the body (plane strain, y out of plane): its rows of ε22, γ23
    and γ12 are zero."""
    n_local = basis.Nbfun
    n_el, n_q = basis.dx.shape
    dim = basis.mesh.dim()
    if dim == 2:  # the mesh's (x, y) are the body's (x, z): ε_xx, ε_zz and γ_xz, the rest zero
        B = np.zeros((n_el, n_q, 6, n_local))
        for i in range(n_local):
            G = basis.basis[i][0].grad
            B[:, :, 0, i] = G[0, 0]
            B[:, :, 2, i] = G[1, 1]
            B[:, :, 4, i] = G[0, 1] + G[1, 0]
        return B
    B = np.empty((n_el, n_q, 6, n_local))
    for i in range(n_local):
        G = basis.basis[i][0].grad  # [component, direction, element, point] = ∂φ_i,c/∂x_j
        B[:, :, 0, i] = G[0, 0]
        B[:, :, 1, i] = G[1, 1]
        B[:, :, 2, i] = G[2, 2]
        B[:, :, 3, i] = G[1, 2] + G[2, 1]
        B[:, :, 4, i] = G[0, 2] + G[2, 0]
        B[:, :, 5, i] = G[0, 1] + G[1, 0]
    return B


class GaussPointOperators:
    """Strain, internal force and stiffness of a vector basis at its Gauss points."""

    def __init__(self, mesh, element: str = "hex8"):
        self.mesh = mesh
        self.element = element
        self.basis = vector_basis(mesh, element)
        self.dim = mesh.dim()
        self.n_dofs = self.basis.N
        self.element_dofs = np.ascontiguousarray(self.basis.element_dofs.T)  # [n_el, 24]
        self.n_elements, self.n_local = self.element_dofs.shape
        self.B = strain_operator(self.basis)  # [n_el, n_q, 6, n_local]
        self.dV = np.asarray(self.basis.dx)  # [n_el, n_q]
        self.points_per_element = self.dV.shape[1]
        self.n_gauss_points = self.dV.size
        # nodes: the vertices, then the mid-side node of every facet (quadratic elements)
        node_dofs = [self.basis.nodal_dofs.T]
        if self.basis.facet_dofs.size:
            node_dofs.append(self.basis.facet_dofs.T)
        self.node_dof_index = np.ascontiguousarray(np.concatenate(node_dofs))  # [n_nodes, dim]
        positions = [mesh.p.T]
        if self.basis.facet_dofs.size:
            positions.append(mesh.p[:, mesh.facets].mean(axis=1).T)
        self._node_positions = np.concatenate(positions)
        self._BT_dV = np.ascontiguousarray(
            (self.B * self.dV[:, :, None, None]).reshape(self.n_elements, -1, self.n_local).transpose(0, 2, 1)
        )  # [n_el, 24, 8*6]
        self._build_pattern()

    # -- fixed sparsity pattern -------------------------------------------------------
    def _build_pattern(self) -> None:
        rows = np.repeat(self.element_dofs, self.n_local, axis=1).ravel()
        cols = np.tile(self.element_dofs, (1, self.n_local)).ravel()
        keys = rows.astype(np.int64) * self.n_dofs + cols
        unique, self._scatter = np.unique(keys, return_inverse=True)
        self.nnz = unique.size
        self._indices = (unique % self.n_dofs).astype(np.int32)
        self._indptr = np.searchsorted(unique // self.n_dofs, np.arange(self.n_dofs + 1)).astype(np.int32)
        self._row_of_entry = (unique // self.n_dofs).astype(np.int64)
        self._col_of_entry = self._indices.astype(np.int64)

    def csr(self, data: np.ndarray) -> sp.csr_matrix:
        return sp.csr_matrix((data, self._indices, self._indptr), shape=(self.n_dofs, self.n_dofs))

    def entries_touching(self, dofs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Masks over the CSR data: entries in a row or column of `dofs`, and their diagonal entries."""
        is_dof = np.zeros(self.n_dofs, dtype=bool)
        is_dof[dofs] = True
        touching = is_dof[self._row_of_entry] | is_dof[self._col_of_entry]
        diagonal = is_dof[self._row_of_entry] & (self._row_of_entry == self._col_of_entry)
        return touching, diagonal

    # -- operators --------------------------------------------------------------------
    def strain(self, u: np.ndarray) -> np.ndarray:
        """Nodal displacements [n_dofs] -> tensorial strain [n_gp, 6]."""
        ue = u[self.element_dofs]  # [n_el, 24]
        eng = np.einsum("eqai,ei->eqa", self.B, ue, optimize=True)
        return eng.reshape(-1, 6) / ENGINEERING_FACTOR

    def internal_force(self, stress: np.ndarray) -> np.ndarray:
        """Stress [n_gp, 6] (Pa) -> consistent nodal forces f_int = Σ dV Bᵀ σ [n_dofs]."""
        s = stress.reshape(self.n_elements, -1, 1)  # [n_el, 8*6, 1]
        fe = np.matmul(self._BT_dV, s)[:, :, 0]  # [n_el, 24]
        return np.bincount(self.element_dofs.ravel(), weights=fe.ravel(), minlength=self.n_dofs)

    def stiffness_data(self, tangent: np.ndarray) -> np.ndarray:
        """Tangent [n_gp, 6, 6] -> CSR data of K = Σ dV Bᵀ D B on the fixed pattern."""
        B = self.B.reshape(-1, 6, self.n_local)  # [n_gp, 6, 24]
        DB = np.matmul(tangent, B).reshape(self.n_elements, -1, self.n_local)  # [n_el, 48, 24]
        Ke = np.matmul(self._BT_dV, DB)  # [n_el, 24, 24]
        return np.bincount(self._scatter, weights=Ke.ravel(), minlength=self.nnz)

    def stiffness(self, tangent: np.ndarray) -> sp.csr_matrix:
        return self.csr(self.stiffness_data(tangent))

    def gauss_point_positions(self) -> np.ndarray:
        """[n_gp, 3] coordinates of the Gauss points (gp = element * points_per_element + q; (x, 0, z) in 2D)."""
        x = np.asarray(self.basis.mapping.F(self.basis.X)).reshape(self.dim, -1).T  # [n_gp, dim]
        return _as_3d(x)

    @property
    def node_positions(self) -> np.ndarray:
        """[n_nodes, 3] coordinates of the nodes (vertices, then mid-side nodes; (x, 0, z) in 2D)."""
        return _as_3d(self._node_positions)

    @property
    def mesh_node_positions(self) -> np.ndarray:
        """[n_nodes, dim] node coordinates in the mesh's own axes."""
        return self._node_positions.copy()

    @property
    def n_nodes(self) -> int:
        return self.node_dof_index.shape[0]

    def element_vertices(self) -> np.ndarray:
        """[n_elements, vertices] vertex node indices of each element, scikit-fem's local order."""
        return self.mesh.t.T.copy()

    def volume_average(self, field: np.ndarray) -> np.ndarray:
        """Volume average of a Gauss-point field [n_gp, ...]."""
        w = self.dV.ravel()
        return np.tensordot(w, field, axes=(0, 0)) / w.sum()

    def nodal(self, u: np.ndarray) -> np.ndarray:
        """Dof vector -> [n_nodes, 3] ((u_x, 0, u_z) in 2D)."""
        return _as_3d(u[self.node_dof_index])

    def node_dofs(self, nodes: np.ndarray, component: int) -> np.ndarray:
        return self.node_dof_index[nodes, component]

    def pressure_load(self, facets: np.ndarray, pressure: float) -> np.ndarray:
        """Nodal forces of a uniform pressure (compression positive) on boundary facets: ∫ −p n·v ds."""
        fbasis = FacetBasis(self.mesh, self.basis.elem, facets=facets, intorder=GAUSS_ORDER)

        @LinearForm
        def traction(v, w):
            return -pressure * dot(w.n, v)

        return traction.assemble(fbasis)


def _as_3d(x: np.ndarray) -> np.ndarray:
    """[n, dim] -> [n, 3]: a 2D mesh's (x, y) are the body's (x, z), y = 0 (the data contract's xyz)."""
    x = np.asarray(x, dtype=float)
    if x.shape[1] == 3:
        return x.copy()
    return np.column_stack([x[:, 0], np.zeros(x.shape[0]), x[:, 1]])
