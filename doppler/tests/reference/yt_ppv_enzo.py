#!/usr/bin/env python3
"""Reference position-position-velocity cubes of the Enzo snapshot made with yt's PPVCube.

Usage:  python3 yt_ppv_enzo.py [DATA_DIR] [OUT_DIR]
        (defaults: ../../../../shared/data/enzo-moving7 relative to the repo, and
        doppler/tests/reference/enzo_ppv next to this script)
Needs:  pip install "yt==4.4.*" "yt-astro-analysis==1.1.*"  (made with yt 4.4.3,
        yt_astro_analysis 1.1.4, numpy 2.4.6, Python 3.11).

Input: the derived uniform 64^3 grid of DD0010 (shared/data/enzo-moving7/*.raw, made by yt
4.4.3's covering_grid at level 2; see its SOURCE.md), cropped to the octant holding the
collapsing clump, cells [32, 64)^3 = code lengths [0.5, 1)^3, loaded with
yt.load_uniform_grid (cell-centred, length unit 1 code length = 5.6149e23 cm). The crop is
written to OUT_DIR (raw f32 little-endian, x fastest; velocity interleaved vx,vy,vz in km/s)
so the Rust test runs without the shared data.

Cubes (32 x 32 pixels = one cell each, 16 channels over v_los = -260..-140 km/s, normal
"z": yt's v_los = -v_z, the observer at +z), field ("gas", "density"), method "integrate":
  yt_thermal_off.f32   PPVCube(thermal_broad=False): tent weights 1 - |v_c - v_los| / dv
  yt_thermal_on.f32    PPVCube(thermal_broad=True, atomic_weight=1 -> m = 1.007947 u):
                       weights dv * Gaussian(v_c - v_los) sampled at the channel centre
  yt_thermal_on_erf.f32  the same projection with the Gaussian integrated EXACTLY over each
                       channel (erf differences) instead of sampled at its centre
Each cube is f32 little-endian, [channel][y][x] (y = 0 at the bottom), in g cm^-2.
meta.json records the versions, bins, units and sums.
"""
import json
import math
import os
import sys

import numpy as np
import yt
import yt_astro_analysis
from yt_astro_analysis.ppv_cube.api import PPVCube
from yt.utilities.physical_constants import kboltz, mh

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "../../../../shared/data/enzo-moving7")
OUT = sys.argv[2] if len(sys.argv) > 2 else os.path.join(HERE, "enzo_ppv")
N = 64
LO, HI = 32, 64
CODE_LENGTH_CM = 5.6149e23
VMIN, VMAX, NV = -260.0, -140.0, 16
yt.set_log_level(40)


def load(name, comps=1):
    a = np.fromfile(os.path.join(DATA, name), "<f4")
    a = a.reshape((N, N, N, comps)) if comps > 1 else a.reshape((N, N, N))
    return a[LO:HI, LO:HI, LO:HI]  # [z][y][x]


rho = load("density_gcm3_64x64x64_f32le.raw")
temp = load("temperature_K_64x64x64_f32le.raw")
vel = load("velocity_kms_64x64x64x3_f32le.raw", 3)
os.makedirs(OUT, exist_ok=True)
rho.astype("<f4").tofile(os.path.join(OUT, "crop_density_gcm3_32x32x32.f32"))
temp.astype("<f4").tofile(os.path.join(OUT, "crop_temperature_K_32x32x32.f32"))
vel.astype("<f4").tofile(os.path.join(OUT, "crop_velocity_kms_32x32x32x3.f32"))

# yt wants arrays indexed [x][y][z].
t = lambda a: np.ascontiguousarray(np.transpose(a, (2, 1, 0))).astype("f8")
data = {
    ("gas", "density"): (t(rho), "g/cm**3"),
    ("gas", "temperature"): (t(temp), "K"),
    ("gas", "velocity_x"): (t(vel[..., 0]), "km/s"),
    ("gas", "velocity_y"): (t(vel[..., 1]), "km/s"),
    ("gas", "velocity_z"): (t(vel[..., 2]), "km/s"),
}
bbox = np.array([[0.5, 1.0]] * 3)
ds = yt.load_uniform_grid(data, (32, 32, 32), length_unit=(CODE_LENGTH_CM, "cm"), bbox=bbox, nprocs=1)


class ExactPPV(PPVCube):
    """PPVCube with the thermal Gaussian integrated over each channel (erf)."""

    def _create_intensity(self):
        erf = np.frompyfunc(math.erf, 1, 1)

        def _intensity(field, data):
            v = data["gas", "v_los"].in_cgs().v
            T = data["gas", "temperature"].in_cgs().v
            s = np.sqrt(kboltz.v * T / self.particle_mass.in_cgs().v)  # sigma, cm/s
            lo = self.current_v - 0.5 * self.dv_cgs
            hi = self.current_v + 0.5 * self.dv_cgs
            z = np.sqrt(2.0) * s
            w = 0.5 * (erf((hi - v) / z).astype("f8") - erf((lo - v) / z).astype("f8"))
            return data[self.field] * w

        return _intensity


meta = {
    "script": "doppler/tests/reference/yt_ppv_enzo.py",
    "yt": yt.__version__,
    "yt_astro_analysis": yt_astro_analysis.__version__,
    "numpy": np.__version__,
    "python": sys.version.split()[0],
    "input": "shared/data/enzo-moving7 derived 64^3 uniform grid, cells [32,64)^3 ([z][y][x] order in the files)",
    "crop_files": {
        "density": "crop_density_gcm3_32x32x32.f32",
        "temperature": "crop_temperature_K_32x32x32.f32",
        "velocity": "crop_velocity_kms_32x32x32x3.f32",
    },
    "code_length_cm": CODE_LENGTH_CM,
    "normal": "z",
    "field": "density",
    "velocity_bins_kms": [VMIN, VMAX, NV],
    "pixels": [32, 32],
    "atomic_weight": 1.0,
    "particle_mass_amu": float(mh.to("amu").v),
    "units": "g/cm**2",
    "layout": "f32 little-endian [channel][y][x], y = 0 at the bottom",
    "cubes": {},
}
for name, cls, thermal in [
    ("yt_thermal_off", PPVCube, False),
    ("yt_thermal_on", PPVCube, True),
    ("yt_thermal_on_erf", ExactPPV, True),
]:
    cube = cls(ds, "z", ("gas", "density"), (VMIN, VMAX, NV, "km/s"), dims=32, thermal_broad=thermal, atomic_weight=1.0)
    a = np.asarray(cube.data.in_units("g/cm**2").v)  # [x][y][v]
    out = np.ascontiguousarray(np.transpose(a, (2, 1, 0))).astype("<f4")
    out.tofile(os.path.join(OUT, name + ".f32"))
    meta["cubes"][name] = {"file": name + ".f32", "sum": float(a.sum()), "max": float(a.max())}
    print(name, out.shape, "sum", a.sum(), "max", a.max())
# The unbroadened projection (moment 0 truth): sum of rho dz over cells.
proj = (rho.astype("f8").sum(axis=0) * (0.5 / 32) * CODE_LENGTH_CM)
meta["projected_density_sum_gcm2"] = float(proj.sum())
with open(os.path.join(OUT, "meta.json"), "w") as f:
    json.dump(meta, f, indent=1)
print("projected density sum", proj.sum())
