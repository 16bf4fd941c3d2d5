# The FEM–DEM reference's own numerical error (config section tolerance_study; not part of
# `all`, run on purpose):
#
#   snakemake -j2 tolerance_study          the runs, then tables/tolerance_study.{csv,html}
#                                          and figures/tolerance_study.png
#   snakemake --report {output_dir}/report.html all tolerance_study     the report with them
#
#   fem_dem_variant  {OUT}/tolerance_study/{variant}/{path}.h5: the fem_dem rule with the
#                    variant's Newton settings in place of the dem.newton keys it names

STUDY = config["tolerance_study"]
CAT_REFERENCE = "5 Reference"


def study_dem(variant):
    """The dem section of a study run: dem.newton with the variant's settings."""
    return {**RUN_DEFINITION, "newton": {**config["dem"]["newton"], **STUDY["variants"][variant]}}


use rule fem_dem as fem_dem_variant with:
    output:
        f"{OUT}/tolerance_study/{{variant}}/{{path}}.h5",
    log:
        f"{OUT}/logs/tolerance_study/{{variant}}/{{path}}.log",
    benchmark:
        f"{OUT}/benchmarks/tolerance_study/{{variant}}/{{path}}.tsv"
    params:
        checkpoint=f"{OUT}/checkpoints/tolerance_study/{{variant}}/{{path}}.ckpt",
        dem=lambda wildcards: study_dem(wildcards.variant),
        specimen=config["specimen"],
        newton=config["newton"],
        path=lambda wildcards: config["load_paths"][wildcards.path],
        dem_newton=lambda wildcards: STUDY["variants"][wildcards.variant],
    wildcard_constraints:
        variant="|".join(STUDY["variants"]),


rule tolerance_study:
    input:
        runs=[f"{OUT}/tolerance_study/{v}/{STUDY['path']}.h5" for v in STUDY["variants"]],
    output:
        csv=report(f"{OUT}/tables/tolerance_study.csv", caption="../report/tolerance_study_csv.rst",
                   category=CAT_REFERENCE, subcategory="Tolerance study"),
        html=report(f"{OUT}/tables/tolerance_study.html", caption="../report/tolerance_study.rst",
                    category=CAT_REFERENCE, subcategory="Tolerance study"),
        figure=report(f"{OUT}/figures/tolerance_study.png", caption="../report/tolerance_study_figure.rst",
                      category=CAT_REFERENCE, subcategory="Tolerance study"),
    log:
        f"{OUT}/logs/analysis/tolerance_study.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/tolerance_study.tsv"
    params:
        variants=STUDY["variants"],
        converged=STUDY["converged"],
        baseline=STUDY["baseline"],
        path_label=STUDY["path"][:1].upper() + STUDY["path"][1:],
        settings=config["analysis"],
    script:
        "../../scripts/tolerance_study.py"
