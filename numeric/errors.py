"""Domain errors raised by numeric code; the service maps them to problem responses."""


class ChizuError(Exception):
    """Root of chizu's domain errors."""


class InvalidInput(ChizuError):
    """Input that is well-formed JSON but makes no sense for the method."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field
