"""Rule table_active_learning: the adaptive runs of the active-learning round before and after it
(tables/active_learning.{csv,html})."""

from granular_multiscale.analysis.tables import active_learning_table, write_csv, write_html_table
from granular_multiscale.data import read_run
from granular_multiscale.runlog import setup_logging, timed_rule


def main(runs: list[str], references: list[str], fem_ml: list[str], paths: list[str], rounds: list[str],
         csv: str, html: str, log: str | None) -> None:
    logger = setup_logging(log)
    with timed_rule(logger, "table active_learning"):
        # runs: every path of the first round, then every path of the next (the rule's order)
        by_round = {name: {p: read_run(runs[k * len(paths) + i]) for i, p in enumerate(paths)}
                    for k, name in enumerate(rounds)}
        table = active_learning_table(by_round, {p: read_run(f) for p, f in zip(paths, references)},
                                      {p: read_run(f) for p, f in zip(paths, fem_ml)})
        write_csv(table, csv)
        write_html_table(table, html, title="Active learning: adaptive FEM–DEM–ML before and after one round",
                         note="Same threshold in both rounds. The round's networks were trained again with the DEM "
                              "answers of the first round's promoted points, along the same load path: the second "
                              "run is not a held-out validation of them, it measures how much DEM the run needs "
                              "once the networks have learnt where they were unsure.")
        logger.info("active learning:\n%s", table.to_string(index=False))


if "snakemake" in globals():
    sm = snakemake  # noqa: F821
    main(list(sm.input.runs), list(sm.input.references), list(sm.input.fem_ml), list(sm.params.paths),
         list(sm.params.rounds), sm.output.csv, sm.output.html, sm.log[0])
