# Reference runs with the analytic elastoplastic model (reference_material: elastoplastic).


rule fem_elastoplastic:
    output:
        f"{OUT}/fem_elastoplastic/{{path}}.h5",
    log:
        f"{OUT}/logs/fem_elastoplastic/{{path}}.log",
    benchmark:
        f"{OUT}/benchmarks/fem_elastoplastic/{{path}}.tsv"
    params:
        # what the run depends on, so that editing it in the config re-runs the rule
        model=lambda wc: {
            "specimen": config["specimen"],
            "newton": config["newton"],
            "elastoplastic": config["elastoplastic"],
            "segments": config["load_paths"][wc.path]["segments"],
        },
    threads: 1
    script:
        "../../scripts/run_fem_reference.py"


if config["reference_material"] == "elastoplastic":
    ALL_TARGETS += [reference_run(p) for p in PATH_NAMES]
