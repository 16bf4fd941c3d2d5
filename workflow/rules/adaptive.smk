# Adaptive FEM–DEM–ML: the FEM–ML networks at every Gauss point and the point's own YADE RVE where
# the surrogate's indicator reaches the threshold (config section `adaptive`, docs/adaptive.md).
#
#   adaptive        {OUT}/adaptive/t<threshold>/{path}.h5 (t0.01, t0.05, tinf, ...), checkpoint under
#                   {OUT}/checkpoints/adaptive/ (not a declared output: a rerun after a kill resumes)
#   adaptive_runs   every threshold of adaptive.thresholds on every path of adaptive.paths
#
# Not in `all` unless adaptive.report (then the report's speed figure, tables and mode map show
# the validation path's runs, analysis.smk): at the default scale each run costs its DEM share
# of a FEM–DEM run plus the replays; `snakemake -j2 adaptive_runs` runs them.
import re

from granular_multiscale.adaptive import threshold_label

ADAPTIVE = config["adaptive"]
ADAPTIVE_THRESHOLDS = {threshold_label(t): float(t) for t in ADAPTIVE["thresholds"]}
ADAPTIVE_PATHS = ADAPTIVE["paths"] or [VALIDATION_PATH]
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


rule adaptive:
    input:
        packings=PACKINGS,
        sigma=model_file("sigma"),
        tangent=model_file("tangent"),
    output:
        f"{OUT}/adaptive/{{label}}/{{path}}.h5",
    log:
        f"{OUT}/logs/adaptive/{{label}}/{{path}}.log",
    benchmark:
        f"{OUT}/benchmarks/adaptive/{{label}}/{{path}}.tsv"
    params:
        threshold=lambda wc: ADAPTIVE_THRESHOLDS[wc.label],
        checkpoint=f"{OUT}/checkpoints/adaptive/{{label}}/{{path}}.ckpt",
        tangent=SURROGATE["tangent"],
        allow_partial=SURROGATE["keep_partial_runs"],
        depends=adaptive_depends,
    wildcard_constraints:
        label="|".join(re.escape(label) for label in ADAPTIVE_THRESHOLDS),
    threads: config["dem"]["n_workers"]
    script:
        "../../scripts/run_adaptive.py"


rule adaptive_runs:
    input:
        ADAPTIVE_RUNS,
