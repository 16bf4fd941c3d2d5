# Problems beyond the triaxial specimen (config key `problems`: biaxial, footing), each with the
# reference material at its Gauss points, run by `all` beside the triaxial pipeline:
#
#   rve_weak           {OUT}/rve/packing_weak.yade.gz: the packing of rule rve (seed `seed`) with its
#                      interparticle friction restored to biaxial.weak_zone.dem_friction
#   problem_fem_dem    {OUT}/{problem}/fem_dem/{case}.h5 for each load path {case} of the problem's
#                      section; checkpoint under {OUT}/checkpoints/{problem}/
#   problem_fem_elastoplastic   the same with the analytic model (reference_material: elastoplastic)
#   element_test       {OUT}/element_tests/{reference}/{test}.h5: one RVE (uniform field) in triaxial
#                      and in plane-strain compression, for its friction and dilatancy angles
#   table_rve_angles, figure_problem_response, figure_problem_fields, table_bands, table_footing,
#   vtk_problem        what the report shows of each problem
#   biaxial_mesh_study (not in `all`) the biaxial test's first load path on the meshes of
#                      analysis.biaxial_meshes ({OUT}/biaxial_mesh/; the configured mesh's run is reused)

from granular_multiscale.plan import ELEMENT_TESTS, PROBLEM_LABEL

PROBLEM_CASES = PLAN.problem_cases
CAT_PROBLEMS = "7 Problems beyond the triaxial specimen"
WEAK_ZONE = config["biaxial"]["weak_zone"]


wildcard_constraints:
    problem="|".join(PLAN.problems) or "no-problem",
    case="|".join(sorted({c for cases in PROBLEM_CASES.values() for c in cases})) or "no-case",
    test="|".join(ELEMENT_TESTS),


use rule rve as rve_weak with:
    output:
        packings=[L.weak_packing()],
        summary=L.weak_packing_summary(),
    params:
        dem=PLAN.packing_definition,
        pressure=config["specimen"]["confining_pressure"],
        seed=config["seed"],
        friction=WEAK_ZONE["dem_friction"] if WEAK_ZONE else None,
    log:
        L.log("rve_weak"),
    benchmark:
        L.benchmark("rve_weak")
    threads: 1


use rule fem_dem as problem_fem_dem with:
    input:
        packings=PLAN.packings,
        weak_packing=lambda wc: PLAN.weak_packing_input(wc.problem),
    output:
        L.problem_run("{problem}", "fem_dem", "{case}"),
    log:
        L.log("{problem}/fem_dem/{case}"),
    benchmark:
        L.benchmark("{problem}/fem_dem/{case}")
    params:
        checkpoint=L.checkpoint("{problem}/fem_dem/{case}"),
        definition=lambda wc: PLAN.problem_definition(wc.problem),
        problem=lambda wc: wc.problem,
        path_name=lambda wc: wc.case,
        path=None,  # (rule fem_dem's triaxial path; the problem's is in definition)


use rule fem_elastoplastic as problem_fem_elastoplastic with:
    output:
        L.problem_run("{problem}", "fem_elastoplastic", "{case}"),
    log:
        L.log("{problem}/fem_elastoplastic/{case}"),
    benchmark:
        L.benchmark("{problem}/fem_elastoplastic/{case}")
    params:
        model=lambda wc: PLAN.analytic_problem_definition(wc.problem),
        problem=lambda wc: wc.problem,
        path_name=lambda wc: wc.case,


use rule fem_dem as element_test_fem_dem with:
    input:
        packings=PLAN.packings,
    output:
        L.element_test("fem_dem", "{test}"),
    log:
        L.log("element_tests/fem_dem/{test}"),
    benchmark:
        L.benchmark("element_tests/fem_dem/{test}")
    params:
        checkpoint=L.checkpoint("element_tests/fem_dem/{test}"),
        overrides=lambda wc: PLAN.element_test_overrides(wc.test),
        definition=PLAN.run_definition,
        problem=lambda wc: wc.test,
        path_name="element",
        path=None,
    threads: 1


use rule fem_elastoplastic as element_test_fem_elastoplastic with:
    output:
        L.element_test("fem_elastoplastic", "{test}"),
    log:
        L.log("element_tests/fem_elastoplastic/{test}"),
    benchmark:
        L.benchmark("element_tests/fem_elastoplastic/{test}")
    params:
        overrides=lambda wc: PLAN.element_test_overrides(wc.test),
        model=config["elastoplastic"],
        problem=lambda wc: wc.test,
        path_name="element",


ELEMENT_RUNS = PLAN.element_runs()


rule table_rve_angles:
    input:
        runs=list(ELEMENT_RUNS.values()),
    output:
        csv=report(L.table("rve_angles.csv"), caption="../report/rve_angles.rst", category=CAT_PROBLEMS,
                   subcategory="The RVE's friction and dilatancy angles"),
        html=report(L.table("rve_angles.html"), caption="../report/rve_angles.rst", category=CAT_PROBLEMS,
                    subcategory="The RVE's friction and dilatancy angles"),
    log:
        L.log("analysis/table_rve_angles"),
    benchmark:
        L.benchmark("analysis/table_rve_angles")
    params:
        kind="angles",
        labels=list(ELEMENT_RUNS),
    script:
        "../../scripts/problem_products.py"


rule figure_problem_response:
    input:
        runs=lambda wc: [PLAN.problem_run(wc.problem, c) for c in PROBLEM_CASES[wc.problem]],
    output:
        report(L.figure("{problem}/response.png"), caption="../report/problem_response.rst",
               category=CAT_PROBLEMS, subcategory="{problem}"),
    log:
        L.log("analysis/{problem}/figure_response"),
    benchmark:
        L.benchmark("analysis/{problem}/figure_response")
    params:
        kind="response",
        labels=lambda wc: [f"{PLAN.reference_label}, {c}" for c in PROBLEM_CASES[wc.problem]],
        title=lambda wc: f"{PROBLEM_LABEL[wc.problem]}: force against displacement",
        settings=config["analysis"],
    script:
        "../../scripts/problem_products.py"


rule figure_problem_fields:
    input:
        run=lambda wc: PLAN.problem_run(wc.problem, wc.case),
    output:
        report(L.figure("{problem}/fields_{case}.png"), caption="../report/problem_fields.rst",
               category=CAT_PROBLEMS, subcategory="{problem}"),
    log:
        L.log("analysis/{problem}/figure_fields_{case}"),
    benchmark:
        L.benchmark("analysis/{problem}/figure_fields_{case}")
    params:
        kind="fields",
        title=lambda wc: f"{PROBLEM_LABEL[wc.problem]}, {PLAN.reference_label}, path {wc.case}",
        settings=config["analysis"],
    script:
        "../../scripts/problem_products.py"


rule table_bands:
    input:
        runs=[PLAN.problem_run("biaxial", c) for c in config["biaxial"]["load_paths"]],
        angles=L.table("rve_angles.csv"),
    output:
        csv=report(L.table("biaxial_bands.csv"), caption="../report/bands.rst", category=CAT_PROBLEMS,
                   subcategory="biaxial"),
        html=report(L.table("biaxial_bands.html"), caption="../report/bands.rst", category=CAT_PROBLEMS,
                    subcategory="biaxial"),
    log:
        L.log("analysis/table_bands"),
    benchmark:
        L.benchmark("analysis/table_bands")
    params:
        kind="bands",
        labels=list(config["biaxial"]["load_paths"]),
        grain_diameter=0.5 * (config["dem"]["diameter_min"] + config["dem"]["diameter_max"]),
    script:
        "../../scripts/problem_products.py"


rule table_footing:
    input:
        runs=[PLAN.problem_run("footing", c) for c in config["footing"]["load_paths"]],
        angles=L.table("rve_angles.csv"),
    output:
        csv=report(L.table("footing.csv"), caption="../report/footing.rst", category=CAT_PROBLEMS,
                   subcategory="footing"),
        html=report(L.table("footing.html"), caption="../report/footing.rst", category=CAT_PROBLEMS,
                    subcategory="footing"),
    log:
        L.log("analysis/table_footing"),
    benchmark:
        L.benchmark("analysis/table_footing")
    params:
        kind="footing",
        labels=list(config["footing"]["load_paths"]),
    script:
        "../../scripts/problem_products.py"


rule vtk_problem:
    input:
        lambda wc: PLAN.problem_run(wc.problem, wc.case),
    output:
        directory(L.vtk("{problem}", "{case}")),
    log:
        L.log("analysis/vtk_{problem}_{case}"),
    benchmark:
        L.benchmark("analysis/vtk_{problem}_{case}")
    params:
        stem=lambda wc: f"{wc.problem}_{wc.case}",
    script:
        "../../scripts/analysis_vtk.py"


use rule problem_fem_dem as biaxial_mesh_fem_dem with:
    input:
        packings=PLAN.packings,
        weak_packing=PLAN.weak_packing_input("biaxial"),
    output:
        L.biaxial_mesh_run("fem_dem", "{mesh}"),
    log:
        L.log("biaxial_mesh/fem_dem/{mesh}"),
    benchmark:
        L.benchmark("biaxial_mesh/fem_dem/{mesh}")
    params:
        checkpoint=L.checkpoint("biaxial_mesh/fem_dem/{mesh}"),
        definition=lambda wc: PLAN.problem_definition("biaxial"),
        overrides=lambda wc: {"biaxial": {**PLAN.problem_section("biaxial"), "elements": [int(v) for v in wc.mesh.split("x")]}},
        problem="biaxial",
        path_name=lambda wc: list(config["biaxial"]["load_paths"])[0],
    wildcard_constraints:
        mesh=r"\d+x\d+",


use rule problem_fem_elastoplastic as biaxial_mesh_fem_elastoplastic with:
    output:
        L.biaxial_mesh_run("fem_elastoplastic", "{mesh}"),
    log:
        L.log("biaxial_mesh/fem_elastoplastic/{mesh}"),
    benchmark:
        L.benchmark("biaxial_mesh/fem_elastoplastic/{mesh}")
    params:
        model=lambda wc: PLAN.analytic_problem_definition("biaxial"),
        overrides=lambda wc: {"biaxial": {**PLAN.problem_section("biaxial"), "elements": [int(v) for v in wc.mesh.split("x")]}},
        problem="biaxial",
        path_name=lambda wc: list(config["biaxial"]["load_paths"])[0],
    wildcard_constraints:
        mesh=r"\d+x\d+",


rule biaxial_mesh_study:
    input:
        runs=[PLAN.biaxial_mesh_run(m) for m in PLAN.biaxial_meshes],
    output:
        csv=report(L.table("biaxial_mesh_study.csv"), caption="../report/mesh_study.rst",
                   category=CAT_PROBLEMS, subcategory="biaxial"),
        html=report(L.table("biaxial_mesh_study.html"), caption="../report/mesh_study.rst",
                    category=CAT_PROBLEMS, subcategory="biaxial"),
        figure=report(L.figure("biaxial/mesh_study.png"), caption="../report/mesh_study.rst",
                      category=CAT_PROBLEMS, subcategory="biaxial"),
    log:
        L.log("analysis/biaxial_mesh_study"),
    benchmark:
        L.benchmark("analysis/biaxial_mesh_study")
    params:
        kind="mesh_study",
        labels=[f"{PLAN.reference_label}, {m}" for m in PLAN.biaxial_meshes],
        settings=config["analysis"],
    script:
        "../../scripts/problem_products.py"
