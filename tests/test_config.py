"""The shipped presets: parsed by the fast loader to the same values as PyYAML's own safe loader."""

from __future__ import annotations

from importlib import resources

import pytest
import yaml

from handeye import config


def _preset_names() -> list[str]:
    folder = resources.files("handeye.configs")
    names = [f.name[:-5] for f in folder.iterdir() if f.name.endswith(".yaml")]
    return sorted(names) + [f"robots/{n}" for n in config.arm_presets()]


@pytest.mark.parametrize("name", _preset_names())
def test_preset_loader_gives_safe_loaders_values(name):
    text = resources.files("handeye.configs").joinpath(f"{name}.yaml").read_text(encoding="utf-8")
    expected = yaml.safe_load(text) or {}
    got = config.load_preset(name)
    assert got == expected
    # the same types too (an int stays an int, a float a float: == alone would let 1 == 1.0 through)
    assert repr(got) == repr(expected)


def test_preset_loader_is_libyaml_when_available():
    assert config.PRESET_LOADER is getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    assert issubclass(config.PRESET_LOADER, yaml.constructor.SafeConstructor)


def test_load_preset_returns_a_fresh_copy():
    a = config.load_preset("qa")
    a["injected"] = 1
    assert "injected" not in config.load_preset("qa")


def test_unknown_preset_is_a_config_error():
    from handeye.errors import ConfigError

    with pytest.raises(ConfigError, match="no shipped preset named 'nope'"):
        config.load_preset("nope")
