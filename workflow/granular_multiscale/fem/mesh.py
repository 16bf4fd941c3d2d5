"""Structured meshes: the box of hexahedra of the triaxial specimen and its faces; the (graded)
rectangles of quadrilaterals of the plane-strain problems."""

from __future__ import annotations

import numpy as np
from skfem import MeshHex, MeshQuad

FACES = ("xmin", "xmax", "ymin", "ymax", "bottom", "top")
LATERAL_FACES = ("xmin", "xmax", "ymin", "ymax")


def box_mesh(size, elements, origin=(0.0, 0.0, 0.0)) -> MeshHex:
    """Box origin + [0, Lx]×[0, Ly]×[0, H] split into nx×ny×nz trilinear hexahedra (z = axial)."""
    size = np.asarray(size, dtype=float)
    elements = np.asarray(elements, dtype=int)
    if size.shape != (3,) or np.any(size <= 0):
        raise ValueError(f"specimen.size must be three positive lengths, got {size.tolist()}")
    if elements.shape != (3,) or np.any(elements < 1):
        raise ValueError(f"specimen.elements must be three positive integers, got {elements.tolist()}")
    axes = [x0 + np.linspace(0.0, L, n + 1) for x0, L, n in zip(np.asarray(origin, dtype=float), size, elements)]
    return MeshHex.init_tensor(*axes)


def _bounds(mesh: MeshHex) -> tuple[np.ndarray, np.ndarray]:
    return mesh.p.min(axis=1), mesh.p.max(axis=1)


def face_nodes(mesh: MeshHex, size) -> dict[str, np.ndarray]:
    """Node indices of the six faces of the mesh's bounding box, by coordinate (tolerance relative to `size`)."""
    x = mesh.p
    lo, hi = _bounds(mesh)
    tol = 1e-9 * float(np.max(size))
    out = {}
    for axis, (lo_name, hi_name) in enumerate((("xmin", "xmax"), ("ymin", "ymax"), ("bottom", "top"))):
        out[lo_name] = np.flatnonzero(np.abs(x[axis] - lo[axis]) < tol)
        out[hi_name] = np.flatnonzero(np.abs(x[axis] - hi[axis]) < tol)
    return out


def lateral_facets(mesh: MeshHex, size, faces=LATERAL_FACES) -> np.ndarray:
    """Boundary facets of the given lateral faces (where the confining pressure acts); default all four."""
    unknown = set(faces) - set(LATERAL_FACES)
    if unknown:
        raise ValueError(f"unknown lateral faces {sorted(unknown)}; known: {LATERAL_FACES}")
    tol = 1e-9 * float(np.max(size))
    lo, hi = _bounds(mesh)
    planes = {"xmin": (0, lo[0]), "xmax": (0, hi[0]), "ymin": (1, lo[1]), "ymax": (1, hi[1])}
    chosen = [planes[f] for f in faces]
    return mesh.facets_satisfying(
        lambda x: np.any([np.abs(x[axis] - value) < tol for axis, value in chosen], axis=0),
        boundaries_only=True,
    )


# -- plane strain ---------------------------------------------------------------------------
def graded_axis(start: float, end: float, n: int, first: float | None = None) -> np.ndarray:
    """n + 1 node coordinates from start to end; with `first`, element sizes grow (or shrink)
    geometrically from `first` at `start` (ratio found by bisection), else they are equal."""
    length = end - start
    if n < 1 or not length > 0:
        raise ValueError(f"an axis needs n >= 1 elements and end > start, got n={n}, [{start}, {end}]")
    if first is None or abs(first * n - length) <= 1e-12 * length:
        return start + np.linspace(0.0, length, n + 1)
    if not 0 < first < length:
        raise ValueError(f"first element size {first} must lie in (0, {length})")

    def total(ratio: float) -> float:
        return first * n if ratio == 1.0 else first * (ratio**n - 1.0) / (ratio - 1.0)

    lo, hi = (1.0, 2.0) if first * n < length else (1e-6, 1.0)
    while first * n < length and total(hi) < length:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if total(mid) < length else (lo, mid)
    sizes = first * ((lo + hi) / 2) ** np.arange(n)
    nodes = start + np.concatenate([[0.0], np.cumsum(sizes)])
    nodes[-1] = end
    return nodes


def rectangle_mesh(x_nodes, y_nodes) -> MeshQuad:
    """Tensor-product quadrilateral mesh of the rectangle spanned by the node coordinates (x, y; y vertical)."""
    x_nodes, y_nodes = np.asarray(x_nodes, dtype=float), np.asarray(y_nodes, dtype=float)
    for name, axis in (("x", x_nodes), ("y", y_nodes)):
        if axis.ndim != 1 or axis.size < 2 or np.any(np.diff(axis) <= 0):
            raise ValueError(f"{name} node coordinates must increase strictly, got {axis.tolist()}")
    return MeshQuad.init_tensor(x_nodes, y_nodes)


def nodes_where(positions: np.ndarray, axis: int, value: float, scale: float) -> np.ndarray:
    """Indices of the nodes whose coordinate `axis` equals `value` (to 1e-9 × scale)."""
    return np.flatnonzero(np.abs(positions[:, axis] - value) < 1e-9 * scale)


def boundary_facets_where(mesh, predicate) -> np.ndarray:
    """Boundary facets whose midpoint satisfies predicate(x) (x: [dim, n] midpoints)."""
    return mesh.facets_satisfying(predicate, boundaries_only=True)
