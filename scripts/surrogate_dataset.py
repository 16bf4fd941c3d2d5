"""Rule dataset: the training sources (reference runs, RVE-path sets) -> train.h5 / heldout.h5,
held out by trajectory class."""

from granular_multiscale.data import read_run
from granular_multiscale.runlog import setup_logging, timed_rule
from granular_multiscale.surrogate.dataset import build_dataset_from_sources, summary, write_dataset


def main(sources: list[str], train_out: str, heldout_out: str, seed: int, train_fraction: float, split: str,
         history_tolerance: float, log: str | None) -> None:
    logger = setup_logging(log)
    with timed_rule(logger, "dataset"):
        runs = [(path, read_run(path, required=("strain", "stress", "tangent"))) for path in sources]
        for path, run in runs:
            logger.info("source %s: method %s, %d steps x %d trajectories", path, run.attrs.get("method", "?"),
                        run.sizes["step"], run.sizes["gp"])
        train, heldout = build_dataset_from_sources(runs, train_fraction, seed, split=split,
                                                    history_tolerance=history_tolerance)
        write_dataset(train, train_out)
        write_dataset(heldout, heldout_out)
        logger.info("dataset: %s", summary(train, heldout))


if "snakemake" in globals():
    sm = snakemake  # noqa: F821
    main(list(sm.input.sources), sm.output.train, sm.output.heldout, sm.params.seed, sm.params.train_fraction,
         sm.params.split, sm.params.history_tolerance, sm.log[0])
