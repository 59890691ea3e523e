#!/usr/bin/env python3
"""References for rendering the Enzo snapshot from its AMR hierarchy (doppler/tests/amr.rs).

Usage:  python3 yt_amr_enzo.py [ENZO_PARAMETER_FILE] [OUT_DIR]
        (defaults: shared/data/enzo-moving7/original/moving7_0010 relative to the repo, and
        doppler/tests/reference/enzo_amr next to this script)
Needs:  pip install "yt>=4.4"  (made with yt 4.4.3, numpy 2.x, Python 3.11).

Writes, f32 little-endian, x fastest, y = 0 at the bottom:
  proj_density_30.f32  yt's projection of ("gas", "density") along z over the whole depth
                       (ds.proj, "integrate": exact path lengths through the AMR leaf cells),
                       averaged over each pixel's area (to_frb's antialiasing)
                       pixelised by to_frb over the whole domain, x, y in [0, 1], at 30 x 30
                       (each pixel the column at its centre), g/cm^2.
  clump_vz_8.f32       a line-of-sight integral through the level-7 clump: for each pixel
                       centre of an 8 x 8 window over x, y in [X0, X0 + 8/2048] (one level-7
                       cell per pixel), yt's ray from z = 0 to z = 1 gives the leaf cells it
                       crosses and their path fractions dts; numpy sums
                       <v_z> = sum(rho v_z dts) / sum(rho dts), km/s (peculiar, proper).
  clump_vz_level2_8.f32  the same integral through yt's level-2 covering grid (what the 64^3
                       resample holds): the clump's structure is gone there.
meta.json records the windows and versions.
"""
import json
import os
import sys

import numpy as np
import yt

HERE = os.path.dirname(os.path.abspath(__file__))
PARAM = sys.argv[1] if len(sys.argv) > 1 else os.path.join(
    HERE, "../../../../shared/data/enzo-moving7/original/moving7_0010")
OUT = sys.argv[2] if len(sys.argv) > 2 else os.path.join(HERE, "enzo_amr")
X0 = 0.74902343750  # the level-7 grid's left edge in x (and a cell boundary in y)
Y0 = 0.74902343750
N_CLUMP = 8
H7 = 1.0 / 2048.0
yt.set_log_level(40)
os.makedirs(OUT, exist_ok=True)
ds = yt.load(PARAM)

# 1. Projection.
proj = ds.proj(("gas", "density"), "z")
# yt's default (antialiased) buffer: each pixel the area average of the projected cells
# over it.
frb = proj.to_frb((1.0, "code_length"), (30, 30), center=(0.5, 0.5))
img = np.asarray(frb["gas", "density"].in_units("g/cm**2").v)  # [y][x], row 0 at the bottom
img.astype("<f4").tofile(os.path.join(OUT, "proj_density_30.f32"))

# 2. The clump's velocity centroid along z, leaf cells of the AMR hierarchy.
vz = np.zeros((N_CLUMP, N_CLUMP))
for j in range(N_CLUMP):
    for i in range(N_CLUMP):
        x = X0 + (i + 0.5) * H7
        y = Y0 + (j + 0.5) * H7
        ray = ds.ray([x, y, 0.0], [x, y, 1.0])
        rho = ray["gas", "density"].in_units("g/cm**3").v
        v = ray["gas", "velocity_z"].in_units("km/s").v
        dts = ray["dts"].v
        vz[j, i] = np.sum(rho * v * dts) / np.sum(rho * dts)
vz.astype("<f4").tofile(os.path.join(OUT, "clump_vz_8.f32"))

# 3. The same through the level-2 covering grid (64^3, what the derived files hold).
cg = ds.covering_grid(2, ds.domain_left_edge, [64, 64, 64])
rho2 = cg["gas", "density"].in_units("g/cm**3").v  # [x][y][z]
v2 = cg["gas", "velocity_z"].in_units("km/s").v
vz2 = np.zeros((N_CLUMP, N_CLUMP))
for j in range(N_CLUMP):
    for i in range(N_CLUMP):
        cx = int((X0 + (i + 0.5) * H7) * 64)
        cy = int((Y0 + (j + 0.5) * H7) * 64)
        r, w = rho2[cx, cy, :], v2[cx, cy, :]
        vz2[j, i] = np.sum(r * w) / np.sum(r)
vz2.astype("<f4").tofile(os.path.join(OUT, "clump_vz_level2_8.f32"))

meta = {
    "script": "doppler/tests/reference/yt_amr_enzo.py",
    "yt": yt.__version__,
    "numpy": np.__version__,
    "python": sys.version.split()[0],
    "input": "shared/data/enzo-moving7/original/moving7_0010 (Enzo AMR, 10 grids, levels 0-7)",
    "projection": {"file": "proj_density_30.f32", "field": "density", "axis": "z",
                   "window_code_length": [[0.0, 1.0], [0.0, 1.0]], "pixels": [30, 30],
                   "units": "g/cm**2", "sum": float(img.sum())},
    "clump": {"file": "clump_vz_8.f32", "level2_file": "clump_vz_level2_8.f32",
              "window_code_length": [[X0, X0 + N_CLUMP * H7], [Y0, Y0 + N_CLUMP * H7]],
              "pixels": [N_CLUMP, N_CLUMP], "units": "km/s",
              "std": float(vz.std()), "level2_std": float(vz2.std()),
              "mean": float(vz.mean())},
}
with open(os.path.join(OUT, "meta.json"), "w") as f:
    json.dump(meta, f, indent=1)
print(json.dumps(meta, indent=1))
