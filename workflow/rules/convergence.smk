# The FEM–DEM reference's own numerical error (config section tolerance_study; not part of
# `all`, run on purpose):
#
#   snakemake -j2 tolerance_study          the runs, then tables/tolerance_study.{csv,html},
#                                          figures/tolerance_study.png and
#                                          tables/reference_convergence.html
#   snakemake --report {output_dir}/report.html all tolerance_study     the report with them
#
#   fem_dem_variant  {OUT}/tolerance_study/{variant}/{path}.h5: the fem_dem rule with the
#                    variant's Newton settings in place of the dem.newton keys it names

from granular_multiscale.plan import path_label

STUDY = config["tolerance_study"]
CAT_REFERENCE = "5 Reference"


use rule fem_dem as fem_dem_variant with:
    output:
        L.tolerance_run("{variant}", "{path}"),
    log:
        L.log("tolerance_study/{variant}/{path}"),
    benchmark:
        L.benchmark("tolerance_study/{variant}/{path}")
    params:
        checkpoint=L.checkpoint("tolerance_study/{variant}/{path}"),
        dem=lambda wildcards: PLAN.study_dem(wildcards.variant),
        specimen=config["specimen"],
        newton=config["newton"],
        path=lambda wildcards: config["load_paths"][wildcards.path],
        dem_newton=lambda wildcards: STUDY["variants"][wildcards.variant],
    wildcard_constraints:
        variant="|".join(STUDY["variants"]),


rule tolerance_study:
    input:
        # a variant solved like the reference is the reference run (Plan.study_run)
        runs=[PLAN.study_run(v) for v in STUDY["variants"]],
    output:
        csv=report(L.table("tolerance_study.csv"), caption="../report/tolerance_study_csv.rst",
                   category=CAT_REFERENCE, subcategory="Tolerance study"),
        html=report(L.table("tolerance_study.html"), caption="../report/tolerance_study.rst",
                    category=CAT_REFERENCE, subcategory="Tolerance study"),
        figure=report(L.figure("tolerance_study.png"), caption="../report/tolerance_study_figure.rst",
                      category=CAT_REFERENCE, subcategory="Tolerance study"),
        # The reference's own error, beside the headline numbers. The headline job (in `all`)
        # cannot state it: the study is not part of `all` and no rule reads result files while
        # the workflow loads. So this job, which has the study's table, writes it as a page of
        # "0 Headline"; a report built with the study (`--report … all tolerance_study`) has it.
        convergence=report(L.table("reference_convergence.html"), caption="../report/reference_convergence.rst",
                           category="0 Headline", subcategory="Reference convergence"),
    log:
        L.log("analysis/tolerance_study"),
    benchmark:
        L.benchmark("analysis/tolerance_study")
    params:
        variants=STUDY["variants"],
        converged=STUDY["converged"],
        baseline=STUDY["baseline"],
        path_label=path_label(STUDY["path"]),
        settings=config["analysis"],
        dem_newton=PLAN.reference_newton,
        reference_material=config["reference_material"],
    script:
        "../../scripts/tolerance_study.py"
