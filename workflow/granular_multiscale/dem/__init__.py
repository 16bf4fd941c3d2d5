"""DEM side: YADE RVEs. YADE code lives in modules run inside worker processes only,
because ``from yade import *`` rebinds globals; nothing here imports yade at import time.

* ``rve``        packing preparation (periodic cell, Table 1, Hertz–Mindlin, consolidation)
* ``worker``     RVE host process: resident scenes, fork-based trials and rollback
* ``executors``  local process pool or Dask actors holding the hosts
* ``material``   ``DemMaterialPointSet``: the material-point set the FEM solver calls
* ``subset``     ``DemSubsetMaterialPointSet``: RVEs everywhere, only an active subset driven; late
                 activation by replay (the DEM points of the adaptive set)
* ``strain_paths``  designed strain histories of the rve_paths rule (numpy only, no YADE)
* ``run``        what the ``rve`` rule script calls (FEM–DEM runs: ``drivers.fem_dem``)
* ``yade_env``   one-thread YADE start-up shared by all of them (VTK first: ``vtk_order``)
"""
