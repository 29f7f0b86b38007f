"""Error types shared by the core and the CLI.

Each error carries the process exit code the CLI should use, so the core decides what kind of
failure happened and the CLI only reports it. Codes: 1 runtime failure, 2 usage or config
error, 3 integrity failure.
"""

from __future__ import annotations


class D2AError(Exception):
    """Base class of every error d2a reports to a user."""

    exit_code = 1


class UsageError(D2AError):
    """The user asked for something invalid (bad argument, bad input file)."""

    exit_code = 2


class ConfigError(UsageError):
    """A config value is unknown, mistyped or out of range. The message names key, value and source."""


class SpecError(UsageError):
    """A track spec or centreline file is invalid. The message names the file and the field or line."""


class NotFoundError(UsageError):
    """An artifact id, prefix or alias does not exist. The message names it and close matches."""


class IntegrityError(D2AError):
    """Stored data does not match its recorded hash."""

    exit_code = 3


class TrainingError(D2AError):
    """Training cannot continue (for example a non-finite loss)."""

    exit_code = 1


class AmbiguousRefError(UsageError):
    """An id prefix matches several artifacts. Not a NotFoundError: nothing is missing, so callers
    that fall back to another lookup on NotFoundError must not swallow it."""


class StoreError(D2AError):
    """The store's filesystem refused an operation (read-only, full, a file where a directory
    belongs). The message names the path and the OS reason."""

    exit_code = 1
