"""The saved map: what a run writes, what a loader accepts and what it refuses."""

from __future__ import annotations

import hashlib
import io
import json
import os
import zipfile
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from chizu.numeric.slam import saved_map as sm
from chizu.numeric.slam.logs import read_log
from chizu.numeric.slam.runner import SlamOptions, run_log
from chizu.numeric.slam.simulate import simulated_log
from chizu.service.cli import app as cli

CLIP = Path(__file__).resolve().parents[2] / "examples" / "aces-clip.clf"


@pytest.fixture(scope="module")
def graph_map() -> sm.SavedMap:
    log = read_log(CLIP, limit=200)
    slam, _ = run_log(log, SlamOptions(method="graph"))
    return sm.saved_map_of_log(slam, log, "graph", 0.05)


def test_a_map_round_trips_bit_for_bit(graph_map: sm.SavedMap) -> None:
    back = sm.from_bytes(sm.to_bytes(graph_map))
    assert back.laser == graph_map.laser and back.resolution_m == 0.05
    for name in ("kf_scan", "kf_time", "kf_pose", "kf_odom", "times", "poses"):
        assert np.array_equal(getattr(back, name), getattr(graph_map, name)), name
    assert all(np.array_equal(a, b) for a, b in zip(back.kf_xy, graph_map.kf_xy, strict=True))
    assert np.array_equal(back.occupancy().state, graph_map.occupancy().state)
    assert back.meta["method"] == "graph" and back.meta["source"]


def test_graph_slam_keeps_its_constraints(graph_map: sm.SavedMap) -> None:
    """Every node after the first has an odometry edge to its predecessor; local matches
    too; the constraints index keyframes (graph SLAM's nodes are its keyframes)."""
    c = graph_map.constraints
    k = len(graph_map)
    odo = c.kind == sm.EDGE_KINDS.index("odometry")
    assert odo.sum() == k - 1
    assert np.array_equal(c.b[odo], np.arange(1, k)) and np.array_equal(c.a[odo], np.arange(k - 1))
    assert (c.kind == sm.EDGE_KINDS.index("local")).sum() > 0
    assert np.all(np.linalg.eigvalsh(c.cov) > 0)


def test_a_method_without_a_pose_graph_saves_keyframes_and_no_constraints() -> None:
    log = simulated_log("room_a", speed_m_s=1.0).head(60)
    slam, _ = run_log(log, SlamOptions(method="icp"))
    m = sm.from_bytes(sm.to_bytes(sm.saved_map_of_log(slam, log, "icp", 0.05)))
    assert len(m) > 0 and len(m.constraints) == 0 and len(m.times) == 60


def test_the_cli_writes_a_map_that_loads(tmp_path: Path) -> None:
    out = tmp_path / "run"
    r = CliRunner().invoke(cli, ["slam", str(CLIP), "--limit", "120", "--out", str(out)])
    assert r.exit_code == 0, r.output
    m = sm.load(out)  # the run directory names its map
    assert len(m.times) == 120 and len(m) > 1


# -- what a loader refuses, saying why --------------------------------------------------
def _rewrite(data: bytes, edit: dict[str, object] | None = None,
             arrays: dict[str, np.ndarray] | None = None) -> bytes:
    """``data`` with manifest entries replaced and arrays swapped (their checksums and
    shapes updated, so only the check under test can fail)."""
    zin = zipfile.ZipFile(io.BytesIO(data))
    man = json.loads(zin.read("manifest.json"))
    blobs = {n: zin.read(n) for n in zin.namelist() if n != "manifest.json"}
    for name, a in (arrays or {}).items():
        buf = io.BytesIO()
        np.lib.format.write_array(buf, a)
        blobs[f"{name}.npy"] = buf.getvalue()
        man["arrays"][name] = {"shape": list(a.shape), "dtype": a.dtype.str,
                               "sha256": hashlib.sha256(buf.getvalue()).hexdigest()}
    man.update(edit or {})
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:
        z.writestr("manifest.json", json.dumps(man))
        for n, b in blobs.items():
            z.writestr(n, b)
    return out.getvalue()


def _corrupt(data: bytes) -> bytes:
    """One byte of an array changed, stored uncompressed so the ZIP's own CRC is
    rewritten and only the manifest's checksum can tell."""
    zin = zipfile.ZipFile(io.BytesIO(data))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:
        for n in zin.namelist():
            b = bytearray(zin.read(n))
            if n == "kf_pose.npy":
                b[-3] ^= 0xFF
            z.writestr(n, bytes(b))
    return out.getvalue()


@pytest.mark.parametrize(("case", "says"), [
    ("empty", "empty"),
    ("not_zip", "not a ZIP"),
    ("truncated", "not a chizu map"),
    ("no_manifest", "no manifest"),
    ("other_format", "not a chizu map"),
    ("newer", "newer chizu"),
    ("checksum", r"corrupt \(checksum\)"),
    ("nan_pose", "NaN"),
    ("bad_offsets", "offsets"),
    ("bad_edges", "constraints"),
    ("bad_scan", "names a scan"),
])
def test_a_bad_map_is_refused_naming_what_is_wrong(graph_map: sm.SavedMap, case: str,
                                                   says: str) -> None:
    good = sm.to_bytes(graph_map)
    k = len(graph_map)
    data = {
        "empty": lambda: b"",
        "not_zip": lambda: b"P6 this is a picture",
        "truncated": lambda: good[: len(good) // 2],
        "no_manifest": lambda: _zip_without_manifest(good),
        "other_format": lambda: _rewrite(good, {"format": "gmapping"}),
        "newer": lambda: _rewrite(good, {"version": sm.VERSION + 1}),
        "checksum": lambda: _corrupt(good),
        "nan_pose": lambda: _rewrite(good, arrays={"kf_pose": np.where(
            np.arange(3 * k).reshape(k, 3) == 4, np.nan, graph_map.kf_pose)}),
        "bad_offsets": lambda: _rewrite(good, arrays={"kf_offsets": np.zeros(k + 1, np.int64)}),
        "bad_edges": lambda: _rewrite(good, arrays={"edge_b": graph_map.constraints.b + k}),
        "bad_scan": lambda: _rewrite(good, arrays={"kf_scan": graph_map.kf_scan + 10**6}),
    }[case]()
    with pytest.raises(sm.MapFileError, match=says) as e:
        sm.from_bytes(data)
    assert e.value.field == "map"


def _zip_without_manifest(good: bytes) -> bytes:
    zin = zipfile.ZipFile(io.BytesIO(good))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:
        for n in zin.namelist():
            if n != "manifest.json":
                z.writestr(n, zin.read(n))
    return out.getvalue()


def test_a_missing_map_says_where_it_looked(tmp_path: Path) -> None:
    with pytest.raises(sm.MapFileError, match="no saved map"):
        sm.load(tmp_path)


def test_a_failed_write_leaves_the_old_map_whole(graph_map: sm.SavedMap, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """The new file is written beside the old and renamed over it: a crash before the
    rename leaves the old map and no stray file."""
    path = sm.save(graph_map, tmp_path)
    before = path.read_bytes()

    def crash(*_: object) -> None:
        raise OSError("disk gone")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError):
        sm.save(graph_map, tmp_path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [sm.FILE_NAME]


def test_another_laser_is_named() -> None:
    a = sm.Laser(180, -np.pi / 2, np.deg2rad(1.0), 40.0)
    assert a.compatible(a) is None
    assert "steps" in (a.compatible(sm.Laser(361, -np.pi / 2, np.deg2rad(0.5), 40.0)) or "")
    assert "field of view" in (a.compatible(sm.Laser(240, -2.1, np.deg2rad(1.0), 40.0)) or "")


def test_the_cli_commits_its_map_into_a_world(tmp_path: Path) -> None:
    """``chizu slam LOG --world W`` (a subprocess: the CLI opens its own Prolog engine)
    commits the map into W as an upload does; an unknown world is refused before the
    log is mapped, and nothing is written."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "CHIZU_DATA_DIR": str(tmp_path / "var"), "CHIZU_DEMO_WORLD": "demo"}

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "chizu.service.cli", "slam", str(CLIP),
                               "--limit", "120", *args], env=env, capture_output=True,
                              text=True, timeout=600)

    r = run("--out", str(tmp_path / "no"), "--world", "nosuch")
    assert r.returncode == 2 and "nosuch" in r.stdout, r.stdout + r.stderr
    assert not (tmp_path / "no").exists()
    r = run("--out", str(tmp_path / "run"), "--world", "demo")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "committed into world demo" in r.stdout
    from chizu.service.container import open_services
    from chizu.service.settings import Settings

    svc = open_services(Settings(data_dir=tmp_path / "var", demo_world="", workers=0),
                        demo=False)
    try:
        assert svc.slam.saved_map("demo") == (tmp_path / "run" / sm.FILE_NAME).read_bytes()
    finally:
        svc.close()
