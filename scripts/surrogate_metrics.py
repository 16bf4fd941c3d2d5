"""Rule metrics: FEM–ML (and the no-history ablation) against the reference runs -> tables/*.csv."""

import pandas as pd

from granular_multiscale.analysis import metrics
from granular_multiscale.data import read_run
from granular_multiscale.runlog import setup_logging, timed_rule
from granular_multiscale.surrogate.dataset import read_dataset, split_of
from granular_multiscale.surrogate.training import write_table


def main(inp, out, params, log) -> None:
    logger = setup_logging(log)
    with timed_rule(logger, "metrics"):
        split = split_of(read_dataset(inp.train))
        tables = {"stress_error_by_gp": [], "stress_error": [], "curve_errors": []}
        for i, path in enumerate(params.paths):
            reference = read_run(inp.references[i])
            for run_name, files in (("fem_ml", inp.fem_ml), ("fem_ml_nohist", inp.fem_ml_nohist)):
                run = read_run(files[i])
                for key, table in metrics.compare(reference, run, split["train"], split["heldout"], path=path,
                                                  run=run_name, method=run.attrs.get("method", "")).items():
                    tables[key].append(table)
        for key, parts in tables.items():
            write_table(pd.concat(parts, ignore_index=True), getattr(out, key))

        validation = params.paths.index(params.validation_path)
        runs = {"reference": read_run(inp.references[validation]),
                "nn": read_run(inp.tangent_runs[0]), "autodiff": read_run(inp.tangent_runs[1]),
                "nohist": read_run(inp.fem_ml_nohist[validation])}
        write_table(metrics.newton_iterations(runs), out.newton_iterations)
        all_ml = {f"{name}/{path}": read_run(f) for name, files in (("fem_ml", inp.fem_ml), ("fem_ml_nohist", inp.fem_ml_nohist))
                  for path, f in zip(params.paths, files)}
        all_ml.update({f"fem_ml_{t}/{params.validation_path}": runs[t] for t in ("nn", "autodiff")})
        write_table(metrics.out_of_range(all_ml), out.out_of_range)
        mae = [pd.read_csv(f).assign(network=n) for n, f in zip(params.networks, inp.training_mae)]
        table = pd.concat(mae, ignore_index=True)
        write_table(table[["network", *(c for c in table.columns if c != "network")]], out.training_mae)

        summary = pd.concat(tables["curve_errors"], ignore_index=True)
        force = summary[(summary.quantity == "top_force") & (summary.path == params.validation_path)]
        logger.info("top-force errors on %s:\n%s", params.validation_path,
                    force[["run", "phase", "max_relative_error_percent", "max_error_percent_of_peak",
                           "rms_error_percent_of_peak"]].to_string(index=False))


if "snakemake" in globals():
    sm = snakemake  # noqa: F821
    main(sm.input, sm.output, sm.params, sm.log[0])
