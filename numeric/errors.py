"""The one root of the errors a caller caused. Each names the offending field; the numeric
code says only what went wrong: the service maps each class to its answer
(service/errors.py), the CLI prints it."""


class ChizuError(Exception):
    """Root of chizu's domain errors: a message and the field it is about."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field


class InvalidInput(ChizuError):
    """Input that is well-formed JSON but makes no sense for the method."""


class NotFound(ChizuError):
    """A world, run, session, job, template or landmark that does not exist."""


class Conflict(ChizuError):
    """A request that clashes with the current state (an existing name, a busy job)."""
