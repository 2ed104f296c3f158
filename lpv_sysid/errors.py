"""Project-wide exception types.

Every error raised for bad input derives from :class:`LpvSysidError` so the CLI can
turn it into a one-line message and exit code 2.
"""


class LpvSysidError(Exception):
    """Base class for all errors caused by bad input or an unusable environment."""


class ConfigError(LpvSysidError):
    """A configuration or data file is malformed; the message names the field."""


class FileReadError(ConfigError):
    """A user file cannot be read at all (missing, not a regular file, too large, permission,
    not UTF-8): ``path`` and ``reason`` (e.g. ``"Permission denied"``) for callers that word
    the message themselves; ``str()`` is the full one-line message."""

    def __init__(self, message: str, path: str = "", reason: str = ""):
        super().__init__(message)
        self.path = path
        self.reason = reason or message


class BagError(LpvSysidError):
    """A rosbag2 recording cannot be read or written."""


class SafetyError(LpvSysidError):
    """A condition that must put the vehicle into a safe state."""


class SolverError(LpvSysidError):
    """An optimisation problem (LMI, least squares) failed or was infeasible."""
