"""One error hierarchy: shells catch only these, count them and keep running."""

from __future__ import annotations


class StereovoxError(Exception):
    """Base of every error stereovox raises on purpose."""


class DecodeError(StereovoxError):
    """A message could not be decoded: what was wrong, and the offending value or limit."""


class ConfigError(StereovoxError):
    """A configuration key, value or file is not valid."""


class RecordingError(StereovoxError):
    """A recording is missing, not MCAP, or truncated; names the file and the offset."""

    def __init__(self, message: str, path: str | None = None, offset: int | None = None) -> None:
        where = ""
        if path is not None:
            where = f"{path}"
            if offset is not None:
                where += f" at byte {offset}"
            where += ": "
        super().__init__(where + message)
        self.path = path
        self.offset = offset


class CalibrationError(StereovoxError):
    """A calibration is unusable (zero or NaN focal length or baseline, wrong image size)."""


class InputError(StereovoxError):
    """An input (image pair, cloud, dataset file) is malformed; names what and where."""


class BusError(StereovoxError):
    """The bus could not be opened or a key is not valid."""
