"""Structured hexahedral mesh of the box-shaped specimen and its faces."""

from __future__ import annotations

import numpy as np
from skfem import MeshHex

FACES = ("xmin", "xmax", "ymin", "ymax", "bottom", "top")


def box_mesh(size, elements) -> MeshHex:
    """Box [0, Lx]×[0, Ly]×[0, H] split into nx×ny×nz trilinear hexahedra (z = axial)."""
    size = np.asarray(size, dtype=float)
    elements = np.asarray(elements, dtype=int)
    if size.shape != (3,) or np.any(size <= 0):
        raise ValueError(f"specimen.size must be three positive lengths, got {size.tolist()}")
    if elements.shape != (3,) or np.any(elements < 1):
        raise ValueError(f"specimen.elements must be three positive integers, got {elements.tolist()}")
    axes = [np.linspace(0.0, L, n + 1) for L, n in zip(size, elements)]
    return MeshHex.init_tensor(*axes)


def face_nodes(mesh: MeshHex, size) -> dict[str, np.ndarray]:
    """Node indices of the six faces, by coordinate (tolerance relative to the specimen)."""
    x = mesh.p
    tol = 1e-9 * float(np.max(size))
    out = {}
    for axis, (lo, hi) in enumerate((("xmin", "xmax"), ("ymin", "ymax"), ("bottom", "top"))):
        out[lo] = np.flatnonzero(np.abs(x[axis]) < tol)
        out[hi] = np.flatnonzero(np.abs(x[axis] - size[axis]) < tol)
    return out


def lateral_facets(mesh: MeshHex, size) -> np.ndarray:
    """Boundary facets of the four lateral faces (where the confining pressure acts)."""
    tol = 1e-9 * float(np.max(size))
    Lx, Ly = size[0], size[1]
    return mesh.facets_satisfying(
        lambda x: (np.abs(x[0]) < tol) | (np.abs(x[0] - Lx) < tol) | (np.abs(x[1]) < tol) | (np.abs(x[1] - Ly) < tol),
        boundaries_only=True,
    )
