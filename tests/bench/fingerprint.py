"""What the methods answer, dumped bit for bit, to hold a refactoring to "the same
estimates": both SLAM estimators on the four shared logs (fixed seeds), viewpoint plans,
eigenspace answers and a mission, through the service as a user calls it.

    .venv/bin/python tests/bench/fingerprint.py dump OUT [--parts slam,service] [--scans N]
    .venv/bin/python tests/bench/fingerprint.py compare REF OUT

``dump`` writes OUT/slam-LOG-METHOD.npz (every SLAM run in a fresh process: online and
finished trajectories, map poses) and OUT/service.json (the answers with their timings
removed). Graph SLAM and the gated method run over whole logs, the RBPFs (512 particles,
seed 0) over the first ``--scans`` scans. ``compare`` exits 1 on the first difference
in any array's bytes or any answer.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

LOGS = {"aces": "aces.recon.clf", "mit-csail": "mit-csail.clf",
        "fr079": "fr079.recon.clf", "fr-clinic": "fr-clinic.recon.clf"}
#: method label -> (SlamOptions fields, whole log?)
METHODS: dict[str, tuple[dict[str, str], bool]] = {
    "graph": ({"method": "graph"}, True),
    "gated": ({"method": "gated"}, True),
    "rbpf-improved": ({"method": "rbpf", "proposal": "improved"}, False),
    "rbpf-paper": ({"method": "rbpf", "proposal": "odometry"}, False),
}
TIMING_KEYS = ("seconds", "_s", "_ms", "_at", "elapsed", "duration", "id", "time", "session",
               "slam_run")


def slam_one(log_name: str, label: str, scans: int, out: Path) -> None:
    """One SLAM run in this process: the trajectories before and after finish()."""
    from chizu.numeric.scan import LaserLog
    from chizu.numeric.slam.datasets import slam_data_dir
    from chizu.numeric.slam.logs import read_log
    from chizu.numeric.slam.runner import SlamOptions, create

    data = slam_data_dir()
    assert data is not None, "no shared SLAM logs"
    log = read_log(data / log_name / LOGS[log_name])
    fields, whole = METHODS[label]
    if not whole:
        log = LaserLog(name=log.name, scans=log.scans[:scans])
    slam = create(SlamOptions(**fields))
    t0 = time.perf_counter()
    for scan in log.scans:
        slam.process(scan)
    t_on, p_on = slam.trajectory()
    slam.finish()
    t_fin, p_fin = slam.trajectory()
    np.savez(out / f"slam-{log_name}-{label}.npz", online_t=t_on, online=p_on,
             times=t_fin, poses=p_fin, map_poses=slam.map_poses(),
             pose=np.asarray(slam.pose))
    print(f"{log_name} {label}: {len(log.scans)} scans, {time.perf_counter() - t0:.1f} s",
          flush=True)


def _strip(v: Any) -> Any:
    """``v`` without timings and ids (which differ from run to run)."""
    if isinstance(v, dict):
        return {k: _strip(x) for k, x in sorted(v.items())
                if not any(k == t or k.endswith(t) for t in TIMING_KEYS)}
    if isinstance(v, list):
        return [_strip(x) for x in v]
    return v


def service_answers() -> dict[str, Any]:
    """Viewpoint plans, eigenspace answers, a path and a mission through the typed client
    (over the app in this process)."""
    import tempfile

    from fastapi.testclient import TestClient
    from pydantic import BaseModel

    from chizu.service.app import create_app
    from chizu.service.client import Client, JobError
    from chizu.service.schemas.jobs import JobOut
    from chizu.service.settings import Settings
    from tests.eigenspace.test_api import SMALL
    from tests.viewpoint.test_api import table1_body

    def wire(answer: BaseModel) -> Any:
        """An answer as its JSON (the keys the server sent), as the dumps hold it."""
        return answer.model_dump(mode="json", by_alias=True, exclude_unset=True)

    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as d, TestClient(create_app(Settings(
            data_dir=Path(d), demo_world="demo", request_budget_s=600.0))) as http, \
            Client(http=http) as c:

        def wait(job: JobOut) -> Any:
            try:
                return wire(c.wait_job(job, timeout_s=3600))
            except JobError as e:  # a failed job is an answer too
                return wire(e.job)

        for name, template in (("vp_a", "fig11a"), ("vp_b", "fig11b"), ("eig", "room_a"),
                               ("m", "mission")):
            c.worlds.create_world({"name": name, "template": template})
        for loss in ("L1", "L2", "L3"):
            out[f"plan-table1-{loss}"] = wire(c.viewpoint.post_plan("vp_a", table1_body(loss)))
        body = {**table1_body("L3"), "solver": "bnb"}
        out["plan-bnb"] = wire(c.viewpoint.post_plan("vp_a", body))
        out["path-demo"] = wire(c.qualitative.get_path("demo", from_="rn0a", to="rs3b"))
        out["eig-learn"] = wait(c.eigenspace.post_eigenspace("eig", SMALL))
        out["eig-summary"] = wire(c.eigenspace.get_eigenspace("eig"))
        for i, (x, y, th) in enumerate([(3.0, 5.0, 0.0), (4.2, 4.7, 0.3), (2.1, 3.3, 1.2),
                                        (5.5, 2.5, -0.7)]):
            imgs = c.eigenspace.post_camera("eig", {"pose": {"x": x, "y": y, "theta": th},
                                                    "turn": 72, "format": "list"})
            out[f"eig-localize-{i}"] = wire(c.eigenspace.post_localize("eig", wire(imgs)))
        out["mission"] = wait(c.mission.post_mission("m", {"seed": 3}))
        out["mission-record"] = wire(c.mission.get_mission("m"))
    return _strip(out)


def dump(out: Path, parts: list[str], scans: int) -> None:
    out.mkdir(parents=True, exist_ok=True)
    if "service" in parts:
        t0 = time.perf_counter()
        (out / "service.json").write_text(json.dumps(service_answers(), indent=1,
                                                     sort_keys=True))
        print(f"service: {time.perf_counter() - t0:.1f} s", flush=True)
    if "slam" in parts:
        for log_name in LOGS:
            for label in METHODS:
                subprocess.run([sys.executable, __file__, "one", log_name, label, str(scans),
                                str(out)], check=True, cwd=ROOT)


def compare(ref: Path, out: Path) -> int:
    bad = 0
    for f in sorted(ref.glob("*.npz")):
        g = out / f.name
        if not g.exists():
            print(f"missing {g.name}")
            bad += 1
            continue
        a, b = np.load(f), np.load(g)
        for k in a.files:
            same = k in b.files and a[k].shape == b[k].shape and a[k].tobytes() == b[k].tobytes()
            if not same:
                diff = (np.max(np.abs(a[k] - b[k])) if k in b.files
                        and a[k].shape == b[k].shape else "shape")
                print(f"DIFF {f.name}:{k} max |d| = {diff}")
                bad += 1
    if (ref / "service.json").exists():
        a = _strip(json.loads((ref / "service.json").read_text()))
        b = _strip(json.loads((out / "service.json").read_text())) \
            if (out / "service.json").exists() else {}
        for k in a:
            if a[k] != b.get(k):
                print(f"DIFF service.json:{k}")
                bad += 1
    print("bitwise equal" if not bad else f"{bad} differences")
    return 1 if bad else 0


def main() -> int:
    p = argparse.ArgumentParser()
    sub = p.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump")
    d.add_argument("out", type=Path)
    d.add_argument("--parts", default="service,slam")
    d.add_argument("--scans", type=int, default=1500)
    c = sub.add_parser("compare")
    c.add_argument("ref", type=Path)
    c.add_argument("out", type=Path)
    o = sub.add_parser("one")
    o.add_argument("log")
    o.add_argument("label")
    o.add_argument("scans", type=int)
    o.add_argument("out", type=Path)
    a = p.parse_args()
    if a.cmd == "dump":
        dump(a.out, a.parts.split(","), a.scans)
    elif a.cmd == "one":
        slam_one(a.log, a.label, a.scans, a.out)
    else:
        return compare(a.ref, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
