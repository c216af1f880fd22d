"""Errors of SSF-PAN: each carries one line that says what is wrong and, where it can, what to fix."""


class SsfError(Exception):
    """Base of every error the project reports to a user as one line."""


class ConfigError(SsfError):
    """A configuration file, parameter or flag is invalid."""


class MessageError(SsfError):
    """A message is malformed (wrong sizes, unknown field types, missing fields, bad values)."""


class BagError(SsfError):
    """A bag is missing, truncated, corrupt or holds something that cannot be decoded."""


class DataError(SsfError):
    """A data file (scan, dataset, weights) is missing or malformed."""


class MiddlewareError(SsfError):
    """The middleware could not be started or used (DDS domain, rclpy, QoS)."""
