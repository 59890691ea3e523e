"""The view of a fast observer (Weiskopf et al.): aberration, Doppler colour shift and the
searchlight effect on an environment map."""

from __future__ import annotations

import os
from typing import Any, Optional, Sequence, Union

import numpy as np

from . import _native
from . import _convert as cv
from ._core import Image


def render(
    envmap: Any = "checker",
    beta: float = 0.9,
    direction: Optional[Sequence[float]] = None,
    effects: Union[str, Sequence[str]] = "aberration,doppler,searchlight",
    look: Sequence[float] = (0.0, 0.0, -1.0),
    up: Sequence[float] = (0.0, 1.0, 0.0),
    fov: float = 90.0,
    width: int = 640,
    height: int = 360,
) -> Image:
    """What an observer moving at ``beta`` (a fraction of c, |beta| < 1; a velocity quantity
    is divided by c) along ``direction`` (default ``look``) sees through a pinhole camera.

    ``envmap`` is a file (equirectangular ``.exr``/``.hdr``/``.pfm``/``.png``, or a cube-map
    folder), ``"checker"``, or a float32 ``[h, w, 3]`` array of linear RGB read as a file
    is, by its aspect ratio: 2:1 equirectangular, or a cube map as a 1:6 or 6:1 strip or a
    4:3 or 3:4 cross (any other shape is refused).
    ``effects`` lists ``aberration``, ``doppler``, ``searchlight`` (or ``all``, ``none``),
    comma-separated or as a sequence.
    Returns linear RGB float32 ``[height, width, 3]`` (``blueshift relativity``'s EXR).
    """
    if cv.is_quantity(beta):
        beta = cv.as_float(beta, "m/s", "beta") / 299_792_458.0
    beta = float(beta)
    if not (np.isfinite(beta) and abs(beta) < 1.0):
        raise ValueError(f"beta {beta}: |beta| must be below 1")
    env: Any = envmap
    if isinstance(envmap, (str, os.PathLike)):
        env = os.fspath(envmap)
    else:
        env = cv.rgb(envmap, "envmap")
    if not isinstance(effects, str):
        effects = ",".join(effects) or "none"
    look3 = cv.triple(look, "look")
    d = look3 if direction is None else cv.triple(direction, "direction")
    img = _native.relativity_render(env, beta, d, look3, cv.triple(up, "up"), float(fov), int(width), int(height), effects)
    return Image(img, "linear-rgb", {"beta": beta})
