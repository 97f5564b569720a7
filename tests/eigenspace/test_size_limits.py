"""Requests too big to serve are refused before any work starts: a learning job over the
size cap, naming the spacing, and PNGs whose header is larger than the eigenspace's
images, naming the image, nothing decoded."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from tests.eigenspace.test_api import SMALL, wait_job
from tests.service.test_malformed_requests import is_problem


def png_header(width: int, height: int) -> bytes:
    """A PNG whose header says ``width`` x ``height`` grey pixels (its pixel data is one
    empty deflate stream: any decoder that got that far would fail or bomb)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b""))
            + chunk(b"IEND", b""))


@pytest.fixture(scope="module")
def learned(client: TestClient) -> str:
    assert client.post("/worlds", json={"name": "hard_eig", "template": "room_a"}
                       ).status_code == 201
    job = wait_job(client, client.post("/worlds/hard_eig/eigenspace", json=SMALL
                                       ).headers["location"])
    assert job["status"] == "done", job
    return "hard_eig"


def test_huge_pngs_are_refused_from_their_header(client: TestClient, learned: str) -> None:
    """A 14 000 x 14 000 PNG was a 500 (Pillow's decompression-bomb error); eight
    4 000 x 4 000 ones were decoded on the event loop for seconds. Now the header is
    compared with the eigenspace's image size first: 422 naming the image, nothing
    decoded. An upload likewise."""
    import base64

    turn = client.post(f"/worlds/{learned}/camera",
                       json={"pose": {"x": 3, "y": 5}, "turn": 72}).json()["images_png"]
    for side, k in ((14_000, 0), (4_000, 5)):
        bad = list(turn)
        bad[k] = base64.b64encode(png_header(side, side)).decode()
        r = client.post(f"/worlds/{learned}/localize", json={"images_png": bad})
        is_problem(r, 422, f"images_png[{k}]")
        assert f"{side} x {side}" in r.json()["detail"] or "bomb" in r.json()["detail"]
    files = [("images", (f"{i}.png", base64.b64decode(p), "image/png"))
             for i, p in enumerate(turn)]
    files[3] = ("images", ("3.png", png_header(4000, 4000), "image/png"))
    is_problem(client.post(f"/worlds/{learned}/localize/images", files=files), 422, "images[3]")
    r = client.post(f"/worlds/{learned}/localize", json={"images_png": turn})
    assert r.status_code == 200, r.text  # the real turn still localizes


def test_a_learning_job_has_a_size_cap(client: TestClient) -> None:
    """Grid spacing 0.06 m x 360 directions x 256 x 256 images was accepted (and would
    run for days); now refused before the job starts, naming the spacing. The paper's
    size starts."""
    assert client.post("/worlds", json={"name": "cap_w", "template": "room_a"}
                       ).status_code == 201
    r = client.post("/worlds/cap_w/eigenspace", json={
        "learning": {"spacing_m": 0.06, "n_directions": 360},
        "camera": {"width_px": 256, "height_px": 256}})
    is_problem(r, 422, "learning.spacing_m")
    assert client.get("/jobs", params={"world": "cap_w"}).json() == []
