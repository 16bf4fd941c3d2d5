"""The package's layers: every import points down, and every module has a layer.

    plan, studies                the workflow's plan; one-off studies of the RVE procedure
    drivers                      compose a problem with a material-point set, write runs
      fem          adaptive             the solver; the set made of the surrogate and DEM sets
            dem  surrogate              the YADE and neural material-point sets
              materials                 the interface and the analytic sets
    analysis                     metrics, figures, tables: reads files, knows no model
    shared modules               tensors, paths, history, data, config, ... (import nothing above)

The solver must not know what sits at its Gauss points, no material-point set may import the
solver, a driver or the analysis, and no set imports a sibling set."""

from __future__ import annotations

import ast
from graphlib import CycleError, TopologicalSorter
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "workflow" / "granular_multiscale"
SHARED = ("atomic", "checkpoint", "config", "data", "history", "integrity", "novelty", "output_lock", "paths",
          "runlog", "tensors", "vtk_order")
# layer -> the layers (besides the shared modules) its modules may import
ALLOWED = {
    "materials": (),
    "fem": ("materials",),
    "dem": ("materials",),
    "surrogate": ("materials",),
    "adaptive": ("materials", "dem", "surrogate"),
    "analysis": (),
    "drivers": ("materials", "fem", "dem", "surrogate", "adaptive"),
    "studies": ("materials", "fem", "dem", "drivers"),
    # the workflow's plan: paths, run sets and labels (threshold_label of the light adaptive package)
    "plan": ("adaptive",),
    **{name: () for name in SHARED},
}


def layer_of(path: Path) -> str:
    rel = path.relative_to(PACKAGE)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def imported_subpackages(path: Path) -> set[str]:
    """Top-level modules and subpackages of granular_multiscale that a module imports (relative or
    absolute, at import time or inside a function)."""
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
            elif node.module == "granular_multiscale":
                names = [[a.name] for a in node.names]
            else:
                continue
            found.update(n[0] for n in names if n)
        elif isinstance(node, ast.Import):
            found.update(a.name.split(".")[1] for a in node.names if a.name.startswith("granular_multiscale."))
    return found


def modules() -> list[Path]:
    return [m for m in sorted(PACKAGE.rglob("*.py")) if m != PACKAGE / "__init__.py"]


def test_import_scanner_sees_relative_and_absolute_imports():
    assert imported_subpackages(PACKAGE / "drivers" / "fem_dem.py") >= {"dem", "data", "checkpoint"}
    assert "materials" in imported_subpackages(PACKAGE / "drivers" / "problems.py")
    assert "vtk_order" in imported_subpackages(PACKAGE / "dem" / "yade_env.py")  # from .. import vtk_order


def test_every_module_has_a_layer():
    unknown = sorted(str(m.relative_to(PACKAGE)) for m in modules() if layer_of(m) not in ALLOWED)
    assert not unknown, f"modules outside every layer (add them to ALLOWED): {unknown}"


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_imports_point_down(layer):
    allowed = {layer, *SHARED, *ALLOWED[layer]}
    offending = {}
    for module in modules():
        if layer_of(module) == layer:
            bad = imported_subpackages(module) - allowed
            if bad:
                offending[str(module.relative_to(PACKAGE))] = sorted(bad)
    assert not offending, f"imports that point up or sideways: {offending}"


def test_the_shared_modules_import_each_other_without_a_cycle():
    graph = {name: imported_subpackages(PACKAGE / f"{name}.py") - {name} for name in SHARED}
    try:
        order = list(TopologicalSorter(graph).static_order())
    except CycleError as error:
        pytest.fail(f"import cycle among the shared modules: {error.args[1]}")
    assert set(order) >= set(SHARED)
