"""Built-in worlds: the demo office floor (and a scalable generator for benchmarks), and
the eigenspace paper's rooms A-D (Table 1): A a 10 m square room, B a room whose shape
changes in complex ways, C a square room with many small bumps, D room A after a lighting
change, a new poster and moved objects; and the SLAM paper's featureless corridor with
reflectivity stripes."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from chizu.numeric.geometry import point_segment_distance
from chizu.numeric.textures import TEXTURE_NAMES
from chizu.numeric.world import Feature, Landmark, Wall, World, WorldDescription, WorldObject


def office_world(name: str = "demo", rooms_per_side: int = 4, room_width_m: float = 6.0,
                 room_depth_m: float = 6.0, corridor_width_m: float = 2.0,
                 door_width_m: float = 1.2) -> WorldDescription:
    """An office floor: a straight corridor with rooms on both sides.

    Each room has a door in the middle of its corridor wall and two landmarks;
    the corridor has a landmark in front of every pair of doors and one at each
    end.  ``rooms_per_side=4`` gives the demo world (22 landmarks); the
    landmark count is ``5 * rooms_per_side + 2``.
    """
    k, rw, rd, cw, dw = rooms_per_side, room_width_m, room_depth_m, corridor_width_m, door_width_m
    length = k * rw
    y0, y1 = 0.0, cw  # corridor between y0 and y1
    walls: list[Wall] = []
    textures = ["brick", "gravel", "grass", "camera", "coffee"]

    def wall(a: tuple[float, float], b: tuple[float, float], i: int, refl: float) -> None:
        walls.append(Wall(a=a, b=b, texture=textures[i % len(textures)], reflectivity=refl))

    # corridor ends
    wall((0.0, y0 - rd), (0.0, y1 + rd), 0, 0.5)
    wall((length, y0 - rd), (length, y1 + rd), 0, 0.5)
    landmarks: list[Landmark] = []
    for side, sign in (("n", 1.0), ("s", -1.0)):
        yc = y1 if sign > 0 else y0           # corridor wall
        yb = yc + sign * rd                   # back wall
        wall((0.0, yb), (length, yb), 1, 0.7)
        for i in range(k):
            x0, x1 = i * rw, (i + 1) * rw
            cx = 0.5 * (x0 + x1)
            # corridor wall with a door gap
            wall((x0, yc), (cx - dw / 2, yc), 2 + i, 0.3)
            wall((cx + dw / 2, yc), (x1, yc), 2 + i, 0.3)
            if i > 0:
                wall((x0, yc), (x0, yb), 3 + i, 0.6)  # partition between rooms
            ym = yc + sign * rd * 0.6
            facing = float(-np.pi / 2 * sign)   # towards the corridor
            for j, dx in enumerate((-rw / 4, rw / 4)):
                landmarks.append(Landmark(
                    id=f"r{side}{i}{'ab'[j]}", x=cx + dx, y=ym,
                    features=[Feature(name="sign", direction_rad=facing, half_width_rad=1.2)],
                ))
    ym = 0.5 * (y0 + y1)
    landmarks.append(Landmark(id="c_w", x=0.8, y=ym,
                              features=[Feature(name="exit", direction_rad=0.0)]))
    for i in range(k):
        landmarks.append(Landmark(id=f"c{i}", x=(i + 0.5) * rw, y=ym))
    landmarks.append(Landmark(id="c_e", x=length - 0.8, y=ym,
                              features=[Feature(name="exit", direction_rad=np.pi)]))
    return WorldDescription(name=name, walls=walls, landmarks=landmarks)


#: Wall textures of the paper rooms, two per side, counter-clockwise from the south-west.
ROOM_TEXTURES = ("brick", "camera", "astronaut", "coffee", "rocket", "chelsea", "clock", "coins")
ROOM_SIZE_M = 10.0


def _polygon_walls(vertices: list[tuple[float, float]], textures: tuple[str, ...],
                   segment_m: float, gains: tuple[float, ...] = (1.0,),
                   offset: int = 0) -> list[Wall]:
    """Walls along a closed polygon; long edges are cut into pieces of ``segment_m``
    so textures change along a side (texture ``i`` for the ``i``-th piece)."""
    walls: list[Wall] = []
    i = offset
    for k, a in enumerate(vertices):
        b = vertices[(k + 1) % len(vertices)]
        length = float(np.hypot(b[0] - a[0], b[1] - a[1]))
        n = max(1, int(round(length / segment_m)))
        for j in range(n):
            pa = (a[0] + (b[0] - a[0]) * j / n, a[1] + (b[1] - a[1]) * j / n)
            pb = (a[0] + (b[0] - a[0]) * (j + 1) / n, a[1] + (b[1] - a[1]) * (j + 1) / n)
            walls.append(Wall(a=pa, b=pb, texture=textures[i % len(textures)],
                              brightness=gains[i % len(gains)], reflectivity=0.6))
            i += 1
    return walls


def _boxes(positions: list[tuple[float, float, float]]) -> list[WorldObject]:
    return [WorldObject(id=f"box{i}", type="box", x=x, y=y, theta=th, size_m=(0.6, 0.6, 0.8),
                        texture="text") for i, (x, y, th) in enumerate(positions)]


_A_BOXES = [(2.0, 8.0, 0.0), (8.2, 2.2, 0.4), (6.2, 0.5, 0.0)]
_D_BOXES = [(2.8, 7.4, 0.6), (7.5, 2.8, 0.0), (4.0, 0.5, 0.0)]


def room_a(name: str = "room_a") -> WorldDescription:
    """Environment A: a 10 m square room, eight textured wall pieces, three boxes."""
    s = ROOM_SIZE_M
    return WorldDescription(name=name, walls=_polygon_walls(
        [(0, 0), (s, 0), (s, s), (0, s)], ROOM_TEXTURES, s / 2), objects=_boxes(_A_BOXES))


def room_b(name: str = "room_b") -> WorldDescription:
    """Environment B: the same textures on a room whose outline changes in complex ways
    (notches, an alcove) plus a square pillar."""
    outline = [(0, 0), (4, 0), (4, 1.5), (6, 1.5), (6, 0), (10, 0), (10, 4), (8.5, 4.6),
               (8.5, 6), (10, 6.5), (10, 10), (6.5, 10), (6.5, 8.5), (3.5, 8.5), (3.5, 10),
               (0, 10), (0, 6), (1.5, 5), (0, 4)]
    walls = _polygon_walls([(float(x), float(y)) for x, y in outline], ROOM_TEXTURES, 2.5)
    pillar = [(4.6, 4.6), (5.4, 4.6), (5.4, 5.4), (4.6, 5.4)]
    walls += _polygon_walls(pillar, ("page",), 1.0)
    return WorldDescription(name=name, walls=walls, objects=_boxes(_A_BOXES[:2]))


def room_c(name: str = "room_c", bump_every_m: float = 1.0, bump_depth_m: float = 0.15,
           bump_width_m: float = 0.3) -> WorldDescription:
    """Environment C: room A's square with small rectangular bumps along every wall."""
    s = ROOM_SIZE_M
    corners = [(0.0, 0.0), (s, 0.0), (s, s), (0.0, s)]
    outline: list[tuple[float, float]] = []
    for k, a in enumerate(corners):
        b = corners[(k + 1) % 4]
        d = np.array(b) - np.array(a)
        length = float(np.hypot(*d))
        u = d / length
        inward = np.array([-u[1], u[0]])  # polygon is counter-clockwise
        outline.append(a)
        pos = bump_every_m
        while pos + bump_width_m < length - 0.2:
            p0 = np.array(a) + u * pos
            p1 = p0 + u * bump_width_m
            for q in (p0, p0 + inward * bump_depth_m, p1 + inward * bump_depth_m, p1):
                outline.append((float(q[0]), float(q[1])))
            pos += bump_every_m
    walls: list[Wall] = []
    # texture by the side of the room and the half of that side, as in room A
    for k, a in enumerate(outline):
        b = outline[(k + 1) % len(outline)]
        mid = (0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]))
        walls.append(Wall(a=a, b=b, texture=ROOM_TEXTURES[_side_piece(mid, s)],
                          reflectivity=0.6))
    return WorldDescription(name=name, walls=walls, objects=_boxes(_A_BOXES))


def _side_piece(p: tuple[float, float], s: float) -> int:
    """Index 0..7 of the wall piece of a square room of side ``s`` nearest to ``p``
    (counter-clockwise from the south-west corner, two pieces per side)."""
    x, y = p
    dists = [y, s - x, s - y, x]  # south, east, north, west
    side = int(np.argmin(dists))
    along = [x, y, s - x, s - y][side]
    return 2 * side + int(along >= s / 2)


def room_d(name: str = "room_d") -> WorldDescription:
    """Environment D: room A after a lighting change (each wall piece brighter or darker),
    with a poster on the north wall and the boxes moved."""
    s = ROOM_SIZE_M
    gains = (0.8, 1.15, 0.9, 1.1, 0.75, 1.2, 0.85, 1.05)
    walls = _polygon_walls([(0, 0), (s, 0), (s, s), (0, s)], ROOM_TEXTURES, s / 2, gains)
    north = next(i for i, w in enumerate(walls) if w.a == (s, s))
    w = walls.pop(north)  # the north wall's eastern half: poster in its middle
    x0, x1 = w.a[0], w.b[0]
    cuts = [x0, x0 - 1.5, x0 - 3.0, x1]
    for j in range(3):
        tex = "chelsea" if j == 1 else w.texture
        walls.insert(north + j, Wall(a=(cuts[j], s), b=(cuts[j + 1], s), texture=tex,
                                     brightness=w.brightness, reflectivity=0.6))
    return WorldDescription(name=name, walls=walls, objects=_boxes(_D_BOXES))


def twin_hexagon(name: str = "twin_hexagon") -> WorldDescription:
    """A hexagon with two pillars, symmetric under a half turn about (5, 4), whose six
    wall photographs repeat after half the walls: every place has a twin that looks the
    same, so no camera can tell the halves apart. The eigenspace method's answer is
    state Y (candidate-multiple sets, Maeda & Shirai §3.3), never a confident pose."""
    walls = _polygon_walls([(2, 0), (8, 0), (10, 4), (8, 8), (2, 8), (0, 4)],
                           ("chelsea", "gravel", "brick", "cell", "coffee", "text"), 2.5)
    for cx, cy in ((3.5, 4.0), (6.5, 4.0)):
        walls += _polygon_walls([(cx - 0.3, cy - 0.3), (cx + 0.3, cy - 0.3),
                                 (cx + 0.3, cy + 0.3), (cx - 0.3, cy + 0.3)], ("page",), 1.0)
    return WorldDescription(name=name, walls=walls)


def stripe_corridor(name: str = "corridor", length_m: float = 40.0, width_m: float = 2.0,
                    stripe_m: tuple[float, float] = (0.3, 1.2),
                    reflectivity: tuple[float, float] = (0.15, 0.9),
                    seed: int = 7) -> WorldDescription:
    """The SLAM paper's hard case (Hara et al., the corridor experiment): a straight
    corridor with no geometric feature along its length -- its ends lie beyond a URG's
    5.6 m when the robot is in the middle -- but with stripes of alternating dark and
    bright material (random widths in ``stripe_m``) on both walls."""
    rng = np.random.default_rng(seed)
    walls: list[Wall] = []
    for y, side in ((0.0, 0), (width_m, 1)):
        x, k = 0.0, side
        while x < length_m - 1e-9:
            nxt = min(length_m, x + float(rng.uniform(*stripe_m)))
            a, b = ((x, y), (nxt, y)) if side == 0 else ((nxt, y), (x, y))
            walls.append(Wall(a=a, b=b, texture="gravel", reflectivity=reflectivity[k % 2]))
            x, k = nxt, k + 1
    walls.append(Wall(a=(length_m, 0.0), b=(length_m, width_m), reflectivity=0.5))
    walls.append(Wall(a=(0.0, width_m), b=(0.0, 0.0), reflectivity=0.5))
    return WorldDescription(name=name, walls=walls)


def loop_corridor(name: str = "loop", outer_m: tuple[float, float] = (24.0, 14.0),
                  width_m: float = 2.0, seed: int = 3) -> WorldDescription:
    """A closed loop of plain 2 m corridors around a block (for loop closure): the
    walls of a long side are beyond a URG's reach from the corners, so a robot that
    goes round accumulates drift until it sees where it started; four boxes stand at
    irregular places so that places can be told apart."""
    w, h = outer_m
    outer = _polygon_walls([(0, 0), (w, 0), (w, h), (0, h)], ROOM_TEXTURES, 4.0)
    inner = _polygon_walls([(width_m, width_m), (width_m, h - width_m),
                            (w - width_m, h - width_m), (w - width_m, width_m)],
                           ROOM_TEXTURES, 4.0, offset=3)
    # boxes against the walls at irregular places (a few metres apart, as doors and
    # cupboards are): every stretch of corridor is told apart along its length
    rng = np.random.default_rng(seed)
    spots: list[tuple[float, float, float]] = []
    near, far = 0.35, width_m - 0.35  # box centres: against the outer or the inner wall
    xs = np.arange(3.0, w - 3.0, 3.2)
    for x in xs + rng.uniform(-0.8, 0.8, len(xs)):
        spots.append((float(x), near if rng.random() < 0.5 else far, 0.0))
        spots.append((float(w - x), h - (near if rng.random() < 0.5 else far), 0.0))
    ys = np.arange(3.0, h - 3.0, 3.2)
    for y in ys + rng.uniform(-0.8, 0.8, len(ys)):
        spots.append((w - (near if rng.random() < 0.5 else far), float(y), 0.0))
        spots.append((near if rng.random() < 0.5 else far, float(h - y), 0.0))
    boxes = _boxes(spots)
    return WorldDescription(name=name, walls=outer + inner, objects=boxes)


#: The mission world's layout (:func:`mission_world`): the goal landmark in the corridor,
#: the goal room's door (a point just inside it) and its extent (lower and upper corner).
MISSION_GOAL = "c1"
MISSION_DOOR = (9.0, 2.6)
MISSION_ROOM = ((6.0, 2.0), (12.0, 8.0))


def mission_world(name: str = "mission") -> WorldDescription:
    """The end-to-end mission's office: a corridor with two rooms on each side (the demo
    office, smaller), three candidate objects of the built-in types and a cabinet that
    hides part of the north-east room -- the goal room, whose door is :data:`MISSION_DOOR`
    behind the corridor landmark :data:`MISSION_GOAL`."""
    d = office_world(name=name, rooms_per_side=2)
    (x0, y0), (x1, y1) = MISSION_ROOM
    walls = [*d.walls, Wall(a=(x0 + 2.6, y0 + 3.4), b=(x0 + 4.6, y0 + 3.4), texture="text",
                            reflectivity=0.4)]
    objects = [WorldObject(id=i, type=t, x=x, y=y, theta=th, size_m=(0.4, 0.3, 0.5),
                           texture="coffee")
               for i, t, x, y, th in (("mug", "A", x0 + 1.2, y0 + 4.6, 0.5),
                                      ("kettle", "B", x0 + 4.8, y0 + 2.2, 2.0),
                                      ("box", "A", x0 + 3.6, y0 + 4.7, 1.2))]
    return d.model_copy(update={"walls": walls, "objects": objects})


def random_mission_world(seed: int, name: str = "random_mission"
                         ) -> tuple[WorldDescription, str, tuple[float, float],
                                    tuple[tuple[float, float], tuple[float, float]]]:
    """An office nobody tuned the mission on: two rooms per side of random width and
    depth (5-7 m), a corridor of 1.8-2.4 m, a random goal room (north or south) with two
    to four objects of the built-in types and, half the time, a cabinet. Returns the
    world and the mission's goal landmark, door point and room corners."""
    rng = np.random.default_rng(seed)
    rw, rd = float(rng.uniform(5.0, 7.0)), float(rng.uniform(5.0, 7.0))
    cw = float(rng.uniform(1.8, 2.4))
    d = office_world(name=name, rooms_per_side=2, room_width_m=rw, room_depth_m=rd,
                     corridor_width_m=cw)
    i, north = int(rng.integers(2)), bool(rng.random() < 0.5)
    x0, x1 = i * rw, (i + 1) * rw
    cx = 0.5 * (x0 + x1)
    if north:
        room, door = ((x0, cw), (x1, cw + rd)), (cx, cw + 0.6)
    else:
        room, door = ((x0, -rd), (x1, 0.0)), (cx, -0.6)
    (rx0, ry0), (rx1, ry1) = room
    walls = list(d.walls)
    far = (lambda y: ry1 - y + ry0) if not north else (lambda y: y)  # mirror for south
    cab: Wall | None = None
    if rng.random() < 0.5:  # a cabinet across part of the room, off the door's line
        length = float(rng.uniform(1.5, 2.5))
        y = far(ry0 + float(rng.uniform(0.45, 0.65)) * rd)
        xa = rx0 + 0.1 if rng.random() < 0.5 else rx1 - 0.1 - length
        cab = Wall(a=(xa, y), b=(xa + length, y), texture="text", reflectivity=0.4)
        walls.append(cab)
    objects: list[WorldObject] = []
    for k in range(int(rng.integers(2, 5))):
        for _ in range(200):
            p = np.array([rng.uniform(rx0 + 0.7, rx1 - 0.7), rng.uniform(ry0 + 0.7, ry1 - 0.7)])
            if abs(p[1] - door[1]) < 1.5 and abs(p[0] - door[0]) < 1.0:
                continue  # not in the doorway
            if cab is not None and point_segment_distance(
                    p[None], np.array([cab.a]), np.array([cab.b]))[0, 0] < 0.6:
                continue
            if all(np.hypot(o.x - p[0], o.y - p[1]) > 1.0 for o in objects):
                break
        objects.append(WorldObject(id=f"obj{k}", type="ABC"[int(rng.integers(3))],
                                   x=float(p[0]), y=float(p[1]),
                                   theta=float(rng.uniform(0, np.pi)), size_m=(0.4, 0.3, 0.5),
                                   texture="coffee"))
    return (d.model_copy(update={"walls": walls, "objects": objects}), f"c{i}", door, room)


TEMPLATES: dict[str, Callable[[str], WorldDescription]] = {
    "corridor": stripe_corridor,
    "loop": loop_corridor,
    "demo": lambda name: office_world(name=name),
    "office": lambda name: office_world(name=name),
    "room_a": room_a,
    "room_b": room_b,
    "summary_room": lambda name: summary_room(name),
    "fig11a": lambda name: summary_room(name, "fig11a"),
    "fig11b": lambda name: summary_room(name, "fig11b"),
    "room_c": room_c,
    "room_d": room_d,
    "twin_hexagon": twin_hexagon,
    "mission": mission_world,
}


#: The viewpoint-planning paper's rooms (7.0 m x 5.5 m, §7): the robot enters at the
#: door in the middle of the south wall. ``summary_room``: the real-robot experiment
#: (Fig. 12) -- two objects, one behind a cabinet; ``fig11a``: two objects far apart, near
#: and far from the door (Table 1); ``fig11b``: four objects (two close together) and two
#: cabinets that hide two regions from the door (Fig. 11(b)).
SUMMARY_ROOM_M = (7.0, 5.5)
SUMMARY_DOOR = (3.5, 0.6)
_SUMMARY_LAYOUTS: dict[str, tuple[list[tuple[str, str, float, float, float]],
                                  list[tuple[tuple[float, float], tuple[float, float]]]]] = {
    "summary_room": ([("mug", "A", 1.2, 4.3, 0.5), ("kettle", "B", 5.6, 2.4, 2.0)],
                     [((4.2, 3.4), (6.2, 3.4))]),
    "fig11a": ([("a_near", "A", 5.6, 1.5, 0.3), ("b_far", "B", 1.0, 4.9, 1.1)], []),
    "fig11b": ([("obj1", "A", 1.0, 1.6, 0.2), ("obj2", "B", 1.4, 2.6, 1.3),
                ("obj3", "C", 5.9, 1.7, 2.6), ("obj4", "A", 4.0, 4.7, 0.9)],
               [((0.0, 3.9), (2.0, 3.9)), ((4.6, 3.2), (7.0, 3.2))]),
}


def summary_room(name: str = "summary_room", layout: str = "summary_room") -> WorldDescription:
    """A viewpoint-planning room (see :data:`_SUMMARY_LAYOUTS`)."""
    w, h = SUMMARY_ROOM_M
    walls = _polygon_walls([(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)], ROOM_TEXTURES, 2.0)
    objects, cabinets = _SUMMARY_LAYOUTS[layout]
    for a, b in cabinets:
        walls.append(Wall(a=a, b=b, texture="text", reflectivity=0.4))
    objs = [WorldObject(id=i, type=t, x=x, y=y, theta=th, size_m=(0.4, 0.3, 0.5),
                        texture="coffee") for i, t, x, y, th in objects]
    return WorldDescription(name=name, walls=walls, objects=objs)


def random_summary_room(seed: int, name: str = "random_room") -> WorldDescription:
    """A room nobody tuned the viewpoint planner on: the summary room's outline and door,
    one to three cabinets (wall segments 1.5-2.5 m) that hide parts of it, and two to four
    objects of the built-in types in free space away from walls and cabinets."""
    rng = np.random.default_rng(seed)
    w, h = SUMMARY_ROOM_M
    walls = _polygon_walls([(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)], ROOM_TEXTURES, 2.0)
    segments: list[tuple[np.ndarray, np.ndarray]] = []
    for _ in range(int(rng.integers(1, 4))):
        length = rng.uniform(1.5, 2.5)
        if rng.random() < 0.5:  # from a side wall, horizontal
            y = rng.uniform(2.0, h - 1.0)
            x0 = 0.0 if rng.random() < 0.5 else w - length
            a, b = np.array([x0, y]), np.array([x0 + length, y])
        else:                   # free-standing, vertical
            x, y = rng.uniform(1.0, w - 1.0), rng.uniform(1.8, h - 1.0 - length / 2)
            a, b = np.array([x, y - length / 2]), np.array([x, y + length / 2])
        segments.append((a, b))
        walls.append(Wall(a=tuple(a), b=tuple(b), texture="text", reflectivity=0.4))
    objs: list[WorldObject] = []
    types = ("A", "B", "C")
    want = int(rng.integers(2, 5))
    for _ in range(200):
        if len(objs) >= want:
            break
        p = rng.uniform([0.7, 1.5], [w - 0.7, h - 0.7])
        near_seg = bool(segments) and float(point_segment_distance(
            p, np.array([a for a, _ in segments]), np.array([b for _, b in segments])).min()) < 0.7
        near_obj = any(np.hypot(o.x - p[0], o.y - p[1]) < 1.0 for o in objs)
        if near_seg or near_obj:
            continue
        objs.append(WorldObject(id=f"obj{len(objs) + 1}", type=types[len(objs) % 3],
                                x=float(p[0]), y=float(p[1]),
                                theta=float(rng.uniform(-np.pi, np.pi)), size_m=(0.4, 0.3, 0.5),
                                texture="coffee"))
    return WorldDescription(name=name, walls=walls, objects=objs)


def from_template(template: str, name: str) -> WorldDescription:
    """The built-in world ``template`` under the name ``name``."""
    return TEMPLATES[template](name)


#: the outlines :func:`random_camera_room` builds
CAMERA_ROOM_SHAPES = ("l", "two_rooms", "hall")


def random_camera_room(seed: int, shape: str, name: str = "camera_room") -> WorldDescription:
    """A room nobody tuned the eigenspace method on, drawn from ``seed``: an L (9-13 m by
    8-12 m, a 40-60 % notch), two rooms joined by a 1.0-1.4 m door (12-16 m by 5-8 m) or
    a long hall (16-22 m by 4-6 m); wall pieces of 2.5-4 m with photographs drawn at
    random, one to three boxes and up to one pillar in free space."""
    if shape not in CAMERA_ROOM_SHAPES:
        raise ValueError(f"shape is one of {CAMERA_ROOM_SHAPES}, not {shape!r}")
    rng = np.random.default_rng(seed)
    photos = tuple(t for t in TEXTURE_NAMES if t != "text")
    textures = tuple(str(t) for t in rng.choice(photos, size=24))
    piece = float(rng.uniform(2.5, 4.0))
    inner: list[Wall] = []
    if shape == "l":
        w, h = rng.uniform(9.0, 13.0), rng.uniform(8.0, 12.0)
        nx, ny = w * rng.uniform(0.4, 0.6), h * rng.uniform(0.4, 0.6)
        outline = [(0.0, 0.0), (w, 0.0), (w, h - ny), (w - nx, h - ny), (w - nx, h), (0.0, h)]
    elif shape == "two_rooms":
        w, h = rng.uniform(12.0, 16.0), rng.uniform(5.0, 8.0)
        outline = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]
        x, door = w * rng.uniform(0.4, 0.6), rng.uniform(1.0, 1.4)
        y0 = rng.uniform(0.5, h - 0.5 - door)
        inner = [Wall(a=(x, 0.0), b=(x, y0), texture=textures[-1], reflectivity=0.6),
                 Wall(a=(x, y0 + door), b=(x, h), texture=textures[-2], reflectivity=0.6)]
    else:
        w, h = rng.uniform(16.0, 22.0), rng.uniform(4.0, 6.0)
        outline = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]
    walls = _polygon_walls([(float(x), float(y)) for x, y in outline], textures, piece) + inner
    objects: list[WorldObject] = []
    room = World(WorldDescription(name=name, walls=walls))  # free space before the boxes
    want = int(rng.integers(1, 4))
    for _ in range(200):
        if len(objects) >= want:
            break
        p = rng.uniform([0.0, 0.0], [w, h])
        if not room.is_free(p[None], clearance_m=1.2)[0] or any(
                np.hypot(o.x - p[0], o.y - p[1]) < 2.0 for o in objects):
            continue
        objects.append(WorldObject(id=f"box{len(objects)}", type="box", x=float(p[0]),
                                   y=float(p[1]), theta=float(rng.uniform(-np.pi, np.pi)),
                                   size_m=(0.6, 0.6, 0.8), texture="text"))
    if shape != "hall" and rng.random() < 0.5:
        p = rng.uniform([0.0, 0.0], [w, h])
        if room.is_free(p[None], clearance_m=1.5)[0] and all(
                np.hypot(o.x - p[0], o.y - p[1]) >= 2.0 for o in objects):
            s = 0.3
            walls += _polygon_walls([(p[0] - s, p[1] - s), (p[0] + s, p[1] - s),
                                     (p[0] + s, p[1] + s), (p[0] - s, p[1] + s)],
                                    (textures[-3],), 1.0)
    return WorldDescription(name=name, walls=walls, objects=objects)

