"""The workflow's plan, made from a validated config: where every output goes (:class:`Layout`),
which runs each stage makes (the run sets), what makes a rule run again (its definitions) and
what the figures and tables call each run (the labels).

The rule files (``workflow/rules/*.smk``) only declare rules from one :class:`Plan`; tests and
benches take their paths from it too. Nothing here imports Snakemake or reads a result file.

    plan = Plan(validate_config(config))
    plan.layout.fem_ml("path2")            -> "results/fem_ml/path2.h5"
    plan.layout.model("sigma", "active/")  -> "results/active/models/nn_sigma.pt"
    plan.ml_paths, plan.comparison_runs("path2"), plan.all_targets()
"""

from __future__ import annotations

import math

from .adaptive import threshold_label
from .config import adaptive_tangent, dem_newton_config, problem_adaptive_config
from .paths import load_paths_from_config

# network name -> (what it predicts, whether it reads the history variables)
NETWORKS = {
    "sigma": ("sigma", True),
    "tangent": ("tangent", True),
    "sigma_nohist": ("sigma", False),
    "tangent_nohist": ("tangent", False),
}
NETWORK_LABEL = {"sigma": "NNσ", "tangent": "ND"}
# the keys of `surrogate` that change a trained network (only these re-run the training rules)
TRAINING_KEYS = [
    "hidden_layers", "hidden_units", "activation", "batch_size", "learning_rate", "epochs", "ensemble_size",
    "ensemble_resampling", "lr_schedule", "final_learning_rate", "jacobian_loss_weight", "loss", "log_every",
    "history_variables", "device", "torch_threads",
]
# the dem settings that say where a run is computed, not what it computes: changing them reruns nothing
WHERE_DEM_RUNS = ("executor", "n_workers", "dask_scheduler")
FIELD_QUANTITIES = ["axial_displacement", "shear_strain", "sigma23"]
CONTROL_LABEL = {"linear_elastic": "elastic model", "elastoplastic": "elastoplastic model fitted to Path1"}
#: the rows of FEM–ML solved as a problem's reference is (rule problem_fem_ml_as_reference) and of its
#: networks driven along the reference's strains (rule problem_fem_ml_driven)
AS_REFERENCE_LABEL = "FEM–ML solved as the reference (its Newton settings, ND tangent)"
DRIVEN_LABEL = "FEM–ML's networks along the reference's strains (no FEM)"
PROBLEM_LABEL = {"biaxial": "Biaxial test (plane strain)", "footing": "Strip footing (plane strain)"}
ELEMENT_TESTS = {"triaxial": "triaxial compression", "biaxial": "plane strain compression"}
# the two rounds of the surrogate: the pipeline's networks, and those of one active-learning round
ACTIVE_ROUNDS = {"first": "", "after one round": "active/"}
# the folder of the weak zone's networks (surrogate.weak_zone_sources)
WEAK_ZONE_ROUND = "weak_zone/"


def adaptive_label(threshold: float, indicator: str | None = None) -> str:
    """What the tables and figures call an adaptive run: 'adaptive FEM–DEM–ML, threshold 0.02', with
    `indicator` 'adaptive FEM–DEM–ML, distance ≥ 0.5'; at an infinite threshold no point is
    promoted: DEM only at its anchors (a problem's weak zone)."""
    if math.isinf(threshold):
        return "adaptive FEM–DEM–ML, no promotions (DEM at the anchors)"
    return f"adaptive FEM–DEM–ML, {indicator} ≥ {threshold:g}" if indicator else \
        f"adaptive FEM–DEM–ML, threshold {threshold:g}"


def path_label(path: str) -> str:
    """'path2' -> 'Path2', as the paper names its load paths."""
    return path[:1].upper() + path[1:]


class Layout:
    """Every file the workflow writes under one output directory. Arguments may be Snakemake
    wildcards such as ``"{path}"``: the methods only put names together."""

    def __init__(self, out: str):
        self.out = str(out).rstrip("/")

    def _file(self, *parts: str) -> str:
        return "/".join([self.out, *parts])

    # what every job records beside its outputs
    def log(self, key: str) -> str:
        return self._file("logs", f"{key}.log")

    def benchmark(self, key: str) -> str:
        return self._file("benchmarks", f"{key}.tsv")

    def checkpoint(self, key: str) -> str:
        """Where a long run checkpoints (not a declared output: a rerun after a kill resumes)."""
        return self._file("checkpoints", f"{key}.ckpt")

    # RVE packings: rule rve, at another sphere count (rve_n<n>/) and consolidated at another pressure
    # g·p0 (rve_p<g>/)
    def rve_folder(self, spheres=None, pressure=None) -> str:
        if pressure is not None:
            return f"rve_p{pressure}"
        return "rve" if spheres is None else f"rve_n{spheres}"

    def packings(self, n_packings: int, spheres=None, pressure=None) -> list[str]:
        return [self._file(self.rve_folder(spheres, pressure), f"packing_{k}.yade.gz") for k in range(n_packings)]

    def packing_summary(self, spheres=None, pressure=None) -> str:
        return self._file(self.rve_folder(spheres, pressure), "summary.json")

    def weak_packing(self) -> str:
        return self._file("rve", "packing_weak.yade.gz")

    def weak_packing_summary(self) -> str:
        return self._file("rve", "summary_weak.json")

    # runs of the triaxial specimen: one file per method and load path
    def run(self, method: str, path: str) -> str:
        """fem_dem, fem_elastoplastic, fem_dem_n<n>, fem_ml, fem_ml_nohist, fem_ml_nn, fem_ml_autodiff."""
        return self._file(method, f"{path}.h5")

    def fem_ml(self, path: str) -> str:
        return self.run("fem_ml", path)

    def rve_paths(self, name: str) -> str:
        return self._file("rve_paths", f"{name}.h5")

    def adaptive(self, label: str, path: str, round: str = "") -> str:
        return self._file(f"{round}adaptive", label, f"{path}.h5")

    def adaptive_dem_points(self, label: str, path: str, round: str = "") -> str:
        """The DEM answers of an adaptive run's promoted points (training data of the next round)."""
        return self._file(f"{round}adaptive", label, "dem_points", f"{path}.h5")

    def tolerance_run(self, variant: str, path: str) -> str:
        return self._file("tolerance_study", variant, f"{path}.h5")

    # the surrogate, per training round ("" or "active/")
    def dataset(self, split: str, round: str = "") -> str:
        return self._file(f"{round}dataset", f"{split}.h5")

    def model(self, network: str, round: str = "") -> str:
        return self._file(f"{round}models", f"nn_{network}.pt")

    def training(self, name: str, round: str = "") -> str:
        """<network>.csv (loss per epoch), <network>_mae.csv, <network>_loss.png."""
        return self._file(f"{round}training", name)

    # the problems beyond the triaxial specimen
    def problem_run(self, problem: str, method: str, case: str) -> str:
        return self._file(problem, method, f"{case}.h5")

    def problem_dem_points(self, problem: str, method: str, case: str) -> str:
        """The DEM answers of an adaptive problem run's DEM points (what its control copies)."""
        return self._file(problem, method, "dem_points", f"{case}.h5")

    def element_test(self, method: str, test: str) -> str:
        return self._file("element_tests", method, f"{test}.h5")

    def biaxial_mesh_run(self, method: str, mesh: str) -> str:
        return self._file("biaxial_mesh", method, f"{mesh}.h5")

    # what a reader sees
    def table(self, name: str) -> str:
        return self._file("tables", name)

    def figure(self, name: str) -> str:
        return self._file("figures", name)

    def vtk(self, run: str, path: str) -> str:
        return self._file("vtk", run, path)

    # measured by the benches (bench/), not by a rule
    def bench(self, name: str) -> str:
        """The record a bench of bench/ writes by default (JSON: commit, machine, settings, figures)."""
        return self._file("bench", f"{name}.json")


class Plan:
    """What the workflow makes from one validated config."""

    def __init__(self, config: dict):
        self.config = config
        self.layout = Layout(config["output_dir"])
        self.paths = load_paths_from_config(config)
        self.path_names = list(self.paths)
        self.reference = "fem_dem" if config["reference_material"] == "dem" else "fem_elastoplastic"
        dem = config["dem"]
        self.n_packings = dem["n_packings"]
        self.packings = self.layout.packings(self.n_packings)
        # what defines a packing / a FEM–DEM run, not where it runs: a change of these reruns the rule
        self.packing_definition = {k: v for k, v in dem.items() if k not in (*WHERE_DEM_RUNS, "newton")}
        self.run_definition = {k: v for k, v in dem.items() if k not in WHERE_DEM_RUNS}
        # the Newton settings the specimen's FEM–DEM runs solve with: the tolerance study's row that
        # measures their own error
        solved = dem_newton_config(config)["newton"]
        self.reference_newton = {key: solved[key] for key in ("tolerance", "predictor", "acceleration")}
        self.rve_path_sets = list(config["rve_paths"]["sets"])

        surrogate = config["surrogate"]
        self.training_path = config["training_path"]
        self.validation_path = config["validation_path"]
        # what trains the networks: reference runs of load paths and RVE-path sets ("rve_paths:<set>")
        self.training_sources = surrogate["training_sources"] or [self.training_path]
        self.training_run_paths = [s for s in self.training_sources if not s.startswith("rve_paths:")]
        self.training_rve_sets = [s.split(":", 1)[1] for s in self.training_sources if s.startswith("rve_paths:")]
        # the networks of the biaxial test's weak zone: RVE-path sets of the weak packing, a DEM packing
        # (none, or an analytic reference: FEM–ML gives the weak zone the specimen's networks)
        self.weak_zone_sets = ([s.split(":", 1)[1] for s in surrogate["weak_zone_sources"]]
                               if self.reference == "fem_dem" else [])
        # every load path the training did not use is a validation case; FEM–ML runs every path
        self.validation_paths = [p for p in self.path_names if p not in self.training_run_paths]
        self.ml_paths = list(dict.fromkeys([self.validation_path, *self.validation_paths,
                                            *self.training_run_paths, self.training_path]))

        adaptive = config["adaptive"]
        self.adaptive_paths = adaptive["paths"] or [self.validation_path]
        self.adaptive_thresholds = {threshold_label(t): float(t) for t in adaptive["thresholds"]}
        # one round of active learning: the adaptive runs at its threshold on its paths write the DEM
        # answers of their promoted points, which join the training sources of a second round
        active = adaptive["active_learning"]
        self.active_label = threshold_label(active["threshold"])
        self.active_paths = active["paths"] or self.adaptive_paths
        # the thresholds each round runs at: every configured one in the first, the active-learning one in both
        self.adaptive_round_thresholds = {
            "": {**self.adaptive_thresholds, self.active_label: float(active["threshold"])},
            "active/": {self.active_label: float(active["threshold"])},
        }
        # adaptive.report: the validation path's runs join the speed figure, the tables and the mode map
        self.adaptive_in_report = adaptive["report"] and self.reference == "fem_dem"

        tangent = surrogate["tangent"]
        self.reference_label = (f"FEM–DEM ({dem['n_spheres']} spheres)" if self.reference == "fem_dem"
                                else "FEM, elastoplastic model (reference)")
        self.surrogate_label = f"FEM–ML ({tangent} tangent)"
        self.other_tangent = "autodiff" if tangent == "nn" else "nn"
        self.ablation_label = "FEM–ML, no history"

        self.problems = list(config["problems"])
        self.problem_cases = {p: list(config[p]["load_paths"]) for p in self.problems}
        self.weak_zone = config["biaxial"]["weak_zone"]
        self.biaxial_meshes = ["x".join(map(str, m)) for m in config["analysis"]["biaxial_meshes"]]
        # the surrogate on the problems: FEM–ML, and with a DEM reference, adaptive.report and
        # adaptive.problems the adaptive run (the problem's section, key adaptive) beside its controls
        # (the same promotions, an analytic model instead of the networks)
        self.problem_adaptive_method = "adaptive"
        self.controls = list(adaptive["controls"])
        self.problem_adaptive = self.adaptive_in_report and bool(self.problems) and adaptive["problems"]

    # ---- training -------------------------------------------------------------------------
    @property
    def networks(self) -> dict[str, tuple[str, bool]]:
        """The networks rule fem_ml and its no-history ablation put at the Gauss points ({name: spec of
        :data:`NETWORKS`}). ND is always trained (the runs of both tangents, the runs solved as the
        reference); the ablation's ND only when the pipeline's tangent is ND: with the autodiff
        tangent the ablation differentiates its own NNσ, and that ND would be trained for nothing."""
        needed = {n: spec for n, spec in NETWORKS.items() if n != "tangent_nohist"}
        if self.config["surrogate"]["tangent"] == "nn":
            needed["tangent_nohist"] = NETWORKS["tangent_nohist"]
        return needed

    def fem_ml_models(self, history: bool = True, problem: str | None = None, tangent: str | None = None) -> dict[str, str]:
        """{sigma[, tangent]: model file} that a FEM–ML run solved with `tangent` (default: the
        pipeline's, ``surrogate.tangent``) reads: rule fem_ml's, or with `history` False its no-history
        ablation's; for a `problem`, also the weak zone's networks (:meth:`weak_zone_models`). ND only
        with the ``nn`` tangent: the autodiff tangent is NNσ's own Jacobian, so such a run waits for
        no ND."""
        kinds = ("sigma", "tangent") if (tangent or self.config["surrogate"]["tangent"]) == "nn" else ("sigma",)
        models = {kind: self.layout.model(name) for name, (kind, with_history) in NETWORKS.items()
                  if with_history == history and kind in kinds}
        if problem is not None:
            models.update({key: file for key, file in self.weak_zone_models(problem).items()
                           if key.removeprefix("weak_") in kinds})
        return models

    def reference_run(self, path: str) -> str:
        """The reference run (FEM–DEM or the elastoplastic model) of a load path."""
        return self.layout.run(self.reference, path)

    def training_rounds(self) -> dict[str, tuple[list[str], dict]]:
        """{folder prefix: (training source files, networks)}: the pipeline's networks, those of the
        active-learning round (NNσ and ND with history only: what the adaptive runs use) and, with
        surrogate.weak_zone_sources, those of the biaxial test's weak zone."""
        L = self.layout
        sources = [self.reference_run(p) for p in self.training_run_paths]
        sources += [L.rve_paths(s) for s in self.training_rve_sets]
        promoted = [L.adaptive_dem_points(self.active_label, p) for p in self.active_paths]
        with_history = {n: NETWORKS[n] for n in ("sigma", "tangent")}
        rounds = {"": (sources, self.networks), "active/": (sources + promoted, with_history)}
        if self.weak_zone_sets:
            rounds[WEAK_ZONE_ROUND] = ([L.rve_paths(s) for s in self.weak_zone_sets], with_history)
        return rounds

    def rve_path_packings(self, name: str) -> list[str]:
        """The packings an RVE-path set drives: the specimen's, or the weak zone's (``packing: weak_zone``);
        none for the elastoplastic model."""
        if self.reference != "fem_dem":
            return []
        definition = self.config["rve_paths"]["sets"][name]
        if definition["packing"] == "weak_zone":  # consolidated at p0 (validate_config)
            return [self.layout.weak_packing()]
        fraction = definition["consolidation_pressure"]
        return self.packings if fraction == 1.0 else self.layout.packings(self.n_packings, pressure=f"{fraction:g}")

    def weak_zone_models(self, problem: str) -> dict[str, str]:
        """{weak_sigma, weak_tangent: model file} of the weak zone's networks, for FEM–ML on a problem
        with a weak zone when surrogate.weak_zone_sources trains them; otherwise empty."""
        if problem != "biaxial" or self.weak_zone is None or not self.weak_zone_sets:
            return {}
        return {f"weak_{n}": self.layout.model(n, WEAK_ZONE_ROUND) for n in ("sigma", "tangent")}

    def spread_scale_inputs(self) -> dict[str, str]:
        """{<networks>_sigma, <networks>_heldout}: the NNσ and the held-out dataset of each network pair
        FEM–ML uses (the specimen's, and the weak zone's where the biaxial test has them), on which rule
        table_spread_scale measures the ensemble spread's scale."""
        L = self.layout
        rounds = {"specimen": ""}
        if "biaxial" in self.problems and self.weak_zone_models("biaxial"):
            rounds["weak_zone"] = WEAK_ZONE_ROUND
        return {f"{name}_{kind}": L.model("sigma", r) if kind == "sigma" else L.dataset("heldout", r)
                for name, r in rounds.items() for kind in ("sigma", "heldout")}

    def training_settings(self) -> dict:
        return {k: self.config["surrogate"][k] for k in TRAINING_KEYS}

    # ---- what makes a rule run again --------------------------------------------------------
    def reference_definition(self, path: str) -> dict:
        """What an elastoplastic reference run depends on."""
        c = self.config
        return {"specimen": c["specimen"], "newton": c["newton"], "elastoplastic": c["elastoplastic"],
                "segments": c["load_paths"][path]["segments"]}

    def fem_ml_definition(self, path: str) -> dict:
        """What a FEM–ML run depends on besides the models."""
        c, s = self.config, self.config["surrogate"]
        return {"specimen": c["specimen"], "newton": c["newton"], "segments": c["load_paths"][path]["segments"],
                "surrogate_newton": s["newton"], "anchor_initial_state": s["anchor_initial_state"],
                "out_of_range_tolerance": s["out_of_range_tolerance"], "other_pressure": s["other_pressure"]}

    def adaptive_tangent(self, problem: str | None = None) -> str:
        """The networks' tangent in an adaptive run (of `problem`: with the keys its section's
        ``adaptive`` sets): adaptive.tangent, or surrogate.tangent where that is null."""
        return adaptive_tangent(self.config if problem is None else problem_adaptive_config(self.config, problem)[0])

    def adaptive_definition(self, path: str) -> dict:
        """What an adaptive run depends on besides its inputs."""
        adaptive = self.config["adaptive"]
        return {**self.fem_ml_definition(path), "dem": self.run_definition,
                "adaptive": {k: v for k, v in adaptive.items() if k not in ("thresholds", "paths")},
                "seed": self.config["seed"]}

    def study_dem(self, variant: str) -> dict:
        """The dem section of a tolerance-study run: dem.newton with the variant's settings."""
        study = self.config["tolerance_study"]
        return {**self.run_definition, "newton": {**self.config["dem"]["newton"], **study["variants"][variant]}}

    def study_run(self, variant: str) -> str:
        """The FEM–DEM run of a tolerance-study variant on the study's path. A variant that solves
        exactly like the specimen's FEM–DEM runs (the same Newton settings once merged) is the
        reference run itself: the same computation, not made twice."""
        path = self.config["tolerance_study"]["path"]
        variant_config = {**self.config, "dem": {**self.config["dem"], "newton": self.study_dem(variant)["newton"]}}
        if dem_newton_config(variant_config)["newton"] == dem_newton_config(self.config)["newton"]:
            return self.layout.run("fem_dem", path)
        return self.layout.tolerance_run(variant, path)

    def problem_section(self, problem: str) -> dict:
        """The section of `problem` as its runs depend on it: without its adaptive run's settings, which
        only that run (:meth:`problem_surrogate_definition` with `adaptive`) depends on."""
        return {key: value for key, value in self.config[problem].items() if key != "adaptive"}

    def problem_definition(self, problem: str) -> dict:
        """What a run of `problem` depends on: its section, the confinement, Newton and the material's settings."""
        c = self.config
        material = self.run_definition if self.reference == "fem_dem" else c["elastoplastic"]
        return {"section": self.problem_section(problem), "pressure": c["specimen"]["confining_pressure"], "newton": c["newton"],
                "material": material}

    def analytic_problem_definition(self, problem: str) -> dict:
        """What a run of `problem` with the elastoplastic model depends on (the reference, or beside FEM–DEM)."""
        return {**self.problem_definition(problem), "material": self.config["elastoplastic"]}

    def element_test_overrides(self, test: str) -> dict:
        """The config of an element test: one RVE under a uniform field along analysis.element_test."""
        c = self.config
        path = {"element": {"segments": c["analysis"]["element_test"]}}
        if test == "triaxial":
            return {"specimen": {**c["specimen"], "platen": "smooth", "uniform_field": True, "symmetry": "none"},
                    "load_paths": {**c["load_paths"], **path}}
        return {"biaxial": {**self.problem_section("biaxial"), "uniform_field": True, "weak_zone": None, "load_paths": path}}

    # ---- run sets and labels of the products ------------------------------------------------
    def _thresholds_descending(self) -> list[tuple[str, float]]:
        return sorted(self.adaptive_thresholds.items(), key=lambda item: -item[1])

    def adaptive_runs(self, path: str) -> dict[str, str]:
        """{label: run file} of the adaptive runs of a load path, from the highest threshold to the lowest."""
        return {adaptive_label(t): self.layout.adaptive(label, path) for label, t in self._thresholds_descending()}

    def control_runs(self, path: str) -> dict[str, str]:
        """{label: run file} of the controls of the adaptive runs of a load path: per threshold and
        model of adaptive.controls, the networks replaced by that model, the promotions copied."""
        return {f"control: {CONTROL_LABEL[c]} + the DEM points of threshold {t:g}": self.layout.adaptive(f"{label}_{c}", path)
                for label, t in self._thresholds_descending() for c in self.controls}

    def adaptive_run_files(self) -> list[str]:
        """Every threshold of adaptive.thresholds on every path of adaptive.paths."""
        return [self.layout.adaptive(label, p) for label in self.adaptive_thresholds for p in self.adaptive_paths]

    def comparison_runs(self, path: str) -> dict[str, str]:
        """Ordered {label: run file} of the accuracy products: reference first."""
        L = self.layout
        return {self.reference_label: self.reference_run(path), self.surrogate_label: L.fem_ml(path),
                self.ablation_label: L.run("fem_ml_nohist", path)}

    def timing_runs(self, path: str) -> dict[str, str]:
        """The comparison runs, FEM–ML with the other tangent (the surrogate stage runs both on the
        validation path), and FEM–DEM at the other configured sphere counts (DEM reference only)."""
        runs = self.comparison_runs(path)
        ablation = runs.pop(self.ablation_label)
        runs[f"FEM–ML ({self.other_tangent} tangent)"] = self.layout.run(f"fem_ml_{self.other_tangent}", path)
        runs[self.ablation_label] = ablation
        if self.reference == "fem_dem":
            for n in self.config["analysis"]["fem_dem_sphere_counts"]:
                if n != self.config["dem"]["n_spheres"]:
                    runs[f"FEM–DEM ({n} spheres)"] = self.layout.run(f"fem_dem_n{n}", path)
        if self.adaptive_in_report:
            runs.update(self.adaptive_runs(path))
            runs.update(self.control_runs(path))
        return runs

    def speed_curve(self, path: str) -> list[str]:
        """Labels the speed-vs-error figure joins by a line: FEM–ML, the adaptive runs, the reference."""
        if not self.adaptive_in_report:
            return []
        return [self.surrogate_label, *self.adaptive_runs(path), self.reference_label]

    def validation_cases(self) -> dict[str, str]:
        """Every validation path (the training did not use it), then the training run paths (in-sample)."""
        return {**{p: "validation path" for p in self.validation_paths},
                **{p: "training path" for p in self.training_run_paths if p not in self.validation_paths}}

    def training_curves(self) -> dict[str, str]:
        """{'network|series': loss file} of every network the pipeline trains (:attr:`networks`)."""
        return {f"{NETWORK_LABEL[kind]}|{'with history' if history else 'no history'}": self.layout.training(f"{name}.csv")
                for name, (kind, history) in self.networks.items()}

    def stress_strain_names(self) -> list[str]:
        analysis = self.config["analysis"]
        explicit = analysis["stress_strain_gauss_points"]
        return [f"gp{g}" for g in explicit] if explicit else list(analysis["stress_strain_points"])

    def vtk_runs(self) -> dict:
        """{run name: load path -> run file} of the VTK exports."""
        return {"reference": self.reference_run, "fem_ml": self.layout.fem_ml}

    def metrics_tables(self) -> dict[str, str]:
        L = self.layout
        return {"stress_error_by_gp": L.table("fem_ml_stress_error_by_gp.csv"),
                "stress_error": L.table("fem_ml_stress_error.csv"),
                "curve_errors": L.table("fem_ml_curve_errors.csv"),
                "newton_iterations": L.table("fem_ml_newton_iterations.csv"),
                "out_of_range": L.table("fem_ml_out_of_range.csv"),
                "training_mae": L.table("surrogate_training_mae.csv")}

    def surrogate_cost_items(self) -> list[tuple[str, str, str]]:
        """(what, how to read it, file) of each step that makes the surrogate the FEM–ML runs use:
        the RVE packings (DEM), every training source (the reference runs of the training paths, the
        RVE-path sets), the dataset and the networks rule fem_ml reads (:meth:`fem_ml_models`; the
        no-history ablation is not part of the answer)."""
        L = self.layout
        reference = "FEM–DEM" if self.reference == "fem_dem" else "elastoplastic model (stands in for FEM–DEM)"
        items = []
        if self.reference == "fem_dem":
            items.append(("RVE preparation (YADE packings)", "rve_summary", L.packing_summary()))
        items += [(f"reference run of {path_label(path)}, {reference} (training data)", "run",
                   self.reference_run(path)) for path in self.training_run_paths]
        items += [(f"RVE paths '{name}' (rule rve_paths, training data)", "benchmark",
                   L.benchmark(f"rve_paths/{name}")) for name in self.training_rve_sets]
        items.append(("dataset (rule dataset)", "benchmark", L.benchmark("surrogate/dataset")))
        items += [(f"training {NETWORK_LABEL[kind]} (rule train_{kind})", "benchmark", L.benchmark(f"surrogate/train_{kind}"))
                  for kind in self.fem_ml_models()]
        return items

    def problem_run(self, problem: str, case: str) -> str:
        return self.layout.problem_run(problem, self.reference, case)

    def weak_packing_input(self, problem: str) -> list[str]:
        """The weak packing, for a problem whose config has a weak zone (the biaxial test)."""
        return [self.layout.weak_packing()] if problem == "biaxial" and self.weak_zone is not None else []

    def control_method(self, control: str) -> str:
        """The run folder of a control of the problems' adaptive run: 'control_elastoplastic'."""
        return f"control_{control}"

    def problem_threshold(self, problem: str) -> float:
        """The threshold of a problem's adaptive run (its section's adaptive.threshold)."""
        return problem_adaptive_config(self.config, problem)[1]

    def problem_surrogate_definition(self, problem: str, adaptive: bool = False) -> dict:
        """What a FEM–ML (or with `adaptive`, an adaptive) run of `problem` depends on besides its inputs."""
        c, s = self.config, self.config["surrogate"]
        definition = {"section": self.problem_section(problem), "pressure": c["specimen"]["confining_pressure"],
                      "newton": c["newton"], "surrogate_newton": s["newton"], "anchor_initial_state": s["anchor_initial_state"],
                      "out_of_range_tolerance": s["out_of_range_tolerance"], "other_pressure": s["other_pressure"]}
        if adaptive:
            merged, threshold = problem_adaptive_config(c, problem)
            section = {k: v for k, v in merged["adaptive"].items() if k not in ("thresholds", "paths", "report",
                                                                                "active_learning", "controls", "problems")}
            definition.update({"dem": self.run_definition, "adaptive": section, "threshold": threshold,
                               "seed": c["seed"]})
        return definition

    def problem_adaptive_runs(self, problem: str, case: str) -> dict[str, str]:
        """{label: run file} of a problem's adaptive run and its controls."""
        L = self.layout
        label = adaptive_label(self.problem_threshold(problem), self.config[problem]["adaptive"].get("indicator"))
        runs = {label: L.problem_run(problem, self.problem_adaptive_method, case)}
        for control in self.controls:
            runs[f"control: {CONTROL_LABEL[control]} + the same DEM points"] = L.problem_run(
                problem, self.control_method(control), case)
        return runs

    def problem_comparison(self, problem: str, case: str) -> dict[str, str]:
        """Ordered {label: run file} of a problem's surrogate products: the reference first, FEM–ML, FEM–ML
        solved as the reference is (its Newton settings, ND for the tangent), its networks driven along
        the reference's strains (no FEM: the material's error alone) and the analytic model alone (no
        networks, no DEM), then (adaptive.problems) the adaptive run and its controls."""
        L = self.layout
        runs = {self.reference_label: self.problem_run(problem, case), self.surrogate_label:
                L.problem_run(problem, "fem_ml", case),
                AS_REFERENCE_LABEL: L.problem_run(problem, "fem_ml_as_reference", case),
                DRIVEN_LABEL: L.problem_run(problem, "fem_ml_driven", case)}
        if self.reference == "fem_dem":
            runs["FEM, elastoplastic model fitted to Path1 (no networks)"] = L.problem_run(problem, "fem_elastoplastic",
                                                                                            case)
        if self.problem_adaptive:
            runs.update(self.problem_adaptive_runs(problem, case))
        return runs

    def visited_states_runs(self) -> dict[str, str]:
        """{label: run file} of the states table: every training source, the validation path's
        reference run, and each problem's reference runs."""
        L = self.layout
        runs = {f"training: reference run of {path_label(p)}": self.reference_run(p) for p in self.training_run_paths}
        runs.update({f"training: RVE paths '{s}'": L.rve_paths(s) for s in self.training_rve_sets})
        runs[f"validation: reference run of {path_label(self.validation_path)}"] = self.reference_run(self.validation_path)
        for problem in self.problems:
            runs.update({f"{problem}: reference run of {c}": self.problem_run(problem, c) for c in self.problem_cases[problem]})
        return runs

    def element_runs(self) -> dict[str, str]:
        return {label: self.layout.element_test(self.reference, t) for t, label in ELEMENT_TESTS.items()}

    def biaxial_mesh_run(self, mesh: str) -> str:
        """The biaxial run of a mesh of the study: the problem's own run at its configured mesh."""
        biaxial = self.config["biaxial"]
        if [int(v) for v in mesh.split("x")] == list(biaxial["elements"]):
            return self.problem_run("biaxial", list(biaxial["load_paths"])[0])
        return self.layout.biaxial_mesh_run(self.reference, mesh)

    # ---- what `all` makes -------------------------------------------------------------------
    def all_targets(self) -> list[str]:
        L = self.layout
        targets = [self.reference_run(p) for p in self.path_names]
        targets += [L.model(n) for n in self.networks] + [L.training(f"{n}.csv") for n in self.networks]
        targets += [L.fem_ml(p) for p in self.ml_paths] + [L.run("fem_ml_nohist", p) for p in self.ml_paths]
        targets += list(self.metrics_tables().values())
        v = self.validation_path
        targets += [L.figure("error_map.png"), *[L.figure(f"stress_strain_{n}.png") for n in self.stress_strain_names()],
                    L.figure("top_force_volumetric_strain.png"),
                    *[L.figure(f"fields_{q}.png") for q in FIELD_QUANTITIES],
                    *[L.vtk(run, v) for run in self.vtk_runs()], L.figure("training_curves.png"),
                    L.table("speedup.csv"), L.table("accuracy.csv"), L.table("surrogate_cost.csv"),
                    L.figure("speed_vs_error.png"), L.table("headline.json"), L.table("headline.html"),
                    L.table("validation_by_phase.csv")]
        if self.adaptive_in_report:
            targets.append(L.figure("adaptive_mode_map.png"))
        targets += [L.figure("calibration.png"), L.table("calibration.csv"), L.table("calibration.html"),
                    L.table("spread_scale.csv")]
        if self.problems:
            targets += [L.table("rve_angles.csv"), L.table("visited_states.csv")]
        for p in self.problems:
            targets.append(L.figure(f"{p}/response.png"))
            targets += [L.figure(f"{p}/fields_{c}.png") for c in self.problem_cases[p]]
            targets += [L.vtk(p, c) for c in self.problem_cases[p]]
            targets += [L.table(f"{p}/surrogate_{c}.csv") for c in self.problem_cases[p]]
            targets += [L.figure(f"{p}/calibration_{c}.png") for c in self.problem_cases[p]]
        if "biaxial" in self.problems:
            targets.append(L.table("biaxial_bands.csv"))
        if "footing" in self.problems:
            targets.append(L.table("footing.csv"))
        return targets
