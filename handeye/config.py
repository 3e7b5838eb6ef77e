"""Presets shipped in ``configs/`` (installed as ``handeye.configs``) and site overrides."""

from __future__ import annotations

import copy
import functools
from importlib import resources
from pathlib import Path

import yaml

from .errors import ConfigError, InputError

#: the parser of the shipped presets: libyaml's when PyYAML has it (the same constructors and resolver as
#: ``yaml.SafeLoader``, so the same values; about 15x faster, and every calibration parses five presets)
PRESET_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def parse_yaml(text: str, *, path: str | Path, loader=yaml.SafeLoader):
    """The YAML document in ``text`` (read from ``path``); InputError naming the file and line when it is not YAML.

    A date or time that does not exist (``2026-02-30``, an offset of 25 h) is YAML's timestamp whose value
    Python cannot build: an InputError too, not the ValueError PyYAML lets through.
    """
    try:
        return yaml.load(text, Loader=loader)
    except yaml.YAMLError as e:
        line = getattr(getattr(e, "problem_mark", None), "line", None)
        raise InputError(
            "not valid YAML", path=path, line=None if line is None else line + 1, hint="fix the syntax of this file"
        ) from None
    except (ValueError, OverflowError) as e:  # a timestamp's constructor
        raise InputError(
            f"a date or time in this file does not exist ({' '.join(str(e).split())})",
            path=path,
            hint="write it as YYYY-MM-DD or YYYY-MM-DDTHH:MM:SS with a real day, hour and offset, or quote it",
        ) from None


def load_preset(name: str) -> dict:
    """A shipped preset by name (``calibration``, ``qa``...), found inside the installed package.

    Returns a fresh copy each call (callers may change it); the file is parsed once per process.
    """
    return copy.deepcopy(_parsed_preset(name))


@functools.lru_cache(maxsize=None)
def arm_presets() -> tuple:
    """Names of the shipped arm tables (``configs/robots/<name>.yaml``: ``rm65``, ``ur5e``, ...), sorted."""
    folder = resources.files("handeye.configs").joinpath("robots")
    return tuple(sorted(f.name[:-5] for f in folder.iterdir() if f.name.endswith(".yaml")))


@functools.lru_cache(maxsize=None)
def _parsed_preset(name: str) -> dict:
    try:
        text = resources.files("handeye.configs").joinpath(f"{name}.yaml").read_text(encoding="utf-8")
    except (FileNotFoundError, ModuleNotFoundError):
        raise ConfigError(f"no shipped preset named {name!r}", hint="reinstall handeye") from None
    return yaml.load(text, Loader=PRESET_LOADER) or {}


def merge(base: dict, override: dict, *, source: str = "override") -> dict:
    """Deep-merge ``override`` into a copy of ``base``; unknown keys are an error naming the key."""
    out = dict(base)
    for k, v in override.items():
        if k not in base:
            raise ConfigError(f"unknown setting {k!r}", path=source, expected=", ".join(sorted(base)))
        _check_type(k, base[k], v, source=source)
        out[k] = merge(base[k], v, source=source) if isinstance(base[k], dict) and isinstance(v, dict) else v
    return out


def _type_name(v) -> str:
    if isinstance(v, bool):
        return "true | false"
    if isinstance(v, (int, float)):
        return "a number"
    words: dict[type, str] = {dict: "a mapping", list: "a list", str: "a text"}
    return words.get(type(v), type(v).__name__)


def _check_type(key, base_value, value, *, source: str) -> None:
    """An override must have the preset value's type.

    An override must have the preset value's type (numbers are interchangeable; a null in the preset
    accepts anything, a null override is left to the setting's own check: it may mean "no limit").
    """
    if base_value is None or (value is None and not isinstance(base_value, dict)):
        return
    ok = {
        bool: lambda x: isinstance(x, bool),
        dict: lambda x: isinstance(x, dict),
        list: lambda x: isinstance(x, list),
        str: lambda x: isinstance(x, str),
    }.get(type(base_value))
    if ok is None and isinstance(base_value, (int, float)):
        ok = lambda x: isinstance(x, (int, float)) and not isinstance(x, bool)  # noqa: E731
    if ok is not None and (value is None or not ok(value)):
        raise ConfigError(
            f"setting {key!r} has the wrong type",
            path=source,
            expected=_type_name(base_value),
            received=repr(value)[:60],
            hint=f"write {key} like the shipped preset does",
        )


def load_with_override(name: str, override_path: str | Path | None) -> dict:
    cfg = load_preset(name)
    if override_path is None:
        return cfg
    from .output import read_text

    p = Path(override_path)
    data = parse_yaml(read_text(p, what="config file"), path=p) or {}
    if not isinstance(data, dict):
        raise ConfigError("expected a mapping at the top level", path=p)
    return merge(cfg, data, source=str(p))


def check_section(cls, section, *, name: str, source: str) -> dict:
    """``section`` of a preset as a mapping whose keys are exactly the fields of the dataclass ``cls``.

    Missing, unknown or non-mapping sections are a :class:`ConfigError` naming the section, the keys
    expected and the keys found (``source``: the preset file, for the message).
    """
    from dataclasses import fields

    if not isinstance(section, dict):
        raise ConfigError(f"section {name!r} must be a mapping", path=source, received=repr(section))
    names = {f.name for f in fields(cls)}
    unknown, missing = set(section) - names, names - set(section)
    if unknown or missing:
        raise ConfigError(
            f"section {name!r} does not match its settings",
            path=source,
            expected=", ".join(sorted(names)),
            received=f"unknown {sorted(unknown)}, missing {sorted(missing)}",
        )
    return section
