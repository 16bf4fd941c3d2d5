"""Rule problem_fem_ml_driven: FEM–ML's networks driven along the strain histories of a problem's
reference run, with no FEM (the material's error alone; drivers.fem_ml.run_along_reference)."""

from granular_multiscale.config import validate_config
from granular_multiscale.data import read_run, write_run
from granular_multiscale.drivers.fem_ml import run_along_reference, weak_zone_models_of
from granular_multiscale.runlog import setup_logging, timed_rule


def main(config, reference, sigma, tangent_model, tangent, problem, output, log, weak_zone_models=None) -> None:
    config = validate_config(config)
    logger = setup_logging(log)
    with timed_rule(logger, f"FEM–ML's networks along the strains of {reference} ({tangent} tangent)"):
        ds = run_along_reference(config, read_run(reference), sigma, tangent_model, tangent, problem,
                                 weak_zone_models=weak_zone_models, logger=logger)
        write_run(ds, output, config)
        logger.info("wrote %s (method %s, %d steps)", output, ds.attrs["method"], ds.sizes["step"] - 1)


if "snakemake" in globals():
    sm = snakemake  # noqa: F821
    main(dict(sm.config), sm.input.reference, sm.input.sigma, sm.input.get("tangent"), sm.params.tangent, sm.wildcards.problem,
         sm.output[0], sm.log[0], weak_zone_models=weak_zone_models_of(sm.input))
