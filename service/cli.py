"""The ``chizu`` command line: serve, repl, path."""

from __future__ import annotations

import asyncio
import os
import shutil
import sys
import tempfile
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from service.settings import get_settings

app = typer.Typer(help="chizu: hybrid symbolic-numeric planner for mobile robots.",
                  no_args_is_help=True)
console = Console()


@app.command()
def serve(host: str = typer.Option(None, help="default: CHIZU_HOST or 127.0.0.1"),
          port: int = typer.Option(None, help="default: CHIZU_PORT or 8000")) -> None:
    """Run the HTTP service (one worker: the Prolog engine lives in this process)."""
    import uvicorn

    from service.app import create_app

    s = get_settings()
    uvicorn.run(create_app(s), host=host or s.host, port=port or s.port, workers=1)


def _open_worlds():  # type: ignore[no-untyped-def]
    """A WorldService on the configured data directory (no HTTP), restored."""
    from service.kb import KnowledgeBase
    from service.store import Store
    from service.worlds import WorldService

    s = get_settings()
    store = Store(s.db_path)
    kb = KnowledgeBase(s.prolog_dir, s.kb_time_limit_s, s.kb_inference_limit)
    service = WorldService(store, kb)
    service.restore()
    if s.demo_world and store.world(s.demo_world) is None:
        from service.app import create_demo

        asyncio.run(create_demo(service, s.demo_world))
    return service


@app.command()
def path(world: str, source: str = typer.Argument(..., metavar="FROM"),
         target: str = typer.Argument(..., metavar="TO")) -> None:
    """Print the most probable DRM path FROM -> TO in WORLD."""
    from service.worlds import NotFound

    service = _open_worlds()
    try:
        p = asyncio.run(service.path(world, source, target))
    except NotFound as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    if p is None:
        console.print(f"no path from {source} to {target} in the DRM of {world}")
        raise typer.Exit(1)
    t = Table(title=f"{world}: {source} → {target}   P = {p.probability:.4f}")
    for col in ("from", "to", "method", "via", "p"):
        t.add_column(col)
    for s in p.steps:
        t.add_row(s.source, s.target, s.method, ",".join(s.via), f"{s.p:.4f}")
    console.print(t)


@app.command()
def repl(world: str) -> None:
    """Open swipl with the rule files and WORLD's facts loaded; try ?- reachable(a, c, P, M)."""
    from service.worlds import NotFound

    swipl = shutil.which("swipl")
    if swipl is None:
        console.print("[red]swipl is not installed (make run / make test install it)[/red]")
        raise typer.Exit(2)
    service = _open_worlds()
    try:
        facts = asyncio.run(service.facts(world))
    except NotFound as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    s = get_settings()
    fd, name = tempfile.mkstemp(prefix=f"chizu-{world}-", suffix=".pl")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        for fact in facts:  # written by Prolog itself (format ~k), read back as data
            f.write(fact + ".\n")
    service.kb.close()
    load = str(Path(s.prolog_dir) / "load.pl")
    argv = [swipl, "-g", "repl:main", load, "--", f"--world={world}", f"--facts={name}"]
    sys.stdout.flush()
    os.execv(swipl, argv)


if __name__ == "__main__":
    app()
