#!/usr/bin/env python3
"""Opens a blueshift spectral cube with astropy and checks its WCS.

Usage: python3 check_fits_astropy.py CUBE.fits VMIN_KMS VMAX_KMS NCHAN [vrad|vopt]
(or WAVE cubes: ... MIN_NM MAX_NM NCHAN wave). Needs astropy (pip install astropy).
Checks: the primary HDU is 3-D (NAXIS3 = NCHAN), the spectral axis type, that every
channel centre maps through astropy.wcs to the expected velocity (or wavelength) within
1e-6 of a channel, that the sky axes are centred (pixel centre -> offset 0), that the data
are finite, and that the NRRD next to the cube holds the same numbers. Exit 0 on success.
"""
import os
import sys

import numpy as np
from astropy.io import fits
from astropy.wcs import WCS

path, lo, hi, n = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
kind = sys.argv[5] if len(sys.argv) > 5 else "vrad"
with fits.open(path) as hdul:
    hdul.verify("exception")
    h = hdul[0].header
    data = hdul[0].data
w = WCS(h)
assert h["NAXIS"] == 3 and h["NAXIS3"] == n, (h["NAXIS"], h["NAXIS3"])
assert data.shape == (n, h["NAXIS2"], h["NAXIS1"]), data.shape
assert np.isfinite(data).all()
want_type = {"vrad": "VRAD", "vopt": "VOPT", "wave": "WAVE"}[kind]
assert w.wcs.ctype[2].startswith(want_type), w.wcs.ctype
scale = 1e-9 if kind == "wave" else 1e3  # astropy reports SI: m or m/s
edges = np.linspace(lo, hi, n + 1)
centres = 0.5 * (edges[1:] + edges[:-1]) * scale
nx, ny = h["NAXIS1"], h["NAXIS2"]
pix = np.array([[(nx - 1) / 2, (ny - 1) / 2, k] for k in range(n)], dtype=float)
world = w.all_pix2world(pix, 0)
dv = (hi - lo) / n * scale
assert np.allclose(world[:, 2], centres, rtol=0, atol=1e-6 * dv), (world[:, 2], centres)
assert np.allclose(world[:, :2], 0.0, atol=1e-9 * max(abs(h["CDELT1"]), 1.0)), world[:, :2]
nrrd = os.path.splitext(path)[0] + ".nrrd"
if os.path.exists(nrrd):
    raw = open(nrrd, "rb").read()
    body = raw[raw.index(b"\n\n") + 2:]
    a = np.frombuffer(body, "<f4").reshape(data.shape)
    assert np.array_equal(a, data.astype("<f4")), "NRRD differs from FITS"
print(f"OK {path}: {data.shape[::-1]} {w.wcs.ctype[2]} channel centres {world[0, 2]:.6g}..{world[-1, 2]:.6g} {w.wcs.cunit[2]}, sum {float(data.sum()):.6g}")
