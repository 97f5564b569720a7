"""Wall textures for the camera: real photographs bundled with scikit-image.

Each texture is a grey image in [0, 1] kept as a Gaussian pyramid (mip levels), so
the camera can sample a level whose texel size matches a pixel's footprint on the
wall and small images do not alias.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

import numpy as np
from skimage import color, data, transform

#: Texture id -> loader of the scikit-image sample photograph behind it.
_SOURCES: dict[str, Callable[[], np.ndarray]] = {
    "brick": data.brick,
    "gravel": data.gravel,
    "grass": data.grass,
    "camera": data.camera,
    "coffee": data.coffee,
    "moon": data.moon,
    "coins": data.coins,
    "page": data.page,
    "text": data.text,
    "rocket": data.rocket,
    "astronaut": data.astronaut,
    "chelsea": data.chelsea,
    "clock": data.clock,
    "cell": data.cell,
}

TEXTURE_NAMES: tuple[str, ...] = tuple(sorted(_SOURCES))
#: Side length (texels) of the finest level; photographs are resampled to it.
BASE_TEXELS = 256
#: Number of pyramid levels (each halves the resolution).
LEVELS = 6


@cache
def pyramid(name: str) -> tuple[np.ndarray, ...]:
    """Mip levels of texture ``name``: ``LEVELS`` grey arrays in [0, 1], finest first.

    Raises KeyError for an unknown name (world validation rejects those earlier).
    """
    img = _SOURCES[name]()
    if img.ndim == 3:
        img = color.rgb2gray(img[..., :3])
    img = np.asarray(img, dtype=float)
    if img.max() > 1.0:
        img = img / 255.0
    base = transform.resize(img, (BASE_TEXELS, BASE_TEXELS), anti_aliasing=True)
    levels = tuple(transform.pyramid_gaussian(base, max_layer=LEVELS - 1, downscale=2,
                                              preserve_range=True))
    return tuple(np.ascontiguousarray(lv, dtype=np.float64) for lv in levels)
