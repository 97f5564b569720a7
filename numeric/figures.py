"""chizu's figures (matplotlib, Agg), one PNG each: a viewpoint plan (Masuzawa & Miura,
Fig. 11; :func:`plan_figure`), a goal room's summarisation run (§7.3; :func:`run_figure`)
and a whole mission (:func:`mission_figure`).

Like :mod:`chizu.numeric.mission`, this module draws what the method packages compute; none
of them imports it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from chizu.numeric.mission import MissionTrace
from chizu.numeric.occupancy import FREE, OCCUPIED, OccupancyMap
from chizu.numeric.viewpoint.grid import PlanningGrid
from chizu.numeric.viewpoint.online import SummaryRun
from chizu.numeric.viewpoint.planner import PlanReport, PlanRequest
from chizu.numeric.world import World


def _axes(grid: PlanningGrid) -> tuple[Any, Any]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    img = np.full(grid.state.shape, 0.6)
    img[grid.state == FREE] = 1.0
    img[grid.state == OCCUPIED] = 0.0
    lo = grid.grid.origin
    hi = lo + np.array(grid.state.shape) * grid.resolution
    fig, ax = plt.subplots(figsize=(7, 6))
    ax.imshow(img.T, origin="lower", cmap="gray", vmin=0, vmax=1,
              extent=(lo[0], hi[0], lo[1], hi[1]))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    return fig, ax


def _save(fig: Any, path_png: str) -> None:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path_png, dpi=110)
    plt.close(fig)


def plan_figure(report: PlanReport, req: PlanRequest, grid: PlanningGrid, path_png: str,
                title: str = "") -> None:
    """Groups (candidates by group colour, unknown regions' entry points), the robot, the
    exit and the chosen plan's order."""
    fig, ax = _axes(grid)
    cmap = __import__("matplotlib").colormaps["tab10"]
    cand = {c.id: c for c in req.candidates}
    for k, g in enumerate(report.groups):
        col = cmap(k % 10)
        if g.spec.kind == "objects":
            for m in g.spec.members:
                c = cand[str(m)]
                ax.plot(c.x, c.y, "o", color=col, ms=9)
                ax.annotate(f"{g.name}:{m}", (c.x, c.y), textcoords="offset points",
                            xytext=(6, 6), fontsize=8)
        else:
            ax.plot(g.entries[:, 0], g.entries[:, 1], ".", color=col, ms=3)
            if g.centroid is not None:
                ax.annotate(g.name, (float(g.centroid[0]), float(g.centroid[1])), fontsize=9,
                            color=col)
    best = report.plans[0]
    pts = [np.array(req.robot[:2])]
    pts += [g.entries.mean(axis=0) for g in (report.groups[i] for i in best.order)]
    pts.append(np.array(req.exit))
    p = np.array(pts)
    ax.plot(p[:, 0], p[:, 1], "--", color="tab:blue", lw=1.5, label="plan order")
    ax.plot(*req.robot[:2], "^", color="tab:blue", ms=10, label="robot")
    ax.plot(*req.exit, "s", color="tab:blue", mfc="white", ms=9, label="exit")
    ax.legend(loc="upper right", fontsize=8)
    names = " -> ".join(report.names(best)) or "leave"
    ax.set_title(title or f"{req.loss}: {names}  U = {best.utility:.1f}")
    _save(fig, path_png)


def run_figure(run: SummaryRun, world: World, path_png: str, title: str = "") -> None:
    """The run as a PNG: the final map, the path, verified (green), rejected (red) and
    unverified (orange) candidates, the true objects (black squares)."""
    fig, ax = _axes(run.grid)
    p = np.array(run.path)
    ax.plot(p[:, 0], p[:, 1], "-", color="tab:blue", lw=1.5, label="path")
    ax.plot(p[0, 0], p[0, 1], "o", color="tab:blue", ms=8, mfc="white", label="door")
    for o in world.description.objects:
        ax.plot(o.x, o.y, "s", color="black", ms=5)
    for pts, col, lab in ((run.verified, "tab:green", "verified"),
                          (run.rejected, "tab:red", "rejected"),
                          (run.unverified, "tab:orange", "not verified")):
        for k, (cid, xy) in enumerate(pts.items()):
            ax.plot(xy[0], xy[1], "o", ms=11, mfc="none", mec=col, mew=2,
                    label=lab if k == 0 else None)
            ax.annotate(cid, (float(xy[0]), float(xy[1])), textcoords="offset points",
                        xytext=(6, 6), fontsize=8)
    ax.set_title(title or f"summary run: {run.elapsed_s:.1f} s")
    ax.legend(loc="upper right", fontsize=8)
    _save(fig, path_png)


def mission_figure(trace: MissionTrace, world: World, path_png: str, title: str = "",
                   slam_label: str = "SLAM") -> None:
    """One figure of a mission: the committed SLAM map, the walls, the true path and
    SLAM's (``slam_label``), the localization stops (truth) and the poses fixed, the DRM
    path's landmarks, the planned viewpoints, the goal room's summary path and the
    objects verified."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 9))
    if trace.map is not None:
        _map_image(ax, trace.map)
    for a, b in zip(world.wall_a, world.wall_b, strict=True):
        ax.plot([a[0], b[0]], [a[1], b[1]], "-", color="0.55", lw=0.8)
    _mission_paths(ax, trace, slam_label)
    _mission_poses(ax, trace)
    _mission_route(ax, trace, world)
    if trace.summary is not None:
        s = np.array(trace.summary.path)
        ax.plot(s[:, 0], s[:, 1], "-", color="tab:purple", lw=1.2, label="room summary")
        for k, (cid, xy) in enumerate(trace.summary.verified.items()):
            ax.plot(xy[0], xy[1], "o", ms=12, mfc="none", mec="tab:green", mew=2,
                    label="verified" if k == 0 else None)
            ax.annotate(cid, (float(xy[0]), float(xy[1])), textcoords="offset points",
                        xytext=(6, -10), fontsize=8)
    for o in world.description.objects:
        ax.plot(o.x, o.y, "s", color="black", ms=4)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize=8, framealpha=0.9)
    _save(fig, path_png)


def _map_image(ax: Any, g: OccupancyMap) -> None:
    """An occupancy map in grey: free white, occupied black, unknown light grey."""
    img = np.full(g.state.shape, 0.75)
    img[g.state == FREE] = 1.0
    img[g.state == OCCUPIED] = 0.0
    x0, y0 = g.origin
    x1 = x0 + g.state.shape[0] * g.resolution_m
    y1 = y0 + g.state.shape[1] * g.resolution_m
    ax.imshow(img.T, origin="lower", extent=(x0, x1, y0, y1), cmap="gray", vmin=0, vmax=1)


def _mission_paths(ax: Any, trace: MissionTrace, slam_label: str) -> None:
    """The true path from where the robot woke up, and SLAM's."""
    if trace.truth_path:
        p = np.array(trace.truth_path)
        ax.plot(p[:, 0], p[:, 1], "-", color="tab:blue", lw=1.2, label="true path")
        ax.plot(p[0, 0], p[0, 1], "o", color="tab:blue", ms=9, mfc="white", label="woke up")
    if trace.slam_path is not None and len(trace.slam_path):
        ax.plot(trace.slam_path[:, 0], trace.slam_path[:, 1], "--", color="tab:orange",
                lw=1.2, label=slam_label)


def _mission_poses(ax: Any, trace: MissionTrace) -> None:
    """The localization stops (truth), the eigenspace's pose and, if the mission went on
    from another, the pose fixed at a landmark."""
    for k, t in enumerate(trace.stops):
        ax.plot(t[0], t[1], "x", color="black", ms=8,
                label="localization stops (truth)" if k == 0 else None)
    fixes = [(trace.eigenspace_fix, "tab:red", "eigenspace pose")]
    if trace.fix is not None and (trace.eigenspace_fix is None
                                  or not np.array_equal(trace.fix[0], trace.eigenspace_fix[0])):
        fixes.append((trace.fix, "tab:pink", "pose fixed at a landmark"))
    for fix, colour, label in fixes:
        if fix is not None:
            e = fix[0]
            ax.quiver(e[0], e[1], np.cos(e[2]), np.sin(e[2]), color=colour, scale=20,
                      width=0.008, label=label, zorder=5)


def _mission_route(ax: Any, trace: MissionTrace, world: World) -> None:
    """The DRM path's landmarks and the planned viewpoints, numbered in their order."""
    if trace.landmarks:
        xy = np.array([world.landmark_position(lm) for lm in trace.landmarks])
        ax.plot(xy[:, 0], xy[:, 1], "o-", color="tab:green", lw=2, alpha=0.6,
                label="DRM path")
        for lm, (x, y) in zip(trace.landmarks, xy, strict=True):
            ax.annotate(lm, (x, y), textcoords="offset points", xytext=(5, 5), fontsize=8)
    for k, (x, y, _th) in enumerate(trace.plan_poses):
        ax.plot(x, y, "^", color="tab:cyan", ms=9, mec="black",
                label="planned viewpoints" if k == 0 else None)
        ax.annotate(str(k + 1), (x, y), textcoords="offset points", xytext=(-3, -12),
                    fontsize=8, color="tab:cyan")
