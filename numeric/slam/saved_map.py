"""A saved map: what a SLAM run leaves for the runs after it.

A map outlives its run as one file (``map.chizu``, written beside ``trajectory.tum`` by
``chizu slam --out``): the run's keyframes -- each keyframe's returns in its own robot
frame, its stamp, odometry and pose in the map frame --, the pose graph's constraints
between them (graph SLAM's odometry, local-match and loop-closure edges), every scan's
stamp and pose, and the laser the log was taken with. The occupancy grid is rebuilt
from the keyframes (:meth:`SavedMap.occupancy`), so grid and keyframes cannot
disagree. Later runs localize in it, resume it or merge it with another map.

Format ``chizu-map``, version 1: a ZIP archive holding ``manifest.json`` and one
``.npy`` array per entry of the manifest's ``arrays``, each with its SHA-256. A file
is written beside its destination and moved over it in one rename, so a reader finds
the old map or the new one, never half of one; the loader checks the format, the
version, every array's checksum, shape and dtype and how the arrays fit together, and
says which of these failed (:class:`MapFileError`, field ``map``).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import time
import uuid
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from chizu.numeric.errors import InvalidInput
from chizu.numeric.occupancy import OccupancyMap, build_occupancy
from chizu.numeric.scan import LaserLog, Scan

FORMAT = "chizu-map"
VERSION = 1
#: the file a run directory holds its saved map in
FILE_NAME = "map.chizu"
#: the largest map (uncompressed arrays) a loader accepts: a guard against a corrupt
#: or hostile archive that claims gigabytes
MAX_MAP_BYTES = 2 * 2**30
#: a constraint's kind, as stored in ``edge_kind``
EDGE_KINDS = ("odometry", "local", "loop")
EdgeKind = Literal["odometry", "local", "loop"]


class MapFileError(InvalidInput):
    """A map file that cannot be used: not a chizu map, another version, corrupt."""

    def __init__(self, message: str) -> None:
        super().__init__(message, field="map")


@dataclass(frozen=True)
class Laser:
    """The laser a map was made with: beam count, first beam's angle, angular step
    [rad] and usable range [m]."""

    beams: int
    angle_min: float
    angle_increment: float
    max_range_m: float

    @staticmethod
    def of(log: LaserLog) -> Laser:
        """The laser of ``log``'s first scan."""
        if not log.scans:
            raise InvalidInput("the log holds no scans", field="log")
        return Laser.of_scan(log.scans[0])

    @staticmethod
    def of_scan(s: Scan) -> Laser:
        """The laser that took scan ``s``."""
        inc = float(np.median(np.diff(s.angles))) if len(s.angles) > 1 else 0.0
        return Laser(len(s.angles), float(s.angles[0]), inc, float(s.max_range_m))

    @property
    def field_of_view(self) -> float:
        return self.angle_increment * max(self.beams - 1, 0)

    def compatible(self, other: Laser) -> str | None:
        """None when scans of ``other`` can be matched against a map of this laser;
        else what differs. A laser with another angular step or field of view sees
        the same walls as other points, and its map's ranges are not its own."""
        if abs(self.angle_increment - other.angle_increment) > 1e-4:
            return (f"the map was made with a laser of {np.rad2deg(self.angle_increment):.3f}"
                    f" deg steps, the log's has {np.rad2deg(other.angle_increment):.3f}")
        if abs(self.field_of_view - other.field_of_view) > np.deg2rad(1.0):
            return (f"the map was made with a laser of {np.rad2deg(self.field_of_view):.1f}"
                    f" deg field of view, the log's has "
                    f"{np.rad2deg(other.field_of_view):.1f}")
        return None


@dataclass(frozen=True)
class Frame:
    """One keyframe as the occupancy builder reads it (robot frame)."""

    xy: np.ndarray
    intensity: np.ndarray | None
    misses: np.ndarray | None


@dataclass(frozen=True)
class Constraints:
    """Pose-graph edges between keyframes: node ``b`` at ``delta`` in node ``a``'s
    frame, with covariance ``cov (E, 3, 3)``, of kind :data:`EDGE_KINDS`."""

    a: np.ndarray
    b: np.ndarray
    delta: np.ndarray
    cov: np.ndarray
    kind: np.ndarray

    @staticmethod
    def empty() -> Constraints:
        z = np.zeros(0, dtype=np.int64)
        return Constraints(z, z, np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0, np.int8))

    def __len__(self) -> int:
        return len(self.a)


@dataclass(frozen=True)
class SavedMap:
    """Keyframes (stamps, scan indices, map-frame poses, odometry, returns), the
    constraints between them, every scan's stamp and pose, the laser, the grid
    resolution, and where the map came from (``meta``: source log, method, world)."""

    laser: Laser
    resolution_m: float
    kf_scan: np.ndarray
    kf_time: np.ndarray
    kf_pose: np.ndarray
    kf_odom: np.ndarray
    kf_xy: list[np.ndarray]
    kf_intensity: list[np.ndarray] | None
    kf_misses: list[np.ndarray]
    times: np.ndarray
    poses: np.ndarray
    constraints: Constraints
    meta: dict[str, Any]

    def __len__(self) -> int:
        return len(self.kf_pose)

    def frames(self) -> list[Frame]:
        inten = self.kf_intensity
        return [Frame(self.kf_xy[k], None if inten is None else inten[k], self.kf_misses[k])
                for k in range(len(self))]

    def occupancy(self, resolution_m: float | None = None) -> OccupancyMap:
        """The occupancy grid of the keyframes at their poses."""
        return build_occupancy(self.frames(), self.kf_pose, resolution_m or self.resolution_m)


# -- building ------------------------------------------------------------------------------
def saved_map(slam: Any, laser: Laser, odometry: np.ndarray, method: str,
              resolution_m: float, meta: dict[str, Any] | None = None) -> SavedMap:
    """The map of a finished run of ``slam`` (any estimator of
    :func:`chizu.numeric.slam.runner.create`) over scans of ``laser`` with odometry
    ``odometry (S, 3)``, one row per scan; the constraints of estimators that keep a
    pose graph (graph SLAM's ``constraints()``), none for the others."""
    edges = getattr(slam, "constraints", None)
    constraints = edges() if callable(edges) else Constraints.empty()
    frames = slam.keyframes.frames
    kf_pose = np.asarray(slam.map_poses(), dtype=float).reshape(-1, 3)
    times, poses = slam.trajectory()
    kf_scan = np.array([f.scan_index for f in frames], dtype=np.int64)
    odom = np.asarray(odometry, dtype=float).reshape(-1, 3)
    if len(odom) != len(times):
        raise InvalidInput(f"{len(odom)} odometry readings for {len(times)} scans",
                           field="odometry")
    inten = ([np.asarray(f.intensity, float) for f in frames]
             if frames and all(f.intensity is not None for f in frames) else None)
    return SavedMap(
        laser=laser, resolution_m=float(resolution_m), kf_scan=kf_scan,
        kf_time=np.asarray(times, float)[kf_scan], kf_pose=kf_pose,
        kf_odom=odom[kf_scan] if len(kf_scan) else np.zeros((0, 3)),
        kf_xy=[np.asarray(f.xy, float) for f in frames], kf_intensity=inten,
        kf_misses=[np.zeros((0, 2)) if f.misses is None else np.asarray(f.misses, float)
                   for f in frames],
        times=np.asarray(times, float), poses=np.asarray(poses, float).reshape(-1, 3),
        constraints=constraints, meta={"method": method, **(meta or {})})


def saved_map_of_log(slam: Any, log: LaserLog, method: str, resolution_m: float) -> SavedMap:
    """:func:`saved_map` of a run over a whole ``log``."""
    return saved_map(slam, Laser.of(log), log.odometry, method, resolution_m,
                     {"source": log.name})


# -- writing -------------------------------------------------------------------------------
def _ragged(parts: list[np.ndarray], width: int) -> tuple[np.ndarray, np.ndarray]:
    offsets = np.zeros(len(parts) + 1, dtype=np.int64)
    offsets[1:] = np.cumsum([len(p) for p in parts])
    flat = (np.concatenate(parts).reshape(-1, width) if parts
            else np.zeros((0, width)))
    return (flat if width > 1 else flat.reshape(-1)), offsets


def _arrays(m: SavedMap) -> dict[str, np.ndarray]:
    xy, offsets = _ragged(m.kf_xy, 2)
    misses, miss_offsets = _ragged(m.kf_misses, 2)
    out = {"kf_scan": m.kf_scan, "kf_time": m.kf_time, "kf_pose": m.kf_pose,
           "kf_odom": m.kf_odom, "kf_offsets": offsets, "kf_xy": xy,
           "miss_offsets": miss_offsets, "miss_xy": misses, "times": m.times,
           "poses": m.poses, "edge_a": m.constraints.a, "edge_b": m.constraints.b,
           "edge_delta": m.constraints.delta, "edge_cov": m.constraints.cov,
           "edge_kind": m.constraints.kind}
    if m.kf_intensity is not None:
        out["kf_intensity"] = _ragged(m.kf_intensity, 1)[0]
    return out


def to_bytes(m: SavedMap) -> bytes:
    """The map as a ``chizu-map`` archive."""
    arrays = _arrays(m)
    blobs: dict[str, bytes] = {}
    for name, a in arrays.items():
        buf = io.BytesIO()
        np.lib.format.write_array(buf, np.ascontiguousarray(a), allow_pickle=False)
        blobs[name] = buf.getvalue()
    manifest = {
        "format": FORMAT, "version": VERSION,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "frame": "map", "units": "m, rad, s",
        "laser": vars(m.laser), "resolution_m": m.resolution_m,
        "keyframes": len(m), "scans": len(m.times), "constraints": len(m.constraints),
        "meta": m.meta,
        "arrays": {k: {"shape": list(arrays[k].shape), "dtype": arrays[k].dtype.str,
                       "sha256": hashlib.sha256(b).hexdigest()} for k, b in blobs.items()}}
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        z.writestr("manifest.json", json.dumps(manifest, indent=1))
        for name, b in blobs.items():
            z.writestr(f"{name}.npy", b)
    return buf.getvalue()


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` beside ``path`` and move it over ``path`` in one rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def save(m: SavedMap, path: str | Path) -> Path:
    """Write the map to ``path`` (a file, or a directory that gets :data:`FILE_NAME`)."""
    p = Path(path)
    if p.is_dir() or p.suffix == "":
        p = p / FILE_NAME
    write_atomic(p, to_bytes(m))
    return p


# -- reading -------------------------------------------------------------------------------
def map_path(path: str | Path) -> Path:
    """The map file ``path`` names: itself, or :data:`FILE_NAME` in a directory."""
    p = Path(path)
    if p.is_dir():
        p = p / FILE_NAME
    if not p.is_file():
        raise MapFileError(f"{p}: no saved map there (a run directory written by "
                           f"`chizu slam --out` holds {FILE_NAME})")
    return p


def load(path: str | Path) -> SavedMap:
    """Read a map file (or a run directory holding one)."""
    p = map_path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise MapFileError(f"{p}: cannot be read ({e.strerror})") from None
    return from_bytes(data, str(p))


def _manifest(z: zipfile.ZipFile, name: str) -> dict[str, Any]:
    try:
        raw = z.read("manifest.json")
    except KeyError:
        raise MapFileError(f"{name}: not a chizu map (no manifest.json)") from None
    try:
        man = json.loads(raw)
    except ValueError:
        raise MapFileError(f"{name}: its manifest is not JSON") from None
    if not isinstance(man, dict) or man.get("format") != FORMAT:
        raise MapFileError(f"{name}: not a chizu map (format {man.get('format')!r} "
                           f"where {FORMAT!r} was expected)" if isinstance(man, dict)
                           else f"{name}: not a chizu map")
    version = man.get("version")
    if not isinstance(version, int) or version < 1:
        raise MapFileError(f"{name}: map version {version!r} is not one")
    if version > VERSION:
        raise MapFileError(f"{name}: map version {version} was written by a newer chizu; "
                           f"this one reads version {VERSION}")
    return man


def _read_arrays(z: zipfile.ZipFile, man: dict[str, Any], name: str) -> dict[str, np.ndarray]:
    specs = man.get("arrays")
    if not isinstance(specs, dict):
        raise MapFileError(f"{name}: the manifest lists no arrays")
    total = sum(i.file_size for i in z.infolist())
    if total > MAX_MAP_BYTES:
        raise MapFileError(f"{name}: {total} bytes unpacked, more than the "
                           f"{MAX_MAP_BYTES} a map may hold")
    out = {}
    for key, spec in specs.items():
        try:
            blob = z.read(f"{key}.npy")
        except KeyError:
            raise MapFileError(f"{name}: array {key!r} is missing") from None
        if hashlib.sha256(blob).hexdigest() != spec.get("sha256"):
            raise MapFileError(f"{name}: array {key!r} is corrupt (checksum)")
        try:
            a = np.lib.format.read_array(io.BytesIO(blob), allow_pickle=False)
        except ValueError:
            raise MapFileError(f"{name}: array {key!r} is not a numpy array") from None
        if list(a.shape) != spec.get("shape") or a.dtype.str != spec.get("dtype"):
            raise MapFileError(f"{name}: array {key!r} does not match the manifest")
        out[key] = a
    return out


def _split(flat: np.ndarray, offsets: np.ndarray) -> list[np.ndarray]:
    return [flat[offsets[k]:offsets[k + 1]] for k in range(len(offsets) - 1)]


def _check_offsets(offsets: np.ndarray, n: int, total: int, what: str, name: str) -> None:
    if (len(offsets) != n + 1 or (n + 1 and offsets[0] != 0) or np.any(np.diff(offsets) < 0)
            or (n + 1 and offsets[-1] != total)):
        raise MapFileError(f"{name}: the {what} offsets do not fit the keyframes")


_NEED = ("kf_scan", "kf_time", "kf_pose", "kf_odom", "kf_offsets", "kf_xy", "miss_offsets",
         "miss_xy", "times", "poses", "edge_a", "edge_b", "edge_delta", "edge_cov",
         "edge_kind")


def from_bytes(data: bytes, name: str = "map") -> SavedMap:
    """Parse a ``chizu-map`` archive; raises :class:`MapFileError` saying what is wrong."""
    if not data:
        raise MapFileError(f"{name}: the map file is empty")
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            man = _manifest(z, name)
            a = _read_arrays(z, man, name)
    except zipfile.BadZipFile:
        raise MapFileError(f"{name}: not a chizu map (not a ZIP archive, or a truncated "
                           "one)") from None
    except (zipfile.LargeZipFile, zlib.error, EOFError, OSError) as e:
        raise MapFileError(f"{name}: corrupt archive ({e})") from None
    missing = [k for k in _NEED if k not in a]
    if missing:
        raise MapFileError(f"{name}: arrays {', '.join(missing)} are missing")
    k = len(a["kf_pose"])
    try:
        laser = Laser(**man["laser"])
        resolution = float(man["resolution_m"])
    except (KeyError, TypeError, ValueError):
        raise MapFileError(f"{name}: the manifest's laser or resolution_m is malformed"
                           ) from None
    if not (0.0 < resolution <= 1.0):
        raise MapFileError(f"{name}: resolution_m {resolution} is out of range")
    shapes_ok = (a["kf_pose"].shape == (k, 3) and a["kf_odom"].shape == (k, 3)
                 and a["kf_scan"].shape == (k,) and a["kf_time"].shape == (k,)
                 and a["poses"].ndim == 2 and a["poses"].shape[1:] == (3,)
                 and a["times"].shape == (len(a["poses"]),)
                 and a["kf_xy"].ndim == 2 and a["kf_xy"].shape[1:] == (2,)
                 and a["miss_xy"].ndim == 2 and a["miss_xy"].shape[1:] == (2,))
    if not shapes_ok:
        raise MapFileError(f"{name}: the keyframe and trajectory arrays do not fit together")
    _check_offsets(a["kf_offsets"], k, len(a["kf_xy"]), "keyframe", name)
    _check_offsets(a["miss_offsets"], k, len(a["miss_xy"]), "no-return", name)
    for key in ("kf_pose", "kf_odom", "kf_time", "kf_xy", "miss_xy", "times", "poses"):
        if not np.all(np.isfinite(a[key])):
            raise MapFileError(f"{name}: array {key!r} holds NaN or infinity")
    if k and (a["kf_scan"].min() < 0 or a["kf_scan"].max() >= len(a["times"])):
        raise MapFileError(f"{name}: a keyframe names a scan the trajectory does not hold")
    n_e = len(a["edge_a"])
    if not (a["edge_b"].shape == (n_e,) and a["edge_delta"].shape == (n_e, 3)
            and a["edge_cov"].shape == (n_e, 3, 3) and a["edge_kind"].shape == (n_e,)
            and (n_e == 0 or (min(a["edge_a"].min(), a["edge_b"].min()) >= 0
                            and max(a["edge_a"].max(), a["edge_b"].max()) < k))):
        raise MapFileError(f"{name}: the constraints do not fit the keyframes")
    inten = a.get("kf_intensity")
    if inten is not None and inten.shape != (len(a["kf_xy"]),):
        raise MapFileError(f"{name}: the intensities do not fit the keyframes")
    meta: dict[str, Any] = man["meta"] if isinstance(man.get("meta"), dict) else {}
    return SavedMap(
        laser=laser, resolution_m=resolution, kf_scan=a["kf_scan"], kf_time=a["kf_time"],
        kf_pose=a["kf_pose"], kf_odom=a["kf_odom"],
        kf_xy=_split(a["kf_xy"], a["kf_offsets"]),
        kf_intensity=None if inten is None else _split(inten, a["kf_offsets"]),
        kf_misses=_split(a["miss_xy"], a["miss_offsets"]), times=a["times"],
        poses=a["poses"],
        constraints=Constraints(a["edge_a"], a["edge_b"], a["edge_delta"], a["edge_cov"],
                                a["edge_kind"]),
        meta=meta)
