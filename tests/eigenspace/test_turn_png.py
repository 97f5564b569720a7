"""A turn as one PNG (``turn_png``): its images side by side, decoded once. It answers as
the same turn sent image by image, the camera renders it, and a wrong one is refused
naming ``turn_png``."""

from __future__ import annotations

import base64
import io

import numpy as np
from fastapi.testclient import TestClient
from PIL import Image

SMALL = {"camera": {"width_px": 32, "height_px": 16, "supersample": 1},
         "learning": {"spacing_m": 1.0, "n_directions": 36}, "learning_strategy": None}


def learned(client: TestClient, name: str) -> None:
    assert client.post("/worlds", json={"name": name, "template": "room_a"}).status_code == 201
    r = client.post(f"/worlds/{name}/eigenspace", json=SMALL)
    loc = r.headers["location"]
    while (j := client.get(loc).json())["status"] in ("queued", "running"):
        pass
    assert j["status"] == "done", j


def test_one_png_answers_as_the_turn_image_by_image(client: TestClient) -> None:
    learned(client, "tp")
    pose = {"pose": {"x": 3.0, "y": 5.0, "theta": 0.4}, "turn": 36}
    one = client.post("/worlds/tp/camera", json={**pose, "format": "turn_png"}).json()
    each = client.post("/worlds/tp/camera", json={**pose, "format": "png"}).json()
    strip = Image.open(io.BytesIO(base64.b64decode(one["turn_png"])))
    assert strip.size == (36 * 32, 16) and "images_png" not in one
    # the strip is the images side by side, left to right
    first = np.asarray(Image.open(io.BytesIO(base64.b64decode(each["images_png"][0]))))
    np.testing.assert_array_equal(np.asarray(strip)[:, :32], first)
    a = client.post("/worlds/tp/localize", json={"turn_png": one["turn_png"]})
    b = client.post("/worlds/tp/localize", json={"images_png": each["images_png"]})
    assert a.status_code == 200, a.text
    assert a.json() == b.json()
    # and as a session's stop
    sid = client.post("/worlds/tp/localization-sessions").json()["id"]
    s = client.post(f"/worlds/tp/localization-sessions/{sid}/stops",
                    json={"turn_png": one["turn_png"]})
    assert s.status_code == 200 and s.json()["stops"] == 1


def test_a_wrong_turn_png_is_refused_naming_it(client: TestClient) -> None:
    learned(client, "tq")
    one = client.post("/worlds/tq/camera", json={"pose": {"x": 3.0, "y": 5.0}, "turn": 35,
                                                 "format": "turn_png"}).json()
    for body, field in (({"turn_png": one["turn_png"]}, "turn_png"),  # 35 images wide
                        ({"turn_png": "not base64!"}, "turn_png"),
                        ({"turn_png": base64.b64encode(b"GIF89a").decode()}, "turn_png")):
        r = client.post("/worlds/tq/localize", json=body)
        assert r.status_code == 422 and r.json()["field"] == field, r.text
    r = client.post("/worlds/tq/localize", json={"turn_png": one["turn_png"],
                                                 "images_png": ["x"]})
    assert r.status_code == 422 and "exactly one" in r.json()["detail"]
