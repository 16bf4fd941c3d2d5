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
# (VALIDATION_PATHS: each load path the training did not use) and the training paths, per load phase.
ANALYSIS = config["analysis"]
VALIDATION = config["validation_path"]
TANGENT = config["surrogate"]["tangent"]
DATASET = {"train": f"{OUT}/dataset/train.h5", "heldout": f"{OUT}/dataset/heldout.h5"}
FIELD_QUANTITIES = ["axial_displacement", "shear_strain", "sigma23"]
REFERENCE_LABEL = (
    f"FEM–DEM ({config['dem']['n_spheres']} spheres)"
    if REFERENCE == "fem_dem"
    else "FEM, elastoplastic model (reference)"
)
SURROGATE_LABEL = f"FEM–ML ({TANGENT} tangent)"
OTHER_TANGENT = "autodiff" if TANGENT == "nn" else "nn"
ABLATION_LABEL = "FEM–ML, no history"


def path_label(path):
    return path[:1].upper() + path[1:]


def comparison_runs(path):
    """Ordered {label: run file} of the accuracy products: reference first."""
    return {
        REFERENCE_LABEL: reference_run(path),
        SURROGATE_LABEL: f"{OUT}/fem_ml/{path}.h5",
        ABLATION_LABEL: f"{OUT}/fem_ml_nohist/{path}.h5",
    }


def timing_runs(path):
    """The comparison runs, FEM–ML with the other tangent (the surrogate stage runs both on the
    validation path), and FEM–DEM at the other configured sphere counts (DEM reference only)."""
    runs = comparison_runs(path)
    ablation = runs.pop(ABLATION_LABEL)
    runs[f"FEM–ML ({OTHER_TANGENT} tangent)"] = f"{OUT}/fem_ml_{OTHER_TANGENT}/{path}.h5"
    runs[ABLATION_LABEL] = ablation
    if REFERENCE == "fem_dem":
        for n in ANALYSIS["fem_dem_sphere_counts"]:
            if n != config["dem"]["n_spheres"]:
                runs[f"FEM–DEM ({n} spheres)"] = f"{OUT}/fem_dem_n{n}/{path}.h5"
    if ADAPTIVE_IN_REPORT:
        runs.update(adaptive_runs(path))
    return runs


def speed_curve(path):
    """Labels the speed-vs-error figure joins by a line: FEM–ML, the adaptive runs, the reference."""
    return [SURROGATE_LABEL, *adaptive_runs(path), REFERENCE_LABEL] if ADAPTIVE_IN_REPORT else []


def stress_strain_names():
    explicit = ANALYSIS["stress_strain_gauss_points"]
    return [f"gp{g}" for g in explicit] if explicit else list(ANALYSIS["stress_strain_points"])


TRAINING_CURVES = {
    "NNσ|with history": f"{OUT}/training/sigma.csv",
    "ND|with history": f"{OUT}/training/tangent.csv",
    "NNσ|no history": f"{OUT}/training/sigma_nohist.csv",
    "ND|no history": f"{OUT}/training/tangent_nohist.csv",
}

CAT_GP = "1 Gauss points"
CAT_SPECIMEN = "2 Specimen"
CAT_SPEED = "3 Speed and accuracy"
CAT_TRAINING = "4 Training"
CAT_UNCERTAINTY = "6 Uncertainty"


rule figure_error_map:
    input:
        reference=reference_run(VALIDATION),
        surrogate=f"{OUT}/fem_ml/{VALIDATION}.h5",
        **DATASET,
    output:
        report(f"{OUT}/figures/error_map.png", caption="../report/error_map.rst", category=CAT_GP,
               subcategory="Error map"),
    log:
        f"{OUT}/logs/analysis/figure_error_map.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/figure_error_map.tsv"
    params:
        kind="error_map",
        settings=ANALYSIS,
        path_label=path_label(VALIDATION),
        reference_label=REFERENCE_LABEL,
        surrogate_label=SURROGATE_LABEL,
    script:
        "../../scripts/analysis_figure.py"


rule figure_stress_strain:
    input:
        runs=list(comparison_runs(VALIDATION).values()),
        **DATASET,
    output:
        [
            report(f"{OUT}/figures/stress_strain_{name}.png", caption="../report/stress_strain.rst",
                   category=CAT_GP, subcategory="Stress–strain at held-out points")
            for name in stress_strain_names()
        ],
    log:
        f"{OUT}/logs/analysis/figure_stress_strain.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/figure_stress_strain.tsv"
    params:
        kind="stress_strain",
        settings=ANALYSIS,
        path_label=path_label(VALIDATION),
        labels=list(comparison_runs(VALIDATION)),
        points=stress_strain_names(),
    script:
        "../../scripts/analysis_figure.py"


rule figure_global_response:
    input:
        runs=list(comparison_runs(VALIDATION).values()),
    output:
        report(f"{OUT}/figures/top_force_volumetric_strain.png", caption="../report/global_response.rst",
               category=CAT_SPECIMEN, subcategory="Top force and volumetric strain"),
    log:
        f"{OUT}/logs/analysis/figure_global_response.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/figure_global_response.tsv"
    params:
        kind="global_response",
        settings=ANALYSIS,
        path_label=path_label(VALIDATION),
        labels=list(comparison_runs(VALIDATION)),
    script:
        "../../scripts/analysis_figure.py"


rule figure_fields:
    input:
        reference=reference_run(VALIDATION),
        surrogate=f"{OUT}/fem_ml/{VALIDATION}.h5",
    output:
        report(f"{OUT}/figures/fields_{{quantity}}.png", caption="../report/fields.rst",
               category=CAT_SPECIMEN, subcategory="Fields"),
    log:
        f"{OUT}/logs/analysis/figure_fields_{{quantity}}.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/figure_fields_{{quantity}}.tsv"
    wildcard_constraints:
        quantity="|".join(FIELD_QUANTITIES),
    params:
        kind="fields",
        settings=ANALYSIS,
        path_label=path_label(VALIDATION),
        reference_label=REFERENCE_LABEL,
        surrogate_label=SURROGATE_LABEL,
    script:
        "../../scripts/analysis_figure.py"


VTK_RUNS = {"reference": reference_run, "fem_ml": lambda path: f"{OUT}/fem_ml/{path}.h5"}


rule vtk_export:
    input:
        lambda wc: VTK_RUNS[wc.run](wc.path),
    output:
        directory(f"{OUT}/vtk/{{run}}/{{path}}"),
    log:
        f"{OUT}/logs/analysis/vtk_{{run}}_{{path}}.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/vtk_{{run}}_{{path}}.tsv"
    wildcard_constraints:
        run="|".join(VTK_RUNS),
    script:
        "../../scripts/analysis_vtk.py"


rule figure_training_curves:
    input:
        curves=list(TRAINING_CURVES.values()),
    output:
        report(f"{OUT}/figures/training_curves.png", caption="../report/training_curves.rst",
               category=CAT_TRAINING, subcategory="Loss curves"),
    log:
        f"{OUT}/logs/analysis/figure_training_curves.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/figure_training_curves.tsv"
    params:
        kind="training_curves",
        settings=ANALYSIS,
        labels=list(TRAINING_CURVES),
    script:
        "../../scripts/analysis_figure.py"


rule table_speedup:
    input:
        runs=list(timing_runs(VALIDATION).values()),
    output:
        csv=report(f"{OUT}/tables/speedup.csv", caption="../report/speedup_csv.rst", category=CAT_SPEED,
                   subcategory="Speedup (Table 4)"),
        html=report(f"{OUT}/tables/speedup.html", caption="../report/speedup.rst", category=CAT_SPEED,
                    subcategory="Speedup (Table 4)"),
    log:
        f"{OUT}/logs/analysis/table_speedup.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/table_speedup.tsv"
    params:
        kind="speedup",
        path_label=path_label(VALIDATION),
        labels=list(timing_runs(VALIDATION)),
        paper_reference=ANALYSIS["paper_reference"],
    script:
        "../../scripts/analysis_table.py"


rule table_accuracy:
    input:
        runs=list(timing_runs(VALIDATION).values()),
        **DATASET,
    output:
        csv=report(f"{OUT}/tables/accuracy.csv", caption="../report/accuracy_csv.rst", category=CAT_SPEED,
                   subcategory="Accuracy"),
        html=report(f"{OUT}/tables/accuracy.html", caption="../report/accuracy.rst", category=CAT_SPEED,
                    subcategory="Accuracy"),
    log:
        f"{OUT}/logs/analysis/table_accuracy.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/table_accuracy.tsv"
    params:
        kind="accuracy",
        path_label=path_label(VALIDATION),
        labels=list(timing_runs(VALIDATION)),
    script:
        "../../scripts/analysis_table.py"


rule figure_speed_vs_error:
    input:
        speedup=f"{OUT}/tables/speedup.csv",
        accuracy=f"{OUT}/tables/accuracy.csv",
    output:
        report(f"{OUT}/figures/speed_vs_error.png", caption="../report/speed_vs_error.rst",
               category=CAT_SPEED, subcategory="Speed vs error"),
    log:
        f"{OUT}/logs/analysis/figure_speed_vs_error.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/figure_speed_vs_error.tsv"
    params:
        kind="speed_vs_error",
        settings=ANALYSIS,
        curve=speed_curve(VALIDATION),
    script:
        "../../scripts/analysis_figure.py"


rule figure_mode_map:
    input:
        runs=list(adaptive_runs(VALIDATION).values()),
    output:
        report(f"{OUT}/figures/adaptive_mode_map.png", caption="../report/mode_map.rst", category=CAT_SPECIMEN,
               subcategory="Adaptive: DEM points"),
    log:
        f"{OUT}/logs/analysis/figure_mode_map.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/figure_mode_map.tsv"
    params:
        kind="mode_map",
        settings=ANALYSIS,
        path_label=path_label(VALIDATION),
        labels=list(adaptive_runs(VALIDATION)),
    script:
        "../../scripts/analysis_figure.py"


def surrogate_cost_items():
    """(what, how to read it, file) of each step that makes the surrogate the FEM–ML runs use:
    the RVE packings (DEM), every training source (the reference runs of the training paths, the
    RVE-path sets), the dataset and the two networks of rule fem_ml (the no-history ablation is not
    part of the answer)."""
    reference = "FEM–DEM" if REFERENCE == "fem_dem" else "elastoplastic model (stands in for FEM–DEM)"
    items = []
    if REFERENCE == "fem_dem":
        items.append(("RVE preparation (YADE packings)", "rve_summary", f"{OUT}/rve/summary.json"))
    items += [(f"reference run of {path_label(path)}, {reference} (training data)", "run", reference_run(path))
              for path in TRAINING_RUN_PATHS]
    items += [(f"RVE paths '{name}' (rule rve_paths, training data)", "benchmark", f"{OUT}/benchmarks/rve_paths/{name}.tsv")
              for name in TRAINING_RVE_SETS]
    items += [
        ("dataset (rule dataset)", "benchmark", f"{OUT}/benchmarks/surrogate/dataset.tsv"),
        ("training NNσ (rule train_sigma)", "benchmark", f"{OUT}/benchmarks/surrogate/train_sigma.tsv"),
        ("training ND (rule train_tangent)", "benchmark", f"{OUT}/benchmarks/surrogate/train_tangent.tsv"),
    ]
    return items


rule table_surrogate_cost:
    input:
        speedup=f"{OUT}/tables/speedup.csv",
        cost_files=[path for _, _, path in surrogate_cost_items()],
    output:
        csv=report(f"{OUT}/tables/surrogate_cost.csv", caption="../report/surrogate_cost_csv.rst",
                   category=CAT_SPEED, subcategory="Cost of the surrogate"),
        html=report(f"{OUT}/tables/surrogate_cost.html", caption="../report/surrogate_cost.rst",
                    category=CAT_SPEED, subcategory="Cost of the surrogate"),
    log:
        f"{OUT}/logs/analysis/table_surrogate_cost.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/table_surrogate_cost.tsv"
    params:
        kind="surrogate_cost",
        path_label=path_label(VALIDATION),
        cost_items=[(what, how) for what, how, _ in surrogate_cost_items()],
        reference_label=REFERENCE_LABEL,
        surrogate_label=SURROGATE_LABEL,
    script:
        "../../scripts/analysis_table.py"


rule headline:
    input:
        speedup=f"{OUT}/tables/speedup.csv",
        accuracy=f"{OUT}/tables/accuracy.csv",
        cost=f"{OUT}/tables/surrogate_cost.csv",
        reference=reference_run(VALIDATION),
    output:
        f"{OUT}/tables/headline.json",
    log:
        f"{OUT}/logs/analysis/headline.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/headline.tsv"
    params:
        kind="headline",
        reference_label=REFERENCE_LABEL,
        surrogate_label=SURROGATE_LABEL,
        ablation_label=ABLATION_LABEL,
    script:
        "../../scripts/analysis_table.py"


# every validation path (the training did not use it), then the training run paths (in-sample)
VALIDATION_CASES = {
    **{p: "validation path" for p in VALIDATION_PATHS},
    **{p: "training path" for p in TRAINING_RUN_PATHS if p not in VALIDATION_PATHS},
}


rule validation_tables:
    input:
        runs=[run for path in VALIDATION_CASES for run in comparison_runs(path).values()],
    output:
        csv=report(f"{OUT}/tables/validation_by_phase.csv", caption="../report/validation_by_phase_csv.rst",
                   category=CAT_SPEED, subcategory="Validation by load phase"),
        html=report(f"{OUT}/tables/validation_by_phase.html", caption="../report/validation_by_phase.rst",
                    category=CAT_SPEED, subcategory="Validation by load phase"),
    log:
        f"{OUT}/logs/analysis/validation_tables.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/validation_tables.tsv"
    params:
        cases=list(VALIDATION_CASES.items()),
        labels=list(comparison_runs(VALIDATION)),  # the same labels for every path
        reference_label=REFERENCE_LABEL,
    script:
        "../../scripts/analysis_validation.py"


# the ensemble spread FEM–ML reports (surrogate.ensemble_size) against its realised error
rule figure_calibration:
    input:
        reference=reference_run(VALIDATION),
        surrogate=f"{OUT}/fem_ml/{VALIDATION}.h5",
    output:
        figure=report(f"{OUT}/figures/calibration.png", caption="../report/calibration.rst",
                      category=CAT_UNCERTAINTY, subcategory="Calibration of the ensemble spread"),
        csv=report(f"{OUT}/tables/calibration.csv", caption="../report/calibration_csv.rst",
                   category=CAT_UNCERTAINTY, subcategory="Calibration of the ensemble spread"),
        html=report(f"{OUT}/tables/calibration.html", caption="../report/calibration_table.rst",
                    category=CAT_UNCERTAINTY, subcategory="Calibration of the ensemble spread"),
    log:
        f"{OUT}/logs/analysis/figure_calibration.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/figure_calibration.tsv"
    params:
        settings=ANALYSIS,
        path_label=path_label(VALIDATION),
        reference_label=REFERENCE_LABEL,
        surrogate_label=SURROGATE_LABEL,
    script:
        "../../scripts/analysis_calibration.py"


ANALYSIS_TARGETS = [
    f"{OUT}/figures/error_map.png",
    *[f"{OUT}/figures/stress_strain_{name}.png" for name in stress_strain_names()],
    f"{OUT}/figures/top_force_volumetric_strain.png",
    *[f"{OUT}/figures/fields_{q}.png" for q in FIELD_QUANTITIES],
    *[f"{OUT}/vtk/{run}/{VALIDATION}" for run in VTK_RUNS],
    f"{OUT}/figures/training_curves.png",
    f"{OUT}/tables/speedup.csv",
    f"{OUT}/tables/accuracy.csv",
    f"{OUT}/tables/surrogate_cost.csv",
    f"{OUT}/figures/speed_vs_error.png",
    f"{OUT}/tables/headline.json",
    f"{OUT}/tables/validation_by_phase.csv",
]
ALL_TARGETS += ANALYSIS_TARGETS
if ADAPTIVE_IN_REPORT:
    ALL_TARGETS += [f"{OUT}/figures/adaptive_mode_map.png"]
ALL_TARGETS += [f"{OUT}/figures/calibration.png", f"{OUT}/tables/calibration.csv", f"{OUT}/tables/calibration.html"]


# The report's front page (workflow/report/workflow.rst) states the headline numbers. Its
# template sees only the config, so the numbers of tables/headline.json go under
# config["headline"]:
#   * when the workflow is loaded, if the file exists: `snakemake --report`, the API's
#     create_report and any other way of building the report from a finished run;
#   * again after a successful run (onsuccess), so that `--report-after-run` states the numbers
#     this run has just written, not those of an earlier run (or none, on a fresh run).
# Jobs never depend on it: no rule's params or input holds it (so it never makes a rule rerun),
# onstart (Snakefile) takes it out of the config before the first job, and validate_config drops it (a job
# that reloads the workflow, on a cluster or with --nohooks, validates its config).
HEADLINE_FILE = f"{OUT}/tables/headline.json"


def show_headline():
    from granular_multiscale.analysis.products import read_headline

    try:  # with the reference's own error when the tolerance study has run
        headline = read_headline(HEADLINE_FILE, tolerance_study=f"{OUT}/tables/tolerance_study.csv")
    except (ValueError, OSError) as error:  # a damaged file must not stop the workflow that rebuilds it
        from snakemake.logging import logger

        logger.warning(f"{error}: the report's front page will lack the headline numbers")
        headline = None
    if headline is None:
        config.pop("headline", None)
    else:
        config["headline"] = headline


show_headline()

