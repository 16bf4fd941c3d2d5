"""Configuration: loading, defaults and validation against workflow/schemas/config.schema.yaml.

Errors name the offending key with a dotted path (``dem.n_spheres``), so a user knows
what to edit. Snakemake's ``common.smk`` and the tests both go through :func:`validate_config`.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import jsonschema
import yaml

SCHEMA_PATH = Path(__file__).resolve().parents[1] / "schemas" / "config.schema.yaml"
CONFIG_DIR = Path(__file__).resolve().parents[2] / "config"


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


def _from_text(value: Any, schema: dict) -> Any:
    """Numbers and booleans that arrive as strings, accepted as what they are: YAML 1.1 reads
    `1e-4` (no dot, no exponent sign) as a string, and Snakemake's --config reads the values
    nested in a mapping (`--config 'surrogate={epochs: 100, anchor_initial_state: false}'`, and
    `.inf`) as strings."""
    kind = schema.get("type")
    if isinstance(value, list) and kind == "array" and isinstance(schema.get("items"), dict):
        return [_from_text(v, schema["items"]) for v in value]
    if isinstance(value, str) and kind in ("number", "integer"):
        try:  # YAML's infinity is .inf (adaptive.thresholds)
            return float(value.replace(".inf", "inf")) if kind == "number" else int(value)
        except ValueError:
            return value
    if isinstance(value, str) and kind == "boolean":
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


#: keys the workflow itself puts into Snakemake's config for the report (never a setting):
#: workflow/rules/analysis.smk puts tables/headline.json under "headline" for the front page
REPORT_ONLY_KEYS = ("headline",)


def validate_config(config: dict, schema: dict | None = None) -> dict:
    """Fill defaults and validate; returns the completed config (a copy, without the
    :data:`REPORT_ONLY_KEYS`)."""
    schema = schema or load_schema()
    config = {k: copy.deepcopy(v) for k, v in dict(config).items() if k not in REPORT_ONLY_KEYS}
    _fill_defaults(config, schema)
    validator = jsonschema.Draft7Validator(schema)
    errors = sorted(validator.iter_errors(config), key=lambda e: list(e.absolute_path))
    if errors:
        lines = []
        for e in errors[:10]:
            key = _key(e.absolute_path)
            if e.validator == "additionalProperties":
                lines.append(f"config key '{key}': {e.message} (unknown key; see {SCHEMA_PATH.name})")
            else:
                lines.append(f"config key '{key}': {e.message}")
        raise ConfigError("invalid configuration:\n  " + "\n  ".join(lines))
    if not config["tolerance_study"]["path"]:
        config["tolerance_study"]["path"] = config["validation_path"]
    _check_consistency(config, schema)
    return config


def _check_set_settings(config: dict, schema: dict) -> None:
    """Each RVE-path set's own ``settings``: keys of rve_paths, with the section's schema."""
    from .dem.strain_paths import merged, set_section

    schema = schema["properties"]["rve_paths"]
    section_schema = {**schema, "properties": {k: v for k, v in schema["properties"].items() if k != "sets"}}
    for name, definition in config["rve_paths"]["sets"].items():
        settings = definition.get("settings", {})
        unknown = sorted(set(settings) - set(section_schema["properties"]))
        if unknown:
            raise ConfigError(f"config key 'rve_paths.sets.{name}.settings': unknown keys {unknown} (keys of rve_paths "
                              f"other than sets: {sorted(section_schema['properties'])})")
        errors = list(jsonschema.Draft7Validator(section_schema).iter_errors(merged(set_section(config), settings)))
        if errors:
            e = errors[0]
            raise ConfigError(f"config key 'rve_paths.sets.{name}.settings.{_key(e.absolute_path)}': {e.message}")


def _check_consistency(config: dict, schema: dict) -> None:
    from .paths import load_paths_from_config

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


def load_config(path: str | Path | None = None, overrides: dict | None = None) -> dict:
    """Read a YAML config (default config/config.yaml), apply overrides, validate."""
    path = Path(path) if path else CONFIG_DIR / "config.yaml"
    try:
        with open(path) as f:
            config = yaml.safe_load(f) or {}
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except yaml.YAMLError as e:
        raise ConfigError(f"config file {path} is not valid YAML: {e}") from None
    for key, value in (overrides or {}).items():
        node = config
        *parents, last = key.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[last] = value
    return validate_config(config)
