"""Built-in worlds: the demo office floor (and a scalable generator for benchmarks)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from numeric.world import Feature, Landmark, Wall, WorldDescription


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


TEMPLATES: dict[str, Callable[[str], WorldDescription]] = {
    "demo": lambda name: office_world(name=name),
    "office": lambda name: office_world(name=name),
}


def from_template(template: str, name: str) -> WorldDescription:
    """The built-in world ``template`` under the name ``name``."""
    return TEMPLATES[template](name)
