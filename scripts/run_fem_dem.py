"""Rules fem_dem (the triaxial test) and problem_fem_dem (the problems of ``problems``): one load
path with a YADE RVE at every Gauss point, written in the data contract (plus the DEM time split
per step). Resumes from its checkpoint."""

from granular_multiscale.config import validate_config
from granular_multiscale.drivers.fem_dem import run_fem_dem
from granular_multiscale.runlog import setup_logging, timed_rule


def main(config: dict, path_name: str, packings: list[str], output: str, checkpoint: str, log: str | None,
         threads: int, n_spheres: int | None = None, dem_newton: dict | None = None, problem: str = "triaxial",
         weak_packing: str | None = None, overrides: dict | None = None) -> None:
    config = validate_config({**config, **(overrides or {})})
    if n_spheres is not None:  # rule fem_dem_spheres: another sphere count than dem.n_spheres
        config["dem"]["n_spheres"] = n_spheres
    if dem_newton is not None:  # rule fem_dem_variant: a tolerance-study variant's Newton settings
        config["dem"]["newton"].update(dem_newton)
    logger = setup_logging(log)
    # local pool: one worker per core the rule got; Dask: dem.n_workers actors on the cluster
    workers = threads if config["dem"]["executor"] == "local" else config["dem"]["n_workers"]
    with timed_rule(logger, f"fem_dem {problem} {path_name}"):
        run_fem_dem(config, path_name, packings, output, checkpoint, workers, logger=logger, problem=problem,
                    weak_packing=weak_packing)


if __name__ == "__main__" or "snakemake" in globals():
    p, i = snakemake.params, snakemake.input  # noqa: F821
    main(dict(snakemake.config), p.get("path_name", None) or snakemake.wildcards.path, list(i.packings),  # noqa: F821
         snakemake.output[0], p.checkpoint, snakemake.log[0], snakemake.threads,  # noqa: F821
         p.get("n_spheres", None), p.get("dem_newton", None), p.get("problem", "triaxial"),
         (list(i.get("weak_packing", None) or []) or [None])[0], p.get("overrides", None))
