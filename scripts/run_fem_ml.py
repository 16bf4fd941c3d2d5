"""Rules fem_ml, fem_ml_nohist, fem_ml_tangent, problem_fem_ml, problem_fem_ml_as_reference: the FEM
solver with the surrogate at the Gauss points, on a load path of the triaxial specimen or of another
problem (params.problem), with FEM–ML's Newton settings or those of the reference (params.solver)."""

from granular_multiscale.config import validate_config
from granular_multiscale.data import write_run
from granular_multiscale.runlog import setup_logging, timed_rule
from granular_multiscale.drivers.fem_ml import run_fem_ml, weak_zone_models_of


def main(config, path_name, sigma, tangent_model, tangent, output, log, allow_partial=False,
         problem="triaxial", weak_zone_models=None, solver="fem_ml") -> None:
    config = validate_config(config)
    logger = setup_logging(log)
    with timed_rule(logger, f"FEM–ML {problem} {path_name} ({tangent} tangent, {solver}'s Newton settings)"):
        ds = run_fem_ml(config, path_name, sigma, tangent_model, tangent, logger=logger, allow_partial=allow_partial,
                        problem=problem, weak_zone_models=weak_zone_models, solver=solver)
        write_run(ds, output, config)
        logger.info("wrote %s (method %s, %d steps, completed %d)", output, ds.attrs["method"], ds.sizes["step"] - 1,
                    ds.attrs["completed"])


if "snakemake" in globals():
    sm = snakemake  # noqa: F821
    # ND is not an input of a run solved with the autodiff tangent (Plan.fem_ml_models)
    main(dict(sm.config), sm.params.get("path_name") or sm.wildcards.path, sm.input.sigma, sm.input.get("tangent"),
         sm.params.tangent, sm.output[0], sm.log[0], allow_partial=bool(sm.params.get("allow_partial", False)),
         problem=sm.params.get("problem") or "triaxial",
         weak_zone_models=weak_zone_models_of(sm.input), solver=sm.params.get("solver") or "fem_ml")
