"""The one root of chizu's errors a caller caused. Each names the offending field; the
service maps each class to its HTTP status (service/errors.py: 422, 404, 409), the CLI
prints it."""


class ChizuError(Exception):
    """Root of chizu's domain errors: a message and the field it is about."""

    status = 400  #: the HTTP status the service answers with

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field


class InvalidInput(ChizuError):
    """Input that is well-formed JSON but makes no sense for the method."""

    status = 422


class NotFound(ChizuError):
    """A world, run, session, job, template or landmark that does not exist."""

    status = 404


class Conflict(ChizuError):
    """A request that clashes with the current state (an existing name, a busy job)."""

    status = 409
