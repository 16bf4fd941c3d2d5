"""YADE and pip's VTK in one process (see dem/vtk_order.py and docs/environment.md).

Debian's YADE loads Debian's VTK 9.1 into the global symbol scope; pip's VTK (9.7) loaded after
it binds to those symbols and crashes. Each test runs its imports in a fresh process.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from granular_multiscale import vtk_order
from granular_multiscale.dem.yade_env import child_env

SIGSEGV = {-11, 139}  # killed by SIGSEGV (139 when the exit goes through a shell)

# a DEM step: YADE is usable, not only importable
YADE_STEP = """
from yade import utils
from yade.wrapper import Omega
O = Omega()
O.bodies.append(utils.sphere((0, 0, 0), 0.01))
O.dt = 1e-6
O.run(3, True)
assert O.iter == 3 and len(O.bodies) == 1
"""

# YADE's own VTK exporter (Debian's VTK 9.1) writes a file after the steps above
YADE_VTK_EXPORT = """
import glob
from yade.wrapper import VTKRecorder
O.engines = [VTKRecorder(fileName="yade-", recorders=["spheres"], iterPeriod=1)]
O.run(1, True)
assert glob.glob("yade-spheres.*.vtu")
"""

# the project's VTK side: an off-screen rendering and a VTU file; `result` holds their hashes
FIELDS_USE = """
import hashlib, json, sys
import numpy as np
from skfem import MeshHex
from granular_multiscale.analysis import fields
mesh = MeshHex.init_tensor(np.linspace(0, 1, 3), np.linspace(0, 1, 3), np.linspace(0, 2, 3))
grid = fields.vtk_grid(mesh.p.T, fields.hex_elements(mesh.p.T))
grid.cell_data["value"] = np.arange(grid.n_cells, dtype=float)
renderer = fields.PanelRenderer((120, 160))
image = renderer.render(grid, grid.cell_data["value"], "cell", (0, 8), "viridis")
renderer.close()
grid.save("grid.vtu")
result = json.dumps({"volume": grid.volume, "image": hashlib.sha256(image.tobytes()).hexdigest(),
                     "vtu": hashlib.sha256(open("grid.vtu", "rb").read()).hexdigest(),
                     "yade": "yade.boot" in sys.modules})
"""
PRINT = "print(result)\n"


def _run(code: str, tmp_path, timeout: float = 180) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=child_env(),
                          capture_output=True, text=True, timeout=timeout)


def _ok(code: str, tmp_path) -> dict:
    """Run code that must exit 0 and print one JSON line last."""
    out = _run(code, tmp_path)
    assert out.returncode == 0, f"exit {out.returncode}\n{out.stderr[-3000:]}"
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.needs_yade
@pytest.mark.parametrize("vtk_import", ["import vtk", "import pyvista"])
def test_pinned_upstream_bug_plain_yade_then_vtk_segfaults(vtk_import, tmp_path):
    """PINS THE UPSTREAM BUG (Debian YADE 2023.02a + pip vtk 9.7): plain ``import yade`` then
    ``import vtk``/``import pyvista`` is killed by SIGSEGV. If this test fails because the
    process exits 0, a new YADE or VTK fixed it: docs/environment.md and dem/vtk_order.py
    can then be simplified."""
    out = _run(f"import yade\n{vtk_import}\nprint('survived')", tmp_path)
    assert out.returncode in SIGSEGV, f"exit {out.returncode}: the crash is gone\n{out.stderr[-2000:]}"
    assert "survived" not in out.stdout


@pytest.mark.needs_yade
def test_all_of_vtk_then_yade_works(tmp_path):
    """The safe order: all of VTK first, then YADE steps and pyvista still renders."""
    result = _ok("import vtk\nimport yade\n" + YADE_STEP + FIELDS_USE + PRINT, tmp_path)
    assert result["yade"] and result["volume"] == pytest.approx(2.0)


@pytest.mark.needs_yade
def test_pyvista_then_import_yade_loads_the_rest_of_vtk_first(tmp_path):
    """pyvista loads only part of VTK; import_yade loads the rest before YADE, so plain pyvista
    rendering afterwards (which loads VTK's OpenGL modules) works. Without it this aborts."""
    result = _ok("""
import json, sys
import pyvista as pv
from granular_multiscale.dem.yade_env import import_yade
import_yade()
names = list(sys.modules)
assert names.index("vtkmodules.all") < names.index("yade.boot")
""" + YADE_STEP + """
plotter = pv.Plotter(off_screen=True, window_size=[64, 64])
plotter.add_mesh(pv.Sphere())
image = plotter.screenshot(return_img=True)
plotter.close()
pv.Sphere().save("sphere.vtp")
print(json.dumps({"shape": list(image.shape)}))
""", tmp_path)
    assert result["shape"] == [64, 64, 3]


@pytest.mark.needs_yade
def test_fields_after_yade_renders_like_without_yade(tmp_path):
    """YADE first, then the project's fields module (the bad order, made safe by loading VTK
    with RTLD_DEEPBIND): the rendering and the VTU file are bit-identical to those of a
    process without YADE, and YADE still steps and writes its own VTK files afterwards."""
    alone = _ok(FIELDS_USE + PRINT, tmp_path)
    with_yade = _ok("from granular_multiscale.dem.yade_env import import_yade\nimport_yade()\n"
                    + FIELDS_USE + YADE_STEP + YADE_VTK_EXPORT + PRINT, tmp_path)
    assert not alone["yade"] and with_yade["yade"]
    assert with_yade == {**alone, "yade": True}


@pytest.mark.needs_yade
def test_vtk_loaded_after_yade_elsewhere_gives_a_clear_error(tmp_path):
    """A VTK module imported after YADE without the guard is bound to YADE's VTK for good;
    the fields module then refuses with an ImportError that states the rule."""
    out = _run("import yade\nimport vtkmodules.vtkCommonCore\nfrom granular_multiscale.analysis import fields",
               tmp_path)
    assert out.returncode == 1, out.stderr[-3000:]
    assert "ImportError: VTK modules ['vtkmodules.vtkCommonCore'] were imported after YADE" in out.stderr
    assert "import vtk" in out.stderr and "docs/environment.md" in out.stderr


def test_guard_logic_without_yade(monkeypatch):
    """In-process: no YADE -> before_vtk_import does nothing; a fake boot.so followed by a VTK
    module -> ImportError (sys.modules order is import order)."""
    if "yade.boot" in sys.modules:
        pytest.skip("YADE was imported into the test process itself")
    vtk_order.before_vtk_import()  # no YADE: nothing happens
    monkeypatch.setitem(sys.modules, "yade.boot", object())
    monkeypatch.setitem(sys.modules, "vtkmodules.vtkFakeModule", object())
    assert vtk_order.vtk_modules_loaded_after_yade() == ["vtkmodules.vtkFakeModule"]
    with pytest.raises(ImportError, match="imported after YADE"):
        vtk_order.before_vtk_import()
    vtk_order.before_yade_import()  # YADE already there: nothing to do
