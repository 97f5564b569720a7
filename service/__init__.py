"""chizu service: FastAPI app, Prolog bridge, store and CLI."""

from importlib.metadata import version

#: the distribution's version, kept in one place: pyproject.toml
__version__ = version("chizu")
