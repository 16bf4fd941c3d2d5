# FEM–DEM stage: RVE packings (YADE) and the FEM–DEM reference runs of every load path.
#
#   rve      {OUT}/rve/packing_<k>.yade.gz (k = 0..dem.n_packings-1) + {OUT}/rve/summary.json
#   fem_dem  {OUT}/fem_dem/{path}.h5, checkpoint and RVE snapshots under {OUT}/checkpoints/fem_dem/
#            (not declared outputs: a rerun after a kill resumes from them)
#   rve_paths  {OUT}/rve_paths/{name}.h5 for a set of rve_paths.sets: RVEs driven along designed strain
#            histories (no FEM), checkpoint under {OUT}/checkpoints/rve_paths/; not in `all` by itself
#            (the dataset asks for it through surrogate.training_sources "rve_paths:<name>")

PACKINGS = [f"{OUT}/rve/packing_{k}.yade.gz" for k in range(config["dem"]["n_packings"])]
# what defines a packing / a FEM–DEM run, not where it runs: a change of these reruns the rule
PACKING_DEFINITION = {k: v for k, v in config["dem"].items() if k not in ("executor", "n_workers", "dask_scheduler", "newton")}
RUN_DEFINITION = {k: v for k, v in config["dem"].items() if k not in ("executor", "n_workers", "dask_scheduler")}


rule rve:
    output:
        packings=PACKINGS,
        summary=f"{OUT}/rve/summary.json",
    params:
        dem=PACKING_DEFINITION,
        pressure=config["specimen"]["confining_pressure"],
        seed=config["seed"],
    log:
        f"{OUT}/logs/rve.log",
    benchmark:
        f"{OUT}/benchmarks/rve.tsv"
    threads: min(config["dem"]["n_packings"], config["dem"]["n_workers"])
    script:
        "../../scripts/prepare_rve.py"


rule fem_dem:
    input:
        packings=PACKINGS,
    output:
        f"{OUT}/fem_dem/{{path}}.h5",
    log:
        f"{OUT}/logs/fem_dem/{{path}}.log",
    benchmark:
        f"{OUT}/benchmarks/fem_dem/{{path}}.tsv"
    params:
        checkpoint=f"{OUT}/checkpoints/fem_dem/{{path}}.ckpt",
        dem=RUN_DEFINITION,
        specimen=config["specimen"],
        newton=config["newton"],
        path=lambda wildcards: config["load_paths"][wildcards.path],
    threads: config["dem"]["n_workers"]
    script:
        "../../scripts/run_fem_dem.py"


RVE_PATH_SETS = list(config["rve_paths"]["sets"])


rule rve_paths:
    input:
        # the material points are YADE RVEs, or the elastoplastic model with reference_material: elastoplastic
        packings=PACKINGS if config["reference_material"] == "dem" else [],
    output:
        f"{OUT}/rve_paths/{{name}}.h5",
    log:
        f"{OUT}/logs/rve_paths/{{name}}.log",
    benchmark:
        f"{OUT}/benchmarks/rve_paths/{{name}}.tsv"
    params:
        checkpoint=f"{OUT}/checkpoints/rve_paths/{{name}}.ckpt",
        definition=lambda wildcards: config["rve_paths"]["sets"][wildcards.name],
        rve_paths={k: v for k, v in config["rve_paths"].items() if k != "sets"},
        dem=PACKING_DEFINITION,  # the DEM settings without dem.newton: there is no Newton here
        pressure=config["specimen"]["confining_pressure"],
        seed=config["seed"],
        material=config["reference_material"],
        elastoplastic=config["elastoplastic"] if config["reference_material"] == "elastoplastic" else None,
    wildcard_constraints:
        name="|".join(RVE_PATH_SETS),
    threads: config["dem"]["n_workers"]
    script:
        "../../scripts/run_rve_paths.py"


# FEM–DEM at other sphere counts per RVE (analysis.fem_dem_sphere_counts): the same two rules
# with packings of their own, for the speed-vs-error figure and the speedup/accuracy tables.
#   {OUT}/rve_n{n}/...   {OUT}/fem_dem_n{n}/{path}.h5


use rule rve as rve_spheres with:
    output:
        packings=[f"{OUT}/rve_n{{n}}/packing_{k}.yade.gz" for k in range(config["dem"]["n_packings"])],
        summary=f"{OUT}/rve_n{{n}}/summary.json",
    params:
        dem=PACKING_DEFINITION,
        pressure=config["specimen"]["confining_pressure"],
        seed=config["seed"],
        n_spheres=lambda wildcards: int(wildcards.n),
    log:
        f"{OUT}/logs/rve_n{{n}}.log",
    benchmark:
        f"{OUT}/benchmarks/rve_n{{n}}.tsv"
    wildcard_constraints:
        n=r"\d+",


use rule fem_dem as fem_dem_spheres with:
    input:
        packings=[f"{OUT}/rve_n{{n}}/packing_{k}.yade.gz" for k in range(config["dem"]["n_packings"])],
    output:
        f"{OUT}/fem_dem_n{{n}}/{{path}}.h5",
    log:
        f"{OUT}/logs/fem_dem_n{{n}}/{{path}}.log",
    benchmark:
        f"{OUT}/benchmarks/fem_dem_n{{n}}/{{path}}.tsv"
    params:
        checkpoint=f"{OUT}/checkpoints/fem_dem_n{{n}}/{{path}}.ckpt",
        dem=RUN_DEFINITION,
        specimen=config["specimen"],
        newton=config["newton"],
        path=lambda wildcards: config["load_paths"][wildcards.path],
        n_spheres=lambda wildcards: int(wildcards.n),
    wildcard_constraints:
        n=r"\d+",


if config["reference_material"] == "dem":
    ALL_TARGETS += [reference_run(p) for p in PATH_NAMES]
