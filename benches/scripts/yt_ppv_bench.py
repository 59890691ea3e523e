#!/usr/bin/env python3
"""Times yt's PPVCube on the data of the blueshift cube bench (benches/benches/doppler_cube.rs).

Usage: python3 yt_ppv_bench.py ENZO_DIR GALAXY.nrrd
  ENZO_DIR: shared/data/enzo-moving7 (the derived 64^3 uniform grid, loaded with
            yt.load_uniform_grid as cells of 1/64 code length);
  GALAXY.nrrd: `blueshift synth galaxy --res 128 GALAXY.nrrd` (128 x 128 x 64 voxels, its
            channels hi_density, temperature_k, velocity_m_per_s beside it), loaded as cells.
Cubes: 256 x 256 pixels x 128 channels, field density, method integrate, single process.
Enzo: normal "z", v_los -350..-150 km/s. Galaxy: normal "x" (edge-on), -300..300 km/s.
Prints one line per case: name, thermal, seconds (best of 2 runs).
Made with yt 4.4.3, yt_astro_analysis 1.1.4, numpy 2.4.6, Python 3.11.
"""
import os
import sys
import time

import numpy as np
import yt
from yt_astro_analysis.ppv_cube.api import PPVCube

yt.set_log_level(40)
enzo, galaxy = sys.argv[1], sys.argv[2]


def t(a):  # [z][y][x] -> [x][y][z]
    return np.ascontiguousarray(np.transpose(a, (2, 1, 0))).astype("f8")


def raw(path, shape):
    return np.fromfile(path, "<f4").reshape(shape)


def nrrd(path):
    b = open(path, "rb").read()
    i = b.index(b"\n\n")
    head = b[:i].decode()
    sizes = [int(x) for x in head.split("sizes:")[1].split("\n")[0].split()]
    a = np.frombuffer(b[i + 2:], "<f4")
    return a.reshape(sizes[::-1]), head


n = 64
rho = raw(os.path.join(enzo, "density_gcm3_64x64x64_f32le.raw"), (n, n, n))
T = raw(os.path.join(enzo, "temperature_K_64x64x64_f32le.raw"), (n, n, n))
v = raw(os.path.join(enzo, "velocity_kms_64x64x64x3_f32le.raw"), (n, n, n, 3))
ds_enzo = yt.load_uniform_grid(
    {
        ("gas", "density"): (t(rho), "g/cm**3"),
        ("gas", "temperature"): (t(T), "K"),
        ("gas", "velocity_x"): (t(v[..., 0]), "km/s"),
        ("gas", "velocity_y"): (t(v[..., 1]), "km/s"),
        ("gas", "velocity_z"): (t(v[..., 2]), "km/s"),
    },
    (n, n, n),
    length_unit=(5.6149e23, "cm"),
    nprocs=1,
)
stem = os.path.splitext(galaxy)[0]
g_rho, head = nrrd(galaxy)
g_t, _ = nrrd(stem + "_temperature_k.nrrd")
g_v, _ = nrrd(stem + "_velocity_m_per_s.nrrd")
nz, ny, nx = g_rho.shape
ds_gal = yt.load_uniform_grid(
    {
        ("gas", "density"): (t(g_rho), "g/cm**3"),
        ("gas", "temperature"): (t(g_t), "K"),
        ("gas", "velocity_x"): (t(g_v[..., 0]), "m/s"),
        ("gas", "velocity_y"): (t(g_v[..., 1]), "m/s"),
        ("gas", "velocity_z"): (t(g_v[..., 2]), "m/s"),
    },
    (nx, ny, nz),
    length_unit=(1.0, "kpc"),
    bbox=np.array([[0, nx], [0, ny], [0, nz]], dtype=float),
    nprocs=1,
)
for name, ds, normal, bins in [
    ("enzo64", ds_enzo, "z", (-350.0, -150.0, 128, "km/s")),
    ("galaxy128", ds_gal, "x", (-300.0, 300.0, 128, "km/s")),
]:
    for thermal in (False, True):
        best = 1e30
        for _ in range(2):
            t0 = time.perf_counter()
            PPVCube(ds, normal, ("gas", "density"), bins, dims=256, thermal_broad=thermal, atomic_weight=1.0)
            best = min(best, time.perf_counter() - t0)
        print(f"{name} thermal={thermal} {best:.3f} s", flush=True)
