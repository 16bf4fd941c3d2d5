"""Rules figure_calibration and problem_calibration: the ensemble spread of FEM–ML against its realised
error, as measured and scaled by the held-out trajectories' scale (figure, CSV, HTML), drawn by
granular_multiscale.analysis.calibration."""

from granular_multiscale.analysis import calibration
from granular_multiscale.runlog import setup_logging, timed_rule


def main(sm) -> None:
    logger = setup_logging(sm.log[0])
    p = sm.params
    with timed_rule(logger, f"{sm.rule} -> {', '.join(map(str, sm.output))}"):
        table, _ = calibration.make_calibration(sm.input.surrogate, sm.input.reference, sm.output.figure,
                                                sm.output.csv, sm.output.html, p.settings, path_label=p.path_label,
                                                reference_label=p.reference_label, surrogate_label=p.surrogate_label,
                                                spread_scales=calibration.read_spread_scales(sm.input.spread_scale))
        logger.info("%s", table.to_string(index=False))


if "snakemake" in globals():
    main(snakemake)  # noqa: F821
