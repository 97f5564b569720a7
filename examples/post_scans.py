"""Post the laser scans of a CARMEN log (its FLASER lines) to a chizu SLAM run.

A robot's bridge does the same as its scans come in: each scan is the ranges with the
odometry pose at its time stamp (``POST /worlds/{world}/slam-runs/{run}/scans``, at most
500 scans a request). Standard library only.

    python3 examples/post_scans.py examples/aces-clip.clf \\
        http://127.0.0.1:8000/worlds/aces/slam-runs/RUN
"""

from __future__ import annotations

import argparse
import json
import math
import urllib.request


def flaser_scans(path: str, range_max_m: float) -> list[dict]:
    """The FLASER lines of a CARMEN log as ``ScanIn`` bodies: n ranges at 1 degree (180
    beams; 0.5 degree for 360) from -90 degrees, the odometry pose of the line."""
    scans = []
    with open(path) as f:
        for line in f:
            tok = line.split()
            if not tok or tok[0] != "FLASER":
                continue
            n = int(tok[1])
            ranges = [min(float(r), range_max_m) for r in tok[2:2 + n]]
            odom = [float(v) for v in tok[n + 5:n + 8]]
            scans.append({"t": float(tok[n + 8]), "ranges": ranges,
                          "angle_min": -math.pi / 2, "angle_increment": math.pi / (n - n % 2),
                          "range_max": range_max_m, "odom": odom})
    return scans


def post(url: str, body: dict) -> dict:
    req = urllib.request.Request(url, data=json.dumps(body).encode(), method="POST",
                                 headers={"content-type": "application/json"})
    with urllib.request.urlopen(req) as r:
        return json.load(r)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", help="CARMEN log (.clf) with FLASER lines")
    ap.add_argument("run", help="the run's URL, http://HOST:PORT/worlds/WORLD/slam-runs/ID")
    ap.add_argument("--batch", type=int, default=100, help="scans per request (at most 500)")
    ap.add_argument("--range-max", type=float, default=40.0,
                    help="ranges at or beyond this are no-returns (m)")
    a = ap.parse_args()
    scans = flaser_scans(a.log, a.range_max)
    for i in range(0, len(scans), a.batch):
        run = post(a.run + "/scans", {"scans": scans[i:i + a.batch]})
    p = run["pose"]
    print(f"posted {len(scans)} scans; the run holds {run['scans']} scans, "
          f"{run['keyframes']} keyframes, pose x {p['x']:.2f} m, y {p['y']:.2f} m, "
          f"theta {p['theta']:.3f} rad")


if __name__ == "__main__":
    main()
