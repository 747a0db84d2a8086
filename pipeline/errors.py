"""The one error family of the project.

Every error a user can cause (a bad config, a broken input file, a failed task) is a :class:`GenError`, so a
caller can catch them all in one place and the CLI can print them without a traceback.
"""

from __future__ import annotations


class GenError(Exception):
    """Base class of every error this project raises on purpose."""


class ConfigError(GenError):
    """A config file or override is wrong. The message names the key path, e.g. ``objects.density``."""


class StageError(GenError):
    """A stage was asked for something it cannot do (unknown stage name, missing upstream output)."""


class LockError(GenError):
    """Another run holds the lock on the output folder."""
