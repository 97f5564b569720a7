"""The ``chizu`` command line: serve, repl, path, slam, slam-eval, slam-sim, plan, summarise,
eigenspace (export, learn, localize)."""

from __future__ import annotations

import asyncio
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from chizu.service.settings import get_settings

app = typer.Typer(help="chizu: hybrid symbolic-numeric planner for mobile robots.",
                  no_args_is_help=True)
console = Console()


def _print_version(value: bool) -> None:
    if value:
        from chizu.service import __version__

        console.print(f"chizu {__version__}")
        raise typer.Exit()


@app.callback()
def _process(version: Annotated[bool, typer.Option(
        "--version", callback=_print_version, is_eager=True,
        help="Print the version and exit.")] = False) -> None:
    """chizu: hybrid symbolic-numeric planner for mobile robots."""
    from chizu.numeric.memory import return_large_frees

    return_large_frees()  # long SLAM runs make and drop large grids


@app.command()
def serve(host: str = typer.Option(None, help="default: CHIZU_HOST or 127.0.0.1"),
          port: int = typer.Option(None, help="default: CHIZU_PORT or 8000")) -> None:
    """Run the HTTP service (one worker: the Prolog engine lives in this process)."""
    import uvicorn

    from chizu.service.app import create_app

    s = get_settings()
    uvicorn.run(create_app(s), host=host or s.host, port=port or s.port, workers=1)


def _open_services():  # type: ignore[no-untyped-def]
    """The service's own wiring on the configured data directory (no HTTP): every
    world restored with its events and artifacts, as the app starts
    (:func:`chizu.service.container.open_services`)."""
    from chizu.service.container import open_services

    # the CLI's one request at a time needs no worker processes
    return open_services(get_settings().model_copy(update={"workers": 0}))


@app.command()
def path(world: str, source: str = typer.Argument(..., metavar="FROM"),
         target: str = typer.Argument(..., metavar="TO")) -> None:
    """Print the most probable DRM path FROM -> TO in WORLD."""
    from chizu.numeric.errors import InvalidInput, NotFound

    services = _open_services()
    try:
        p = asyncio.run(services.worlds.path(world, source, target))
    except (NotFound, InvalidInput) as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    finally:
        services.close()
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
def repl(world: str,
         live: bool = typer.Option(False, "--live", help="query the running service's own "
                                   "knowledge base (read-only, its limits) instead of a "
                                   "copy of WORLD's facts"),
         url: str = typer.Option(None, help="the service (with --live); default: "
                                 "http://CHIZU_HOST:CHIZU_PORT, as `chizu serve` listens"),
         allow_remote: bool = typer.Option(False, help="let --live query a service that is "
                                           "not on this machine")) -> None:
    """Open swipl with the rule files and WORLD's facts loaded (try ?- reachable(a, c, P,
    M).), or with --live a prompt on the running service's knowledge base."""
    from chizu.numeric.errors import NotFound

    if live:
        s = get_settings()
        _live_repl(world, url or f"http://{s.host}:{s.port}", allow_remote)
        return

    swipl = shutil.which("swipl")
    if swipl is None:
        console.print("[red]swipl is not installed (make run / make test install it)[/red]")
        raise typer.Exit(2)
    services = _open_services()
    try:
        facts = asyncio.run(services.worlds.facts(world))
    except NotFound as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    finally:
        services.close()
    s = get_settings()
    fd, name = tempfile.mkstemp(prefix=f"chizu-{world}-", suffix=".pl")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        for fact in facts:  # written by Prolog itself (format ~k), read back as data
            f.write(fact + ".\n")
    load = str(Path(s.prolog_dir) / "load.pl")
    argv = [swipl, "-g", "repl:main", load, "--", f"--world={world}", f"--facts={name}"]
    sys.stdout.flush()
    os.execv(swipl, argv)


def _live_repl(world: str, url: str, allow_remote: bool) -> None:
    import httpx

    from chizu.service.live_repl import LiveRepl, ReplError, check_local

    try:
        import readline  # noqa: F401 -- line editing and history for input()

        history = Path.home() / ".chizu_history"
        if history.exists():
            readline.read_history_file(history)
    except (ImportError, OSError):
        history = None  # type: ignore[assignment]
    try:
        check_local(url, allow_remote)
        with httpx.Client(base_url=url, timeout=httpx.Timeout(60.0, connect=5.0)) as client:
            r = LiveRepl(client, world)
            r.check_world()
            console.print(f"% live on {world} at {url}: the service's own knowledge base, "
                          "read-only; ';' next answer, Enter stop, ctrl-C cancel, halt. leave")
            r.run(input)
    except (ReplError, httpx.HTTPError) as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    finally:
        if history is not None:
            try:
                readline.write_history_file(history)
            except OSError:
                pass


def _slam_outputs(out: Path, times, poses, grid) -> None:  # type: ignore[no-untyped-def]
    """The trajectory as TUM and as a ROS 2 bag (nav_msgs/Path), and the map images."""
    from chizu.numeric.slam.logs import write_ros2_path, write_tum

    out.mkdir(parents=True, exist_ok=True)
    write_tum(out / "trajectory.tum", times, poses)
    shutil.rmtree(out / "trajectory-ros2", ignore_errors=True)  # a bag is written anew
    write_ros2_path(out / "trajectory-ros2", times, poses)
    (out / "map.png").write_bytes(grid.to_png())
    (out / "map.pgm").write_bytes(grid.to_pgm())
    (out / "map.yaml").write_text(grid.to_yaml("map.pgm"))


@app.command()
def slam(log: str = typer.Argument(..., help="CARMEN .clf/.log or ROS .bag (or bag dir)"),
         method: str = typer.Option("graph", help="graph (recommended) | rbpf | gated | "
                                             "gated-icp | icp | odom"),
         particles: int = typer.Option(512, min=1, max=4096),
         alpha: float = typer.Option(0.0, min=0.0, help="intensity weight (eqs. 1, 9)"),
         proposal: str = typer.Option(
             "improved", help="RBPF proposal: improved (Grisetti et al. 2007, the default) | "
             "odometry (the paper's eq. 7) | gated-icp"),
         max_range: float = typer.Option(40.0, min=0.1, help="usable range (m)"),
         resolution: float = typer.Option(0.05, min=0.01, help="map cell size (m)"),
         limit: int = typer.Option(0, min=0, help="only the first N scans (0: all)"),
         seed: int = typer.Option(0, min=0),
         out: str = typer.Option("slam-out", help="output directory"),
         world: str | None = typer.Option(None, help="also commit the map into this world "
                                          "(the data directory's): its facts, the planners' "
                                          "grid, localization runs"),
         resume: str | None = typer.Option(None, help="a saved map (map.chizu or the "
                                           "directory holding it) to continue: LOG's "
                                           "scans join it, in its frame")) -> None:
    """Run SLAM over LOG (CARMEN, or a ROS 1 / ROS 2 bag with LaserScan and Odometry or
    /tf); write OUT/trajectory.tum (TUM, the log's stamps) and OUT/trajectory-ros2 (the
    same as a ROS 2 bag of one nav_msgs/Path), map.png
    (intensity-coloured), map.pgm + map.yaml (ROS map_server) and map.chizu, the saved
    map later runs localize in (chizu slam-localize); with --world, commit it into a
    world as a REST commit does. With --resume, LOG continues a saved map: found in it
    from an unknown start, its loops closed against the map's keyframes, and
    trajectory.tum holds LOG's poses in the map's frame, map.chizu both runs."""
    from pydantic import ValidationError
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from chizu.numeric.errors import InvalidInput
    from chizu.numeric.slam.logs import read_log
    from chizu.numeric.slam.runner import SlamOptions, run_log

    try:
        opts = SlamOptions(method=method, particles=particles, alpha=alpha,  # type: ignore[arg-type]
                           proposal=proposal, map_resolution_m=resolution,  # type: ignore[arg-type]
                           seed=seed)
        data = read_log(Path(log), max_range_m=max_range, limit=limit or None)
        if world is not None:
            _require_world(world)
        old = None
        if resume is not None:
            from chizu.numeric.slam.saved_map import load

            if opts.method != "graph":
                raise InvalidInput("--resume continues a map with graph SLAM: --method graph",
                                   field="method")
            old = load(resume)
    except (ValidationError, InvalidInput) as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                  TextColumn("{task.completed}/{task.total} scans"), TimeRemainingColumn(),
                  console=console, transient=True) as bar:
        task = bar.add_task(f"{opts.method} {data.name}", total=len(data))
        try:
            slam_, res = run_log(data, opts, lambda i: bar.update(task, completed=i))
        except InvalidInput as e:
            console.print(f"[red]{e}[/red]")
            raise typer.Exit(2) from None
    from chizu.numeric.slam.saved_map import FILE_NAME, save, saved_map_of_log

    new = saved_map_of_log(slam_, data, opts.method, opts.map_resolution_m)
    times, poses, grid = res.times, res.poses, res.map
    if old is not None:
        from chizu.numeric.slam.merge import resume as resume_map

        try:
            with console.status(f"placing {data.name} in {resume} and closing loops"):
                new, poses = resume_map(old, new)
        except InvalidInput as e:
            console.print(f"[red]{e}[/red]")
            raise typer.Exit(2) from None
        grid = new.occupancy(opts.map_resolution_m)
    _slam_outputs(Path(out), times, poses, grid)
    saved = save(new, Path(out) / FILE_NAME)
    console.print(f"{opts.method}: {len(data)} scans ({data.duration_s:.0f} s of log) in "
                  f"{res.seconds:.1f} s = {data.duration_s / max(res.seconds, 1e-9):.1f}x real "
                  f"time; wrote {out}/trajectory.tum, trajectory-ros2, map.png, map.pgm, "
                  f"map.yaml and "
                  f"{FILE_NAME} (the saved map)")
    if world is not None:
        services = _open_services()
        try:
            c = asyncio.run(services.slam.upload(world, saved.read_bytes()))
        finally:
            services.close()
        console.print(f"committed into world {world}: {c.facts.poses} keyframe poses, "
                      f"{len(c.unknown_regions)} unknown regions, "
                      f"{c.map.free_m2:.0f} m2 free")


def _require_world(world: str) -> None:
    """Raise :class:`chizu.numeric.errors.InvalidInput` (field ``world``) unless the data
    directory has ``world``."""
    from chizu.numeric.errors import InvalidInput, NotFound

    services = _open_services()
    try:
        services.worlds.require(world)
    except NotFound as e:
        raise InvalidInput(str(e), field="world") from None
    finally:
        services.close()


@app.command("slam-merge")
def slam_merge(map_a: str = typer.Argument(..., metavar="MAP_A", help="a saved map (map.chizu "
                                           "or its directory): the frame of the result"),
               map_b: str = typer.Argument(..., metavar="MAP_B", help="a saved map of the "
                                           "same building, in any frame"),
               out: str = typer.Option("merge-out", help="output directory")) -> None:
    """Merge two saved maps of one building made in unrelated frames: MAP_B is found in
    MAP_A, fitted to it and aligned with it, its loops closed against MAP_A's keyframes.
    Writes OUT/map.chizu (both), OUT/trajectory.tum (both runs' scans in MAP_A's frame,
    stamps unchanged, in time order) and the map images. Maps that share no place, or
    of two lasers, are refused and nothing is written."""
    import numpy as np

    from chizu.numeric.errors import InvalidInput
    from chizu.numeric.slam.merge import merge
    from chizu.numeric.slam.saved_map import FILE_NAME, load, save

    try:
        a, b = load(map_a), load(map_b)
        with console.status(f"merging {map_b} into {map_a}"):
            m, placed = merge(a, b)
    except InvalidInput as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    order = np.argsort(m.times, kind="stable")
    _slam_outputs(Path(out), m.times[order], m.poses[order], m.occupancy())
    save(m, Path(out) / FILE_NAME)
    t = placed.transform
    console.print(f"MAP_B lies at x {t[0]:.2f} m, y {t[1]:.2f} m, {np.rad2deg(t[2]):.1f} deg "
                  f"in MAP_A ({placed.agree} of {placed.searched} places agree); {len(m)} "
                  f"keyframes; wrote {out}/map.chizu, trajectory.tum, trajectory-ros2, "
                  "map.png, map.pgm, map.yaml")


@app.command("slam-localize")
def slam_localize(log: str = typer.Argument(..., help="CARMEN .clf/.log or ROS .bag"),
                  map_: str = typer.Option(..., "--map", help="a saved map: map.chizu, or "
                                           "the directory `chizu slam --out` wrote"),
                  max_range: float = typer.Option(40.0, min=0.1, help="usable range (m)"),
                  limit: int = typer.Option(0, min=0, help="only the first N scans (0: all)"),
                  out: str = typer.Option("localize-out", help="output directory")) -> None:
    """Localize LOG on a saved map, which stays as it is: global localization from an
    unknown start, tracking, and a new global fix when the robot is lost or carried
    away. Writes OUT/trajectory.tum (the placed scans -- those tracked, and those
    between tracked ones where the robot was off the map or lost, placed by local SLAM
    and the alignment -- with the log's stamps, in the map's frame) and
    OUT/localization.json (time to the first fix, fixes, losses)."""
    import json as json_

    from chizu.numeric.errors import InvalidInput
    from chizu.numeric.slam.logs import read_log, write_tum
    from chizu.numeric.slam.map_localization import localize_log
    from chizu.numeric.slam.saved_map import load, map_path, write_atomic

    try:
        saved = load(map_)
        data = read_log(Path(log), max_range_m=max_range, limit=limit or None)
        with console.status(f"localizing {data.name} ({len(data)} scans) on {map_}"):
            run = localize_log(saved, data)
    except InvalidInput as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    dest = Path(out)
    dest.mkdir(parents=True, exist_ok=True)
    ok = run.placed
    write_tum(dest / "trajectory.tum", run.times[ok], run.poses[ok])
    t0 = float(run.times[0]) if len(run.times) else 0.0
    report = {"map": str(map_path(map_)), "log": data.name, "scans": len(data),
              "localized": int(run.localized.sum()), "placed": int(ok.sum()),
              "first_fix_s": run.first_fix_s(),
              "fixes_s": [round(f - t0, 3) for f in run.fixes],
              "losses_s": [round(f - t0, 3) for f in run.losses],
              "recoveries": max(0, len(run.fixes) - 1), "seconds": round(run.seconds, 3),
              "real_time_factor": round(data.duration_s / max(run.seconds, 1e-9), 1)}
    write_atomic(dest / "localization.json", json_.dumps(report, indent=1).encode())
    first = "never" if run.first_fix_s() is None else f"after {run.first_fix_s():.1f} s"
    console.print(f"{int(run.localized.sum())} of {len(data)} scans localized online, "
                  f"{int(ok.sum())} placed; first fix {first}, "
                  f"{len(run.losses)} losses, {report['recoveries']} recoveries; "
                  f"{report['real_time_factor']}x real time; wrote {out}/trajectory.tum, "
                  "localization.json")


@app.command("slam-batch")
def slam_batch(logs: Annotated[list[str], typer.Argument(help="CARMEN .clf/.log or ROS .bag "
                                                         "files")],
               grid: str = typer.Option(None, help="parameter grid, YAML or JSON: a key's "
                                        "list is its values (method, particles, alpha, "
                                        "proposal, seed, ...); default: rbpf, 512 particles"),
               out: str = typer.Option("slam-batch-out", help="output directory"),
               scheduler: str = typer.Option(None, envvar="CHIZU_DASK_SCHEDULER",
                                             help="a Dask scheduler, tcp://host:8786"),
               local_workers: int = typer.Option(0, min=0, help="start a Dask cluster of N "
                                                 "worker processes here (0: run in-process)"),
               max_range: float = typer.Option(40.0, min=0.1, help="usable range (m)"),
               limit: int = typer.Option(0, min=0, help="only the first N scans (0: all)")
               ) -> None:
    """SLAM over every LOG with every parameter set of the grid, each run evaluated on
    its log's reference relations (<log>.relations, or the folder's one .relations);
    writes OUT/results.csv, results.md and one TUM trajectory per run."""
    import csv
    import json as json_

    import yaml
    from rich.table import Table

    from chizu.numeric.errors import InvalidInput
    from chizu.numeric.slam.batch import run_batch, tasks_for
    from chizu.numeric.slam.logs import write_tum
    from chizu.service.executors import batch_executor

    try:
        spec = yaml.safe_load(Path(grid).read_text()) if grid else {}
        if not isinstance(spec, dict):
            raise InvalidInput("the grid must be a mapping of parameter -> value(s)",
                               field="grid")
        tasks = tasks_for(logs, spec, max_range, limit or None)
    except (OSError, yaml.YAMLError, InvalidInput) as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    where = scheduler or (f"{local_workers} local Dask workers" if local_workers else
                          "this process")
    console.print(f"{len(tasks)} runs on {where}")
    with console.status("running"), \
            batch_executor(scheduler, local_workers) as ex:
        results = run_batch(tasks, ex)
    dest = Path(out)
    dest.mkdir(parents=True, exist_ok=True)
    rows = [r.row() for r in results]
    with (dest / "results.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows({**r, "options": json_.dumps(r["options"])} for r in rows)
    t = Table("log", "options", "scans", "x real time", "trans (m)", "loop (m)", "rot (deg)")
    md = ["| log | options | scans | x real time | trans (m) | loop (m) | rot (deg) |",
          "|---|---|---|---|---|---|---|"]
    for i, r in enumerate(results):
        import numpy as np

        tr = np.asarray(r.trajectory)
        write_tum(dest / f"{i:03d}-{Path(r.log).stem}.tum", tr[:, 0], tr[:, 1:])
        cells = [Path(r.log).name, json_.dumps(r.options), str(r.scans),
                 f"{r.log_s / max(r.seconds, 1e-9):.1f}",
                 *("-" if v is None else f"{v:.3f}" for v in (r.trans_m, r.loop_trans_m,
                                                               r.rot_deg))]
        t.add_row(*cells)
        md.append("| " + " | ".join(cells) + " |")
    (dest / "results.md").write_text("\n".join(md) + "\n")
    console.print(t)
    console.print(f"wrote {out}/results.csv, results.md and {len(results)} trajectories")


@app.command("slam-eval")
def slam_eval(trajectory: Path, relations: Path,
              max_dt: float = typer.Option(0.1, help="pose-to-relation time tolerance (s)"),
              ) -> None:
    """Relation errors (Kümmerle et al. 2009) of a TUM TRAJECTORY against RELATIONS."""
    from chizu.numeric.errors import InvalidInput
    from chizu.numeric.slam.evaluation import relation_errors
    from chizu.numeric.slam.logs import read_relations, read_tum

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
    from chizu.numeric.errors import InvalidInput
    from chizu.numeric.slam.logs import write_carmen, write_tum
    from chizu.numeric.slam.simulate import TOURS, simulated_log

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



def _world_description(name: str):  # type: ignore[no-untyped-def]
    """A stored world of the data directory, else a built-in template."""
    from chizu.numeric.world import WorldDescription
    from chizu.numeric.worlds import TEMPLATES, from_template
    from chizu.service.store import Store

    s = get_settings()
    if s.db_path.exists():
        row = Store(s.db_path).world(name)
        if row is not None:
            return WorldDescription.model_validate(row.description)
    if name in TEMPLATES:
        return from_template(name, name if name[0].islower() else "w")
    console.print(f"[red]no world {name!r} in {s.db_path} and no such template; "
                  f"templates: {', '.join(sorted(TEMPLATES))}[/red]")
    raise typer.Exit(2)


@app.command()
def plan(scene: str = typer.Argument(..., help="SCENE.json: a viewpoint-plan request"),
         world: str = typer.Option(None, help="world (stored or template) to simulate the "
                                   "grid from when the scene has none"),
         png: str = typer.Option(None, help="write a figure of the groups and the plan"),
         exhaustive: bool = typer.Option(False, help="the paper's exhaustive search")) -> None:
    """Plan one viewpoint-planning scene (the body of POST /worlds/{w}/viewpoint-plan)."""
    import json

    from pydantic import ValidationError

    from chizu.numeric.errors import InvalidInput
    from chizu.numeric.figures import plan_figure
    from chizu.numeric.viewpoint.grid import look_around, scanned_grid
    from chizu.numeric.viewpoint.planner import ViewpointPlanner
    from chizu.numeric.world import World
    from chizu.service.schemas.viewpoint import PlanRequest
    from chizu.service.viewpoint import local_grouper, plan_answer

    try:
        req = PlanRequest.model_validate_json(Path(scene).read_text())
    except (OSError, ValidationError) as e:
        console.print(f"[red]{scene}: {e}[/red]")
        raise typer.Exit(2) from None
    if exhaustive:
        req = req.model_copy(update={"solver": "exhaustive"})
    if req.grid is not None:
        grid = req.grid.to_grid()
    elif world is not None:
        grid = scanned_grid(World(_world_description(world)), look_around(req.robot))
    else:
        console.print("[red]the scene has no grid: give one, or --world to simulate it[/red]")
        raise typer.Exit(2)
    grouper, kb = local_grouper(get_settings().prolog_dir)
    try:
        report = ViewpointPlanner().plan(req, grid, grouper)
    except InvalidInput as e:
        console.print(f"[red]{e.field}: {e}[/red]")
        raise typer.Exit(2) from None
    finally:
        kb.close()
    out = plan_answer("scene", report, "posted" if req.grid else "simulated", grid, req)
    t = Table(title=f"groups ({req.loss}, t_limit {req.time_limit_s:g} s)")
    for col in ("group", "kind", "members", "value", "t_obs (s)", "strategy"):
        t.add_column(col)
    for g in out.groups:
        t.add_row(g.name, g.kind, ",".join(map(str, g.members)), f"{g.value:.1f}",
                  f"{g.t_obs_s:.2f}", g.strategy or "explore")
    console.print(t)
    t = Table(title="plans (best first)")
    for col in ("plan", "V", "time (s)", "loss", "U"):
        t.add_column(col)
    for p in [out.plan, *out.runner_ups]:
        t.add_row(" → ".join(p.groups) or "(leave)", f"{p.value:.1f}",
                  f"{p.expected_time_s:.2f}",
                  "∞" if p.loss is None else f"{p.loss:.2f}",
                  "-∞" if p.utility is None else f"{p.utility:.2f}")
    console.print(t)
    console.print(f"planning {out.timings_ms['total']:.1f} ms "
                  f"(tables built {out.tables.built})")
    if png:
        plan_figure(report, req, grid, png)
        console.print(f"wrote {png}")
    console.print_json(json.dumps({"plan": out.plan.model_dump(exclude_unset=True)}))


@app.command()
def summarise(world: str = typer.Argument(..., help="stored world or template, e.g. "
                                          "summary_room"),
              time_limit: float = typer.Option(55.0, "--time-limit", min=0),
              loss: str = typer.Option("L2", help="L1 | L2 | L3"),
              door: str = typer.Option(None, help="x,y of the door (default: the paper "
                                       "rooms' door)"),
              seed: int = typer.Option(0, min=0),
              out: str = typer.Option("summary", help="directory for run.json and run.png"),
              ) -> None:
    """Summarise a room online (§7.3): plan, move and observe in the simulator, update,
    re-plan, until the plan is to leave; writes the run log and a figure."""
    import json

    import numpy as np

    from chizu.numeric.figures import run_figure
    from chizu.numeric.viewpoint.online import Summariser, SummaryConfig
    from chizu.numeric.viewpoint.planner import BUILTIN_OBJECT_TYPES, ObjectType
    from chizu.numeric.world import World
    from chizu.numeric.worlds import SUMMARY_DOOR
    from chizu.service.viewpoint import local_grouper

    if loss not in ("L1", "L2", "L3"):
        console.print(f"[red]--loss must be L1, L2 or L3, not {loss!r}[/red]")
        raise typer.Exit(2)
    try:
        door_xy = np.array([float(v) for v in door.split(",")]) if door else np.array(
            SUMMARY_DOOR)
        assert door_xy.shape == (2,) and np.all(np.isfinite(door_xy))
    except (ValueError, AssertionError):
        console.print(f"[red]--door must be x,y, not {door!r}[/red]")
        raise typer.Exit(2) from None
    w = World(_world_description(world))
    types = [ObjectType.model_validate(t) for t in BUILTIN_OBJECT_TYPES]
    cfg = SummaryConfig(time_limit_s=time_limit, loss=loss, seed=seed)
    grouper, kb = local_grouper(get_settings().prolog_dir)
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    try:
        with Progress(TextColumn("{task.description}"), BarColumn(),
                      TextColumn("{task.completed:.1f}/{task.total:.0f} s"),
                      TimeElapsedColumn(), console=console) as bar:
            task = bar.add_task("summarising", total=max(time_limit, 1.0))

            def step(e):  # type: ignore[no-untyped-def]
                bar.update(task, completed=min(e.t_s, time_limit))
                what = e.detail.get("plan", e.detail.get("candidate", e.detail.get("group")))
                bar.console.print(f"{e.t_s:6.1f} s  {e.action:<14} {what}")

            run = Summariser(w, types, grouper, cfg, door_xy).run(on_step=step)
    finally:
        kb.close()
    outdir = Path(out)
    outdir.mkdir(parents=True, exist_ok=True)
    summary = run.summary(w)
    log = [{"step": e.step, "t_s": e.t_s, "action": e.action, **e.detail} for e in run.log]
    (outdir / "run.json").write_text(json.dumps({"summary": summary, "log": log}, indent=1,
                                                default=float))
    run_figure(run, w, str(outdir / "run.png"),
               f"{world}: {loss}, t_limit {time_limit:g} s, took {run.elapsed_s:.1f} s")
    console.print(summary)
    console.print(f"wrote {outdir / 'run.json'} and {outdir / 'run.png'}")


@app.command()
def mission(world: str = typer.Argument("mission", help="stored world, or a template to "
                                        "create it from (default: the mission world)"),
            out_dir: str = typer.Option("mission", "--out", help="directory for the figure, the "
                                     "log and the per-seed results"),
            seed: int = typer.Option(0, min=0, help="first seed"),
            seeds: int = typer.Option(1, min=1, max=1000, help="runs, seeds seed..seed+N-1"),
            slam_method: str = typer.Option("graph", help="graph | gated | rbpf"),
            time_limit: float = typer.Option(90.0, "--time-limit", min=1.0,
                                             help="the goal room's summary (s)"),
            goal: str = typer.Option(None, help="goal landmark (default: the mission "
                                     "world's)"),
            door: str = typer.Option(None, help="x,y: a point just inside the goal room's "
                                     "door (default: the mission world's)"),
            room: str = typer.Option(None, help="x0,y0,x1,y1: the goal room's corners "
                                     "(default: the mission world's)"),
            ) -> None:
    """One robot, one knowledge base: wake up lost, localize (eigenspace), reach the
    nearest landmark, follow the DRM path to the goal while mapping (SLAM), then plan
    viewpoints and verify the objects in the goal room. Each run's steps become
    mission_step/3 facts of WORLD (the last run's stay: `chizu repl WORLD`); writes
    mission.png (the first run), mission.json (every record) and results.csv."""
    from chizu.numeric.errors import ChizuError
    from chizu.numeric.world import WorldDescription
    from chizu.numeric.worlds import TEMPLATES

    base = _mission_config(slam_method, time_limit, goal, door, room)
    services = _open_services()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    records, rows = [], []
    try:
        if services.store.world(world) is None:
            if world not in TEMPLATES:
                console.print(f"[red]no world {world!r} and no such template[/red]")
                raise typer.Exit(2)
            asyncio.run(services.worlds.create(WorldDescription(name=world, template=world)))
            console.print(f"created world {world!r} from its template")
        for k in range(seeds):
            cfg = base.model_copy(update={"seed": seed + k})

            def progress(stage: str, frac: float, shown: list[str] = []) -> None:  # noqa: B006
                # each stage once (learning reports every point)
                if "stop" not in stage and (not shown or shown[-1] != stage):
                    shown.append(stage)
                    console.print(f"  {frac:4.0%} {stage}")

            run = asyncio.run(services.mission.run(world, cfg, progress if seeds == 1
                                                   else None))
            rows.append(run.row())
            records.append(run.result())
            console.print(f"seed {cfg.seed}: {'[green]succeeded' if run.success else '[red]failed'}"
                          f"[/] {rows[-1]}")
            if k == 0:
                run.figure(services.worlds.model(world), str(out / "mission.png"))
    except ChizuError as e:
        console.print(f"[red]{e.field}: {e}[/red]")
        raise typer.Exit(2) from None
    finally:
        services.close()
    _write_missions(out, records, rows)


def _mission_config(slam_method: str, time_limit: float, goal: str | None,
                    door: str | None, room: str | None):  # type: ignore[no-untyped-def]
    """The mission command's options as a MissionConfig (exit 2 naming a bad one)."""
    from pydantic import ValidationError

    from chizu.service.schemas.mission import MissionConfig

    over: dict[str, Any] = {"slam_method": slam_method, "time_limit_s": time_limit}
    try:
        if goal:
            over["goal"] = goal
        if door:
            over["door"] = [float(v) for v in door.split(",")]
        if room:
            v = [float(x) for x in room.split(",")]
            over["room"] = [v[:2], v[2:]] if len(v) == 4 else v
    except ValueError:
        console.print("[red]--door is x,y and --room x0,y0,x1,y1 (numbers)[/red]")
        raise typer.Exit(2) from None
    try:
        return MissionConfig.model_validate(over)
    except ValidationError as e:
        err = e.errors()[0]
        console.print(f"[red]{'.'.join(map(str, err['loc']))}: {err['msg']}[/red]")
        raise typer.Exit(2) from None


def _write_missions(out: Path, records: list[dict[str, Any]],
                    rows: list[dict[str, Any]]) -> None:
    """mission.json (every record) and results.csv (one row per run), and the tally."""
    import csv
    import json

    (out / "mission.json").write_text(json.dumps(records, indent=1))
    with open(out / "results.csv", "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=list(rows[0]))
        wr.writeheader()
        wr.writerows(rows)
    ok = sum(r["success"] for r in rows)
    console.print(f"success {ok}/{len(rows)} ({ok / len(rows):.0%}); wrote {out}/mission.png, "
                  "mission.json, results.csv")


eigen = typer.Typer(help="Eigenspace localization: learn from the simulator or a camera's "
                    "images, export the simulator's images, localize a turn of images.",
                    no_args_is_help=True)
app.add_typer(eigen, name="eigenspace")
ConfigOpt = Annotated[Path | None, typer.Option(help="EigenspaceConfig JSON file")]
SizeOpt = Annotated[str | None, typer.Option(help="resize images to WIDTHxHEIGHT px")]


def _eigen_config(path: Path | None):  # type: ignore[no-untyped-def]
    from pydantic import ValidationError

    from chizu.numeric.eigenspace.analysis import EigenspaceConfig

    if path is None:
        return EigenspaceConfig()
    try:
        return EigenspaceConfig.model_validate_json(path.read_text())
    except (OSError, ValidationError) as e:
        console.print(f"[red]--config {path}: {e}[/red]")
        raise typer.Exit(2) from None


@eigen.command("export")
def eigen_export(world: Annotated[str, typer.Argument(help="stored world or template")],
                 out: Annotated[Path, typer.Argument(help="folder to write")],
                 config: ConfigOpt = None) -> None:
    """Write the simulator's learning turns and calibration images of WORLD as an image
    folder (poses.csv + 16-bit PNGs): the format `learn --images` reads."""
    from chizu.numeric.eigenspace.analysis import render_image_set
    from chizu.numeric.eigenspace.image_sets import write_image_folder
    from chizu.numeric.world import World

    with console.status("rendering and analysing"):
        images, a = render_image_set(World(_world_description(world)), _eigen_config(config))
    n = write_image_folder(out, images)
    console.print(f"wrote {n} images and {out / 'poses.csv'}: {len(images.points)} learning "
                  f"points x {images.n_directions} directions, {len(images.calib_poses)} "
                  f"calibration images (c_a {a.c_a:.3f}, {len(a.triplets)} triplets)")


@eigen.command("learn")
def eigen_learn(world: Annotated[str, typer.Argument(help="stored world")],
                images: Annotated[Path | None, typer.Option(
                    help="image folder (poses.csv + images); default: the simulator")] = None,
                size: SizeOpt = None, config: ConfigOpt = None,
                strategy: Annotated[bool, typer.Option(
                    help="after the grid, add learning points by the learning strategy "
                         "(§4.2) until P(Z within 5 stops) >= 0.9 (simulator only; "
                         "--config sets its learning_strategy parameters); "
                         "--no-strategy: the grid alone")] = True,
                scheduler: Annotated[str | None, typer.Option(
                    envvar="CHIZU_DASK_SCHEDULER",
                    help="run the learning strategy's Monte Carlo evaluation on this Dask "
                         "scheduler, tcp://host:8786")] = None,
                local_workers: Annotated[int, typer.Option(
                    min=0, help="... or on a Dask cluster of N worker processes started "
                                "here")] = 0) -> None:
    """Learn WORLD's eigenspace and store it (the service and the REPL see it). A WORLD
    not stored yet but named like a template (e.g. room_a) is created from it."""
    from chizu.service.executors import batch_executor

    cfg = _eigen_config(config)
    if not strategy:
        cfg = cfg.model_copy(update={"learning_strategy": None})
    with batch_executor(scheduler, local_workers) as ex:
        _eigen_learn(world, images, size, cfg, ex)


def _eigen_learn(world: str, images: Path | None, size: str | None, cfg: Any,
                 executor: Any) -> None:
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from chizu.numeric.eigenspace.image_sets import parse_size, read_image_folder
    from chizu.numeric.errors import ChizuError
    from chizu.numeric.world import WorldDescription
    from chizu.numeric.worlds import TEMPLATES

    services = _open_services()
    eig = services.eigenspace
    eig.executor = executor  # the learning strategy's Monte Carlo runs there (None: here)
    try:
        if eig.store.world(world) is None and world in TEMPLATES:
            asyncio.run(eig.worlds.create(WorldDescription(name=world, template=world)))
            console.print(f"created world {world!r} from its template")
        image_set = None if images is None else read_image_folder(images, parse_size(size))
        with Progress(TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(),
                      console=console) as bar:
            task = bar.add_task("learning", total=1.0)

            def progress(stage: str, frac: float) -> None:
                bar.update(task, description=stage, completed=frac)

            a = asyncio.run(eig.learn(world, cfg, image_set, progress))
        console.print(a.summary(eig.worlds.model(world)))
    except ChizuError as e:
        console.print(f"[red]{e.field}: {e}[/red]")
        raise typer.Exit(2) from None
    finally:
        services.close()


@eigen.command("localize")
def eigen_localize(world: Annotated[str, typer.Argument(help="stored world with an "
                                                          "eigenspace")],
                   files: Annotated[list[Path], typer.Argument(
                       help="one full turn of images, in order of relative heading "
                            "2*pi*j/n")],
                   size: SizeOpt = None) -> None:
    """Localize one full turn of image files: state, pose when localized, candidates."""

    import numpy as np

    from chizu.numeric.eigenspace.image_sets import decode_image, parse_size
    from chizu.numeric.errors import ChizuError

    services = _open_services()
    eig = services.eigenspace
    try:
        wh = parse_size(size)
        turn = np.stack([decode_image(f.name, f.read_bytes(), wh) for f in files])
        r = asyncio.run(eig.localize(world, turn))
        console.print_json(r.model_dump_json())
    except (ChizuError, ValueError, OSError) as e:
        console.print(f"[red]{getattr(e, 'field', '')}: {e}[/red]")
        raise typer.Exit(2) from None
    finally:
        services.close()


if __name__ == "__main__":
    app()
