"""One-off studies that chose the RVE procedure: not part of the workflow, run by benches and
tests on purpose.

* ``direct_triaxial``  direct (no FEM) servo, replay and PeriTriax tests of one RVE (YADE, own process)
* ``uniform_fem_dem``  the uniform-field FEM–DEM run of one RVE they are compared with
"""
