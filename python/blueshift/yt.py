"""yt: scenes from datasets, and blueshift's Doppler renderer as a yt ``RenderSource``.

yt is optional: ``import blueshift`` works without it; this module imports it when used.
"""

from __future__ import annotations

from typing import Any, Dict, Mapping, Optional, Sequence

import numpy as np

from . import _convert as cv
from ._core import Volume
from .doppler import Scene

# Scene roles from_yt understands (fields={role: yt field}).
_ROLES = ("velocity", "velocity_x", "velocity_y", "velocity_z", "temperature", "blackbody", "density")


def _grid(ds: Any, level: int, left_edge: Any, dims: Any) -> Any:
    if left_edge is None:
        left_edge = ds.domain_left_edge
    if dims is None:
        dims = ds.domain_dimensions * int(ds.refine_by) ** int(level)
    return ds.covering_grid(level=int(level), left_edge=left_edge, dims=[int(d) for d in dims])


def from_yt(
    ds: Any,
    fields: Mapping[str, Any],
    level: int = 0,
    left_edge: Any = None,
    dims: Optional[Sequence[int]] = None,
    species: Optional[Mapping[str, Any]] = None,
    blackbody: Optional[Mapping[str, Any]] = None,
    kind: str = "doppler",
    length_unit: str = "code_length",
    **scene_options: Any,
) -> Any:
    """A Doppler scene (or, with ``kind="volume"``, a :class:`blueshift.Volume`) from a
    yt dataset's covering grid at ``level`` over ``left_edge`` with ``dims`` (default the
    whole domain at that level's resolution), with its units.

    ``fields`` maps roles to yt fields: ``velocity`` (a vector field name prefix, e.g.
    ``("gas", "velocity")``, expanded to ``_x``, ``_y``, ``_z``) or ``velocity_x/_y/_z``,
    ``temperature``, ``blackbody`` (the black body's density) and ``density`` (the gas
    density the species take, with their mass fractions). ``species`` maps species names
    to a mass fraction or a dict (``mass_fraction``, ``lines``, ``scale``, ``absorb``,
    ``field``: another yt field for its density); default ``{"H I": 0.76}`` with hydrogen
    lines. ``blackbody`` gives the black body's ``mass_fraction`` and ``scale`` (and
    optionally its ``field``, instead of ``fields["blackbody"]``). For ``kind="volume"`` every ``fields`` entry becomes a channel of that name.
    World lengths are in ``length_unit`` (default the code length), so a scene file over
    files exported from the same grid (spacing in code units) renders the same picture.
    """
    cg = _grid(ds, level, left_edge, dims)
    dds = cg.dds.to(length_unit)
    spacing = [float(v) for v in np.asarray(dds)]
    le = np.asarray(cg.left_edge.to(length_unit), dtype=np.float64)
    origin = [float(a + d / 2.0) for a, d in zip(le, spacing)]
    if kind == "volume":
        return Volume.from_arrays({str(k): cg[f] for k, f in fields.items()}, spacing=spacing, origin=origin)
    if kind != "doppler":
        raise ValueError(f"kind '{kind}': doppler or volume")
    unknown = set(fields) - set(_ROLES)
    if unknown:
        raise ValueError(f"fields: unknown roles {sorted(unknown)} (known: {', '.join(_ROLES)})")
    velocity = None
    if "velocity" in fields:
        base = fields["velocity"]
        comps = [(base[0], f"{base[1]}_{a}") if isinstance(base, tuple) else f"{base}_{a}" for a in "xyz"]
        velocity = _stack([cg[c] for c in comps])
    elif any(f"velocity_{a}" in fields for a in "xyz"):
        velocity = _stack([cg[fields[f"velocity_{a}"]] for a in "xyz"])
    temperature = cg[fields["temperature"]] if "temperature" in fields else None
    bb_opts = dict(blackbody or {})
    bb_field = bb_opts.pop("field", None) or fields.get("blackbody")
    unknown_bb = set(bb_opts) - {"mass_fraction", "particle_mass_amu", "scale"}
    if unknown_bb:
        raise ValueError(f"blackbody: unknown keys {sorted(unknown_bb)}")
    bb = None
    if bb_field is not None:
        bb = dict(bb_opts, density=cg[bb_field])
    elif bb_opts:
        raise ValueError("blackbody options need fields['blackbody'] or blackbody['field']")
    sp: Dict[str, Any] = {}
    if species is None:
        species = {"H I": 0.76}
    for name, s in species.items():
        spec = dict(s) if isinstance(s, Mapping) else {"mass_fraction": float(s)}
        f = spec.pop("field", None) or fields.get("density")
        if f is None:
            raise ValueError(f"species '{name}': give fields['density'] or its own 'field'")
        spec["density"] = cg[f]
        sp[name] = spec
    return Scene(velocity=velocity, temperature=temperature, blackbody=bb, species=sp,
                 spacing=spacing, origin=origin, **scene_options)


def _stack(comps: Sequence[Any]) -> Any:
    """Three component arrays (quantities) as one ``[x, y, z, 3]`` quantity."""
    first = comps[0]
    if hasattr(first, "units"):
        unit = first.units
        vals = np.stack([np.asarray(c.to(unit)) for c in comps], axis=-1)
        return type(first)(vals, unit) if hasattr(type(first), "__array_ufunc__") else vals
    return np.stack([np.asarray(c) for c in comps], axis=-1)


def _render_source_base() -> Any:
    from yt.visualization.volume_rendering.render_source import RenderSource

    return RenderSource


def _make_source_class() -> Any:
    base = _render_source_base()

    class BlueshiftSource(base):  # type: ignore[misc, valid-type]
        """blueshift's Doppler renderer as a yt ``RenderSource``: add it to a yt
        ``Scene`` and yt's camera (position, focus, north vector, width, resolution; a
        plane-parallel lens) drives an orthographic Doppler render; the source returns
        the display image as RGBA in [0, 1] (linear).

        ``scene`` is a :class:`blueshift.doppler.Scene` in the dataset's ``length_unit``
        (what :func:`from_yt` makes); ``options`` are
        :meth:`blueshift.doppler.Scene.render`'s.
        """

        def __init__(self, scene: Scene, length_unit: str = "code_length", **options: Any) -> None:
            super().__init__()
            self.scene = scene
            self.length_unit = length_unit
            self.options = options
            self.last = None

        def _validate(self) -> None:
            if not isinstance(self.scene, Scene):
                raise TypeError("BlueshiftSource needs a blueshift.doppler.Scene")

        def _camera_options(self, camera: Any) -> Dict[str, Any]:
            lens = type(camera.lens).__name__
            if "PlaneParallel" not in lens:
                raise ValueError(f"BlueshiftSource renders with a plane-parallel lens, not {lens}")
            pos = np.asarray(camera.position.to(self.length_unit), dtype=np.float64)
            focus = np.asarray(camera.focus.to(self.length_unit), dtype=np.float64)
            north = np.asarray(camera.north_vector, dtype=np.float64)
            width = np.asarray(camera.width.to(self.length_unit), dtype=np.float64)
            w, h = (int(v) for v in camera.resolution)
            if not np.isclose(width[0] / width[1], w / h, rtol=1e-6):
                raise ValueError(
                    f"BlueshiftSource renders square pixels: the camera's width {width[0]:g} x {width[1]:g} "
                    f"does not have the resolution's aspect {w} x {h} (set_width to match it)"
                )
            return {"eye": tuple(pos), "target": tuple(focus), "up": tuple(north), "ortho_height": float(width[1])}

        def render(self, camera: Any, zbuffer: Any = None) -> Any:
            from yt.data_objects.image_array import ImageArray

            self._validate()
            w, h = (int(v) for v in camera.resolution)
            opts = dict(self.options)
            opts.update(self._camera_options(camera))
            r = self.scene.render(width=w, height=h, **opts)
            self.last = r
            rgb = np.asarray(r.rgb, dtype=np.float64) / 255.0
            lin = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
            # yt's composite image is indexed [x, row from the top] (its PNGs put x right
            # and y up, as blueshift's images do) and yt rotates it by 180 degrees after
            # the sources render: hand over blueshift's picture transposed, pre-rotated.
            img = np.ones((w, h, 4))
            img[:, :, :3] = np.transpose(lin, (1, 0, 2))
            img = np.rot90(img, k=2)
            if zbuffer is not None:
                zbuffer.rgba = img
            return ImageArray(img, info={"source": "blueshift doppler"})

        def __repr__(self) -> str:
            return f"<BlueshiftSource> species={self.scene.species} options={self.options}"

    return BlueshiftSource


_cls = None


def __getattr__(name: str) -> Any:
    global _cls
    if name == "BlueshiftSource":
        if _cls is None:
            _cls = _make_source_class()
        return _cls
    raise AttributeError(name)
