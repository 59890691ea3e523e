"""blueshift: physically based scientific volume rendering from numpy, yt and Jupyter.

- :func:`render` / :func:`render_progressive`: Woodcock, multi-density Woodcock and the
  HDR marcher over volumes (:class:`Volume`) and transfer functions
  (:class:`TransferFunction`).
- :mod:`blueshift.doppler`: Doppler volume rendering (``Scene``: images, picked spectra,
  traces, spectral cubes); :func:`from_yt` builds scenes from yt datasets and
  ``blueshift.yt.BlueshiftSource`` renders them inside a yt ``Scene``.
- :mod:`blueshift.spectrum`: black bodies, lines, Doppler shifts, colours.
- :func:`tonemap`, :func:`read_hdr`; :mod:`blueshift.relativity` for a fast observer.
- :func:`view`: the interactive viewer, embedded in a notebook.

Arrays: volumes are indexed ``[x, y, z]``; images ``[row, column, channel]`` with row 0
at the top. Units: quantities (unyt/yt ``.units``, astropy ``.unit``) are converted;
plain numbers are in the library's units (SI: m/s, K; wavelengths nm). The GIL is
released during work and Ctrl-C cancels it; errors are :class:`BlueshiftError`.
"""

from . import _native
from ._core import (
    Image,
    TransferFunction,
    Volume,
    read_hdr,
    render,
    render_progressive,
    tonemap,
    tonemap_parameters,
)
from ._native import BlueshiftError, __version__
from . import doppler, relativity, spectrum
from ._view import Viewer


def from_yt(ds, fields, **kwargs):
    """A Doppler scene (or a Volume) from a yt dataset: see :func:`blueshift.yt.from_yt`."""
    from .yt import from_yt as f

    return f(ds, fields, **kwargs)


def view(obj=None, *, port=0, save_dir=".", **opts):
    """Serves the interactive viewer of ``obj`` on loopback and returns a :class:`Viewer`
    (an iframe in Jupyter). ``obj`` is a :class:`blueshift.doppler.Scene` (``opts``: its
    render options) or a tracking scene: a scene-file path or dict, or ``channels=`` /
    ``volume=`` / ``tf=`` as :func:`render` takes them."""
    from ._core import _scene_request

    if isinstance(obj, doppler.Scene):
        w = opts.pop("width", 256)
        h = opts.pop("height", 256)
        return obj.view(width=w, height=h, port=port, save_dir=save_dir, **opts)
    channels = opts.pop("channels", None)
    volume = opts.pop("volume", None)
    tf = opts.pop("tf", None)
    req = _scene_request(obj, channels, volume, tf, opts)
    return Viewer(_native.serve_tracking(*req, port=port, save_dir=save_dir))


__all__ = [
    "BlueshiftError",
    "Image",
    "TransferFunction",
    "Viewer",
    "Volume",
    "__version__",
    "doppler",
    "from_yt",
    "read_hdr",
    "relativity",
    "render",
    "render_progressive",
    "spectrum",
    "tonemap",
    "tonemap_parameters",
    "view",
]
