"""Doppler volume rendering (Alghamdi et al.): species' emission and absorption lines and a
black body, Doppler-shifted by a velocity field, as images, picked spectra, step-by-step
traces and position-position-velocity cubes.

Fields are indexed ``[x, y, z]`` (velocity ``[x, y, z, 3]``), as yt's covering grids give
them. Units: a unyt/yt or astropy quantity is converted; a plain array is in the library's
units, which are velocity in m/s (positive components along +x, +y, +z), temperature in
K, and density as the model's number density (cm^-3 with world lengths in the grid's
spacing unit). A mass density (g/cm^3 as a quantity) becomes a number density as
``rho * mass_fraction / (particle_mass_amu * u)``, as scene files say.
"""

from __future__ import annotations

import json
import os
import re
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _native
from . import _convert as cv
from ._core import Image, Volume

_CATALOGUES = {"h": "H", "hi": "H", "h i": "H", "hydrogen": "H", "he": "He", "hei": "He", "he i": "He",
               "helium": "He", "c": "C", "ci": "C", "c i": "C", "carbon": "C"}


def _catalogue(name: str) -> Optional[str]:
    return _CATALOGUES.get(name.strip().lower())


class Scene:
    """A Doppler scene on one grid.

    ``species`` maps a name to a density, or to a dict with ``density`` and any of
    ``lines`` (a catalogue ``"H"``, ``"He"``, ``"C"``, or ``[(wavelength_nm,
    relative_intensity), ...]``), ``mass_fraction``, ``particle_mass_amu``, ``scale``
    (multiplies the number density) and ``absorb`` (default True). A species named by a
    catalogue (``"H"``, ``"He"``, ``"C"``, ``"H I"``...) takes its lines. ``blackbody`` is
    the black-body emitter's density (or such a dict); it needs ``temperature``.
    ``factors`` are the paper's Table 1 multipliers (``velocity``, ``temperature``,
    ``emission``, ``absorption``, ``blackbody``). ``spacing`` and ``origin`` (the centre of
    voxel (0, 0, 0)) are in world units (a quantity in cm gives cm).
    """

    def __init__(
        self,
        velocity: Any = None,
        temperature: Any = None,
        blackbody: Any = None,
        species: Optional[Mapping[str, Any]] = None,
        spacing: Any = 1.0,
        origin: Any = 0.0,
        factors: Optional[Mapping[str, float]] = None,
        subtract_mean_velocity: bool = False,
        cube_units: Optional[Mapping[str, str]] = None,
        _native_scene: Any = None,
    ) -> None:
        self._arrays: Dict[str, Tuple[np.ndarray, bool]] = {}
        self._doc: Dict[str, Any] = {}
        if _native_scene is not None:
            self._native = _native_scene
            return
        doc: Dict[str, Any] = {}
        species = dict(species or {})
        if temperature is not None:
            doc["temperature"] = self._field("temperature", temperature, "K")
        if velocity is not None:
            v = self._vector("velocity", velocity)
            v["subtract_mean"] = bool(subtract_mean_velocity)
            doc["velocity"] = v
        elif subtract_mean_velocity:
            raise ValueError("subtract_mean_velocity needs a velocity")
        if blackbody is not None:
            doc["blackbody"] = {"density": self._density("black body", blackbody)}
        doc["species"] = [self._species(name, spec) for name, spec in species.items()]
        if factors:
            doc["factors"] = {k: float(v) for k, v in factors.items()}
        if cube_units:
            doc["cube"] = dict(cube_units)
        self._spacing = cv.triple(spacing, "spacing", "cm" if cv.is_quantity(spacing) else None)
        self._origin = cv.triple(origin, "origin", "cm" if cv.is_quantity(origin) else None)
        self._doc = doc
        vols = {key: _native.Volume.from_arrays([(key, a)], self._spacing, self._origin)
                for key, (a, _) in self._arrays.items()}
        self._native = _native.DopplerScene(json.dumps(doc), None, vols)

    # -- building the scene document ---------------------------------------------------

    def _put(self, key: str, arr: Any, vector: bool) -> str:
        self._arrays[key] = (cv.field(arr, key, vector=vector), vector)
        return key

    def _field(self, name: str, x: Any, unit: str) -> Dict[str, Any]:
        if isinstance(x, Mapping):
            raise TypeError(f"{name}: give an array or a quantity")
        if np.ndim(x) == 0:
            return {"value": cv.as_float(x, unit, name), "unit": unit}
        return {"file": self._put(name, cv.to_unit(x, unit, name), False), "unit": unit}

    def _vector(self, name: str, x: Any) -> Dict[str, Any]:
        return {"file": self._put(name, cv.to_unit(x, "m/s", name), True), "unit": "m/s"}

    def _density(self, name: str, x: Any) -> Dict[str, Any]:
        extra: Optional[Mapping[str, Any]] = None
        if isinstance(x, Mapping):
            extra = {k: v for k, v in x.items() if k != "density"}
            x = x["density"]
        if cv.is_quantity(x):
            if cv.converts_to(x, "g/cm3"):
                unit = "g/cm3"
            elif cv.converts_to(x, "cm-3"):
                unit = "cm-3"
            else:
                raise TypeError(f"{name}: density in {cv.unit_name(x)} is neither a mass density nor a number density")
        else:
            unit = "1"
        key = f"{name} density"
        if np.ndim(x) == 0:
            spec = {"value": cv.as_float(x, unit, name) if unit != "1" else float(x), "unit": unit}
        else:
            vals = cv.to_unit(x, unit, name) if unit != "1" else x
            spec = {"file": self._put(key, vals, False), "unit": unit}
        for k in ("mass_fraction", "particle_mass_amu", "scale"):
            if extra and k in extra:
                spec[k] = float(extra[k])
        return spec

    def _species(self, name: str, spec: Any) -> Dict[str, Any]:
        d: Dict[str, Any] = {"name": name}
        extra = dict(spec) if isinstance(spec, Mapping) else {}
        unknown = set(extra) - {"density", "lines", "mass_fraction", "particle_mass_amu", "scale", "absorb"}
        if unknown:
            raise TypeError(f"species '{name}': unknown keys {sorted(unknown)}")
        lines = extra.get("lines")
        if lines is None:
            cat = _catalogue(name)
            if cat is None:
                raise ValueError(
                    f"species '{name}': not a catalogue name (H, He, C); give its lines: "
                    "{'density': ..., 'lines': 'H' or [(nm, relative_intensity), ...]}"
                )
            d["lines"] = cat
        elif isinstance(lines, str):
            d["lines"] = _catalogue(lines) or lines
        else:
            d["line_table"] = [[float(a), float(b)] for a, b in lines]
        if "absorb" in extra:
            d["absorb"] = bool(extra["absorb"])
        d["density"] = self._density(name, spec)
        return d

    # -- reading and writing -----------------------------------------------------------

    @classmethod
    def read(
        cls,
        path: Union[str, "os.PathLike[str]"],
        species: Optional[Sequence[str]] = None,
        cache_mb: Optional[int] = None,
    ) -> "Scene":
        """Reads a scene file (``blueshift doppler --scene``'s format); ``species`` selects
        parts by name (``bb`` for the black body). Fields in ``.bsv`` files stay on disk and
        are read brick by brick through one cache of ``cache_mb`` MiB (default: a quarter of
        physical memory), so a scene larger than memory renders."""
        return cls(_native_scene=_native.DopplerScene.read(os.fspath(path), cv.names(species), cache_mb))

    @property
    def levels(self) -> Optional[List[Tuple[int, int, int]]]:
        """Voxels per axis of each level of detail, finest first, when every field is a
        ``.bsv`` file; ``None`` for a scene in memory."""
        return self._native.levels

    def at_level(self, level: int) -> "Scene":
        """The same scene sampled at level of detail ``level`` (0: the finest), e.g. a fast
        preview of a large out-of-core scene."""
        return type(self)(_native_scene=self._native.at_level(int(level)))

    def save(self, folder: Union[str, "os.PathLike[str]"], name: str = "scene.json") -> str:
        """Writes the scene as NRRD files and a scene file in ``folder`` (created; files
        there are never replaced) and returns the scene file's path, for ``blueshift
        doppler --scene``."""
        if not self._doc:
            raise ValueError("only a scene built from arrays can be saved (this one was read from a file)")
        os.makedirs(folder, exist_ok=True)
        doc = json.loads(json.dumps(self._doc))
        names: Dict[str, str] = {}
        for key in self._arrays:
            stem = re.sub(r"[^A-Za-z0-9_-]", "_", key) or "field"
            # Attached NRRD: one file a field.
            fname, k = stem + ".nrrd", 2
            while fname in names.values():
                fname, k = f"{stem}_{k}.nrrd", k + 1
            names[key] = fname
        targets = [os.path.join(folder, name)] + [os.path.join(folder, f) for f in names.values()]
        taken = [t for t in targets if os.path.exists(t)]
        if taken:
            raise FileExistsError(f"{taken[0]} exists: Scene.save never replaces a file (use an empty folder)")
        files: Dict[str, str] = {}
        written: List[str] = []
        try:
            for key, (arr, _) in self._arrays.items():
                fname = names[key]
                vol = _native.Volume.from_arrays([(key, arr)], self._spacing, self._origin)
                vol.write_nrrd(key, os.path.join(folder, fname))
                written.append(os.path.join(folder, fname))
                files[key] = fname
        except BaseException:
            for f in written:  # no half-written scene: the files this save made go again
                os.remove(f)
            raise

        def fix(node: Any) -> None:
            if isinstance(node, dict):
                if isinstance(node.get("file"), str) and node["file"] in files:
                    node["file"] = files[node["file"]]
                for v in node.values():
                    fix(v)
            elif isinstance(node, list):
                for v in node:
                    fix(v)

        fix(doc)
        path = os.path.join(folder, name)
        try:
            with open(path, "x", encoding="utf-8") as f:
                json.dump(doc, f, indent=2)
        except BaseException:
            for f in written:
                os.remove(f)
            raise
        return path

    @property
    def dims(self) -> Tuple[int, int, int]:
        return self._native.dims

    @property
    def species(self) -> List[str]:
        return self._native.species

    # -- rendering ---------------------------------------------------------------------

    @staticmethod
    def _opts(width: int, height: int, opts: Dict[str, Any]) -> str:
        o: Dict[str, Any] = {"width": int(width), "height": int(height)}
        for k, v in opts.items():
            if v is None:
                continue
            if k == "line_sigma":
                v = cv.as_float(v, "km/s", k) if cv.is_quantity(v) else float(v)
            if isinstance(v, (tuple, list, np.ndarray)):
                v = [float(c) for c in v]
                if not all(np.isfinite(v)):
                    raise ValueError(f"{k} {v}: every component must be finite")
            elif isinstance(v, float) and not np.isfinite(v):
                raise ValueError(f"{k} = {v}: must be finite")
            if k == "exposure_scale" and isinstance(v, (bool, np.bool_)):
                raise TypeError(
                    f"exposure_scale = {v!r}: give a number, 'pNN' or 'per-pixel', not a bool"
                )
            if k == "exposure_scale" and isinstance(v, (int, float, np.number)):
                # A number, as blueshift doppler --exposure-scale takes it.
                v = repr(float(v))
            o[k] = v
        return json.dumps(o)

    @staticmethod
    def _pixel(x: int, y: int) -> Tuple[int, int]:
        x, y = int(x), int(y)
        if x < 0 or y < 0:
            raise ValueError(f"pixel ({x}, {y}): columns and rows count from 0")
        return x, y

    def render(self, width: int = 256, height: int = 256, **opts: Any) -> "Render":
        """Renders the image ``blueshift doppler`` renders with the same options.

        Options (``blueshift doppler``'s flags): ``integrator`` (``pwl``, ``banded:N``,
        ``banded-ec:N``), ``doppler`` (``classical``, ``relativistic``), ``invariant``,
        ``merge_tol``, ``piece_budget``, ``step``, ``line_width`` (nm), ``inclination``,
        ``axis``, ``normal``, ``cell_domain``, ``view``, ``fov``, ``eye``, ``target``,
        ``up``, ``zoom``; display: ``matrix`` (``srgb``, ``cie``), ``exposure_scale`` (a
        number, ``pNN``, ``per-pixel``), ``exposure`` (stops); ``device`` (``cpu``, the
        reference; ``gpu``; ``auto``: a hardware GPU when it supports the scene) and
        ``gpu_precision`` (``auto``, ``f32``, ``f64``). ``Render.backend`` says where it ran.
        A moving observer: ``observer_velocity=(bx, by, bz)`` (units of c) or ``beta`` along
        ``direction`` (default: the view direction); with ``invariant`` the searchlight.
        """
        out = self._native.render(self._opts(width, height, opts))
        rgb = Image(out["rgb8"], "srgb8")
        xyz = Image(out["xyz"], "xyz", {"display": out["rgb8"], "pieces": out["pieces"]})
        r = Render(xyz, rgb, out["pieces"])
        r.backend, r.fallback = out["device"], out["fallback"]
        return r

    def spectrum(self, x: int, y: int, width: int = 256, height: int = 256, **opts: Any) -> Tuple[np.ndarray, np.ndarray]:
        """The spectrum reaching pixel ``(x, y)`` (column, row from the top) of the image
        :meth:`render` makes with the same size and options: ``(wavelengths_nm, values)``,
        the exact piecewise-linear polyline (a jump is two points at one wavelength; gaps
        fall to zero), as ``blueshift doppler --pick`` writes it."""
        x, y = self._pixel(x, y)
        pieces, rng = self._native.spectrum(x, y, self._opts(width, height, opts))
        return polyline(pieces, rng)

    def trace(self, x: int, y: int, width: int = 256, height: int = 256, **opts: Any) -> List["TraceStep"]:
        """The ray of pixel ``(x, y)`` step by step (paper Fig. 5): the spectrum after each
        segment, back to front."""
        x, y = self._pixel(x, y)
        steps, rng = self._native.trace(x, y, self._opts(width, height, opts))
        return [TraceStep(t, v, *polyline(p, rng)) for t, v, p in steps]

    def cube(
        self,
        line: Union[str, float] = "H-alpha",
        velocity_bins: Optional[Tuple[Any, Any, int]] = None,
        wavelength_bins: Optional[Tuple[float, float, int]] = None,
        spectral_axis: str = "vrad",
        thermal: bool = False,
        line_sigma: Any = 0.0,
        masses: Optional[Mapping[str, float]] = None,
        width: int = 256,
        height: int = 256,
        bunit: Optional[str] = None,
        world_unit: Optional[Tuple[str, float]] = None,
        **opts: Any,
    ) -> "Cube":
        """A position-position-velocity cube of one line (``blueshift doppler --cube``).

        ``velocity_bins`` is ``(vmin, vmax, n)`` in km/s (quantities converted), channel
        edges from vmin to vmax; or ``wavelength_bins`` ``(min_nm, max_nm, n)``.
        ``thermal`` broadens every line by ``sqrt(kT/m)``; ``line_sigma`` adds a Gaussian
        width (km/s); ``masses`` gives species' atomic masses (amu). ``axis`` (``x``,
        ``y``, ``z``) or ``normal`` place the observer on that side (yt's projections);
        ``cell_domain`` treats voxels as cells (Enzo, yt).
        """
        vb = None
        if velocity_bins is not None:
            a, b, n = velocity_bins
            vb = [cv.as_float(a, "km/s", "velocity_bins"), cv.as_float(b, "km/s", "velocity_bins"), int(n)]
        wb = None if wavelength_bins is None else [float(wavelength_bins[0]), float(wavelength_bins[1]), int(wavelength_bins[2])]
        spec = {"line": line, "velocity_bins": vb, "wavelength_bins": wb, "spectral_axis": spectral_axis,
                "bunit": bunit, "world_unit": list(world_unit) if world_unit else None}
        o = dict(opts, thermal=thermal, line_sigma=line_sigma, masses=dict(masses) if masses else None)
        return Cube(self._native.cube(self._opts(width, height, o), json.dumps(spec)))

    def view(self, width: int = 256, height: int = 256, port: int = 0, save_dir: str = ".", **opts: Any) -> "Viewer":
        """Serves the interactive viewer on loopback; in Jupyter the result shows the page
        in an iframe. ``stop()`` ends it."""
        from ._view import Viewer

        return Viewer(_native.serve_doppler(self._native, self._opts(width, height, opts), port, save_dir))


def polyline(pieces: np.ndarray, rng: Tuple[float, float]) -> Tuple[np.ndarray, np.ndarray]:
    """The exact polyline of pieces ``(start, end, v0, v1)``: every piece's end points
    (a jump is two points at one wavelength), dropping to zero across gaps and at both
    ends. ``rng`` is the render's wavelength range (pieces may reach beyond it)."""
    xs: List[float] = []
    ys: List[float] = []
    prev = None
    for a, b, v0, v1 in np.asarray(pieces):
        if prev is None or a != prev:
            if prev is not None:
                xs.append(prev)
                ys.append(0.0)
            xs.append(a)
            ys.append(0.0)
        xs += [a, b]
        ys += [v0, v1]
        prev = b
    if prev is not None:
        xs.append(prev)
        ys.append(0.0)
    if not xs:
        xs, ys = [rng[0], rng[1]], [0.0, 0.0]
    return np.array(xs), np.array(ys)


class Render:
    """A Doppler image: ``xyz`` (float64 ``[h, w, 3]`` CIE XYZ, what the CLI's EXR holds),
    ``rgb`` (uint8 sRGB, the CLI's PNG) and the piece statistics."""

    def __init__(self, xyz: Image, rgb: Image, pieces: Dict[str, Any]) -> None:
        self.xyz = xyz
        self.rgb = rgb
        self.pieces = pieces

    def _repr_png_(self) -> bytes:
        return self.rgb._repr_png_()


class TraceStep:
    """One step of a traced ray: path position ``t`` (world units from the ray's entry),
    the radial velocity there (m/s) and the spectrum after the segment."""

    def __init__(self, t: float, radial_velocity: float, wavelengths: np.ndarray, values: np.ndarray) -> None:
        self.t = t
        self.radial_velocity = radial_velocity
        self.wavelengths = wavelengths
        self.values = values

    def __repr__(self) -> str:
        return f"TraceStep(t={self.t:.4g}, radial_velocity={self.radial_velocity:.4g} m/s, points={len(self.values)})"


class Cube:
    """A position-position-velocity cube.

    ``data`` is float32 indexed ``[x, y, v]`` (y = 0 at the bottom, as FITS and yt's
    PPVCube); ``velocities`` the channel centres (km/s; nm for a wavelength axis); ``wcs``
    the FITS header's keywords (CTYPE, CRVAL, CDELT, CRPIX, CUNIT, BUNIT...).
    """

    def __init__(self, native: Any) -> None:
        self._native = native
        self.data = native.data().transpose(2, 1, 0)
        c = np.array(native.centres())
        self.velocities = c / 1e3 if native.ctype != "WAVE" else c
        self.wavelengths_nm = np.array(native.centres_nm())
        self.wcs = dict(native.header())
        self.ctype = native.ctype

    def moments(self) -> Dict[str, np.ndarray]:
        """Moment maps ``m0`` (integrated line), ``m1`` (mean velocity) and ``m2``
        (dispersion), each float32 ``[x, y]``; velocities in km/s as ``velocities`` (nm for
        a wavelength axis). The FITS file and ``wcs`` keep the FITS unit, m/s."""
        m0, m1, m2 = self._native.moments()
        k = 1e-3 if self.ctype != "WAVE" else 1.0
        return {"m0": m0.T, "m1": m1.T * np.float32(k), "m2": m2.T * np.float32(k)}

    def to_fits(self, path: Union[str, "os.PathLike[str]"], overwrite: bool = False) -> None:
        """Writes the FITS file the CLI writes (atomically; no overwrite unless asked)."""
        self._native.to_fits(os.fspath(path), overwrite)

    def fits_bytes(self) -> bytes:
        return bytes(self._native.fits_bytes())

    def _repr_png_(self) -> bytes:
        m0 = self.moments()["m0"].T[::-1]
        top = float(np.nanmax(m0)) if np.any(np.isfinite(m0)) else 1.0
        g = np.clip(np.nan_to_num(m0 / (top or 1.0)), 0, 1)
        rgb = np.repeat((g[:, :, None] * 255).round().astype(np.uint8), 3, axis=2)
        return bytes(_native.png_bytes(np.ascontiguousarray(rgb)))
