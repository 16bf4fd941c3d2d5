"""Rule tolerance_study: table (CSV + HTML) and figure of the FEM–DEM runs at every Newton variant
against the converged one, and the page of the reference's own error (the row solved like it)."""

from granular_multiscale.analysis import convergence, products
from granular_multiscale.runlog import setup_logging, timed_rule


def main(sm) -> None:
    logger = setup_logging(sm.log[0])
    p = sm.params
    with timed_rule(logger, f"tolerance_study -> {', '.join(map(str, sm.output))}"):
        table = convergence.make_tolerance_study(dict(zip(p.variants, sm.input.runs)), p.variants, p.converged,
                                              p.baseline, sm.output.csv, sm.output.html, sm.output.figure,
                                              path_label=p.path_label, settings=p.settings)
        logger.info("\n%s", table.to_string())
        own = products.make_reference_convergence(sm.output.csv, sm.output.convergence, newton=p.dem_newton,
                                                  study_path=p.path_label, reference_material=p.reference_material)
        logger.info("the reference's own error (row solved with %s): %s", p.dem_newton, own)


if "snakemake" in globals():
    main(snakemake)  # noqa: F821
