"""DreamerV3 agent (Hafner et al. 2023, the "v1" algorithm the Dream2Assist paper uses).

Names are imported lazily (PEP 562), so reading `d2a_core.agents.dreamer.config` (as the config
schema does at CLI start-up) does not import torch.
"""

from importlib import import_module

_EXPORTS = {
    "DreamerAgent": ".agent",
    "PolicyState": ".agent",
    "DreamerConfig": ".config",
    "HeadConfig": ".config",
    "ExpertFilter": ".expert",
    "ExpertPrediction": ".expert",
    "HEAD_KINDS": ".heads",
    "WorldModelHead": ".heads",
    "register_head": ".heads",
    "SequenceReplay": ".replay",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
