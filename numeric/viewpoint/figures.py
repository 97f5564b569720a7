"""Figures of viewpoint plans (Masuzawa & Miura, Fig. 11) and summarisation runs
(§7.3) (matplotlib, Agg)."""

from __future__ import annotations

from typing import Any

import numpy as np

from numeric.occupancy import FREE, OCCUPIED
from numeric.viewpoint.grid import PlanningGrid
from numeric.viewpoint.online import SummaryRun
from numeric.viewpoint.planner import PlanReport, PlanRequest
from numeric.world import World


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
