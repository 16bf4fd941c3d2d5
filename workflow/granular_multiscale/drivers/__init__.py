"""Drivers: the layer that composes a problem (``fem/``) with a material-point set
(``materials/``, ``dem/``, ``surrogate/``, ``adaptive/``) and writes a run in the data contract.

Every arrow points down: the drivers import the solver and the material sets, never the other
way round, so the solver never learns what sits at its Gauss points.

    fem_dem    FEM–DEM runs (YADE RVEs at the Gauss points)
    fem_ml     FEM–ML runs (the neural surrogate at the Gauss points)
    reference  the elastoplastic reference runs (the analytic model at the Gauss points)
    rve_paths  RVEs driven along designed strain histories (the DEM set alone, no FEM)
    adaptive   adaptive FEM–DEM–ML runs (the surrogate, and a YADE RVE where it is unsure)
"""
