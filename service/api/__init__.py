"""The HTTP routes (one module per part of the API, in ``routes/``) and the typed client's
generator (:mod:`chizu.service.api.client_gen`)."""

from fastapi.routing import APIRoute


def operation_id(route: APIRoute) -> str:
    """``<routes module>.<route function>``, e.g. ``qualitative.get_path``: the OpenAPI's
    operation ids, and the typed client's groups and method names."""
    return f"{route.endpoint.__module__.rsplit('.', 1)[-1]}.{route.name}"
