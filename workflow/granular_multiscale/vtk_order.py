"""YADE and pip's VTK in one process: load VTK so that the two VTK builds never mix.

Cause. Debian's YADE links Debian's VTK 9.1 (``libvtk*-9.1.so.1``, needed by ``boot.so``,
``libyade.so`` and several plugins), and ``yade/__init__.py`` switches Python's dlopen flags to
``RTLD_NOW | RTLD_GLOBAL`` before loading them (and never switches back): VTK 9.1 then sits in
the process's global symbol scope. pip's ``vtk`` wheel (9.7, under pyvista) ships its own
``libvtk*.so``: other sonames, but the same C++ symbol names and no symbol versions. The dynamic
linker looks a symbol up in the global scope first, so every wheel library loaded *after* YADE
binds most of its VTK symbols to the 9.1 copies, and 9.1 code runs on 9.7 objects. ``import
vtk`` after ``import yade`` segfaults in a static initializer of the wheel's
libvtkDomainsChemistry.so (its ``vtkStringArray::InsertTuple`` call lands in
libvtkCommonCore-9.1.so.1); a smaller VTK import survives and crashes on first use.

Wheel libraries loaded *before* YADE are bound already and stay out of the global scope (Python
loads extensions ``RTLD_LOCAL``), so VTK-then-YADE is safe, but only for what was loaded then:
pyvista imports VTK modules lazily, and one loaded after YADE clashes again. Hence:

* :func:`before_yade_import` (``yade_env.import_yade``): if VTK is partly loaded, load all of it
  now, before YADE. A DEM process that never touched VTK pays nothing.
* :func:`before_vtk_import` (``analysis.fields``, before ``import pyvista``): if YADE is loaded,
  load all of VTK with ``RTLD_DEEPBIND``, which makes each wheel library look symbols up in its
  own dependencies (the wheel's) before the global scope. If some VTK module was already loaded
  after YADE without it, that module is bound to VTK 9.1 for good: raise ImportError.

Neither imports YADE or VTK unless the process already holds the other one.
"""

from __future__ import annotations

import os
import sys

_deep_bound = False  # before_vtk_import has loaded all of VTK with RTLD_DEEPBIND

ORDER_RULE = (
    "In one process, load VTK before YADE: `import vtk` (all of VTK; pyvista alone loads only "
    "part of it) before `import yade`, or import YADE with "
    "granular_multiscale.dem.yade_env.import_yade(); after YADE, the first VTK/pyvista import "
    "must be granular_multiscale.analysis.fields. See docs/environment.md."
)


def yade_loaded() -> bool:
    """True once YADE's boot.so, the extension that brings Debian's VTK 9.1 in, is loaded."""
    return "yade.boot" in sys.modules


def vtk_modules_loaded_after_yade() -> list[str]:
    """VTK extension modules imported after YADE's boot.so (``sys.modules`` keeps import order)."""
    names = list(sys.modules)
    if "yade.boot" not in names:
        return []
    return [n for n in names[names.index("yade.boot") + 1 :] if n.startswith("vtkmodules.vtk")]


def before_yade_import() -> None:
    """Call right before importing YADE: load the rest of VTK now if some of it is loaded."""
    if "vtkmodules" in sys.modules and not yade_loaded():
        import vtkmodules.all  # noqa: F401  (every VTK extension module, bound to the wheel)


def before_vtk_import() -> None:
    """Call right before importing vtk/pyvista: in a process with YADE, load VTK deep-bound."""
    global _deep_bound
    if _deep_bound or not yade_loaded():
        return
    late = vtk_modules_loaded_after_yade()
    if late:
        raise ImportError(
            f"VTK modules {late[:3]}{' ...' if len(late) > 3 else ''} were imported after YADE in "
            "this process; they are bound to YADE's VTK 9.1 instead of pip's VTK and crash when "
            "used. Restart the Python process. " + ORDER_RULE
        )
    flags = sys.getdlopenflags()  # YADE's RTLD_NOW | RTLD_GLOBAL
    sys.setdlopenflags(os.RTLD_NOW | os.RTLD_DEEPBIND)
    try:
        import vtkmodules.all  # noqa: F401  (all of VTK now: nothing left for pyvista to load lazily)
    finally:
        sys.setdlopenflags(flags)
    _deep_bound = True
