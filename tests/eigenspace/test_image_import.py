"""A camera's own learning images: import a folder (CLI, REST multipart), the same
eigenspace and answers as the simulator's, and bad folders named file by file."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from chizu.numeric.camera import Camera
from chizu.numeric.eigenspace.analysis import (
    EigenspaceAnalysis,
    EigenspaceConfig,
    analyse_images,
    render_image_set,
)
from chizu.numeric.eigenspace.image_sets import (
    POSES_FILE,
    ImageSet,
    decode_image,
    encode_png,
    read_image_folder,
    read_image_set,
    write_image_folder,
)
from chizu.numeric.eigenspace.localization import Session, turn_candidates
from chizu.numeric.errors import InvalidInput
from chizu.numeric.world import World
from chizu.numeric.worlds import room_a

# the simulator drops triplets whose regions place its probe turns wrong (a folder
# has no turns of known pose to probe with): off, so both learn the same triplets
SMALL = {"camera": {"width_px": 32, "height_px": 16}, "learning": {"k": 12},
         "entry": {"samples": 30},
         "regions": {"calibration_per_triplet": 2, "max_wrong_share": None}}
PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory
             ) -> tuple[Path, ImageSet, EigenspaceAnalysis, World]:
    w = World(room_a())
    images, a = render_image_set(w, EigenspaceConfig.model_validate(SMALL))
    folder = tmp_path_factory.mktemp("room_a_images")
    write_image_folder(folder, images)
    return folder, images, a, w


def answer(a: EigenspaceAnalysis, turn: np.ndarray) -> np.ndarray | None:
    s = Session(a.config.localization)
    s.add_stop(turn_candidates(a.regions, turn), a.config.regions.d_thd_m)
    v = s.vote()
    return s.estimate(v) if v.unique and v.winner is not None else None


def test_an_exported_folder_learns_the_same_eigenspace_and_answers(exported: Any) -> None:
    folder, images, a, w = exported
    back = read_image_folder(folder)
    assert np.allclose(back.turns, images.turns, atol=1e-5)  # 16-bit PNG
    assert np.allclose(back.points, images.points) and len(back.calib_poses) > 20
    b = analyse_images(w, back, EigenspaceConfig.model_validate(SMALL))
    assert b.source == "images" and a.source == "simulator"
    # the same eigenspace: the same subspace and the same projections (up to sign)
    sign = np.sign(np.sum(a.model.basis * b.model.basis, axis=0))
    assert np.allclose(b.model.basis * sign, a.model.basis, atol=1e-3)
    assert np.allclose(b.model.projections * sign, a.model.projections, atol=1e-3)
    # c_a from the calibration images, the same triplets
    assert b.c_a == pytest.approx(a.c_a, rel=1e-3)
    assert {tuple(r) for r in b.triplets.point_idx} == {tuple(r) for r in a.triplets.point_idx}
    # eq. 7 from the calibration images and the learning turns: it reaches 0 within the
    # range the learning turns cover (they hold the zeros beyond one grid spacing)
    assert b.entry is not None and b.entry.c0 > 0 and b.entry.c1 < 0
    assert -b.entry.c0 / b.entry.c1 <= b.config.entry.max_distance_m
    # the same answers to turns uploaded as 16-bit PNGs
    cam, rng = Camera(w, a.config.camera), np.random.default_rng(3)
    localized = 0
    for p in w.sample_free(12, rng):
        turn = cam.render_turn(p, rng.uniform(-np.pi, np.pi), 72)
        turn = np.stack([decode_image("q", encode_png(im)) for im in turn])
        ra, rb = answer(a, turn), answer(b, turn)
        assert (ra is None) == (rb is None)
        if ra is not None and rb is not None:
            localized += 1
            assert np.allclose(ra, rb, atol=1e-3)
    assert localized >= 3


def test_without_calibration_images_c_a_is_a_safe_bound_and_eq7_is_unknown(
        exported: Any) -> None:
    folder, images, a, w = exported
    bare = ImageSet(images.points, images.turns, np.zeros((0, 3)),
                    np.zeros((0, *images.image_shape)))
    b = analyse_images(w, bare, EigenspaceConfig.model_validate(SMALL))
    assert b.c_a > 1.5 * a.c_a  # leave-one-out observations stand outside the triangles
    assert b.entry is None and b.coverage(w) is None
    with pytest.raises(InvalidInput) as e:
        b.layout(w)
    assert e.value.field == "calibration"
    assert EigenspaceAnalysis.from_bytes(b.to_bytes()).entry is None


def _copy(folder: Path, tmp: Path) -> Path:
    dst = tmp / "set"
    shutil.copytree(folder, dst)
    return dst


def _rewrite_poses(d: Path, edit: Any) -> None:
    lines = (d / POSES_FILE).read_text().splitlines()
    (d / POSES_FILE).write_text("\n".join(edit(lines)) + "\n")


@pytest.mark.parametrize("case,field", [
    ("missing file", "learn_003_010.png"),
    ("wrong size", "learn_002_005.png"),
    ("corrupt image", "learn_004_000.png"),
    ("not an image format we read", "learn_004_001.png"),
    ("incomplete turn", "learn_000_000.png"),
    ("off-grid heading", "learn_001_003.png"),
    ("non-finite pose", POSES_FILE),
    ("unknown role", POSES_FILE),
    ("path in a file name", POSES_FILE),
    ("missing column", POSES_FILE),
    ("listed twice", "learn_000_001.png"),
])
def test_bad_folders_name_the_file(exported: Any, tmp_path: Path, case: str,
                                   field: str) -> None:
    d = _copy(exported[0], tmp_path)
    if case == "missing file":
        (d / field).unlink()
    elif case == "wrong size":
        (d / field).write_bytes(encode_png(np.zeros((10, 10))))
    elif case == "corrupt image":
        (d / field).write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 20)
    elif case == "not an image format we read":
        buf = io.BytesIO()
        Image.new("L", (32, 16)).save(buf, format="BMP")
        (d / field).write_bytes(buf.getvalue())
    elif case == "incomplete turn":
        _rewrite_poses(d, lambda ls: [ls[0]] + [x for x in ls[1:] if
                                               not x.startswith("learn_000_071")])
        (d / "learn_000_071.png").unlink()
    elif case == "off-grid heading":
        _rewrite_poses(d, lambda ls: [x.replace(",0.261799388,", ",0.3,")
                                      if x.startswith(field) else x for x in ls])
    elif case == "non-finite pose":
        _rewrite_poses(d, lambda ls: [ls[0], ls[1].replace("1.000000,1", "nan,1", 1),
                                      *ls[2:]])
    elif case == "unknown role":
        _rewrite_poses(d, lambda ls: [ls[0], ls[1].replace(",learn", ",teach"), *ls[2:]])
    elif case == "path in a file name":
        _rewrite_poses(d, lambda ls: [ls[0], "../" + ls[1], *ls[2:]])
    elif case == "missing column":
        _rewrite_poses(d, lambda ls: [ls[0].replace("theta", "heading"), *ls[1:]])
    elif case == "listed twice":
        _rewrite_poses(d, lambda ls: [*ls, ls[2]])
    with pytest.raises(InvalidInput) as e:
        read_image_folder(d)
    assert e.value.field == field, str(e.value)


def test_an_uploaded_file_not_in_poses_csv_is_named(exported: Any) -> None:
    folder = exported[0]
    files = {f.name: f.read_bytes() for f in folder.glob("*.png")}
    files["extra.png"] = files["learn_000_000.png"]
    with pytest.raises(InvalidInput) as e:
        read_image_set((folder / POSES_FILE).read_text(), files)
    assert e.value.field == "extra.png"


def test_images_are_resized_and_colour_jpeg_is_read_as_grey() -> None:
    rgb = np.zeros((64, 128, 3), dtype=np.uint8)
    rgb[..., 1] = 200
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="JPEG", quality=95)
    g = decode_image("cam.jpg", buf.getvalue(), (32, 16))
    assert g.shape == (16, 32) and abs(g.mean() - 0.46) < 0.03  # ITU-R 601 luma of green
    with pytest.raises(InvalidInput, match="at most 256"):
        decode_image("big.png", encode_png(np.zeros((300, 300)), bits=8))


# -- REST -------------------------------------------------------------------------------
def _files(folder: Path) -> list[tuple[str, tuple[str, bytes, str]]]:
    """The folder as one zip part (25 x 72 images are more than a form's 1000 parts)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
        for f in sorted(folder.iterdir()):
            z.writestr(f"set/{f.name}", f.read_bytes())
    return [("archive", ("set.zip", buf.getvalue(), "application/zip"))]


def _wait(client: TestClient, location: str) -> dict[str, Any]:
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        j = client.get(location).json()
        if j["status"] in ("done", "failed"):
            return j  # type: ignore[no-any-return]
        time.sleep(0.2)
    raise AssertionError("learning job did not finish")


@pytest.fixture(scope="module")
def cam_a(client: TestClient, exported: Any) -> dict[str, Any]:
    """World ``cam_a`` learned over REST from the exported images: its learning job (the
    tests that use it may run on different pytest workers, each with its own service)."""
    assert client.post("/worlds", json={"name": "cam_a", "template": "room_a"}).status_code \
        == 201
    r = client.post("/worlds/cam_a/eigenspace/images", files=_files(exported[0]),
                    data={"config": json.dumps({"learning": {"k": 12}})})
    assert r.status_code == 202, r.text
    return _wait(client, r.headers["location"])


def test_rest_upload_learns_and_localizes_uploaded_images(
        client: TestClient, exported: Any, cam_a: dict[str, Any]) -> None:
    folder = exported[0]
    assert cam_a["status"] == "done", cam_a
    s = client.get("/worlds/cam_a/eigenspace").json()
    assert s["source"] == "images" and s["learning_points"] == 25
    assert s["image_shape"] == [16, 32] and s["c_a"] == pytest.approx(exported[2].c_a, 1e-3)
    # one turn as files, straight from the camera; the same answer as the JSON route
    turn = sorted(folder.glob("learn_012_*.png"))
    files = [("images", (f.name, f.read_bytes(), "image/png")) for f in turn]
    up = client.post("/worlds/cam_a/localize/images", files=files)
    assert up.status_code == 200, up.text
    assert up.json()["state"] == {"state": "z"}
    assert up.json()["pose"]["x"] == pytest.approx(exported[1].points[12][0], abs=0.05)
    import base64
    js = client.post("/worlds/cam_a/localize", json={
        "images_png": [base64.b64encode(f.read_bytes()).decode() for f in turn]})
    assert js.json() == up.json()
    # a camera may name every frame alike: the turn is the order of the parts
    same = [("images", ("frame.png", f.read_bytes(), "image/png")) for f in turn]
    assert client.post("/worlds/cam_a/localize/images", files=same).json() == up.json()
    # the next move needs eq. 7, which the calibration images gave
    sid = client.post("/worlds/cam_a/localization-sessions").json()["id"]
    assert client.get(f"/worlds/cam_a/localization-sessions/{sid}/next-move").status_code \
        == 200


def test_rest_upload_errors_name_the_file(client: TestClient, exported: Any,
                                          tmp_path: Path, cam_a: dict[str, Any]) -> None:
    folder = exported[0]
    r = client.post("/worlds/nowhere/eigenspace/images", files=_files(folder))
    assert r.status_code == 404 and r.headers["content-type"].startswith(PROBLEM)
    assert client.post("/worlds", json={"name": "cam_bad", "template": "room_a"}
                       ).status_code == 201
    # a corrupt image, named; the same as separate parts (poses + images)
    parts = [("poses", (POSES_FILE, (folder / POSES_FILE).read_bytes(), "text/csv"))]
    for f in sorted(folder.glob("learn_00[0-9]_*.png"))[:300]:
        parts.append(("images", (f.name, b"not an image" if f.name == "learn_001_001.png"
                                 else f.read_bytes(), "image/png")))
    r = client.post("/worlds/cam_bad/eigenspace/images", files=parts)
    assert r.status_code == 422 and r.json()["field"] == "learn_001_001.png", r.text
    r = client.post("/worlds/cam_bad/eigenspace/images",
                    files=[("archive", ("x.zip", b"PK junk", "application/zip"))])
    assert r.status_code == 422 and r.json()["field"] == "archive", r.text
    r = client.post("/worlds/cam_bad/eigenspace/images", files=_files(folder),
                    data={"config": '{"learning": {"k": -1}}'})
    assert r.status_code == 422 and r.json()["field"] == "config.learning.k", r.text
    # the learning strategy renders the points it adds: not for a camera's images
    r = client.post("/worlds/cam_bad/eigenspace/images", files=_files(folder),
                    data={"config": '{"learning_strategy": {}}'})
    assert r.status_code == 422 and r.json()["field"] == "config.learning_strategy", r.text
    r = client.post("/worlds/cam_bad/eigenspace/images", files=_files(folder),
                    data={"size": "big"})
    assert r.status_code == 422 and r.json()["field"] == "size"
    r = client.post("/worlds/cam_bad/eigenspace/images", data={"size": "64x32"})
    assert r.status_code == 422 and r.json()["field"] == "archive"  # neither way
    # nothing was learned by the failed uploads
    assert client.get("/worlds/cam_bad/eigenspace").status_code == 404
    # a learned world refuses a turn of the wrong size from the first file's header
    turn = [("images", (f"{j}.png", encode_png(np.zeros((10, 10))), "image/png"))
            for j in range(72)]
    r = client.post("/worlds/cam_a/localize/images", files=turn)
    assert r.status_code == 422 and r.json()["field"] == "images[0]", r.text
    h, w = client.get("/worlds/cam_a/eigenspace").json()["image_shape"]
    turn = [("images", (f"{j}.png", encode_png(np.zeros((h, w))), "image/png"))
            for j in range(72)]
    turn[3] = ("images", ("3.png", b"junk", "image/png"))
    r = client.post("/worlds/cam_a/localize/images", files=turn)
    assert r.status_code == 422 and r.json()["field"] == "images[3]", r.text


# -- CLI --------------------------------------------------------------------------------
def test_cli_export_learn_localize(tmp_path: Path) -> None:
    """In a subprocess: the CLI opens its own Prolog engine, one per process."""
    env = {**os.environ, "CHIZU_DATA_DIR": str(tmp_path / "var"), "CHIZU_DEMO_WORLD": ""}

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "chizu.service.cli", "eigenspace", *args],
                              env=env, capture_output=True, text=True, timeout=300)

    cfg = tmp_path / "small.json"
    cfg.write_text(json.dumps(SMALL))
    r = run("export", "room_a", str(tmp_path / "imgs"), "--config", str(cfg))
    assert r.returncode == 0, r.stdout + r.stderr
    r = run("learn", "room_a", "--images", str(tmp_path / "imgs"), "--config", str(cfg))
    assert r.returncode == 0, r.stdout + r.stderr
    turn = sorted(str(p) for p in (tmp_path / "imgs").glob("learn_007_*.png"))
    r = run("localize", "room_a", *turn)
    assert r.returncode == 0, r.stdout + r.stderr
    out = json.loads(r.stdout[r.stdout.index("{"):r.stdout.rindex("}") + 1])
    assert out["state"] == {"state": "z"} and abs(out["pose"]["x"] - 5.0) < 0.05
    r = run("localize", "room_a", *turn[:5])
    assert r.returncode == 2 and "images" in r.stdout


def test_uploads_have_their_own_size_limits(client: TestClient, exported: Any) -> None:
    """An image set may exceed the 8 MiB body limit of other routes (up to
    CHIZU_MAX_UPLOAD_BYTES); a member that inflates past 16 MiB is refused by its
    declared size before it is inflated; a turn upload keeps the 8 MiB limit."""
    folder = exported[0]
    assert client.post("/worlds", json={"name": "cam_big", "template": "room_a"}
                       ).status_code == 201
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
        for f in sorted(folder.iterdir()):
            z.writestr(f"set/{f.name}", f.read_bytes())
        z.writestr("other/padding.bin", np.random.default_rng(0).bytes(9 * 1024 * 1024))
    assert len(buf.getvalue()) > 8 * 1024 * 1024
    r = client.post("/worlds/cam_big/eigenspace/images",
                    files=[("archive", ("set.zip", buf.getvalue(), "application/zip"))])
    assert r.status_code == 202, r.text
    assert _wait(client, r.headers["location"])["status"] == "done"
    bomb = io.BytesIO()
    with zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("poses.csv", (folder / POSES_FILE).read_text())
        z.writestr("learn_000_000.png", b"\0" * (17 * 1024 * 1024))
    assert len(bomb.getvalue()) < 100_000
    r = client.post("/worlds/cam_big/eigenspace/images",
                    files=[("archive", ("bomb.zip", bomb.getvalue(), "application/zip"))])
    assert r.status_code == 422 and r.json()["field"] == "learn_000_000.png", r.text
    big = [("images", (f"{j}.png", np.random.default_rng(j).bytes(200_000), "image/png"))
           for j in range(50)]
    r = client.post("/worlds/cam_big/localize/images", files=big)
    assert r.status_code == 413 and r.headers["content-type"].startswith(PROBLEM)
    assert client.get("/health").status_code == 200
