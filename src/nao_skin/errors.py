"""One exception type whose message is a single line naming the input at fault."""
from __future__ import annotations


class NaoSkinError(ValueError):
    """Bad input: the message is one line that names the file/touch/field and the problem."""

    def __init__(self, message: str):
        super().__init__(" ".join(str(message).split()))


class ConfigError(NaoSkinError):
    """A robot, skin or calibration configuration file is wrong."""


class DataError(NaoSkinError):
    """A recording, taxel file or message is wrong."""


class TooFewTouches(DataError):
    """The touches cannot determine what is asked yet: more touches will (a live update waits for them)."""


def one_line(exc: BaseException, limit: int = 300) -> str:
    """Any exception as one line for a report or a log: its type and message, whitespace collapsed."""
    return " ".join(f"{type(exc).__name__}: {exc}".split())[:limit]
