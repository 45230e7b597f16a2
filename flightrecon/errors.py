"""User-facing errors.

Bad input (a missing or corrupt file, a bad config key, NaN data) is reported as one clear message
naming the file or key; the CLI prints it and exits with code 2, without a traceback unless --debug.
"""

from __future__ import annotations


class FlightReconError(Exception):
    """An error caused by the user's input, worded for the user."""

    exit_code = 2


class ConfigError(FlightReconError):
    """An unknown key or an invalid value in a scenario config; the message names the key."""


class SceneError(FlightReconError):
    """A scene file that is missing, truncated, malformed, empty or holds NaN; names the file."""


class DataError(FlightReconError):
    """Sensor or dataset content that cannot be used (NaN or empty depth, missing frames)."""


class CheckpointError(FlightReconError):
    """A checkpoint this version cannot resume (another format or version, or a torn file); the
    message names the file, what it holds and what to do."""
