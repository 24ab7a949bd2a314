"""Project error classes: anything a user can cause raises one of these.

Each derives from the matching builtin so callers can catch either.
"""


class RATouchError(Exception):
    """Base class of every error the project raises on purpose."""


class ConfigError(RATouchError, ValueError):
    """A configuration field or argument has a value the code cannot use."""


class DataError(RATouchError, ValueError):
    """Input data (an image, a CSV, a corpus file) is malformed or inconsistent."""


class DataNotFoundError(RATouchError, FileNotFoundError):
    """A file or folder the user named does not exist."""


class ServiceError(RATouchError, RuntimeError):
    """An outside service (e.g. an LLM endpoint) failed or answered nonsense."""
