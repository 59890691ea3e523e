"""Spectra as algebra: black bodies, emission lines, Doppler shifts and their colours.

Wavelengths are in nm, values spectral radiance in W sr^-1 m^-2 nm^-1 (a line of relative
intensity r contributes r x ``line_strength`` W sr^-1 m^-2), velocities in m/s with
receding positive (quantities are converted).
"""

from __future__ import annotations

import json
from typing import Any, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _native
from . import _convert as cv


class Spectrum:
    """A spectrum over an observed wavelength range, exactly piecewise linear (what
    ``blueshift spectrum`` builds)."""

    def __init__(self, native: Any) -> None:
        self._native = native

    def xyz(self, observer: str = "1931") -> Tuple[float, float, float]:
        """CIE XYZ over the range (observer ``1931`` 2-degree or ``1964`` 10-degree)."""
        return self._native.xyz(observer)

    def xy(self, observer: str = "1931") -> Optional[Tuple[float, float]]:
        """Chromaticity ``(x, y)``; None when there is no light in the range."""
        x, y, z = self.xyz(observer)
        s = x + y + z
        return None if s <= 0 else (x / s, y / s)

    def srgb(self, display: bool = True, observer: str = "1931") -> Tuple[float, float, float]:
        """sRGB: with ``display``, Y normalised to 1, clipped and encoded (what the CLI
        prints as ``display sRGB``); else linear sRGB of XYZ."""
        return self._native.srgb(display, observer)

    def eval(self, wavelengths_nm: Any) -> np.ndarray:
        """Values at the wavelengths (nm; quantities converted)."""
        w = cv.to_unit(wavelengths_nm, "nm", "wavelengths_nm")
        a = np.ascontiguousarray(np.atleast_1d(w), dtype=np.float64).ravel()
        return self._native.eval(a)

    def integral(self, lo: Optional[float] = None, hi: Optional[float] = None) -> float:
        """The integral over ``[lo, hi]`` nm (default the range), W sr^-1 m^-2."""
        return self._native.integral(lo, hi)

    def pieces(self) -> np.ndarray:
        """float64 ``[n, 4]`` rows ``(start_nm, end_nm, value_start, value_end)``."""
        return self._native.pieces()

    def polyline(self) -> Tuple[np.ndarray, np.ndarray]:
        """``(wavelengths_nm, values)`` whose linear interpolation is the spectrum."""
        from .doppler import polyline

        return polyline(self.pieces(), self.range)

    @property
    def range(self) -> Tuple[float, float]:
        return self._native.range

    @property
    def shift(self) -> float:
        """The wavelength ratio s = lambda_obs / lambda_emit applied."""
        return self._native.shift

    @property
    def observed_temperature_k(self) -> Optional[float]:
        """With ``radiometric="invariant"``: the shifted black body's temperature T / s."""
        return self._native.observed_temperature_k

    def _repr_png_(self) -> Optional[bytes]:
        try:
            import io

            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
        except Exception:
            return None
        w, v = self.polyline()
        fig, ax = plt.subplots(figsize=(6, 3), dpi=100)
        ax.plot(w, v, color=np.clip(self.srgb(), 0, 1) if max(self.srgb()) > 0 else "k")
        ax.set_xlabel("wavelength (nm)")
        ax.set_ylabel("W sr$^{-1}$ m$^{-2}$ nm$^{-1}$")
        buf = io.BytesIO()
        fig.tight_layout()
        fig.savefig(buf, format="png")
        plt.close(fig)
        return buf.getvalue()


def build(
    blackbody: Any = None,
    lines: Union[None, str, Sequence[str]] = None,
    line_table: Optional[Sequence[Sequence[float]]] = None,
    line_strength: float = 1.0,
    line_width: float = 1.0,
    line_profile: str = "box",
    shift: Optional[float] = None,
    radial_velocity: Any = None,
    doppler: str = "classical",
    radiometric: str = "none",
    range: Tuple[float, float] = (360.0, 830.0),
    max_error: float = 1e-4,
) -> Spectrum:
    """A spectrum as ``blueshift spectrum`` builds it from the same flags: a black body of
    ``blackbody`` K and/or catalogue ``lines`` (``"H"``, ``"He"``, ``"C"``) or a
    ``line_table`` of ``(nm, relative_intensity)`` rows, then a shift ``s`` or a
    ``radial_velocity`` (m/s) with ``doppler`` ``classical`` or ``relativistic``;
    ``radiometric="invariant"`` applies I_nu / nu^3 invariance."""
    recipe = {
        "blackbody": None if blackbody is None else cv.as_float(blackbody, "K", "blackbody"),
        "lines": cv.names(lines),
        "line_table": None if line_table is None else [[float(a), float(b)] for a, b in line_table],
        "line_strength": float(line_strength),
        "line_width": float(line_width),
        "line_profile": line_profile,
        "shift": None if shift is None else float(shift),
        "radial_velocity": None if radial_velocity is None else cv.as_float(radial_velocity, "m/s", "radial_velocity"),
        "doppler": doppler,
        "radiometric": radiometric,
        "range": [float(range[0]), float(range[1])],
        "max_error": float(max_error),
    }
    return Spectrum(_native.Spectrum.build(json.dumps({k: v for k, v in recipe.items() if v is not None})))


def blackbody(t_kelvin: Any, range: Tuple[float, float] = (360.0, 830.0), max_error: float = 1e-4) -> Spectrum:
    """A black body of temperature ``t_kelvin`` (K; quantities converted) as a
    piecewise-linear spectrum within ``max_error`` relative error."""
    return build(blackbody=t_kelvin, range=range, max_error=max_error)


def doppler_shift(radial_velocity: Any, model: str = "classical") -> float:
    """The wavelength ratio s = lambda_obs / lambda_emit of a radial velocity (m/s,
    positive receding): ``1 + v/c`` (classical) or ``sqrt((1 + beta) / (1 - beta))``."""
    return _native.doppler_shift(cv.as_float(radial_velocity, "m/s", "radial_velocity"), model)


def catalogue(name: str) -> List[Tuple[float, float]]:
    """A built-in line catalogue (``H`` Balmer, ``He`` He I, ``C`` C I):
    ``(wavelength_nm, relative_intensity)`` rows."""
    return _native.catalogue(name)


lines = catalogue
