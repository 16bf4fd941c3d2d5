# Adaptive FEM–DEM–ML: the FEM–ML networks at every Gauss point and the point's own YADE RVE where
# the surrogate's indicator reaches the threshold (config section `adaptive`, docs/adaptive.md).
#
#   adaptive        {OUT}/adaptive/t<threshold>/{path}.h5 (t0.01, t0.05, tinf, ...), checkpoint under
#                   {OUT}/checkpoints/adaptive/ (not a declared output: a rerun after a kill resumes)
#                   and .../dem_points/{path}.h5: the DEM answers of its promoted points (training data)
#   adaptive_control  {OUT}/adaptive/t<threshold>_{control}/{path}.h5: the run's control, the networks
#                   replaced by the analytic model {control} (adaptive.controls), its promotions copied
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

from granular_multiscale.plan import ACTIVE_ROUNDS


for _round, _thresholds in PLAN.adaptive_round_thresholds.items():

    rule:
        name:
            f"adaptive{'_active' if _round else ''}"
        input:
            packings=PLAN.packings,
            sigma=L.model("sigma", _round),
            tangent=L.model("tangent", _round),
        output:
            run=L.adaptive("{label}", "{path}", _round),
            trajectories=L.adaptive_dem_points("{label}", "{path}", _round),
        log:
            L.log(f"{_round}adaptive/{{label}}/{{path}}"),
        benchmark:
            L.benchmark(f"{_round}adaptive/{{label}}/{{path}}")
        params:
            threshold=lambda wc, thresholds=_thresholds: thresholds[wc.label],
            checkpoint=L.checkpoint(f"{_round}adaptive/{{label}}/{{path}}"),
            tangent=PLAN.adaptive_tangent(),
            allow_partial=config["surrogate"]["keep_partial_runs"],
            depends=lambda wc: PLAN.adaptive_definition(wc.path),
        wildcard_constraints:
            label="|".join(re.escape(label) for label in _thresholds),
        threads: config["dem"]["n_workers"]
        script:
            "../../scripts/run_adaptive.py"


use rule adaptive as adaptive_control with:
    input:
        packings=PLAN.packings,
        schedule_from=L.adaptive_dem_points("{label}", "{path}"),
    output:
        run=L.adaptive("{label}_{control}", "{path}"),
        trajectories=L.adaptive_dem_points("{label}_{control}", "{path}"),
    log:
        L.log("adaptive/{label}_{control}/{path}"),
    benchmark:
        L.benchmark("adaptive/{label}_{control}/{path}")
    params:
        threshold=lambda wc: PLAN.adaptive_thresholds[wc.label],
        checkpoint=L.checkpoint("adaptive/{label}_{control}/{path}"),
        tangent=PLAN.adaptive_tangent(),
        allow_partial=True,
        depends=lambda wc: {**PLAN.adaptive_definition(wc.path), "model": config[wc.control]},
        control=lambda wc: wc.control,
    wildcard_constraints:
        label="|".join(re.escape(label) for label in PLAN.adaptive_thresholds),
        control="|".join(PLAN.controls) or "no-control",


rule adaptive_runs:
    input:
        PLAN.adaptive_run_files(),


rule table_active_learning:
    input:
        runs=[L.adaptive(PLAN.active_label, p, r) for r in ACTIVE_ROUNDS.values() for p in PLAN.active_paths],
        references=[PLAN.reference_run(p) for p in PLAN.active_paths] if PLAN.reference == "fem_dem" else [],
        fem_ml=[L.fem_ml(p) for p in PLAN.active_paths],
    output:
        csv=L.table("active_learning.csv"),
        html=L.table("active_learning.html"),
    log:
        L.log("analysis/table_active_learning"),
    params:
        paths=PLAN.active_paths,
        rounds=list(ACTIVE_ROUNDS),
    threads: 1
    script:
        "../../scripts/table_active_learning.py"


rule active_learning:
    input:
        rules.table_active_learning.output,
