# FEM–DEM stage: RVE packings (YADE) and the FEM–DEM reference runs of every load path.
#
#   rve      {OUT}/rve/packing_<k>.yade.gz (k = 0..dem.n_packings-1) + {OUT}/rve/summary.json
#            (rve_pressure: the same at another consolidation pressure, {OUT}/rve_p<g>/)
#   fem_dem  {OUT}/fem_dem/{path}.h5, checkpoint and RVE snapshots under {OUT}/checkpoints/fem_dem/
#            (not declared outputs: a rerun after a kill resumes from them)
#   rve_paths  {OUT}/rve_paths/{name}.h5 for a set of rve_paths.sets: RVEs driven along designed strain
#            histories (no FEM), checkpoint under {OUT}/checkpoints/rve_paths/; not in `all` by itself
#            (the dataset asks for it through surrogate.training_sources "rve_paths:<name>")


rule rve:
    output:
        packings=PLAN.packings,
        summary=L.packing_summary(),
    params:
        dem=PLAN.packing_definition,
        pressure=config["specimen"]["confining_pressure"],
        seed=config["seed"],
    log:
        L.log("rve"),
    benchmark:
        L.benchmark("rve")
    threads: min(config["dem"]["n_packings"], config["dem"]["n_workers"])
    script:
        "../../scripts/prepare_rve.py"


rule fem_dem:
    input:
        packings=PLAN.packings,
    output:
        L.run("fem_dem", "{path}"),
    log:
        L.log("fem_dem/{path}"),
    benchmark:
        L.benchmark("fem_dem/{path}")
    params:
        checkpoint=L.checkpoint("fem_dem/{path}"),
        dem=PLAN.run_definition,
        specimen=config["specimen"],
        newton=config["newton"],
        path=lambda wildcards: config["load_paths"][wildcards.path],
    priority: DEM_PRIORITY
    threads: config["dem"]["n_workers"]
    script:
        "../../scripts/run_fem_dem.py"


rule rve_paths:
    input:
        # the material points are YADE RVEs (the specimen's packings, or the weak zone's with the set's
        # packing: weak_zone), or the elastoplastic model with reference_material: elastoplastic
        packings=lambda wc: PLAN.rve_path_packings(wc.name),
    output:
        L.rve_paths("{name}"),
    log:
        L.log("rve_paths/{name}"),
    benchmark:
        L.benchmark("rve_paths/{name}")
    params:
        checkpoint=L.checkpoint("rve_paths/{name}"),
        definition=lambda wildcards: config["rve_paths"]["sets"][wildcards.name],
        rve_paths={k: v for k, v in config["rve_paths"].items() if k != "sets"},
        dem=PLAN.packing_definition,  # the DEM settings without dem.newton: there is no Newton here
        pressure=config["specimen"]["confining_pressure"],
        seed=config["seed"],
        material=config["reference_material"],
        elastoplastic=config["elastoplastic"] if config["reference_material"] == "elastoplastic" else None,
    wildcard_constraints:
        name="|".join(PLAN.rve_path_sets),
    priority: DEM_PRIORITY
    threads: config["dem"]["n_workers"]
    script:
        "../../scripts/run_rve_paths.py"


# FEM–DEM at other sphere counts per RVE (analysis.fem_dem_sphere_counts): the same two rules
# with packings of their own, for the speed-vs-error figure and the speedup/accuracy tables.
#   {OUT}/rve_n{n}/...   {OUT}/fem_dem_n{n}/{path}.h5


use rule rve as rve_spheres with:
    output:
        packings=L.packings(PLAN.n_packings, spheres="{n}"),
        summary=L.packing_summary(spheres="{n}"),
    params:
        dem=PLAN.packing_definition,
        pressure=config["specimen"]["confining_pressure"],
        seed=config["seed"],
        n_spheres=lambda wildcards: int(wildcards.n),
    log:
        L.log("rve_n{n}"),
    benchmark:
        L.benchmark("rve_n{n}")
    wildcard_constraints:
        n=r"\d+",


# packings consolidated at g·p0 for the RVE-path sets with consolidation_pressure g (the networks'
# history variable p0):   {OUT}/rve_p{g}/...


use rule rve as rve_pressure with:
    output:
        packings=L.packings(PLAN.n_packings, pressure="{g}"),
        summary=L.packing_summary(pressure="{g}"),
    params:
        dem=PLAN.packing_definition,
        pressure=lambda wildcards: float(wildcards.g) * config["specimen"]["confining_pressure"],
        seed=config["seed"],
    log:
        L.log("rve_p{g}"),
    benchmark:
        L.benchmark("rve_p{g}")
    wildcard_constraints:
        g=r"[0-9.]+",


use rule fem_dem as fem_dem_spheres with:
    input:
        packings=L.packings(PLAN.n_packings, spheres="{n}"),
    output:
        L.run("fem_dem_n{n}", "{path}"),
    log:
        L.log("fem_dem_n{n}/{path}"),
    benchmark:
        L.benchmark("fem_dem_n{n}/{path}")
    params:
        checkpoint=L.checkpoint("fem_dem_n{n}/{path}"),
        dem=PLAN.run_definition,
        specimen=config["specimen"],
        newton=config["newton"],
        path=lambda wildcards: config["load_paths"][wildcards.path],
        n_spheres=lambda wildcards: int(wildcards.n),
    wildcard_constraints:
        n=r"\d+",
