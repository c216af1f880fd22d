"""Errors of SSF-PAN: each carries one line that says what is wrong and, where it can, what to fix."""

# Characters that would break a message into several lines (str.splitlines splits on all of them) or move the
# cursor; user input quoted in a message (a file name, a parameter name) must not do either.
_LINE_BREAKERS = {code: f"\\x{code:02x}" for code in (*range(0x20), 0x7F, 0x85)}
_LINE_BREAKERS |= {ord("\n"): "\\n", ord("\r"): "\\r", ord("\t"): " ", 0x2028: "\\u2028", 0x2029: "\\u2029"}


class SsfError(Exception):
    """Base of every error the project reports to a user as one line."""

    def __str__(self) -> str:
        return super().__str__().translate(_LINE_BREAKERS)


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
