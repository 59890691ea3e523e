"""Units, dtypes and layouts at the boundary.

Units are duck-typed: an argument with ``.units`` (unyt, yt) or ``.unit`` (astropy) is
converted with its own ``.to(...)``; neither package is imported here. Plain numbers and
arrays are taken to be in the library's units (SI: m, m/s, K), as each docstring says.
"""

from __future__ import annotations

import numbers
from typing import Any, Optional, Sequence, Tuple

import numpy as np

# The library's unit of each quantity kind, spelt for unyt and for astropy.
_SPELLING = {
    "m/s": ("m/s", "m / s"),
    "km/s": ("km/s", "km / s"),
    "K": ("K", "K"),
    "g/cm3": ("g/cm**3", "g / cm3"),
    "cm-3": ("cm**-3", "1 / cm3"),
    "nm": ("nm", "nm"),
    "cm": ("cm", "cm"),
}


def is_quantity(x: Any) -> bool:
    """Whether ``x`` carries units (unyt/yt ``.units`` or astropy ``.unit``)."""
    return hasattr(x, "units") or (hasattr(x, "unit") and hasattr(x, "to"))


def unit_name(x: Any) -> Optional[str]:
    """The unit of a quantity as text, or None for a plain number or array."""
    if hasattr(x, "units"):
        return str(x.units)
    if hasattr(x, "unit") and hasattr(x, "to"):
        return str(x.unit)
    return None


def to_unit(x: Any, unit: str, name: str) -> Any:
    """``x`` in ``unit`` (one of the library's names above) as a float64 numpy value.

    A quantity is converted with its own ``.to``; a plain value is returned as it is (it
    is already in the library's unit). A quantity of the wrong dimension raises
    ``TypeError`` naming the argument.
    """
    if not is_quantity(x):
        return np.asarray(x, dtype=np.float64) if not isinstance(x, numbers.Number) else float(x)
    unyt_name, astropy_name = _SPELLING[unit]
    target = unyt_name if hasattr(x, "units") else astropy_name
    try:
        y = x.to(target)
    except Exception as e:  # unyt raises UnitConversionError, astropy UnitConversionError
        raise TypeError(f"{name}: cannot convert {unit_name(x)} to {unit} ({e})") from None
    v = getattr(y, "value", None)
    if v is None:
        v = getattr(y, "d", y)
    v = np.asarray(v, dtype=np.float64)
    return float(v) if v.ndim == 0 else v


def converts_to(x: Any, unit: str) -> bool:
    """Whether quantity ``x`` converts to ``unit``."""
    try:
        to_unit(x, unit, "x")
        return True
    except TypeError:
        return False


def as_float(x: Any, unit: str, name: str) -> float:
    """A scalar in ``unit``, finite."""
    v = to_unit(x, unit, name)
    v = float(np.asarray(v))
    if not np.isfinite(v):
        raise ValueError(f"{name} = {v}: must be finite")
    return v


def triple(x: Any, name: str, unit: Optional[str] = None) -> Tuple[float, float, float]:
    """Three finite numbers (a scalar is repeated)."""
    v = to_unit(x, unit, name) if unit else x
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.size != 3 or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} {x!r}: expected three finite numbers")
    return (float(a[0]), float(a[1]), float(a[2]))


def field(a: Any, name: str, vector: bool = False, finite: bool = True) -> np.ndarray:
    """A field indexed ``[x, y, z]`` (``[x, y, z, 3]`` for vectors) as the C-contiguous
    float32 ``[z, y, x]`` array the native module takes (x fastest in memory).

    float64, integer, non-contiguous and C-ordered inputs are converted; a Fortran-ordered
    float32 input needs no conversion (it is viewed, not copied, here; the native side
    copies it once into its grid). Complex, object or string arrays, a wrong number
    of dimensions, and empty arrays raise ``TypeError``/``ValueError`` naming the array;
    with ``finite``, so do NaN and infinite values.
    """
    arr = np.asarray(getattr(a, "value", a) if hasattr(a, "unit") and not hasattr(a, "units") else a)
    if arr.dtype.kind not in "fiub":
        raise TypeError(
            f"array '{name}': dtype {arr.dtype} is not a real number type "
            f"(shape {arr.shape}, strides {arr.strides})"
        )
    want = 4 if vector else 3
    if arr.ndim != want or (vector and arr.shape[3] != 3):
        shape = "[nx, ny, nz, 3]" if vector else "[nx, ny, nz]"
        raise ValueError(f"array '{name}': shape {arr.shape}; expected {shape} (indexed [x, y, z])")
    if arr.size == 0:
        raise ValueError(f"array '{name}': shape {arr.shape} has no voxels")
    if vector:
        out = np.ascontiguousarray(arr.transpose(2, 1, 0, 3), dtype=np.float32)
    else:
        out = np.ascontiguousarray(arr.T, dtype=np.float32)
    if finite and not np.all(np.isfinite(out)):
        bad = int(np.size(out) - np.count_nonzero(np.isfinite(out)))
        raise ValueError(f"array '{name}': {bad} values are NaN or infinite (after conversion to float32)")
    return out


def rgb(a: Any, name: str) -> np.ndarray:
    """An image as a C-contiguous float32 ``[h, w, 3]`` array (RGBA: alpha dropped)."""
    arr = np.asarray(a)
    if arr.dtype.kind not in "fiu":
        raise TypeError(f"{name}: dtype {arr.dtype} is not a real number type")
    if arr.ndim != 3 or arr.shape[2] not in (3, 4):
        raise ValueError(f"{name}: shape {arr.shape}; expected [height, width, 3] (or 4)")
    return np.ascontiguousarray(arr[:, :, :3], dtype=np.float32)


def names(x: Optional[Sequence[str]]) -> Optional[list]:
    if x is None:
        return None
    if isinstance(x, str):
        return [t.strip() for t in x.split(",") if t.strip()]
    return list(x)
