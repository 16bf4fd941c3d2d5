"""Rule table_spread_scale: the ensemble spread's scale (median error / spread) of each network pair on
its held-out trajectories, by granular_multiscale.analysis.calibration."""

from granular_multiscale.analysis import calibration
from granular_multiscale.runlog import setup_logging, timed_rule


def main(sm) -> None:
    logger = setup_logging(sm.log[0])
    networks = {name[:-len("_sigma")]: (sm.input[name], sm.input[name[:-len("_sigma")] + "_heldout"])
                for name in sm.input.keys() if name.endswith("_sigma")}
    with timed_rule(logger, f"{sm.rule} -> {', '.join(map(str, sm.output))}"):
        table = calibration.make_spread_scale(networks, sm.output.csv, sm.output.html)
        logger.info("%s", table.to_string(index=False))


if "snakemake" in globals():
    main(snakemake)  # noqa: F821
