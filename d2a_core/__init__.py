"""d2a core: simulator, agents, training, evaluation and the artifact store (no CLI code)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("d2a")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+unknown"
