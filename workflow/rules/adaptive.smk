# Adaptive FEM–DEM–ML: the FEM–ML networks at every Gauss point and the point's own YADE RVE where
# the surrogate's indicator reaches the threshold (config section `adaptive`, docs/adaptive.md).
#
#   adaptive        {OUT}/adaptive/t<threshold>/{path}.h5 (t0.01, t0.05, tinf, ...), checkpoint under
#                   {OUT}/checkpoints/adaptive/ (not a declared output: a rerun after a kill resumes)
#                   and .../dem_points/{path}.h5: the DEM answers of its promoted points (training data)
#   adaptive_runs   every threshold of adaptive.thresholds on every path of adaptive.paths
#   active_learning one round (adaptive.active_learning): the DEM answers of the runs at its
#                   threshold join the training sources (surrogate.smk: dataset_active,
#                   train_*_active -> {OUT}/active/models), adaptive_active runs them again
#                   ({OUT}/active/adaptive/...), tables/active_learning.{csv,html} compares both rounds
#
# Not in `all` unless adaptive.report (then the report's speed figure, tables and mode map show
# the validation path's runs, analysis.smk): at the default scale each run costs its DEM share
# of a FEM–DEM run plus the replays; `snakemake -j2 adaptive_runs` runs them.
import re

ADAPTIVE = config["adaptive"]
ADAPTIVE_THRESHOLDS = {threshold_label(t): float(t) for t in ADAPTIVE["thresholds"]}
ADAPTIVE_RUNS = [f"{OUT}/adaptive/{label}/{p}.h5" for label in ADAPTIVE_THRESHOLDS for p in ADAPTIVE_PATHS]
# adaptive.report: the validation path's runs join the speed figure, the tables and the mode map
ADAPTIVE_IN_REPORT = ADAPTIVE["report"] and REFERENCE == "fem_dem"


def adaptive_runs(path):
    """{label: run file} of the adaptive runs of a load path, from the highest threshold to the lowest."""
    return {f"adaptive FEM–DEM–ML, threshold {t:g}": f"{OUT}/adaptive/{label}/{path}.h5"
            for label, t in sorted(ADAPTIVE_THRESHOLDS.items(), key=lambda item: -item[1])}


def adaptive_depends(wc):
    """What an adaptive run depends on besides its inputs, so that editing it re-runs the rule."""
    return {
        **fem_ml_depends(wc),
        "dem": RUN_DEFINITION,
        "adaptive": {k: v for k, v in ADAPTIVE.items() if k not in ("thresholds", "paths")},
        "seed": config["seed"],
    }


# the thresholds each round runs at: every configured one in the first, the active-learning one in both
ADAPTIVE_ROUND_THRESHOLDS = {
    "": {**ADAPTIVE_THRESHOLDS, ACTIVE_LABEL: float(ACTIVE["threshold"])},
    "active/": {ACTIVE_LABEL: float(ACTIVE["threshold"])},
}

for _round, _thresholds in ADAPTIVE_ROUND_THRESHOLDS.items():

    rule:
        name:
            f"adaptive{'_active' if _round else ''}"
        input:
            packings=PACKINGS,
            sigma=model_file("sigma", _round),
            tangent=model_file("tangent", _round),
        output:
            run=f"{OUT}/{_round}adaptive/{{label}}/{{path}}.h5",
            trajectories=f"{OUT}/{_round}adaptive/{{label}}/dem_points/{{path}}.h5",
        log:
            f"{OUT}/logs/{_round}adaptive/{{label}}/{{path}}.log",
        benchmark:
            f"{OUT}/benchmarks/{_round}adaptive/{{label}}/{{path}}.tsv"
        params:
            threshold=lambda wc, thresholds=_thresholds: thresholds[wc.label],
            checkpoint=f"{OUT}/checkpoints/{_round}adaptive/{{label}}/{{path}}.ckpt",
            tangent=SURROGATE["tangent"],
            allow_partial=SURROGATE["keep_partial_runs"],
            depends=adaptive_depends,
        wildcard_constraints:
            label="|".join(re.escape(label) for label in _thresholds),
        threads: config["dem"]["n_workers"]
        script:
            "../../scripts/run_adaptive.py"


rule adaptive_runs:
    input:
        ADAPTIVE_RUNS,


ACTIVE_ROUNDS = {"first": "", "after one round": "active/"}


rule table_active_learning:
    input:
        runs=[f"{OUT}/{r}adaptive/{ACTIVE_LABEL}/{p}.h5" for r in ACTIVE_ROUNDS.values() for p in ACTIVE_PATHS],
        references=[reference_run(p) for p in ACTIVE_PATHS] if REFERENCE == "fem_dem" else [],
        fem_ml=[f"{OUT}/fem_ml/{p}.h5" for p in ACTIVE_PATHS],
    output:
        csv=f"{OUT}/tables/active_learning.csv",
        html=f"{OUT}/tables/active_learning.html",
    log:
        f"{OUT}/logs/analysis/table_active_learning.log",
    params:
        paths=ACTIVE_PATHS,
        rounds=list(ACTIVE_ROUNDS),
    threads: 1
    script:
        "../../scripts/table_active_learning.py"


rule active_learning:
    input:
        rules.table_active_learning.output,
