"""Figures, tables and report numbers of the workflow.

* ``quantities`` — invariants of the stored tensors (q, p, equivalent shear strain) and
  signs for plotting; pure numpy.
* ``runs``       — reading the run files of the data contract and describing a run
  (method label, load steps, reversals, wall time, Newton iterations).
* ``selection``  — the stated rule that picks the Gauss points of the stress–strain figures.
* ``figures``    — matplotlib figures (error map, stress–strain, top force and volumetric
  strain, training curves, speed vs error).
* ``fields``     — the hexahedral mesh as a VTK grid, off-screen pyvista renderings of
  fields on the deformed mesh, and VTU/PVD export for ParaView.
* ``tables``     — speedup table (paper Table 4 layout), accuracy table, headline numbers.
* ``validation`` — FEM–ML against the reference per load path, method and load phase
  (cycles numbered), the validation table of every validation path.
* ``calibration`` — the ensemble spread FEM–ML reports against its realised error (per spread
  decile, per step; figure and table).

The error metrics themselves live in ``metrics`` (the FEM–ML stage); this package only
draws and tabulates them.
"""
