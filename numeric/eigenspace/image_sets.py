"""Learning images from a user's own camera (paper §2.1 with real images).

An image set is a folder: one image per pose (PNG or JPEG, grey or colour, read as grey
in [0, 1]) and ``poses.csv`` with the columns ``file, x, y, theta`` [m, m, rad] and an
optional ``role``:

- ``learn`` (the default): the images of the learning points. Every learning point is
  one full turn, the same number N_theta of images at each, taken at the headings
  ``2 pi j / N_theta`` (j = 0 .. N_theta - 1, counter-clockwise from the world's x axis,
  within a quarter of a step), as the paper's robot does at its N_w points;
- ``calibrate``: single images at other known poses, e.g. from a motion-capture run.
  Those inside a triplet's triangle fit the constant c_a of eq. 6 as the simulator's
  observations do (:func:`chizu.numeric.eigenspace.analysis.analyse_images`).

:func:`chizu.numeric.eigenspace.analysis.render_image_set` renders the simulator's images and
:func:`write_image_folder` writes them in this form, so a user can see the format; an
imported folder gives the same eigenspace as learning in the simulator (a test does
the round trip).
"""

from __future__ import annotations

import csv
import io
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import heading_bin, wrap_angle

POSES_FILE = "poses.csv"
FORMATS = ("PNG", "JPEG")
MAX_FILE_SIDE_PX = 4096  # per file, checked from the header before decoding
MAX_SIDE_PX = 256  # per image as learned (the camera's limit; the paper's are ~64 x 32)
MAX_IMAGES = 20_000
MAX_FILE_BYTES = 16 * 1024 * 1024  # per file inside a zip archive (uncompressed)
MAX_ARCHIVE_BYTES = 1024 * 1024 * 1024  # all files of an archive (uncompressed)
ROLES = ("learn", "calibrate")


@dataclass
class ImageSet:
    """Learning turns ``turns (Nw, Nt, H, W)`` at ``points (Nw, 2)`` and calibration
    images ``calib_images (M, H, W)`` at ``calib_poses (M, 3)``."""

    points: np.ndarray
    turns: np.ndarray
    calib_poses: np.ndarray
    calib_images: np.ndarray

    @property
    def n_directions(self) -> int:
        return int(self.turns.shape[1])

    @property
    def image_shape(self) -> tuple[int, int]:
        return int(self.turns.shape[2]), int(self.turns.shape[3])


def parse_size(text: str | None) -> tuple[int, int] | None:
    """``"64x32"`` -> (64, 32): the width x height images are resized to (None: keep)."""
    if not text:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InvalidInput(f"size must read WIDTHxHEIGHT, e.g. 64x32, got {text!r}",
                           field="size") from None
    if not (4 <= w <= MAX_SIDE_PX and 4 <= h <= MAX_SIDE_PX):
        raise InvalidInput(f"size: width and height must lie in 4..{MAX_SIDE_PX} px",
                           field="size")
    return w, h


def decode_image(name: str, data: bytes, size: tuple[int, int] | None = None,
                 formats: tuple[str, ...] = FORMATS,
                 expect: tuple[int, int] | None = None,
                 max_side_px: int = MAX_SIDE_PX) -> np.ndarray:
    """A grey image ``(H, W)`` in [0, 1] from the bytes of a file in one of ``formats``
    (PNG or JPEG), resized to ``size`` (width, height) when given; the file's size is
    checked from its header before any pixel is decoded: at most MAX_FILE_SIDE_PX a
    side, and exactly ``expect`` (width, height) when given without ``size`` (an
    eigenspace's own image size: a larger image is refused unread); the decoded image
    is at most ``max_side_px`` a side (a turn's images side by side may be wider).
    Errors name the file."""
    try:
        with Image.open(io.BytesIO(data)) as im:
            if im.format not in formats:
                raise InvalidInput(f"{name}: {im.format or 'unknown'} image; "
                                   f"{' or '.join(formats)} expected", field=name)
            w, h = im.size
            if max(w, h) > max(MAX_FILE_SIDE_PX, max_side_px):
                raise InvalidInput(f"{name}: {w} x {h} px; at most {MAX_FILE_SIDE_PX} px a "
                                   "side", field=name)
            if expect is not None and size is None and (w, h) != tuple(expect):
                raise InvalidInput(f"{name}: {w} x {h} px; this eigenspace's images are "
                                   f"{expect[0]} x {expect[1]} px", field=name)
            deep = im.mode in ("I;16", "I;16B", "I;16L", "I")  # 16-bit grey PNG
            grey = im if deep else im.convert("L")
            if size is not None and (w, h) != tuple(size):
                grey = grey.convert("F").resize(size, Image.Resampling.BOX)
            a = np.asarray(grey, dtype=np.float64) / (65535.0 if deep else 255.0)
    except InvalidInput:
        raise
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as e:
        raise InvalidInput(f"{name}: not a readable PNG or JPEG image ({e})",
                           field=name) from e
    if max(a.shape) > max_side_px:
        raise InvalidInput(f"{name}: {a.shape[1]} x {a.shape[0]} px; at most {max_side_px} "
                           "px a side: give a size to resize to (e.g. 64 x 32)", field=name)
    return np.clip(a, 0.0, 1.0)


def encode_png(img: np.ndarray, bits: int = 16) -> bytes:
    """Grey PNG of an image in [0, 1], 16-bit by default (written images read back
    within 1e-5, so an exported set learns the same eigenspace) or 8-bit."""
    buf = io.BytesIO()
    c = np.clip(np.asarray(img, dtype=float), 0.0, 1.0)
    if bits == 16:
        Image.fromarray(np.round(c * 65535.0).astype(np.uint16)).save(buf, format="PNG")
    else:
        Image.fromarray(np.round(c * 255.0).astype(np.uint8), mode="L").save(buf, format="PNG")
    return buf.getvalue()


@dataclass
class _Row:
    file: str
    x: float
    y: float
    theta: float
    role: str


def parse_poses(text: str) -> list[_Row]:
    """Rows of ``poses.csv``; errors name ``poses.csv`` and the line."""
    reader = csv.DictReader(io.StringIO(text))
    cols = {c.strip() for c in (reader.fieldnames or [])}
    missing = {"file", "x", "y", "theta"} - cols
    if missing:
        raise InvalidInput(f"{POSES_FILE} lacks the column(s) {sorted(missing)}; expected "
                           "file,x,y,theta[,role]", field=POSES_FILE)
    rows: list[_Row] = []
    seen: set[str] = set()
    for line, r in enumerate(reader, start=2):
        r = {(k or "").strip(): (v or "").strip() for k, v in r.items()}
        where = f"{POSES_FILE} line {line}"
        name = r["file"]
        if not name or "/" in name or "\\" in name or name in (".", ".."):
            raise InvalidInput(f"{where}: file must be a plain file name, got {name!r}",
                               field=POSES_FILE)
        if name in seen:
            raise InvalidInput(f"{where}: {name} is listed twice", field=name)
        seen.add(name)
        try:
            x, y, th = float(r["x"]), float(r["y"]), float(r["theta"])
        except ValueError as e:
            raise InvalidInput(f"{where}: x, y, theta must be numbers ({e})",
                               field=POSES_FILE) from e
        if not np.isfinite([x, y, th]).all():
            raise InvalidInput(f"{where}: x, y, theta must be finite", field=POSES_FILE)
        role = r.get("role") or "learn"
        if role not in ROLES:
            raise InvalidInput(f"{where}: role must be one of {ROLES}, got {role!r}",
                               field=POSES_FILE)
        rows.append(_Row(name, x, y, th, role))
        if len(rows) > MAX_IMAGES:
            raise InvalidInput(f"{POSES_FILE}: more than {MAX_IMAGES} images",
                               field=POSES_FILE)
    if not rows:
        raise InvalidInput(f"{POSES_FILE} lists no images", field=POSES_FILE)
    return rows


def read_image_set(poses_csv: str, files: Mapping[str, bytes],
                   size: tuple[int, int] | None = None) -> ImageSet:
    """An :class:`ImageSet` from the text of ``poses.csv`` and the listed files' bytes,
    every image resized to ``size`` (width, height) when given.

    Wrong sizes, missing or unlisted files, incomplete or irregular turns and corrupt
    images raise :class:`InvalidInput` naming the file (or ``poses.csv``)."""
    rows = parse_poses(poses_csv)
    listed = {r.file for r in rows}
    extra = sorted(set(files) - listed - {POSES_FILE})
    if extra:
        raise InvalidInput(f"{extra[0]} is not listed in {POSES_FILE}", field=extra[0])
    images: dict[str, np.ndarray] = {}
    for r in rows:
        if r.file not in files:
            raise InvalidInput(f"{r.file} is listed in {POSES_FILE} but missing", field=r.file)
        images[r.file] = decode_image(r.file, files[r.file], size)
    shape = images[rows[0].file].shape
    for r in rows:
        if images[r.file].shape != shape:
            raise InvalidInput(f"{r.file} is {images[r.file].shape[1]} x "
                               f"{images[r.file].shape[0]} px, {rows[0].file} is "
                               f"{shape[1]} x {shape[0]}: all images must have one size",
                               field=r.file)
    # learning turns: rows grouped by position (to the millimetre)
    groups: dict[tuple[int, int], list[_Row]] = {}
    for r in rows:
        if r.role == "learn":
            groups.setdefault((round(r.x * 1000), round(r.y * 1000)), []).append(r)
    if len(groups) < 3:
        raise InvalidInput(f"{POSES_FILE}: {len(groups)} learning point(s); at least 3 are "
                           "needed", field=POSES_FILE)
    counts = {len(g) for g in groups.values()}
    n = max(counts)
    if len(counts) > 1 or n < 4:
        key, g = min(groups.items(), key=lambda kv: len(kv[1]))
        raise InvalidInput(f"the learning point at ({key[0] / 1000:g}, {key[1] / 1000:g}) has "
                           f"{len(g)} images; every learning point needs one full turn of "
                           f"the same number (>= 4) of images (the largest here: {n})",
                           field=g[0].file)
    step = 2.0 * np.pi / n
    points = np.array([(k[0] / 1000.0, k[1] / 1000.0) for k in groups])
    turns = np.empty((len(groups), n, *shape))
    for i, g in enumerate(groups.values()):
        filled = [False] * n
        for r in g:
            j = int(heading_bin(r.theta, n))
            if abs(wrap_angle(r.theta - j * step)) > 0.25 * step or filled[j]:
                raise InvalidInput(f"{r.file}: heading {r.theta:.4f} rad is not one of a "
                                   f"turn's {n} headings 2*pi*j/{n} (or repeats one)",
                                   field=r.file)
            filled[j] = True
            turns[i, j] = images[r.file]
    cal = [r for r in rows if r.role == "calibrate"]
    calib_poses = np.array([(r.x, r.y, r.theta) for r in cal]).reshape(-1, 3)
    calib_images = np.array([images[r.file] for r in cal]).reshape(-1, *shape)
    return ImageSet(points, turns, calib_poses, calib_images)


def read_image_folder(path: str | Path, size: tuple[int, int] | None = None) -> ImageSet:
    """:func:`read_image_set` on a folder holding ``poses.csv`` and the images."""
    root = Path(path)
    pf = root / POSES_FILE
    if not pf.is_file():
        raise InvalidInput(f"{root} has no {POSES_FILE}", field=POSES_FILE)
    text = pf.read_text(encoding="utf-8-sig")
    files = {}
    for r in parse_poses(text):
        f = root / r.file
        if not f.is_file():
            raise InvalidInput(f"{r.file} is listed in {POSES_FILE} but missing", field=r.file)
        files[r.file] = f.read_bytes()
    return read_image_set(text, files, size)


def read_image_zip(data: bytes, size: tuple[int, int] | None = None) -> ImageSet:
    """:func:`read_image_set` on a zip archive of a folder (``poses.csv`` and the images
    at its top level or inside one folder). Sizes are checked from the archive's
    directory before anything is inflated."""
    try:
        zf = zipfile.ZipFile(io.BytesIO(data))
    except (zipfile.BadZipFile, ValueError) as e:
        raise InvalidInput(f"not a zip archive: {e}", field="archive") from e
    with zf:
        infos = [i for i in zf.infolist() if not i.is_dir()]
        if len(infos) > MAX_IMAGES + 1:
            raise InvalidInput(f"more than {MAX_IMAGES} files in the archive", field="archive")
        if sum(i.file_size for i in infos) > MAX_ARCHIVE_BYTES:
            raise InvalidInput(f"the archive inflates to more than {MAX_ARCHIVE_BYTES} bytes",
                               field="archive")
        pose_files = [i for i in infos if i.filename.rsplit("/", 1)[-1] == POSES_FILE]
        if len(pose_files) != 1:
            raise InvalidInput(f"the archive must hold exactly one {POSES_FILE}",
                               field="archive")
        root = pose_files[0].filename[:-len(POSES_FILE)]
        files: dict[str, bytes] = {}
        for i in infos:
            if not i.filename.startswith(root) or "/" in i.filename[len(root):]:
                continue  # not beside poses.csv
            name = i.filename[len(root):]
            if i.file_size > MAX_FILE_BYTES:
                raise InvalidInput(f"{name}: more than {MAX_FILE_BYTES} bytes", field=name)
            try:
                files[name] = zf.read(i)
            except (zipfile.BadZipFile, OSError, ValueError) as e:
                raise InvalidInput(f"{name}: cannot be read from the archive ({e})",
                                   field=name) from e
    text = files.pop(POSES_FILE).decode("utf-8-sig", errors="replace")
    listed = {r.file for r in parse_poses(text)}
    return read_image_set(text, {k: v for k, v in files.items() if k in listed}, size)


def write_image_folder(path: str | Path, images: ImageSet) -> int:
    """Write ``images`` as a folder :func:`read_image_folder` reads; returns the count."""
    root = Path(path)
    root.mkdir(parents=True, exist_ok=True)
    lines = ["file,x,y,theta,role"]
    n = images.n_directions
    for i, (x, y) in enumerate(images.points):
        for j in range(n):
            name = f"learn_{i:03d}_{j:03d}.png"
            (root / name).write_bytes(encode_png(images.turns[i, j]))
            lines.append(f"{name},{x:.6f},{y:.6f},{2.0 * np.pi * j / n:.9f},learn")
    for k, (pose, img) in enumerate(zip(images.calib_poses, images.calib_images, strict=True)):
        name = f"calibrate_{k:04d}.png"
        (root / name).write_bytes(encode_png(img))
        lines.append(f"{name},{pose[0]:.6f},{pose[1]:.6f},{pose[2]:.9f},calibrate")
    (root / POSES_FILE).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return len(lines) - 1
