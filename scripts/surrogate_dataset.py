"""Rule dataset: the training path's reference run -> train.h5 / heldout.h5 (split by Gauss point)."""

from granular_multiscale.data import read_run
from granular_multiscale.runlog import setup_logging, timed_rule
from granular_multiscale.surrogate.dataset import build_dataset, summary, write_dataset


def main(reference: str, train_out: str, heldout_out: str, seed: int, train_fraction: float, split: str,
         log: str | None) -> None:
    logger = setup_logging(log)
    with timed_rule(logger, "dataset"):
        run = read_run(reference, required=("strain", "stress", "tangent"))
        train, heldout = build_dataset(run, train_fraction, seed, source=reference, split=split)
        write_dataset(train, train_out)
        write_dataset(heldout, heldout_out)
        logger.info("dataset from %s (method %s): %s", reference, run.attrs.get("method", "?"), summary(train, heldout))


if "snakemake" in globals():
    main(
        snakemake.input[0],  # noqa: F821
        snakemake.output.train,  # noqa: F821
        snakemake.output.heldout,  # noqa: F821
        snakemake.params.seed,  # noqa: F821
        snakemake.params.train_fraction,  # noqa: F821
        snakemake.params.split,  # noqa: F821
        snakemake.log[0],  # noqa: F821
    )
