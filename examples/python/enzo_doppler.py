"""The Enzo Doppler figure from Python: the moving7 snapshot (DD0010, z = 9.99) as the
figures issue draws it with `blueshift doppler --scene scenes/enzo-moving7.json --figure`:
the Doppler picture (black body + H I and He I lines, bulk motion subtracted), the H-alpha
line-of-sight velocity (moment 1 of a spectral cube) and the spectra of two picked pixels.

    python examples/python/enzo_doppler.py [--out enzo_doppler.png] [--yt]

By default it reads the yt-resampled level-2 grids in ../shared/data/enzo-moving7 (64^3,
made with yt's covering_grid; see SOURCE.md) as numpy arrays with their units. With --yt
it loads the original AMR snapshot with yt (needs h5py) and resamples it the same way
through blueshift.from_yt. Needs matplotlib (yt brings it).
"""

import argparse
import os
import sys
from pathlib import Path

import numpy as np

import blueshift
from blueshift import doppler

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data" / "enzo-moving7"
MPC_H_CM = 3.0857e24 / 0.5  # the box: 1 Mpc/h comoving, h = 0.5


def scene_from_files() -> doppler.Scene:
    """The scene of scenes/enzo-moving7.json, built from numpy arrays with units."""
    import unyt

    def grid(name):
        return blueshift.Volume.read(DATA / name)

    rho = grid("density_gcm3_64x64x64_f32le.nhdr")
    temp = grid("temperature_K_64x64x64_f32le.nhdr")
    vel = grid("velocity_kms_64x64x64x3_f32le.nhdr")
    density = unyt.unyt_array(rho.array(), "g/cm**3")
    return doppler.Scene(
        velocity=unyt.unyt_array(vel.array(), "km/s"),
        temperature=unyt.unyt_array(temp.array(), "K"),
        blackbody={"density": density, "mass_fraction": 0.76, "scale": 1e9},
        species={"H I": {"density": density, "mass_fraction": 0.76, "lines": "H"},
                 "He I": {"density": density, "mass_fraction": 0.24, "lines": "He"}},
        spacing=rho.spacing,
        origin=rho.origin,
        subtract_mean_velocity=True,
    )


def scene_from_yt() -> doppler.Scene:
    """The same grid resampled by yt from the original AMR snapshot."""
    import yt

    ds = yt.load(str(DATA / "original" / "moving7_0010"))
    return blueshift.from_yt(
        ds,
        {"velocity": ("gas", "velocity"), "temperature": ("gas", "temperature"),
         "density": ("gas", "density"), "blackbody": ("gas", "density")},
        level=2,
        dims=(64, 64, 64),
        species={"H I": {"mass_fraction": 0.76, "lines": "H"}, "He I": {"mass_fraction": 0.24, "lines": "He"}},
        blackbody={"mass_fraction": 0.76, "scale": 1e9},
        subtract_mean_velocity=True,
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="enzo_doppler.png")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--yt", action="store_true", help="resample the original AMR snapshot with yt")
    args = ap.parse_args()
    if os.path.exists(args.out):
        print(f"{args.out} exists; not replacing it", file=sys.stderr)
        return 1
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scene = scene_from_yt() if args.yt else scene_from_files()
    n = args.size
    img = scene.render(width=n, height=n, cell_domain=True)
    cube = scene.cube(line="H-alpha", velocity_bins=(-120, 120, 48), axis="z", width=n, height=n, cell_domain=True)
    m = cube.moments()
    m0 = m["m0"]
    v1 = np.where(m0 > 0.01 * np.nanmax(m0), m["m1"], np.nan)  # km/s
    # Picks: the brightest pixel and the most receding bright one.
    lum = img.xyz[:, :, 1]
    bright = np.unravel_index(np.argmax(lum), lum.shape)
    vimg = v1.T[::-1]  # [row from the top, column]
    recede = np.unravel_index(np.nanargmax(np.where(lum > np.percentile(lum, 90), vimg, np.nan)), lum.shape)
    picks = [(int(bright[1]), int(bright[0])), (int(recede[1]), int(recede[0]))]

    fig, ax = plt.subplots(1, 3, figsize=(15, 4.8), dpi=120)
    box_mpc = 1.0 / 0.5  # comoving Mpc across the box
    extent = [0, box_mpc, 0, box_mpc]
    ax[0].imshow(img.rgb, extent=extent)
    ax[0].set_title("Doppler volume rendering (bb + H I + He I)")
    ax[0].set_xlabel("x (comoving Mpc)")
    ax[0].set_ylabel("y (comoving Mpc)")
    for k, (x, y) in enumerate(picks):
        ax[0].plot((x + 0.5) / n * box_mpc, box_mpc - (y + 0.5) / n * box_mpc, "o", mfc="none", mec="w")
        ax[0].annotate(str(k + 1), ((x + 0.5) / n * box_mpc, box_mpc - (y + 0.5) / n * box_mpc), color="w",
                       xytext=(4, 4), textcoords="offset points")
    lim = np.nanpercentile(np.abs(v1), 99) or 1.0
    im1 = ax[1].imshow(v1.T, origin="lower", cmap="RdBu_r", vmin=-lim, vmax=lim, extent=extent)
    ax[1].set_title("H-alpha line-of-sight velocity (moment 1)")
    ax[1].set_xlabel("x (comoving Mpc)")
    fig.colorbar(im1, ax=ax[1], label="v (km/s, receding > 0)")
    for k, (x, y) in enumerate(picks):
        w, v = scene.spectrum(x, y, width=n, height=n, cell_domain=True)
        ax[2].plot(w, v / (v.max() or 1.0), label=f"pixel {k + 1} ({x}, {y})")
    ax[2].set_xlim(380, 780)
    ax[2].set_xlabel("wavelength (nm)")
    ax[2].set_ylabel("spectral radiance (normalised)")
    ax[2].set_title("picked spectra")
    ax[2].legend()
    fig.suptitle("Enzo moving7 DD0010 (z = 9.99), level-2 grid 64$^3$, bulk motion subtracted")
    fig.tight_layout()
    tmp = args.out + ".tmp.png"
    fig.savefig(tmp)
    os.replace(tmp, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
