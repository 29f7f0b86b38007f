"""Configuration: typed schema, shipped presets, and the preset < file < --set resolution."""

from d2a_core.config.loader import ResolvedConfig, available_presets, parse_yaml, resolve_config
from d2a_core.config.schema import Config, Section


def load(preset: str = "quick", config_file=None, overrides=()) -> ResolvedConfig:
    """Resolve the project's root config (see `resolve_config`)."""
    return resolve_config(Config, preset, config_file, overrides)


__all__ = ["Config", "ResolvedConfig", "Section", "available_presets", "load", "parse_yaml", "resolve_config"]
