"""Baseline assistants of the paper's comparison (agents without DreamerV3's world model).

Names are imported lazily (PEP 562), so reading a config module (as the config schema does at
CLI start-up) does not import torch.
"""

from importlib import import_module

_EXPORTS = {
    "NoRSSMAgent": ".no_rssm",
    "NoRSSMState": ".no_rssm",
    "gae_advantages": ".no_rssm",
    "NoRSSMConfig": ".no_rssm_config",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
