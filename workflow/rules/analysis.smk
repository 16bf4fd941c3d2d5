# Figures, tables and the HTML report: the comparison a reader sees.
#
#   snakemake -j2 all                                 builds every figure and table below
#   snakemake --report {output_dir}/report.html       then builds the self-contained report
#                                                     (same --configfile/--config as the run)
#
# All products compare runs of the validation path (Path2): the reference (FEM–DEM, or the
# elastoplastic model with reference_material: elastoplastic), FEM–ML and the no-history
# ablation; the speed figure and tables add FEM–DEM at other sphere counts when configured.
# The surrogate cost table adds what making the surrogate cost (RVE packings, the training
# path's reference run, dataset, NNσ and ND training) and the break-even number of FEM–ML runs.
# validation_tables compares FEM–ML and the ablation with the reference on every validation path
# (PLAN.validation_paths: each load path the training did not use) and the training paths, per load phase.
from granular_multiscale.plan import FIELD_QUANTITIES, path_label

ANALYSIS = config["analysis"]
VALIDATION = PLAN.validation_path
DATASET = {"train": L.dataset("train"), "heldout": L.dataset("heldout")}
COMPARISON = PLAN.comparison_runs(VALIDATION)  # reference, FEM–ML, the ablation
TIMING = PLAN.timing_runs(VALIDATION)  # and the other tangent, sphere counts, adaptive runs
TRAINING_CURVES = PLAN.training_curves()
VTK_RUNS = PLAN.vtk_runs()

CAT_HEADLINE = "0 Headline"
CAT_GP = "1 Gauss points"
CAT_SPECIMEN = "2 Specimen"
CAT_SPEED = "3 Speed and accuracy"
CAT_TRAINING = "4 Training"
CAT_UNCERTAINTY = "6 Uncertainty"


rule figure_error_map:
    input:
        reference=PLAN.reference_run(VALIDATION),
        surrogate=L.fem_ml(VALIDATION),
        **DATASET,
    output:
        report(L.figure("error_map.png"), caption="../report/error_map.rst", category=CAT_GP,
               subcategory="Error map"),
    log:
        L.log("analysis/figure_error_map"),
    benchmark:
        L.benchmark("analysis/figure_error_map")
    params:
        kind="error_map",
        settings=ANALYSIS,
        path_label=path_label(VALIDATION),
        reference_label=PLAN.reference_label,
        surrogate_label=PLAN.surrogate_label,
    script:
        "../../scripts/analysis_figure.py"


rule figure_stress_strain:
    input:
        runs=list(COMPARISON.values()),
        **DATASET,
    output:
        [
            report(L.figure(f"stress_strain_{name}.png"), caption="../report/stress_strain.rst",
                   category=CAT_GP, subcategory="Stress–strain at held-out points")
            for name in PLAN.stress_strain_names()
        ],
    log:
        L.log("analysis/figure_stress_strain"),
    benchmark:
        L.benchmark("analysis/figure_stress_strain")
    params:
        kind="stress_strain",
        settings=ANALYSIS,
        path_label=path_label(VALIDATION),
        labels=list(COMPARISON),
        points=PLAN.stress_strain_names(),
    script:
        "../../scripts/analysis_figure.py"


rule figure_global_response:
    input:
        runs=list(COMPARISON.values()),
    output:
        report(L.figure("top_force_volumetric_strain.png"), caption="../report/global_response.rst",
               category=CAT_SPECIMEN, subcategory="Top force and volumetric strain"),
    log:
        L.log("analysis/figure_global_response"),
    benchmark:
        L.benchmark("analysis/figure_global_response")
    params:
        kind="global_response",
        settings=ANALYSIS,
        path_label=path_label(VALIDATION),
        labels=list(COMPARISON),
    script:
        "../../scripts/analysis_figure.py"


rule figure_fields:
    input:
        reference=PLAN.reference_run(VALIDATION),
        surrogate=L.fem_ml(VALIDATION),
    output:
        report(L.figure("fields_{quantity}.png"), caption="../report/fields.rst",
               category=CAT_SPECIMEN, subcategory="Fields"),
    log:
        L.log("analysis/figure_fields_{quantity}"),
    benchmark:
        L.benchmark("analysis/figure_fields_{quantity}")
    wildcard_constraints:
        quantity="|".join(FIELD_QUANTITIES),
    params:
        kind="fields",
        settings=ANALYSIS,
        path_label=path_label(VALIDATION),
        reference_label=PLAN.reference_label,
        surrogate_label=PLAN.surrogate_label,
    script:
        "../../scripts/analysis_figure.py"


rule vtk_export:
    input:
        lambda wc: VTK_RUNS[wc.run](wc.path),
    output:
        directory(L.vtk("{run}", "{path}")),
    log:
        L.log("analysis/vtk_{run}_{path}"),
    benchmark:
        L.benchmark("analysis/vtk_{run}_{path}")
    wildcard_constraints:
        run="|".join(VTK_RUNS),
    script:
        "../../scripts/analysis_vtk.py"


rule figure_training_curves:
    input:
        curves=list(TRAINING_CURVES.values()),
    output:
        report(L.figure("training_curves.png"), caption="../report/training_curves.rst",
               category=CAT_TRAINING, subcategory="Loss curves"),
    log:
        L.log("analysis/figure_training_curves"),
    benchmark:
        L.benchmark("analysis/figure_training_curves")
    params:
        kind="training_curves",
        settings=ANALYSIS,
        labels=list(TRAINING_CURVES),
    script:
        "../../scripts/analysis_figure.py"


rule table_speedup:
    input:
        runs=list(TIMING.values()),
    output:
        csv=report(L.table("speedup.csv"), caption="../report/speedup_csv.rst", category=CAT_SPEED,
                   subcategory="Speedup (Table 4)"),
        html=report(L.table("speedup.html"), caption="../report/speedup.rst", category=CAT_SPEED,
                    subcategory="Speedup (Table 4)"),
    log:
        L.log("analysis/table_speedup"),
    benchmark:
        L.benchmark("analysis/table_speedup")
    params:
        kind="speedup",
        path_label=path_label(VALIDATION),
        labels=list(TIMING),
        paper_reference=ANALYSIS["paper_reference"],
    script:
        "../../scripts/analysis_table.py"


rule table_accuracy:
    input:
        runs=list(TIMING.values()),
        **DATASET,
    output:
        csv=report(L.table("accuracy.csv"), caption="../report/accuracy_csv.rst", category=CAT_SPEED,
                   subcategory="Accuracy"),
        html=report(L.table("accuracy.html"), caption="../report/accuracy.rst", category=CAT_SPEED,
                    subcategory="Accuracy"),
    log:
        L.log("analysis/table_accuracy"),
    benchmark:
        L.benchmark("analysis/table_accuracy")
    params:
        kind="accuracy",
        path_label=path_label(VALIDATION),
        labels=list(TIMING),
    script:
        "../../scripts/analysis_table.py"


rule figure_speed_vs_error:
    input:
        speedup=L.table("speedup.csv"),
        accuracy=L.table("accuracy.csv"),
    output:
        report(L.figure("speed_vs_error.png"), caption="../report/speed_vs_error.rst",
               category=CAT_SPEED, subcategory="Speed vs error"),
    log:
        L.log("analysis/figure_speed_vs_error"),
    benchmark:
        L.benchmark("analysis/figure_speed_vs_error")
    params:
        kind="speed_vs_error",
        settings=ANALYSIS,
        curve=PLAN.speed_curve(VALIDATION),
    script:
        "../../scripts/analysis_figure.py"


rule figure_mode_map:
    input:
        runs=list(PLAN.adaptive_runs(VALIDATION).values()),
    output:
        report(L.figure("adaptive_mode_map.png"), caption="../report/mode_map.rst", category=CAT_SPECIMEN,
               subcategory="Adaptive: DEM points"),
    log:
        L.log("analysis/figure_mode_map"),
    benchmark:
        L.benchmark("analysis/figure_mode_map")
    params:
        kind="mode_map",
        settings=ANALYSIS,
        path_label=path_label(VALIDATION),
        labels=list(PLAN.adaptive_runs(VALIDATION)),
    script:
        "../../scripts/analysis_figure.py"


rule table_surrogate_cost:
    input:
        speedup=L.table("speedup.csv"),
        cost_files=[path for _, _, path in PLAN.surrogate_cost_items()],
    output:
        csv=report(L.table("surrogate_cost.csv"), caption="../report/surrogate_cost_csv.rst",
                   category=CAT_SPEED, subcategory="Cost of the surrogate"),
        html=report(L.table("surrogate_cost.html"), caption="../report/surrogate_cost.rst",
                    category=CAT_SPEED, subcategory="Cost of the surrogate"),
    log:
        L.log("analysis/table_surrogate_cost"),
    benchmark:
        L.benchmark("analysis/table_surrogate_cost")
    params:
        kind="surrogate_cost",
        path_label=path_label(VALIDATION),
        cost_items=[(what, how) for what, how, _ in PLAN.surrogate_cost_items()],
        reference_label=PLAN.reference_label,
        surrogate_label=PLAN.surrogate_label,
    script:
        "../../scripts/analysis_table.py"


# The headline numbers (tables/headline.json) and the report's page that states them, with what
# ran, the reference's tolerance and the machine (tables/headline.html, category "0 Headline"):
# the front page (workflow/report/workflow.rst) is rendered from the config alone and points to it.
rule headline:
    input:
        speedup=L.table("speedup.csv"),
        accuracy=L.table("accuracy.csv"),
        cost=L.table("surrogate_cost.csv"),
        reference=PLAN.reference_run(VALIDATION),
    output:
        json=L.table("headline.json"),
        page=report(L.table("headline.html"), caption="../report/headline.rst", category=CAT_HEADLINE,
                    subcategory="Headline numbers"),
    log:
        L.log("analysis/headline"),
    benchmark:
        L.benchmark("analysis/headline")
    params:
        kind="headline",
        reference_label=PLAN.reference_label,
        surrogate_label=PLAN.surrogate_label,
        ablation_label=PLAN.ablation_label,
    script:
        "../../scripts/analysis_table.py"


VALIDATION_CASES = PLAN.validation_cases()


rule validation_tables:
    input:
        runs=[run for path in VALIDATION_CASES for run in PLAN.comparison_runs(path).values()],
    output:
        csv=report(L.table("validation_by_phase.csv"), caption="../report/validation_by_phase_csv.rst",
                   category=CAT_SPEED, subcategory="Validation by load phase"),
        html=report(L.table("validation_by_phase.html"), caption="../report/validation_by_phase.rst",
                    category=CAT_SPEED, subcategory="Validation by load phase"),
    log:
        L.log("analysis/validation_tables"),
    benchmark:
        L.benchmark("analysis/validation_tables")
    params:
        cases=list(VALIDATION_CASES.items()),
        labels=list(COMPARISON),  # the same labels for every path
        reference_label=PLAN.reference_label,
    script:
        "../../scripts/analysis_validation.py"


# the ensemble spread FEM–ML reports (surrogate.ensemble_size) against its realised error: its scale on
# the networks' held-out trajectories, then the calibration of the validation run
rule table_spread_scale:
    input:
        unpack(lambda wc: PLAN.spread_scale_inputs()),
    output:
        csv=report(L.table("spread_scale.csv"), caption="../report/spread_scale.rst",
                   category=CAT_UNCERTAINTY, subcategory="Calibration of the ensemble spread"),
        html=report(L.table("spread_scale.html"), caption="../report/spread_scale.rst",
                    category=CAT_UNCERTAINTY, subcategory="Calibration of the ensemble spread"),
    log:
        L.log("analysis/table_spread_scale"),
    benchmark:
        L.benchmark("analysis/table_spread_scale")
    script:
        "../../scripts/analysis_spread_scale.py"


rule figure_calibration:
    input:
        reference=PLAN.reference_run(VALIDATION),
        surrogate=L.fem_ml(VALIDATION),
        spread_scale=L.table("spread_scale.csv"),
    output:
        figure=report(L.figure("calibration.png"), caption="../report/calibration.rst",
                      category=CAT_UNCERTAINTY, subcategory="Calibration of the ensemble spread"),
        csv=report(L.table("calibration.csv"), caption="../report/calibration_csv.rst",
                   category=CAT_UNCERTAINTY, subcategory="Calibration of the ensemble spread"),
        html=report(L.table("calibration.html"), caption="../report/calibration_table.rst",
                    category=CAT_UNCERTAINTY, subcategory="Calibration of the ensemble spread"),
    log:
        L.log("analysis/figure_calibration"),
    benchmark:
        L.benchmark("analysis/figure_calibration")
    params:
        settings=ANALYSIS,
        path_label=path_label(VALIDATION),
        reference_label=PLAN.reference_label,
        surrogate_label=PLAN.surrogate_label,
    script:
        "../../scripts/analysis_calibration.py"
