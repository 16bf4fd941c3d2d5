# The surrogate on the problems beyond the triaxial specimen, with the pipeline's networks (trained
# on triaxial and RVE-path data only: the problems' own runs validate, docs/problems.md):
#
#   problem_fem_ml            {OUT}/{problem}/fem_ml/{case}.h5: FEM–ML (the weak zone's networks at the
#                             biaxial test's weak zone, with surrogate.weak_zone_sources); a run that
#                             stops keeps its converged steps (completed = 0) and the table says
#                             where it stopped
#   problem_fem_ml_as_reference  {OUT}/{problem}/fem_ml_as_reference/{case}.h5: FEM–ML solved as the reference
#                             is: its Newton settings (tolerance, predictor, acceleration) and ND, the
#                             network of the reference's own tangent (FEM–DEM: contact stiffness)
#   problem_fem_ml_driven     {OUT}/{problem}/fem_ml_driven/{case}.h5: the same networks driven along the
#                             reference run's strain histories, no FEM: the material's share of FEM–ML's
#                             error (its force from the networks' stresses in virtual work)
#   problem_adaptive          {OUT}/{problem}/adaptive/{case}.h5 (the problem's section, key adaptive:
#                             threshold, indicator, ...; the weak zone's points are anchors) and its DEM
#                             answers under dem_points/
#   problem_adaptive_control  {OUT}/{problem}/control_{control}/{case}.h5 for each model of
#                             adaptive.controls: the networks replaced by that analytic model, the DEM
#                             points and their promotion steps copied from problem_adaptive's run
#   problem_surrogate_products  tables/{problem}/surrogate_{case}.{csv,html} and the figures
#                             {problem}/surrogate_response_{case}.png, {problem}/error_map_{case}.png:
#                             every run against the reference (force, volumetric strain, band, stress
#                             error inside and outside the band or under the footing, DEM share, time)
#   problem_calibration       {problem}/calibration_{case}.png, tables/{problem}/calibration_{case}.{csv,html}:
#                             FEM–ML's ensemble spread against its error per spread decile (as
#                             figure_calibration on the validation path)
#   table_visited_states      tables/visited_states.{csv,html}: the range of states (p, q, Lode angle,
#                             principal-axis rotation, strains) of the training sources and of each
#                             problem's reference run, and the share of its states off the networks'
#                             training data (k-nearest-neighbour distance in their inputs)
#   problem_adaptive_runs     every problem's adaptive run and its controls (in `all` with
#                             adaptive.problems, adaptive.report and a DEM reference)

CAT_PROBLEMS_SURROGATE = "8 The surrogate on the problems"


use rule fem_ml as problem_fem_ml with:
    input:
        # the biaxial test's weak zone gets its own networks where surrogate.weak_zone_sources trains them
        unpack(lambda wc: PLAN.fem_ml_models(problem=wc.problem)),
    output:
        L.problem_run("{problem}", "fem_ml", "{case}"),
    log:
        L.log("{problem}/fem_ml/{case}"),
    benchmark:
        L.benchmark("{problem}/fem_ml/{case}")
    params:
        tangent=config["surrogate"]["tangent"],
        depends=lambda wc: PLAN.problem_surrogate_definition(wc.problem),
        allow_partial=True,
        problem=lambda wc: wc.problem,
        path_name=lambda wc: wc.case,


use rule problem_fem_ml as problem_fem_ml_as_reference with:
    input:
        unpack(lambda wc: PLAN.fem_ml_models(problem=wc.problem, tangent="nn")),
    output:
        L.problem_run("{problem}", "fem_ml_as_reference", "{case}"),
    log:
        L.log("{problem}/fem_ml_as_reference/{case}"),
    benchmark:
        L.benchmark("{problem}/fem_ml_as_reference/{case}")
    params:
        tangent="nn",
        solver="reference",
        depends=lambda wc: {**PLAN.problem_surrogate_definition(wc.problem),
                            "reference_newton": reference_newton_config(config, wc.problem)["newton"]},
        allow_partial=True,
        problem=lambda wc: wc.problem,
        path_name=lambda wc: wc.case,


rule problem_fem_ml_driven:
    input:
        unpack(lambda wc: {"reference": PLAN.problem_run(wc.problem, wc.case),
                           **PLAN.fem_ml_models(problem=wc.problem)}),
    output:
        L.problem_run("{problem}", "fem_ml_driven", "{case}"),
    log:
        L.log("{problem}/fem_ml_driven/{case}"),
    benchmark:
        L.benchmark("{problem}/fem_ml_driven/{case}")
    params:
        tangent=config["surrogate"]["tangent"],
        depends=lambda wc: PLAN.problem_surrogate_definition(wc.problem),
    threads: SURROGATE_THREADS
    script:
        "../../scripts/run_fem_ml_driven.py"


use rule adaptive as problem_adaptive with:
    input:
        packings=PLAN.packings,
        weak_packing=lambda wc: PLAN.weak_packing_input(wc.problem),
        sigma=L.model("sigma"),
        tangent=L.model("tangent"),
    output:
        run=L.problem_run("{problem}", PLAN.problem_adaptive_method, "{case}"),
        trajectories=L.problem_dem_points("{problem}", PLAN.problem_adaptive_method, "{case}"),
    log:
        L.log(f"{{problem}}/{PLAN.problem_adaptive_method}/{{case}}"),
    benchmark:
        L.benchmark(f"{{problem}}/{PLAN.problem_adaptive_method}/{{case}}")
    params:
        threshold=lambda wc: PLAN.problem_threshold(wc.problem),
        checkpoint=L.checkpoint(f"{{problem}}/{PLAN.problem_adaptive_method}/{{case}}"),
        tangent=lambda wc: PLAN.adaptive_tangent(wc.problem),
        allow_partial=True,
        depends=lambda wc: PLAN.problem_surrogate_definition(wc.problem, adaptive=True),
        problem=lambda wc: wc.problem,
        path_name=lambda wc: wc.case,


use rule adaptive as problem_adaptive_control with:
    input:
        packings=PLAN.packings,
        weak_packing=lambda wc: PLAN.weak_packing_input(wc.problem),
        schedule_from=L.problem_dem_points("{problem}", PLAN.problem_adaptive_method, "{case}"),
    output:
        run=L.problem_run("{problem}", PLAN.control_method("{control}"), "{case}"),
        trajectories=L.problem_dem_points("{problem}", PLAN.control_method("{control}"), "{case}"),
    log:
        L.log(f"{{problem}}/{PLAN.control_method('{control}')}/{{case}}"),
    benchmark:
        L.benchmark(f"{{problem}}/{PLAN.control_method('{control}')}/{{case}}")
    params:
        threshold=lambda wc: PLAN.problem_threshold(wc.problem),
        checkpoint=L.checkpoint(f"{{problem}}/{PLAN.control_method('{control}')}/{{case}}"),
        tangent=lambda wc: PLAN.adaptive_tangent(wc.problem),
        allow_partial=True,
        depends=lambda wc: {**PLAN.problem_surrogate_definition(wc.problem, adaptive=True), "model": config[wc.control]},
        problem=lambda wc: wc.problem,
        path_name=lambda wc: wc.case,
        control=lambda wc: wc.control,
    wildcard_constraints:
        control="|".join(PLAN.controls) or "no-control",


rule problem_surrogate_products:
    input:
        runs=lambda wc: list(PLAN.problem_comparison(wc.problem, wc.case).values()),
    output:
        csv=report(L.table("{problem}/surrogate_{case}.csv"), caption="../report/problem_surrogate.rst",
                   category=CAT_PROBLEMS_SURROGATE, subcategory="{problem}"),
        html=report(L.table("{problem}/surrogate_{case}.html"), caption="../report/problem_surrogate.rst",
                    category=CAT_PROBLEMS_SURROGATE, subcategory="{problem}"),
        response=report(L.figure("{problem}/surrogate_response_{case}.png"),
                        caption="../report/problem_surrogate_response.rst", category=CAT_PROBLEMS_SURROGATE,
                        subcategory="{problem}"),
        error_map=report(L.figure("{problem}/error_map_{case}.png"), caption="../report/problem_error_map.rst",
                         category=CAT_PROBLEMS_SURROGATE, subcategory="{problem}"),
    log:
        L.log("analysis/{problem}/surrogate_{case}"),
    benchmark:
        L.benchmark("analysis/{problem}/surrogate_{case}")
    params:
        kind="surrogate",
        labels=lambda wc: list(PLAN.problem_comparison(wc.problem, wc.case)),
        title=lambda wc: f"{PROBLEM_LABEL[wc.problem]}, path {wc.case}",
        settings=config["analysis"],
    script:
        "../../scripts/problem_products.py"


use rule figure_calibration as problem_calibration with:
    input:
        reference=lambda wc: PLAN.problem_run(wc.problem, wc.case),
        surrogate=L.problem_run("{problem}", "fem_ml", "{case}"),
        spread_scale=L.table("spread_scale.csv"),
    output:
        figure=report(L.figure("{problem}/calibration_{case}.png"), caption="../report/calibration.rst",
                      category=CAT_PROBLEMS_SURROGATE, subcategory="{problem}"),
        csv=report(L.table("{problem}/calibration_{case}.csv"), caption="../report/calibration_csv.rst",
                   category=CAT_PROBLEMS_SURROGATE, subcategory="{problem}"),
        html=report(L.table("{problem}/calibration_{case}.html"), caption="../report/calibration_table.rst",
                    category=CAT_PROBLEMS_SURROGATE, subcategory="{problem}"),
    log:
        L.log("analysis/{problem}/calibration_{case}"),
    benchmark:
        L.benchmark("analysis/{problem}/calibration_{case}")
    params:
        settings=config["analysis"],
        path_label=lambda wc: f"{PROBLEM_LABEL[wc.problem]}, path {wc.case}",
        reference_label=PLAN.reference_label,
        surrogate_label=PLAN.surrogate_label,


rule table_visited_states:
    input:
        runs=list(PLAN.visited_states_runs().values()),
        dataset=L.dataset("train"),
    output:
        csv=report(L.table("visited_states.csv"), caption="../report/visited_states.rst",
                   category=CAT_PROBLEMS_SURROGATE, subcategory="States the material points visit"),
        html=report(L.table("visited_states.html"), caption="../report/visited_states.rst",
                    category=CAT_PROBLEMS_SURROGATE, subcategory="States the material points visit"),
    log:
        L.log("analysis/table_visited_states"),
    benchmark:
        L.benchmark("analysis/table_visited_states")
    params:
        kind="visited_states",
        labels=list(PLAN.visited_states_runs()),
        pressure=config["specimen"]["confining_pressure"],
        history=config["surrogate"]["history_variables"],
    script:
        "../../scripts/problem_products.py"


rule problem_adaptive_runs:
    input:
        [f for p in PLAN.problems for c in PLAN.problem_cases[p] for f in PLAN.problem_adaptive_runs(p, c).values()],
