# Reference runs with the analytic elastoplastic model (reference_material: elastoplastic).


rule fem_elastoplastic:
    output:
        L.run("fem_elastoplastic", "{path}"),
    log:
        L.log("fem_elastoplastic/{path}"),
    benchmark:
        L.benchmark("fem_elastoplastic/{path}")
    params:
        # what the run depends on, so that editing it in the config re-runs the rule
        model=lambda wc: PLAN.reference_definition(wc.path),
    threads: 1
    script:
        "../../scripts/run_fem_reference.py"
