"""Rule rve_paths: RVEs driven along the designed strain histories of one set of
`rve_paths.sets`, no FEM, written in the data contract. Resumes from its checkpoint."""

from granular_multiscale.config import validate_config
from granular_multiscale.drivers.rve_paths import run_rve_paths
from granular_multiscale.runlog import setup_logging, timed_rule


def main(config: dict, set_name: str, packings: list[str], output: str, checkpoint: str, log: str | None,
         threads: int) -> None:
    config = validate_config(config)
    logger = setup_logging(log)
    # local pool: one worker per core the rule got; Dask: dem.n_workers actors on the cluster
    workers = threads if config["dem"]["executor"] == "local" else config["dem"]["n_workers"]
    with timed_rule(logger, f"rve_paths {set_name}"):
        run_rve_paths(config, set_name, packings, output, checkpoint, workers, logger=logger)


if __name__ == "__main__" or "snakemake" in globals():
    main(dict(snakemake.config), snakemake.wildcards.name, list(snakemake.input.packings),  # noqa: F821
         snakemake.output[0], snakemake.params.checkpoint, snakemake.log[0], snakemake.threads)  # noqa: F821
