"""Exceptions shared across threedcal: one base class so the CLI can turn any of them into one line."""


class ThreedcalError(Exception):
    """Base of every error threedcal raises on purpose (bad input, hardware faults, ...)."""


class ConfigError(ThreedcalError, ValueError):
    """A configuration, profile, plan or data file is invalid; the message names the file and key."""


class FrameSizeError(ConfigError):
    """A frame (or blank) whose size a model cannot take; the caller adds which file it was."""


class TrainingError(ThreedcalError, ArithmeticError):
    """A training step's loss stopped being finite; the message names the job and what to change."""


class RegistrationError(ThreedcalError):
    """The probe frames do not register the camera (too few contacts, mismatched shapes, ...)."""
