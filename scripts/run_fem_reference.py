"""Rule fem_elastoplastic: the triaxial test on one load path with the analytic elastoplastic
model at every Gauss point, written in the data contract."""

from granular_multiscale.config import validate_config
from granular_multiscale.drivers.reference import run_fem_reference
from granular_multiscale.runlog import setup_logging, timed_rule


def main(config: dict, path_name: str, output: str, log: str | None) -> None:
    config = validate_config(config)
    logger = setup_logging(log)
    with timed_rule(logger, f"fem_elastoplastic {path_name}"):
        run_fem_reference(config, path_name, output, logger)


if __name__ == "__main__" or "snakemake" in globals():
    main(dict(snakemake.config), snakemake.wildcards.path, snakemake.output[0], snakemake.log[0])  # noqa: F821
