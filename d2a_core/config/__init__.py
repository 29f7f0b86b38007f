"""Configuration: typed schema, shipped presets, and the preset < file < --set resolution.

The root schema (`d2a_core.config.schema.Config`) mounts the sections that subsystems define next
to their code; it is imported lazily here so those subsystems can import `Section` from this
package without a cycle.
"""

from d2a_core.config.loader import ResolvedConfig, available_presets, parse_yaml, resolve_config
from d2a_core.config.section import Section


def load(preset: str = "quick", config_file=None, overrides=(), pair: str | None = None) -> ResolvedConfig:
    """Resolve the project's root config (see `resolve_config`); `pair` (e.g. `left-right`) takes
    the preset's and file's `pairs.<pair>` values, for a run that trains or serves that pair."""
    from d2a_core.config.schema import Config
    from d2a_core.objectives.rewards import INTENTS

    return resolve_config(Config, preset, config_file, overrides, pair=pair, intents=INTENTS)


__all__ = ["ResolvedConfig", "Section", "available_presets", "load", "parse_yaml", "resolve_config"]
