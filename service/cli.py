"""The ``chizu`` command line: serve, repl, path, slam, slam-eval, slam-sim."""

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


def _slam_outputs(out: Path, times, poses, grid) -> None:  # type: ignore[no-untyped-def]
    from numeric.slam.logs import write_tum

    out.mkdir(parents=True, exist_ok=True)
    write_tum(out / "trajectory.tum", times, poses)
    (out / "map.png").write_bytes(grid.to_png())
    (out / "map.pgm").write_bytes(grid.to_pgm())
    (out / "map.yaml").write_text(grid.to_yaml("map.pgm"))


@app.command()
def slam(log: str = typer.Argument(..., help="CARMEN .clf/.log or ROS .bag (or bag dir)"),
         method: str = typer.Option("rbpf", help="odom | icp | gated | rbpf"),
         particles: int = typer.Option(512, min=1, max=4096),
         alpha: float = typer.Option(0.0, min=0.0, help="intensity weight (eqs. 1, 9)"),
         proposal: str = typer.Option("odometry", help="RBPF proposal: odometry | gated-icp"),
         max_range: float = typer.Option(40.0, min=0.1, help="usable range (m)"),
         resolution: float = typer.Option(0.05, min=0.01, help="map cell size (m)"),
         limit: int = typer.Option(0, min=0, help="only the first N scans (0: all)"),
         seed: int = typer.Option(0, min=0),
         out: str = typer.Option("slam-out", help="output directory")) -> None:
    """Run SLAM over LOG; write OUT/trajectory.tum (TUM, the log's stamps), map.png
    (intensity-coloured), map.pgm + map.yaml (ROS map_server)."""
    from pydantic import ValidationError
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from numeric.errors import InvalidInput
    from numeric.slam.logs import read_log
    from numeric.slam.runner import SlamOptions, run_log

    try:
        opts = SlamOptions(method=method, particles=particles, alpha=alpha,  # type: ignore[arg-type]
                           proposal=proposal, map_resolution_m=resolution,  # type: ignore[arg-type]
                           seed=seed)
        data = read_log(Path(log), max_range_m=max_range, limit=limit or None)
    except (ValidationError, InvalidInput) as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                  TextColumn("{task.completed}/{task.total} scans"), TimeRemainingColumn(),
                  console=console, transient=True) as bar:
        task = bar.add_task(f"{opts.method} {data.name}", total=len(data))
        try:
            _, res = run_log(data, opts, lambda i: bar.update(task, completed=i))
        except InvalidInput as e:
            console.print(f"[red]{e}[/red]")
            raise typer.Exit(2) from None
    _slam_outputs(Path(out), res.times, res.poses, res.map)
    console.print(f"{opts.method}: {len(data)} scans ({data.duration_s:.0f} s of log) in "
                  f"{res.seconds:.1f} s = {data.duration_s / max(res.seconds, 1e-9):.1f}x real "
                  f"time; wrote {out}/trajectory.tum, map.png, map.pgm, map.yaml")


@app.command("slam-eval")
def slam_eval(trajectory: Path, relations: Path,
              max_dt: float = typer.Option(0.1, help="pose-to-relation time tolerance (s)"),
              ) -> None:
    """Relation errors (Kümmerle et al. 2009) of a TUM TRAJECTORY against RELATIONS."""
    from numeric.errors import InvalidInput
    from numeric.slam.evaluation import relation_errors
    from numeric.slam.logs import read_relations, read_tum

    try:
        t, p = read_tum(trajectory)
        rt, rd = read_relations(relations)
        e = relation_errors(t, p, rt, rd, max_dt)
    except InvalidInput as exc:
        console.print(f"[red]{exc}[/red]")
        raise typer.Exit(2) from None
    table = Table(title=f"{trajectory} vs {relations.name}: {e.n} relations"
                        + (f" ({e.missing} without poses)" if e.missing else ""))
    for col in ("error", "mean", "std"):
        table.add_column(col)
    table.add_row("abs trans (m)", f"{e.trans_m:.4f}", f"{e.trans_std_m:.4f}")
    table.add_row("sq trans (m²)", f"{e.trans_sq_m2:.4f}", f"{e.trans_sq_std_m2:.4f}")
    table.add_row("abs rot (deg)", f"{e.rot_deg:.3f}", f"{e.rot_std_deg:.3f}")
    table.add_row("sq rot (deg²)", f"{e.rot_sq_deg2:.3f}", f"{e.rot_sq_std_deg2:.3f}")
    console.print(table)


@app.command("slam-sim")
def slam_sim(template: str = typer.Argument("corridor", help="built-in world"),
             out: str = typer.Option("sim.clf", help="CARMEN log to write"),
             seed: int = typer.Option(0, min=0)) -> None:
    """Record a simulated URG-04LX log (with intensities) in a built-in world as a
    CARMEN ROBOTLASER1 log, plus OUT.truth.tum with the true poses."""
    from numeric.errors import InvalidInput
    from numeric.slam.logs import write_carmen, write_tum
    from numeric.slam.simulate import TOURS, simulated_log

    try:
        log = simulated_log(template, seed=seed)
    except (InvalidInput, KeyError) as e:
        console.print(f"[red]no simulated tour for {template!r}; try one of {sorted(TOURS)}"
                      f" ({e})[/red]")
        raise typer.Exit(2) from None
    write_carmen(out, log)
    assert log.truth is not None
    write_tum(Path(str(out) + ".truth.tum"), log.times, log.truth)
    console.print(f"wrote {out} ({len(log)} scans) and {out}.truth.tum")


if __name__ == "__main__":
    app()
