"""YAML presets shipped with handeye (installed as ``handeye.configs``); see handeye/config.py."""
