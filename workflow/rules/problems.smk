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

PROBLEMS = list(config["problems"])
PROBLEM_CASES = {p: list(config[p]["load_paths"]) for p in PROBLEMS}
PROBLEM_LABEL = {"biaxial": "Biaxial test (plane strain)", "footing": "Strip footing (plane strain)"}
CAT_PROBLEMS = "7 Problems beyond the triaxial specimen"
WEAK_ZONE = config["biaxial"]["weak_zone"]
WEAK_PACKING = f"{OUT}/rve/packing_weak.yade.gz"
ELEMENT_TESTS = {"triaxial": "triaxial compression", "biaxial": "plane strain compression"}


def problem_run(problem, case):
    return f"{OUT}/{problem}/{REFERENCE}/{case}.h5"


def problem_definition(problem):
    """What a run of `problem` depends on: its section, the confinement, Newton and the material's settings."""
    material = RUN_DEFINITION if REFERENCE == "fem_dem" else config["elastoplastic"]
    return {"section": config[problem], "pressure": config["specimen"]["confining_pressure"],
            "newton": config["newton"], "material": material}


def weak_packing_input(problem):
    """The weak packing, for a problem whose config has a weak zone (the biaxial test)."""
    return [WEAK_PACKING] if problem == "biaxial" and WEAK_ZONE is not None else []


wildcard_constraints:
    problem="|".join(PROBLEMS) or "no-problem",
    case="|".join(sorted({c for cases in PROBLEM_CASES.values() for c in cases})) or "no-case",
    test="|".join(ELEMENT_TESTS),


use rule rve as rve_weak with:
    output:
        packings=[WEAK_PACKING],
        summary=f"{OUT}/rve/summary_weak.json",
    params:
        dem=PACKING_DEFINITION,
        pressure=config["specimen"]["confining_pressure"],
        seed=config["seed"],
        friction=WEAK_ZONE["dem_friction"] if WEAK_ZONE else None,
    log:
        f"{OUT}/logs/rve_weak.log",
    benchmark:
        f"{OUT}/benchmarks/rve_weak.tsv"
    threads: 1


use rule fem_dem as problem_fem_dem with:
    input:
        packings=PACKINGS,
        weak_packing=lambda wc: weak_packing_input(wc.problem),
    output:
        f"{OUT}/{{problem}}/fem_dem/{{case}}.h5",
    log:
        f"{OUT}/logs/{{problem}}/fem_dem/{{case}}.log",
    benchmark:
        f"{OUT}/benchmarks/{{problem}}/fem_dem/{{case}}.tsv"
    params:
        checkpoint=f"{OUT}/checkpoints/{{problem}}/fem_dem/{{case}}.ckpt",
        definition=lambda wc: problem_definition(wc.problem),
        problem=lambda wc: wc.problem,
        path_name=lambda wc: wc.case,
        path=None,  # (rule fem_dem's triaxial path; the problem's is in definition)


use rule fem_elastoplastic as problem_fem_elastoplastic with:
    output:
        f"{OUT}/{{problem}}/fem_elastoplastic/{{case}}.h5",
    log:
        f"{OUT}/logs/{{problem}}/fem_elastoplastic/{{case}}.log",
    benchmark:
        f"{OUT}/benchmarks/{{problem}}/fem_elastoplastic/{{case}}.tsv"
    params:
        model=lambda wc: problem_definition(wc.problem),
        problem=lambda wc: wc.problem,
        path_name=lambda wc: wc.case,


def element_test_overrides(test):
    """The config of an element test: one RVE under a uniform field along analysis.element_test."""
    path = {"element": {"segments": config["analysis"]["element_test"]}}
    if test == "triaxial":
        return {"specimen": {**config["specimen"], "platen": "smooth", "uniform_field": True, "symmetry": "none"},
                "load_paths": {**config["load_paths"], **path}}
    return {"biaxial": {**config["biaxial"], "uniform_field": True, "weak_zone": None, "load_paths": path}}


use rule fem_dem as element_test_fem_dem with:
    input:
        packings=PACKINGS,
    output:
        f"{OUT}/element_tests/fem_dem/{{test}}.h5",
    log:
        f"{OUT}/logs/element_tests/fem_dem/{{test}}.log",
    benchmark:
        f"{OUT}/benchmarks/element_tests/fem_dem/{{test}}.tsv"
    params:
        checkpoint=f"{OUT}/checkpoints/element_tests/fem_dem/{{test}}.ckpt",
        overrides=lambda wc: element_test_overrides(wc.test),
        definition=RUN_DEFINITION,
        problem=lambda wc: wc.test,
        path_name="element",
        path=None,
    threads: 1


use rule fem_elastoplastic as element_test_fem_elastoplastic with:
    output:
        f"{OUT}/element_tests/fem_elastoplastic/{{test}}.h5",
    log:
        f"{OUT}/logs/element_tests/fem_elastoplastic/{{test}}.log",
    benchmark:
        f"{OUT}/benchmarks/element_tests/fem_elastoplastic/{{test}}.tsv"
    params:
        overrides=lambda wc: element_test_overrides(wc.test),
        model=config["elastoplastic"],
        problem=lambda wc: wc.test,
        path_name="element",


ELEMENT_RUNS = {ELEMENT_TESTS[t]: f"{OUT}/element_tests/{REFERENCE}/{t}.h5" for t in ELEMENT_TESTS}


rule table_rve_angles:
    input:
        runs=list(ELEMENT_RUNS.values()),
    output:
        csv=report(f"{OUT}/tables/rve_angles.csv", caption="../report/rve_angles.rst", category=CAT_PROBLEMS,
                   subcategory="The RVE's friction and dilatancy angles"),
        html=report(f"{OUT}/tables/rve_angles.html", caption="../report/rve_angles.rst", category=CAT_PROBLEMS,
                    subcategory="The RVE's friction and dilatancy angles"),
    log:
        f"{OUT}/logs/analysis/table_rve_angles.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/table_rve_angles.tsv"
    params:
        kind="angles",
        labels=list(ELEMENT_RUNS),
    script:
        "../../scripts/problem_products.py"


rule figure_problem_response:
    input:
        runs=lambda wc: [problem_run(wc.problem, c) for c in PROBLEM_CASES[wc.problem]],
    output:
        report(f"{OUT}/figures/{{problem}}/response.png", caption="../report/problem_response.rst",
               category=CAT_PROBLEMS, subcategory="{problem}"),
    log:
        f"{OUT}/logs/analysis/{{problem}}/figure_response.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/{{problem}}/figure_response.tsv"
    params:
        kind="response",
        labels=lambda wc: [f"{REFERENCE_LABEL}, {c}" for c in PROBLEM_CASES[wc.problem]],
        title=lambda wc: f"{PROBLEM_LABEL[wc.problem]}: force against displacement",
        settings=config["analysis"],
    script:
        "../../scripts/problem_products.py"


rule figure_problem_fields:
    input:
        run=lambda wc: problem_run(wc.problem, wc.case),
    output:
        report(f"{OUT}/figures/{{problem}}/fields_{{case}}.png", caption="../report/problem_fields.rst",
               category=CAT_PROBLEMS, subcategory="{problem}"),
    log:
        f"{OUT}/logs/analysis/{{problem}}/figure_fields_{{case}}.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/{{problem}}/figure_fields_{{case}}.tsv"
    params:
        kind="fields",
        title=lambda wc: f"{PROBLEM_LABEL[wc.problem]}, {REFERENCE_LABEL}, path {wc.case}",
        settings=config["analysis"],
    script:
        "../../scripts/problem_products.py"


rule table_bands:
    input:
        runs=[problem_run("biaxial", c) for c in config["biaxial"]["load_paths"]],
        angles=f"{OUT}/tables/rve_angles.csv",
    output:
        csv=report(f"{OUT}/tables/biaxial_bands.csv", caption="../report/bands.rst", category=CAT_PROBLEMS,
                   subcategory="biaxial"),
        html=report(f"{OUT}/tables/biaxial_bands.html", caption="../report/bands.rst", category=CAT_PROBLEMS,
                    subcategory="biaxial"),
    log:
        f"{OUT}/logs/analysis/table_bands.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/table_bands.tsv"
    params:
        kind="bands",
        labels=list(config["biaxial"]["load_paths"]),
        grain_diameter=0.5 * (config["dem"]["diameter_min"] + config["dem"]["diameter_max"]),
    script:
        "../../scripts/problem_products.py"


rule table_footing:
    input:
        runs=[problem_run("footing", c) for c in config["footing"]["load_paths"]],
        angles=f"{OUT}/tables/rve_angles.csv",
    output:
        csv=report(f"{OUT}/tables/footing.csv", caption="../report/footing.rst", category=CAT_PROBLEMS,
                   subcategory="footing"),
        html=report(f"{OUT}/tables/footing.html", caption="../report/footing.rst", category=CAT_PROBLEMS,
                    subcategory="footing"),
    log:
        f"{OUT}/logs/analysis/table_footing.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/table_footing.tsv"
    params:
        kind="footing",
        labels=list(config["footing"]["load_paths"]),
    script:
        "../../scripts/problem_products.py"


rule vtk_problem:
    input:
        lambda wc: problem_run(wc.problem, wc.case),
    output:
        directory(f"{OUT}/vtk/{{problem}}/{{case}}"),
    log:
        f"{OUT}/logs/analysis/vtk_{{problem}}_{{case}}.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/vtk_{{problem}}_{{case}}.tsv"
    params:
        stem=lambda wc: f"{wc.problem}_{wc.case}",
    script:
        "../../scripts/analysis_vtk.py"


BIAXIAL_MESHES = ["x".join(map(str, m)) for m in config["analysis"]["biaxial_meshes"]]


def biaxial_mesh_run(mesh):
    """The biaxial run of a mesh of the study: the problem's own run at its configured mesh."""
    if [int(v) for v in mesh.split("x")] == list(config["biaxial"]["elements"]):
        return problem_run("biaxial", list(config["biaxial"]["load_paths"])[0])
    return f"{OUT}/biaxial_mesh/{REFERENCE}/{mesh}.h5"


use rule problem_fem_dem as biaxial_mesh_fem_dem with:
    input:
        packings=PACKINGS,
        weak_packing=weak_packing_input("biaxial"),
    output:
        f"{OUT}/biaxial_mesh/fem_dem/{{mesh}}.h5",
    log:
        f"{OUT}/logs/biaxial_mesh/fem_dem/{{mesh}}.log",
    benchmark:
        f"{OUT}/benchmarks/biaxial_mesh/fem_dem/{{mesh}}.tsv"
    params:
        checkpoint=f"{OUT}/checkpoints/biaxial_mesh/fem_dem/{{mesh}}.ckpt",
        definition=lambda wc: problem_definition("biaxial"),
        overrides=lambda wc: {"biaxial": {**config["biaxial"], "elements": [int(v) for v in wc.mesh.split("x")]}},
        problem="biaxial",
        path_name=lambda wc: list(config["biaxial"]["load_paths"])[0],
    wildcard_constraints:
        mesh=r"\d+x\d+",


use rule problem_fem_elastoplastic as biaxial_mesh_fem_elastoplastic with:
    output:
        f"{OUT}/biaxial_mesh/fem_elastoplastic/{{mesh}}.h5",
    log:
        f"{OUT}/logs/biaxial_mesh/fem_elastoplastic/{{mesh}}.log",
    benchmark:
        f"{OUT}/benchmarks/biaxial_mesh/fem_elastoplastic/{{mesh}}.tsv"
    params:
        model=lambda wc: problem_definition("biaxial"),
        overrides=lambda wc: {"biaxial": {**config["biaxial"], "elements": [int(v) for v in wc.mesh.split("x")]}},
        problem="biaxial",
        path_name=lambda wc: list(config["biaxial"]["load_paths"])[0],
    wildcard_constraints:
        mesh=r"\d+x\d+",


rule biaxial_mesh_study:
    input:
        runs=[biaxial_mesh_run(m) for m in BIAXIAL_MESHES],
    output:
        csv=report(f"{OUT}/tables/biaxial_mesh_study.csv", caption="../report/mesh_study.rst",
                   category=CAT_PROBLEMS, subcategory="biaxial"),
        html=report(f"{OUT}/tables/biaxial_mesh_study.html", caption="../report/mesh_study.rst",
                    category=CAT_PROBLEMS, subcategory="biaxial"),
        figure=report(f"{OUT}/figures/biaxial/mesh_study.png", caption="../report/mesh_study.rst",
                      category=CAT_PROBLEMS, subcategory="biaxial"),
    log:
        f"{OUT}/logs/analysis/biaxial_mesh_study.log",
    benchmark:
        f"{OUT}/benchmarks/analysis/biaxial_mesh_study.tsv"
    params:
        kind="mesh_study",
        labels=[f"{REFERENCE_LABEL}, {m}" for m in BIAXIAL_MESHES],
        settings=config["analysis"],
    script:
        "../../scripts/problem_products.py"


PROBLEM_TARGETS = []
if PROBLEMS:
    PROBLEM_TARGETS += [f"{OUT}/tables/rve_angles.csv"]
for p in PROBLEMS:
    PROBLEM_TARGETS += [f"{OUT}/figures/{p}/response.png"]
    PROBLEM_TARGETS += [f"{OUT}/figures/{p}/fields_{c}.png" for c in PROBLEM_CASES[p]]
    PROBLEM_TARGETS += [f"{OUT}/vtk/{p}/{c}" for c in PROBLEM_CASES[p]]
if "biaxial" in PROBLEMS:
    PROBLEM_TARGETS += [f"{OUT}/tables/biaxial_bands.csv"]
if "footing" in PROBLEMS:
    PROBLEM_TARGETS += [f"{OUT}/tables/footing.csv"]
ALL_TARGETS += PROBLEM_TARGETS
