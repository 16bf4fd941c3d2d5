"""Rules train_<network>: NNσ or ND (with or without history variables) from the dataset files."""

from granular_multiscale.analysis.figures import plot_losses
from granular_multiscale.runlog import setup_logging, timed_rule
from granular_multiscale.surrogate.dataset import read_dataset
from granular_multiscale.surrogate.training import train, write_table


def main(train_file, heldout_file, kind, use_history, settings, seed, config, out, log) -> None:
    logger = setup_logging(log)
    name = f"{'NNσ' if kind == 'sigma' else 'ND'}{'' if use_history else ' (no history)'}"
    with timed_rule(logger, f"train {name}"):
        train_ds, heldout_ds = read_dataset(train_file), read_dataset(heldout_file)
        model, losses, mae = train(train_ds, heldout_ds, kind, settings, seed, use_history=use_history,
                                   config=config, logger=logger)
        model.save(out.model)
        write_table(losses, out.losses)
        write_table(mae, out.mae)
        plot_losses({name: losses}, out.figure, loss_name=settings["loss"].upper())
        logger.info("final MAE per component (Pa):\n%s", mae.to_string(index=False))


if "snakemake" in globals():
    sm = snakemake  # noqa: F821
    main(sm.input.train, sm.input.heldout, sm.params.kind, sm.params.use_history, dict(sm.params.settings),
         sm.params.seed, dict(sm.config), sm.output, sm.log[0])
