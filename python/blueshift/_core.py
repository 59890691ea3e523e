"""Volumes, transfer functions, images, tracking renders and tone mapping."""

from __future__ import annotations

import json
import os
from typing import Any, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _native
from . import _convert as cv

PathLike = Union[str, "os.PathLike[str]"]


class Image(np.ndarray):
    """A numpy array that knows what it holds, and shows itself in Jupyter.

    ``kind`` is ``"linear-rgba"`` (a render's mean: linear RGB and alpha), ``"linear-rgb"``
    (HDR RGB: relativity, an input to tone mapping), ``"display"`` (display-linear RGB, 1
    the display's white, brighter values clipped when encoded: a tone mapper's output), ``"xyz"`` (CIE 1931 XYZ) or ``"srgb8"`` (8-bit sRGB).
    ``meta`` holds what the engine reported (noise, samples per pixel, heat maps...).
    ``_repr_png_`` shows linear images with a plain exposure (clipped), display images
    sRGB-encoded, XYZ images through the display mapping the render made.
    """

    def __new__(cls, array: Any, kind: str, meta: Optional[dict] = None) -> "Image":
        obj = np.asarray(array).view(cls)
        obj.kind = kind
        obj.meta = dict(meta or {})
        return obj

    def __array_finalize__(self, obj: Any) -> None:
        self.kind = getattr(obj, "kind", "array")
        meta = dict(getattr(obj, "meta", {}))
        # A slice or a reshape keeps no display image of another shape.
        disp = meta.get("display")
        if disp is not None and np.shape(disp)[:2] != self.shape[:2]:
            del meta["display"]
        self.meta = meta

    def __getattr__(self, name: str) -> Any:
        meta = self.__dict__.get("meta", {})
        if name in meta:
            return meta[name]
        raise AttributeError(name)

    def to_srgb8(self) -> np.ndarray:
        """8-bit sRGB ``[h, w, 3]`` of the image as ``_repr_png_`` shows it."""
        a = np.asarray(self)
        if self.kind == "srgb8":
            return np.ascontiguousarray(a[:, :, :3], dtype=np.uint8)
        if self.kind == "xyz" and "display" in self.meta:
            return np.asarray(self.meta["display"])
        if self.kind == "xyz":
            m = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]])
            a = a @ m.T
            y = np.percentile(np.asarray(self)[:, :, 1], 99.0)
            a = a / y if y > 0 else a
        return _native.encode_srgb8(cv.rgb(a, "image"))

    def _repr_png_(self) -> Optional[bytes]:
        if self.ndim != 3 or self.shape[2] not in (3, 4) or self.size == 0:
            return None
        return bytes(_native.png_bytes(np.ascontiguousarray(self.to_srgb8())))


class Volume:
    """Channels (scalar or 3-vector) on one regular grid.

    Arrays are indexed ``[x, y, z]`` (``[x, y, z, 3]`` for vectors), as yt's covering grids
    give them; spacing and origin (the centre of voxel (0, 0, 0)) are in world units.
    """

    def __init__(self, native: Any) -> None:
        self._native = native

    @classmethod
    def from_arrays(
        cls,
        channels: Union[Mapping[str, Any], np.ndarray],
        spacing: Any = 1.0,
        origin: Any = 0.0,
        finite: bool = False,
    ) -> "Volume":
        """A volume from ``{"name": array}`` (or one array, named ``value``).

        float64, integer and C-ordered arrays are converted to float32 x-fastest (a
        Fortran-ordered float32 array needs no conversion: its buffer is copied once, into
        the grid); ``finite=True`` also refuses NaN and infinities.
        """
        if not isinstance(channels, Mapping):
            channels = {"value": channels}
        if not channels:
            raise ValueError("a volume needs at least one array")
        arrs = []
        for name, a in channels.items():
            vector = np.ndim(a) == 4
            arrs.append((str(name), cv.field(a, str(name), vector=vector, finite=finite)))
        return cls(
            _native.Volume.from_arrays(arrs, cv.triple(spacing, "spacing"), cv.triple(origin, "origin"))
        )

    @classmethod
    def read(cls, path: PathLike) -> "Volume":
        """Reads NRRD/.nhdr, MetaImage, VTK, raw-with-header or .bsv."""
        return cls(_native.Volume.read(os.fspath(path)))

    @property
    def dims(self) -> Tuple[int, int, int]:
        """Voxels along x, y, z."""
        return self._native.dims

    @property
    def spacing(self) -> Tuple[float, float, float]:
        return self._native.spacing

    @property
    def origin(self) -> Tuple[float, float, float]:
        return self._native.origin

    @property
    def channel_names(self) -> List[str]:
        return self._native.channel_names

    def array(self, name: Optional[str] = None) -> np.ndarray:
        """A channel indexed ``[x, y, z]`` (a view of a fresh copy)."""
        name = name or self.channel_names[0]
        a = self._native.array(name)
        return a.transpose(2, 1, 0, 3) if a.ndim == 4 else a.T

    def write_nrrd(self, name: str, path: PathLike) -> None:
        """Writes channel ``name`` as NRRD: ``.nhdr`` (a header naming ``.raw`` voxels
        beside it) or ``.nrrd`` (attached); any other extension is refused. Never replaces
        a file, and leaves none half-written."""
        self._native.write_nrrd(name, os.fspath(path))

    def __repr__(self) -> str:
        return repr(self._native)


class TransferFunction:
    """Colour and opacity knots over a data domain (linear or logarithmic data axis) with
    the global opacity alpha_g (HDR VolVis section 5)."""

    def __init__(self, native: Any) -> None:
        self._native = native

    @classmethod
    def builtin(cls, name: str, domain: Optional[Tuple[float, float]] = None) -> "TransferFunction":
        """A built-in map (``blueshift tf --list``), stretched over ``domain``."""
        return cls(_native.TransferFunction.builtin(name, None if domain is None else tuple(map(float, domain))))

    @classmethod
    def load(cls, path: PathLike) -> "TransferFunction":
        """A blueshift JSON or ParaView preset file."""
        return cls(_native.TransferFunction.load(os.fspath(path)))

    @classmethod
    def from_json(cls, text: str) -> "TransferFunction":
        return cls(_native.TransferFunction.from_json(text))

    @classmethod
    def from_knots(
        cls,
        domain: Tuple[float, float],
        color: Sequence[Sequence[float]],
        opacity: Sequence[Sequence[float]],
        log: bool = False,
        alpha_g: float = 1.0,
        name: Optional[str] = None,
    ) -> "TransferFunction":
        """From colour rows ``(x, r, g, b)`` and opacity rows ``(x, alpha)``, x in data units."""
        return cls(
            _native.TransferFunction.from_knots(
                tuple(map(float, domain)),
                [tuple(map(float, k)) for k in color],
                [tuple(map(float, k)) for k in opacity],
                bool(log),
                float(alpha_g),
                name,
            )
        )

    @property
    def domain(self) -> Tuple[float, float]:
        return self._native.domain

    @property
    def log(self) -> bool:
        return self._native.log

    @property
    def alpha_g(self) -> float:
        return self._native.alpha_g

    def rescaled(self, lo: float, hi: float) -> "TransferFunction":
        """The same knots stretched over ``[lo, hi]`` (ParaView's rescale)."""
        return TransferFunction(self._native.rescaled(float(lo), float(hi)))

    def with_alpha_g(self, alpha_g: float) -> "TransferFunction":
        return TransferFunction(self._native.with_alpha_g(float(alpha_g)))

    def eval(self, values: Any) -> np.ndarray:
        """RGBA at each value, float32 ``[n, 4]`` (opacity times alpha_g)."""
        return self._native.eval(np.ascontiguousarray(np.ravel(values), dtype=np.float64))

    def lut(self, entries: int = 256) -> np.ndarray:
        """A lookup table, float32 ``[entries, 4]`` over the domain."""
        return self._native.lut(int(entries))

    def to_json(self) -> str:
        return self._native.to_json()

    def save(self, path: PathLike, overwrite: bool = False) -> None:
        """Writes blueshift JSON (never replaces a file unless ``overwrite``)."""
        mode = "w" if overwrite else "x"
        with open(path, mode, encoding="utf-8") as f:
            f.write(self.to_json())

    def __repr__(self) -> str:
        return repr(self._native)


# --- tracking renders ------------------------------------------------------------------


def _scene_request(
    scene: Any, channels: Any, volume: Any, tf: Any, settings: Dict[str, Any]
) -> Tuple[str, Optional[str], Dict[str, Any], Dict[str, Any]]:
    """The scene JSON, its base folder and the in-memory volumes and TFs it names."""
    base: Optional[str] = None
    doc: Dict[str, Any] = {}
    if scene is not None:
        if isinstance(scene, Mapping):
            doc = dict(scene)
        else:
            path = os.fspath(scene)
            with open(path, encoding="utf-8") as f:
                doc = json.load(f)
            base = os.path.dirname(os.path.abspath(path))
    volumes: Dict[str, Any] = {}
    tfs: Dict[str, Any] = {}
    if volume is not None:
        if channels is not None:
            raise ValueError("give channels or volume, not both")
        vols = volume if isinstance(volume, (list, tuple)) else [volume]
        tf_list = tf if isinstance(tf, (list, tuple)) else [tf] * len(vols)
        if len(tf_list) != len(vols):
            raise ValueError(f"{len(vols)} volumes but {len(tf_list)} transfer functions")
        channels = [{"volume": v, "tf": t if t is not None else "builtin:viridis"} for v, t in zip(vols, tf_list)]
    if channels is not None:
        out = []
        for i, c in enumerate(channels):
            c = dict(c)
            v = c.get("volume")
            if isinstance(v, Volume):
                key = f"python:channels[{i}]"
                volumes[key] = v._native
                c["volume"] = key
            elif isinstance(v, np.ndarray) or cv.is_quantity(v):
                key = f"python:channels[{i}]"
                volumes[key] = Volume.from_arrays({c.get("channel") or "value": v})._native
                c["volume"] = key
            elif v is not None:
                c["volume"] = os.path.abspath(os.fspath(v))
            t = c.get("tf")
            if isinstance(t, TransferFunction):
                key = f"python:tf[{i}]"
                tfs[key] = t._native
                c["tf"] = key
            elif t is None:
                c["tf"] = "builtin:viridis"
            out.append(c)
        doc["channels"] = out
    for k, v in settings.items():
        if v is None:
            continue
        if isinstance(v, (tuple, np.ndarray)):
            v = [float(c) for c in v]
        for c in v if isinstance(v, list) else [v]:
            if isinstance(c, float) and not np.isfinite(c):
                raise ValueError(f"{k} = {v}: must be finite")
        doc[k] = v
    if not doc.get("channels"):
        raise ValueError("nothing to render: give scene, channels or volume")
    return json.dumps(doc), base, volumes, tfs


def render(
    scene: Any = None,
    *,
    channels: Optional[Sequence[Mapping[str, Any]]] = None,
    volume: Any = None,
    tf: Any = None,
    device: str = "cpu",
    **settings: Any,
) -> Image:
    """Renders a volume scene with Woodcock, multi-density Woodcock or the HDR marcher.

    ``scene`` is a scene file (path) or its dict (``blueshift render``'s format); or give
    ``channels`` (dicts ``{"volume": Volume | array [x, y, z] | path, "channel": name,
    "tf": TransferFunction | "builtin:NAME" | "log:NAME" | path}``) or ``volume`` and
    ``tf`` (one each, or lists). Keyword settings are the scene file's keys and override
    it: ``method`` (``woodcock``, ``mdwt-ndda``, ``mdwt-1dda``, ``mdwt-summed``,
    ``marcher``), ``blend``, ``weights``, ``spp``, ``seed``, ``width``, ``height``,
    ``camera``, ``fov_y_deg``, ``view``, ``eye``, ``target``, ``up``, ``zoom``,
    ``background``, ``density_scale``, ``macrocell``, ``precision``, ``step``, ``alpha_g``,
    ``noise_target``, ``light``, ``shading``, ``heatmaps``, ``tf_range``.

    ``device`` is ``blueshift render --device``'s: ``cpu`` (the bit-reproducible reference),
    ``gpu`` (any wgpu adapter, or an error) or ``auto`` (a hardware GPU when it supports the
    job, else the CPU; the reason lands in ``fallback``).

    Returns the mean image, float32 ``[height, width, 4]`` linear RGBA (an :class:`Image`
    with ``noise``, ``spp``, ``heatmaps``, ``backend`` (``cpu`` or ``gpu``: where it ran)
    and ``fallback``), the same numbers
    ``blueshift render`` writes to its EXR. The GIL is released while rendering; Ctrl-C
    cancels (between passes).
    """
    req = _scene_request(scene, channels, volume, tf, settings)
    out = _native.render_tracking(*req, device=device)
    meta = {k: out[k] for k in ("noise", "spp", "heatmaps", "fallback")}
    meta["backend"] = out["device"]  # not "device": numpy arrays have a .device of their own
    return Image(out["image"], "linear-rgba", meta)


def render_progressive(
    scene: Any = None,
    *,
    channels: Optional[Sequence[Mapping[str, Any]]] = None,
    volume: Any = None,
    tf: Any = None,
    **settings: Any,
) -> Iterator[Tuple[int, Image, Optional[float]]]:
    """:func:`render`, yielding ``(pass, image, noise)`` after every pass of one sample per
    pixel (``image`` the mean so far; ``noise`` the RMS standard error, None after one
    pass). Stop iterating (or ``close()`` the generator) to cancel the render. A bad scene
    raises here, before the first pass."""
    req = _scene_request(scene, channels, volume, tf, settings)
    run = _native.TrackingRun(*req)

    def passes() -> Iterator[Tuple[int, Image, Optional[float]]]:
        try:
            for k, img, noise in run:
                yield k, Image(img, "linear-rgba", {"noise": noise, "spp": k}), noise
        finally:
            run.close()

    return passes()


# --- images ------------------------------------------------------------------------------

_OPERATORS = {
    "linear": "Linear",
    "drago": "Drago",
    "reinhard": "Reinhard",
    "reinhard-local": "ReinhardLocal",
    "durand": "Durand",
    "fattal": "Fattal",
}


def tonemap(image: Any, op: str = "drago", **params: Any) -> Image:
    """Tone-maps a linear HDR image (``[h, w, 3]``, or RGBA with alpha ignored).

    ``op`` is ``linear``, ``drago``, ``reinhard``, ``reinhard-local``, ``durand`` or
    ``fattal``; ``params`` are the operator's parameters by name (for example Drago's
    ``bias`` and ``ld_max``; :func:`tonemap_parameters` lists them with their defaults).
    Returns display-linear RGB, 1 the display's white (``.to_srgb8()`` clips and encodes it
    as the CLI's PNGs).
    """
    tag = _OPERATORS.get(op)
    if tag is None:
        raise ValueError(f"tonemap: op '{op}' is not one of {', '.join(_OPERATORS)}")
    defaults = tonemap_parameters(op)
    for k in params:
        if k not in defaults:
            raise TypeError(f"tonemap: {op} has no parameter '{k}' (it has {', '.join(defaults)})")
    merged = {**defaults, **params}
    out = _native.tonemap(cv.rgb(image, "image"), json.dumps({tag: merged}))
    return Image(out, "display", {"operator": op, "parameters": merged})


def tonemap_parameters(op: str) -> Dict[str, Any]:
    """An operator's parameters with their defaults."""
    tag = _OPERATORS.get(op)
    if tag is None:
        raise ValueError(f"tonemap: op '{op}' is not one of {', '.join(_OPERATORS)}")
    return json.loads(_native.tonemap_defaults(op))[tag]


def read_hdr(path: PathLike) -> Image:
    """Reads ``.exr``, ``.hdr`` or ``.pfm`` as linear RGB float32 ``[h, w, 3]``."""
    return Image(_native.read_hdr(os.fspath(path)), "linear-rgb")
