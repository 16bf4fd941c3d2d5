"""Configuration: loading, defaults and validation against workflow/schemas/config.schema.yaml.

Errors name the offending key with a dotted path (``dem.n_spheres``), so a user knows
what to edit. Snakemake's ``common.smk`` and the tests both go through :func:`validate_config`.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import jsonschema
import yaml

SCHEMA_PATH = Path(__file__).resolve().parents[1] / "schemas" / "config.schema.yaml"
REPO_ROOT = Path(__file__).resolve().parents[2]
CONFIG_DIR = REPO_ROOT / "config"
#: schema keyword of the numbers for which +inf means something (adaptive.thresholds: never
#: promote); jsonschema ignores keywords it does not know
ALLOW_INFINITY = "x-allow-infinity"


class ConfigError(ValueError):
    """Invalid configuration; the message names the key."""


def _key(path) -> str:
    parts = []
    for p in path:
        if isinstance(p, int):
            parts.append(f"[{p}]")
        else:
            parts.append(("." if parts else "") + str(p))
    return "".join(parts) or "<top level>"


def _as_number(text: str, kind: str) -> Any:
    """A number from its text, YAML's spellings of infinity and nan (.inf, -.Inf, .NaN) included,
    so that a non-finite value from --config is refused as one, not as a string."""
    if kind == "integer":
        return int(text)
    return float(text.strip().lower().replace(".inf", "inf").replace(".nan", "nan"))


def _from_text(value: Any, schema: dict) -> Any:
    """Numbers and booleans that arrive as strings, accepted as what they are: YAML 1.1 reads
    `1e-4` (no dot, no exponent sign) as a string, and Snakemake's --config reads the values
    nested in a mapping (`--config 'surrogate={epochs: 100, anchor_initial_state: false}'`, and
    `.inf`) as strings."""
    kinds = schema.get("type")
    kinds = set(kinds) if isinstance(kinds, list) else {kinds}
    items = schema.get("items")
    if isinstance(value, list) and "array" in kinds:
        if isinstance(items, dict):
            return [_from_text(v, items) for v in value]
        if isinstance(items, list):  # tuple form, e.g. a load path's [steps, target]
            return [_from_text(v, sub) for v, sub in zip(value, items)] + value[len(items):]
    if isinstance(value, str) and kinds & {"number", "integer"}:
        for kind in ("integer", "number"):
            if kind in kinds:
                try:
                    return _as_number(value, kind)
                except ValueError:
                    pass
        return value
    if isinstance(value, str) and "boolean" in kinds:
        return {"true": True, "false": False}.get(value.strip().lower(), value)
    return value


def _fill_defaults(instance: Any, schema: dict) -> None:
    if not isinstance(instance, dict):
        return
    props = schema.get("properties", {})
    for name, sub in props.items():
        if name not in instance and "default" in sub:
            instance[name] = copy.deepcopy(sub["default"])
        if name in instance:
            instance[name] = _from_text(instance[name], sub)
            _fill_defaults(instance[name], sub)
    extra = schema.get("additionalProperties")
    if isinstance(extra, dict):
        for name, value in instance.items():
            if name not in props:
                _fill_defaults(value, extra)


def load_schema() -> dict:
    with open(SCHEMA_PATH) as f:
        return yaml.safe_load(f)


def _non_finite(value: Any, schema: dict, path: list, found: list) -> None:
    """Collect (path, value, +inf allowed) of every nan and ±inf under ``value``, following the
    schema (properties, additionalProperties, items in either form) only to find the
    :data:`ALLOW_INFINITY` marks; parts without a schema are walked all the same. Needed because
    a schema's minimum/maximum let nan through (every comparison with nan is false)."""
    if isinstance(value, float) and not math.isfinite(value):
        allow = bool(schema.get(ALLOW_INFINITY))
        if not (allow and value > 0):
            found.append((path, value, allow))
    elif isinstance(value, dict):
        props, extra = schema.get("properties", {}), schema.get("additionalProperties")
        for name, v in value.items():
            _non_finite(v, props.get(name, extra if isinstance(extra, dict) else {}), path + [name], found)
    elif isinstance(value, (list, tuple)):
        items = schema.get("items", {})
        for i, v in enumerate(value):
            sub = items if isinstance(items, dict) else (items[i] if i < len(items) else {})
            _non_finite(v, sub, path + [i], found)


def _finite_errors(config: dict, schema: dict) -> list[str]:
    found: list = []
    _non_finite(config, schema, [], found)
    lines = []
    for path, value, allow in found:
        if allow:
            lines.append(f"config key '{_key(path)}': {value} is not allowed (a finite number, or .inf)")
        elif math.isinf(value):
            lines.append(f"config key '{_key(path)}': {value} is not a finite number (.inf, or a number beyond "
                         f"1.8e308 such as 1e999)")
        else:
            lines.append(f"config key '{_key(path)}': {value} is not a finite number")
    return lines


def _check_output_dir(config: dict) -> None:
    """output_dir, normalised once (no trailing slash, relative stays relative: rules build
    f"{OUT}/..." paths); refused where outputs would land on / or among the sources."""
    raw = config["output_dir"]
    if not raw.strip():
        raise ConfigError(f"config key 'output_dir': {raw!r} is empty; name a folder for the outputs, e.g. results")
    folder = raw.rstrip("/") or "/"
    resolved = Path(folder).resolve()
    if resolved == Path(resolved.anchor):
        raise ConfigError(f"config key 'output_dir': {raw!r} is the filesystem root; name a folder for the outputs")
    if resolved == REPO_ROOT:
        raise ConfigError(f"config key 'output_dir': {raw!r} is the repository itself ({REPO_ROOT}); outputs would "
                          f"mix with the sources, name a subfolder such as results")
    config["output_dir"] = folder


def _refuse(lines: list[str]) -> None:
    if len(lines) == 1:  # one problem, one line (Snakemake prints it as "Configuration error: ...")
        raise ConfigError(f"invalid configuration: {lines[0]}")
    raise ConfigError("invalid configuration:\n  " + "\n  ".join(lines[:10]))


#: (section, key) of a key that moved -> where its setting lives now
MOVED_KEYS = {("adaptive", "problem_threshold"): "each problem's own: biaxial.adaptive.threshold, "
                                                  "footing.adaptive.threshold"}


def validate_config(config: dict, schema: dict | None = None) -> dict:
    """Fill defaults and validate; returns the completed config (a copy). A key the schema does not
    know is refused, naming it (also ``headline``: the workflow keeps no numbers of a run in its
    config; they reach the report as the pages of rule headline)."""
    schema = schema or load_schema()
    config = copy.deepcopy(dict(config))
    _fill_defaults(config, schema)
    non_finite = _finite_errors(config, schema)  # first: the schema's bounds would let nan pass
    if non_finite:
        _refuse(non_finite)
    validator = jsonschema.Draft7Validator(schema)
    errors = sorted(validator.iter_errors(config), key=lambda e: list(e.absolute_path))
    if errors:
        lines = []
        for e in errors:
            key = _key(e.absolute_path)
            moved = [f"'{key}.{name}' is now {MOVED_KEYS[key, name]}" for name in e.instance
                     if (key, name) in MOVED_KEYS] if e.validator == "additionalProperties" else []
            if moved:
                lines.append(f"config key {'; '.join(moved)}")
            elif e.validator == "additionalProperties":
                lines.append(f"config key '{key}': {e.message} (unknown key; see {SCHEMA_PATH.name})")
            else:
                lines.append(f"config key '{key}': {e.message}")
        _refuse(lines)
    _check_output_dir(config)
    if not config["tolerance_study"]["path"]:
        config["tolerance_study"]["path"] = config["validation_path"]
    _check_consistency(config, schema)
    return config


def merged(base: dict, override: dict) -> dict:
    """`base` with the keys of `override` replaced, nested mappings key by key."""
    out = dict(base)
    for key, value in override.items():
        out[key] = merged(base[key], value) if isinstance(value, dict) and isinstance(base.get(key), dict) else value
    return out


def rve_paths_section(config: dict) -> dict:
    """The ``rve_paths`` settings every RVE-path set starts from (all but ``sets``)."""
    return {k: v for k, v in config["rve_paths"].items() if k != "sets"}


def _check_set_settings(config: dict, schema: dict) -> None:
    """Each RVE-path set's own ``settings``: keys of rve_paths, with the section's schema."""
    schema = schema["properties"]["rve_paths"]
    section_schema = {**schema, "properties": {k: v for k, v in schema["properties"].items() if k != "sets"}}
    for name, definition in config["rve_paths"]["sets"].items():
        settings = definition.get("settings", {})
        unknown = sorted(set(settings) - set(section_schema["properties"]))
        if unknown:
            raise ConfigError(f"config key 'rve_paths.sets.{name}.settings': unknown keys {unknown} (keys of rve_paths "
                              f"other than sets: {sorted(section_schema['properties'])})")
        errors = list(jsonschema.Draft7Validator(section_schema).iter_errors(merged(rve_paths_section(config), settings)))
        if errors:
            e = errors[0]
            raise ConfigError(f"config key 'rve_paths.sets.{name}.settings.{_key(e.absolute_path)}': {e.message}")


def _check_weak_zone_sources(config: dict) -> None:
    """The weak zone's networks train on RVE-path sets of the weak packing, and only they do."""
    sets = config.get("rve_paths", {}).get("sets", {})
    key = "config key 'surrogate.weak_zone_sources'"
    weak_sources = config["surrogate"]["weak_zone_sources"]
    for source in weak_sources:
        name = source.split(":", 1)[1]
        if name not in sets:
            raise ConfigError(f"{key}: {source!r} names no set of 'rve_paths.sets' (defined: {sorted(sets)})")
        if sets[name]["packing"] != "weak_zone":
            raise ConfigError(f"{key}: the set {name!r} drives the specimen's packings; the weak zone's networks "
                              f"need a set with 'rve_paths.sets.{name}.packing: weak_zone'")
    for source in config["surrogate"]["training_sources"]:
        name = source.split(":", 1)[1] if source.startswith("rve_paths:") else None
        if name in sets and sets[name]["packing"] == "weak_zone":
            raise ConfigError(f"config key 'surrogate.training_sources': the set {name!r} drives the weak zone's "
                              f"packing, another material than the specimen's; list it in "
                              f"'surrogate.weak_zone_sources' instead")
    for name, definition in sets.items():
        if definition["packing"] == "weak_zone" and definition["consolidation_pressure"] != 1.0:
            raise ConfigError(f"config key 'rve_paths.sets.{name}.consolidation_pressure': "
                              f"{definition['consolidation_pressure']:g} needs the specimen's packings (packing: "
                              "specimen); the weak zone's packing is consolidated at specimen.confining_pressure")


def _check_consistency(config: dict, schema: dict) -> None:
    from .paths import load_paths_from_config

    dem = config["dem"]
    if dem["diameter_min"] >= dem["diameter_max"]:  # YADE's psd would make one size, or none
        raise ConfigError(f"config key 'dem.diameter_min': {dem['diameter_min']} is not below "
                          f"'dem.diameter_max' ({dem['diameter_max']})")
    paths = load_paths_from_config(config)
    for key in ("training_path", "validation_path"):
        if config[key] not in paths:
            raise ConfigError(
                f"config key '{key}': unknown path {config[key]!r}; defined paths: {sorted(paths)}"
            )
    for source in config["surrogate"]["training_sources"]:
        kind, _, name = source.rpartition(":")
        if kind and name not in config.get("rve_paths", {}).get("sets", {}):
            raise ConfigError(f"config key 'surrogate.training_sources': {source!r} names no set of 'rve_paths.sets' "
                              f"(defined: {sorted(config.get('rve_paths', {}).get('sets', {}))})")
        if not kind and name not in paths:
            raise ConfigError(f"config key 'surrogate.training_sources': unknown load path {name!r}; defined paths: "
                              f"{sorted(paths)}")
    _check_weak_zone_sources(config)
    _check_set_settings(config, schema)
    for key, names in (("adaptive.paths", config["adaptive"]["paths"]),
                       ("adaptive.active_learning.paths", config["adaptive"]["active_learning"]["paths"])):
        for name in names:
            if name not in paths:
                raise ConfigError(f"config key '{key}': unknown load path {name!r}; defined paths: {sorted(paths)}")
    study = config["tolerance_study"]
    if study["path"] not in paths:
        raise ConfigError(f"config key 'tolerance_study.path': unknown path {study['path']!r}; defined paths: "
                          f"{sorted(paths)}")
    for key in ("converged", "baseline"):
        if study[key] not in study["variants"]:
            raise ConfigError(f"config key 'tolerance_study.{key}': {study[key]!r} is not one of the variants "
                              f"{sorted(study['variants'])}")


def read_config_file(path: str | Path) -> dict:
    """The mapping of a YAML config file; a ConfigError of one line naming the file, and for
    invalid YAML the line and column (Snakemake's own message names neither)."""
    try:
        with open(path) as f:
            config = yaml.safe_load(f)
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        context, start = getattr(e, "context", None), getattr(e, "context_mark", None)
        if context and start:  # where the construct that is left unfinished began
            problem += f" ({context} at line {start.line + 1}, column {start.column + 1})"
        raise ConfigError(f"config file {path} is not valid YAML{where}: {problem}") from None
    if config is not None and not isinstance(config, dict):
        raise ConfigError(f"config file {path}: the top level must be a mapping of keys, not {type(config).__name__}")
    return config or {}


def load_config(path: str | Path | list | tuple | None = None, overrides: dict | None = None) -> dict:
    """Read a YAML config (default config/config.yaml), or several merged in order as Snakemake
    merges --configfile files (a nested key replaces only itself), apply overrides, validate."""
    paths = list(path) if isinstance(path, (list, tuple)) else [path or CONFIG_DIR / "config.yaml"]
    config = {}
    for file in paths:
        config = merged(config, read_config_file(Path(file)))
    for key, value in (overrides or {}).items():
        node = config
        *parents, last = key.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[last] = value
    return validate_config(config)


#: the Newton settings that dem.newton (and a problem's dem_newton) override for FEM–DEM runs
NEWTON_OVERRIDES = ("tolerance", "max_iterations", "max_cutbacks", "line_search", "tangent_repair", "acceleration",
                    "anderson_depth", "predictor")


def problem_adaptive_config(config: dict, problem: str) -> tuple[dict, float]:
    """The config and threshold of the adaptive run of `problem` (biaxial, footing): the section
    ``adaptive`` with the keys the problem's ``adaptive`` sets, and that section's threshold."""
    settings = dict(config[problem]["adaptive"])
    threshold = float(settings.pop("threshold"))
    cfg = copy.deepcopy(config)
    cfg["adaptive"].update(settings)
    return cfg, threshold


def adaptive_tangent(config: dict) -> str:
    """The networks' tangent in an adaptive run of `config`: adaptive.tangent, or surrogate.tangent
    where that is null."""
    return config["adaptive"].get("tangent") or config["surrogate"]["tangent"]


def dem_newton_config(config: dict, problem: str = "triaxial") -> dict:
    """The config a FEM–DEM run of `problem` uses: ``newton`` with the overrides of ``dem.newton``,
    and then those of the problem's ``dem_newton`` (the plane-strain problems' sections)."""
    cfg = copy.deepcopy(config)
    for key in NEWTON_OVERRIDES:
        if key in cfg["dem"].get("newton", {}):
            cfg["newton"][key] = cfg["dem"]["newton"][key]
    if problem != "triaxial":
        cfg["newton"].update(cfg[problem].get("dem_newton", {}))
    return cfg


def reference_newton_config(config: dict, problem: str = "triaxial") -> dict:
    """The config the reference run of `problem` is solved with: :func:`dem_newton_config` for
    FEM–DEM (``reference_material: dem``), the config as it is for the analytic reference."""
    return dem_newton_config(config, problem) if config["reference_material"] == "dem" else copy.deepcopy(config)
