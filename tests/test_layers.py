"""The package's layers: every import points down.

    drivers                      compose a problem with a material-point set, write runs
      fem          adaptive             the solver; the set made of the surrogate and DEM sets
            materials  dem  surrogate   the material-point sets
        tensors, paths, history, data, ...   shared foundations

The solver must not know what sits at its Gauss points, and no material-point set may
import the solver or a driver (DESIGN.md §1 and §7)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "workflow" / "granular_multiscale"
MATERIAL_SETS = ("materials", "dem", "surrogate")
# subpackage -> subpackages it must not import
FORBIDDEN = {
    "fem": ("drivers", "dem", "surrogate", "adaptive", "analysis"),
    **{m: ("drivers", "fem", "adaptive") for m in MATERIAL_SETS},
    # the adaptive set is made of the surrogate and DEM sets: above them, still below the solver
    "adaptive": ("drivers", "fem", "analysis"),
}


def imported_subpackages(path: Path) -> set[str]:
    """Top-level subpackages of granular_multiscale that a module imports (relative or absolute)."""
    tree = ast.parse(path.read_text())
    depth = len(path.relative_to(PACKAGE).parts) - 1  # 1 for a module of a subpackage
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                parts = path.relative_to(PACKAGE).parts[: depth + 1 - node.level]
                target = [*parts, *(node.module.split(".") if node.module else [])]
                names = [target] if target else [[a.name] for a in node.names]
            elif node.module and node.module.startswith("granular_multiscale."):
                names = [node.module.split(".")[1:]]
            else:
                continue
            found.update(n[0] for n in names if n)
        elif isinstance(node, ast.Import):
            found.update(a.name.split(".")[1] for a in node.names if a.name.startswith("granular_multiscale."))
    return found


def test_import_scanner_sees_relative_and_absolute_imports(tmp_path):
    assert imported_subpackages(PACKAGE / "drivers" / "fem_dem.py") >= {"fem", "dem", "data", "paths"}
    assert "materials" in imported_subpackages(PACKAGE / "drivers" / "problems.py")


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_imports_point_down(layer):
    offending = {}
    for module in sorted((PACKAGE / layer).rglob("*.py")):
        bad = imported_subpackages(module) & set(FORBIDDEN[layer])
        if bad:
            offending[str(module.relative_to(PACKAGE))] = sorted(bad)
    assert not offending, f"imports that point up (or sideways into the solver): {offending}"
