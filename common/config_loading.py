"""Reading configuration into the tree (common/config.py): a file, ``--set`` and a recording's stored tree.

The tree holds the settings and why each has its value; this is how values reach it, checked
against its type hints so that a typo or a wrong type is named with its dotted key.
"""

from __future__ import annotations

import dataclasses
import tomllib
import typing
from pathlib import Path
from typing import Any

import yaml

from common.config import Config
from common.errors import ConfigError


def _coerce(value: Any, hint: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {value!r}")
        return _apply(hint(), value, where)
    if origin is list:
        if isinstance(value, str):
            value = [v for v in value.split(",") if v]
        if not isinstance(value, list):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        (item,) = typing.get_args(hint)
        return [_coerce(v, item, f"{where}[]") for v in value]
    if hint is bool:
        if isinstance(value, str) and value.lower() in ("true", "false", "1", "0", "yes", "no"):
            return value.lower() in ("true", "1", "yes")
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if hint in (int, float):
        try:
            if isinstance(value, bool):
                raise ValueError
            out = hint(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{where}: expected {hint.__name__}, got {value!r}") from None
        if hint is int and isinstance(value, float) and value != out:
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return out
    if hint is str:
        return "" if value is None else str(value)  # "key=" on the command line: the empty string
    raise ConfigError(f"{where}: unsupported type {hint!r}")


def _apply(obj: Any, values: dict[str, Any], where: str = "", unknown: list[str] | None = None) -> Any:
    """Set ``values`` on the tree; a key it lacks is an error, or, given ``unknown``, left out and listed there."""
    hints = typing.get_type_hints(type(obj))
    names = {f.name for f in dataclasses.fields(obj)}
    for key, value in values.items():
        path = f"{where}.{key}" if where else key
        if key not in names:
            if unknown is None:
                raise ConfigError(f"unknown configuration key {path!r}; known here: {sorted(names)}")
            unknown.append(path)
            continue
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current) and isinstance(value, dict):
            _apply(current, value, path, unknown)
        else:
            setattr(obj, key, _coerce(value, hints[key], path))
    return obj


def _parse_scalar(text: str) -> Any:
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def load_file(path: str | Path) -> dict[str, Any]:
    """Read a TOML, YAML or JSON configuration file into a plain mapping."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read configuration {p}: {exc.strerror}") from None
    try:
        data = tomllib.loads(text) if p.suffix == ".toml" else yaml.safe_load(text) or {}
    except (tomllib.TOMLDecodeError, yaml.YAMLError) as exc:
        raise ConfigError(f"{p}: not valid {p.suffix.lstrip('.') or 'YAML'}: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: the top level must be a table")
    return data


def parse_set(item: str) -> dict[str, Any]:
    """``voxel.edge=0.2`` -> ``{"voxel": {"edge": 0.2}}``."""
    if "=" not in item:
        raise ConfigError(f"--set takes key=value, got {item!r}")
    dotted, text = item.split("=", 1)
    keys = [k for k in dotted.strip().split(".") if k]
    if not keys:
        raise ConfigError(f"--set has an empty key: {item!r}")
    tree: dict[str, Any] = {keys[-1]: _parse_scalar(text)}
    for k in reversed(keys[:-1]):
        tree = {k: tree}
    return tree


def load_config(
    file: str | Path | None = None,
    sets: typing.Iterable[str] = (),
    base: dict[str, Any] | None = None,
    base_unknown: list[str] | None = None,
) -> Config:
    """Defaults in code, then ``base`` (e.g. a recording's metadata), then a file, then ``--set``.

    Given ``base_unknown``, keys of ``base`` this version lacks are left out and listed there: a
    recording stores the whole configuration that made it, and keys come and go between versions
    (session 54's ``tracker.upright_by_points`` became ``upright_by_points_m`` within the session),
    yet a log made by another version should still restart at a later stage. A file or ``--set``
    with an unknown key stays an error (a typo).
    """
    cfg = Config()
    if base:
        _apply(cfg, base, unknown=base_unknown)
    if file:
        _apply(cfg, load_file(file))
    for item in sets:
        _apply(cfg, parse_set(item))
    return cfg


def from_dict(values: dict[str, Any]) -> Config:
    """A configuration stored as a mapping (a recording's metadata) back into the tree."""
    return _apply(Config(), values)


def recording_overrides(info: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """What a recording says of itself that every stage must follow: its volume (KITTI's is longer)
    and its rig's settings (KITTI's disparity bias), by configuration section."""
    settings: dict[str, dict[str, Any]] = {}
    if isinstance(info.get("volume"), dict):
        settings["volume"] = dict(info["volume"])
    for section, values in (info.get("settings") or {}).items():
        if isinstance(values, dict):
            settings.setdefault(section, {}).update(values)
    return settings
