"""The web console: a page served at ``/`` that shows what the robot knows — worlds, the
map with its landmarks, objects and committed grid, the DRM and paths, the eigenspace,
missions, jobs and Prolog queries — drawn from the same REST API every client uses.

Static files only (``static/``, shipped in the package, no CDN, no build step): the page
works offline, like ``/docs``.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

STATIC = Path(__file__).parent / "static"


def install(app: FastAPI) -> None:
    """``GET /`` serves the console's page, ``/console/*`` its scripts and styles."""
    app.mount("/console", StaticFiles(directory=STATIC), name="console")

    @app.get("/", include_in_schema=False)
    async def console_page() -> FileResponse:
        return FileResponse(STATIC / "index.html", media_type="text/html")
