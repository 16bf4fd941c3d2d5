"""Structured hexahedral mesh of the box-shaped specimen and its faces."""

from __future__ import annotations

import numpy as np
from skfem import MeshHex

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
