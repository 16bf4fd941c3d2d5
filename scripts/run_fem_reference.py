"""Rules fem_elastoplastic (the triaxial test) and problem_fem_elastoplastic (the problems of
``problems``): one load path with the analytic elastoplastic model at every Gauss point, written
in the data contract."""

from granular_multiscale.config import validate_config
from granular_multiscale.drivers.reference import run_fem_reference
from granular_multiscale.runlog import setup_logging, timed_rule


def main(config: dict, path_name: str, output: str, log: str | None, problem: str = "triaxial",
         overrides: dict | None = None) -> None:
    config = validate_config({**config, **(overrides or {})})
    logger = setup_logging(log)
    with timed_rule(logger, f"fem_elastoplastic {problem} {path_name}"):
        run_fem_reference(config, path_name, output, logger, problem=problem)


if __name__ == "__main__" or "snakemake" in globals():
    p = snakemake.params  # noqa: F821
    main(dict(snakemake.config), p.get("path_name", None) or snakemake.wildcards.path, snakemake.output[0],  # noqa: F821
         snakemake.log[0], p.get("problem", "triaxial"), p.get("overrides", None))  # noqa: F821
