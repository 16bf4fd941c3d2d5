"""Rule table_spread_scale: the ensemble spread's scale (median error / spread) of each network pair on
its held-out trajectories (granular_multiscale.surrogate.training), tabled by
granular_multiscale.analysis.calibration."""

from granular_multiscale.analysis import calibration
from granular_multiscale.runlog import setup_logging, timed_rule
from granular_multiscale.surrogate.dataset import read_dataset
from granular_multiscale.surrogate.models import SurrogateModel
from granular_multiscale.surrogate.training import heldout_spread_scale


def main(sm) -> None:
    logger = setup_logging(sm.log[0])
    networks = [name[:-len("_sigma")] for name in sm.input.keys() if name.endswith("_sigma")]
    with timed_rule(logger, f"{sm.rule} -> {', '.join(map(str, sm.output))}"):
        rows = [{"networks": name, "model": str(sm.input[f"{name}_sigma"]),
                 **heldout_spread_scale(SurrogateModel.load(sm.input[f"{name}_sigma"]),
                                        read_dataset(sm.input[f"{name}_heldout"]))} for name in networks]
        table = calibration.write_spread_scale(rows, sm.output.csv, sm.output.html)
        logger.info("%s", table.to_string(index=False))


if "snakemake" in globals():
    main(snakemake)  # noqa: F821
