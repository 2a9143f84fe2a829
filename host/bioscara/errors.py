"""Exceptions carrying the original driver's error codes, with messages that name the joint."""

from __future__ import annotations

from enum import IntEnum

from .firmware.spec import protocol

ErrorCode = IntEnum("ErrorCode", {name: value for value, name, _ in protocol.ERROR_CODES})
ErrorCode.__doc__ = "Error codes of the original Bioscara driver (uErr.h)."


class BioscaraError(Exception):
    """Base of every error this package raises on purpose. `code` is the original error code."""

    code: ErrorCode = ErrorCode.ERROR

    def __init__(self, message: str, *, joint: str | None = None) -> None:
        self.joint = joint
        self.detail = message
        prefix = f"{joint}: " if joint else ""
        super().__init__(f"{prefix}{message} [{self.code.name}: {protocol.error_string(self.code)}]")

    @property
    def message(self) -> str:
        """The error as a user reads it: `JOINT: what`, without the original driver's code."""
        return f"{self.joint}: {self.detail}" if self.joint else self.detail


class NotHomedError(BioscaraError):
    code = ErrorCode.NOT_HOMED


class NotEnabledError(BioscaraError):
    code = ErrorCode.NOT_ENABLED


class StalledError(BioscaraError):
    code = ErrorCode.STALLED


class NotInitError(BioscaraError):
    code = ErrorCode.NOT_INIT


class CommError(BioscaraError):
    code = ErrorCode.COMM_ERROR


class InvalidArgumentError(BioscaraError, ValueError):
    code = ErrorCode.INVALID_ARGUMENT


class IncorrectStateError(BioscaraError):
    code = ErrorCode.INCORRECT_STATE


class ConfigError(BioscaraError, ValueError):
    """A configuration file or value is invalid; the message lists every problem found."""

    code = ErrorCode.INVALID_ARGUMENT

