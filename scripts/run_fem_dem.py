"""Rule fem_dem: the triaxial test on one load path with a YADE RVE at every Gauss point,
written in the data contract (plus the DEM time split per step). Resumes from its checkpoint."""

from granular_multiscale.config import validate_config
from granular_multiscale.drivers.fem_dem import run_fem_dem
from granular_multiscale.runlog import setup_logging, timed_rule


def main(config: dict, path_name: str, packings: list[str], output: str, checkpoint: str, log: str | None,
         threads: int, n_spheres: int | None = None, dem_newton: dict | None = None) -> None:
    config = validate_config(config)
    if n_spheres is not None:  # rule fem_dem_spheres: another sphere count than dem.n_spheres
        config["dem"]["n_spheres"] = n_spheres
    if dem_newton is not None:  # rule fem_dem_variant: a tolerance-study variant's Newton settings
        config["dem"]["newton"].update(dem_newton)
    logger = setup_logging(log)
    # local pool: one worker per core the rule got; Dask: dem.n_workers actors on the cluster
    workers = threads if config["dem"]["executor"] == "local" else config["dem"]["n_workers"]
    with timed_rule(logger, f"fem_dem {path_name}"):
        run_fem_dem(config, path_name, packings, output, checkpoint, workers, logger=logger)


if __name__ == "__main__" or "snakemake" in globals():
    main(dict(snakemake.config), snakemake.wildcards.path, list(snakemake.input.packings),  # noqa: F821
         snakemake.output[0], snakemake.params.checkpoint, snakemake.log[0], snakemake.threads,  # noqa: F821
         getattr(snakemake.params, "n_spheres", None), getattr(snakemake.params, "dem_newton", None))  # noqa: F821
