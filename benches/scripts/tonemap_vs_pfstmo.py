#!/usr/bin/env python3
"""Structure of blueshift's Durand and Fattal against pfstmo: luminance SSIM after
histogram matching (issue 19 item 15).

For each image, the HDR input is cleaned once by blueshift (the dirty-input rule: NaN and
negatives -> 0) and the same pixels go to pfstmo and to each blueshift build, so only the
operators differ. Both outputs are reduced to display luminance (Rec. 709 weights,
clamped to [0, 1], gamma 1/2.2); blueshift's is then histogram-matched to pfstmo's
(skimage.exposure.match_histograms), which removes any global tone curve difference
(exposure, contrast, white point) and leaves the spatial structure, and the SSIM of the
two is reported (skimage structural_similarity, data_range 1). The raw SSIM (no matching)
and a low-frequency figure (RMS of the matched difference blurred with sigma 16 px: a glow
or a wash shows up here) are reported too.

pfstmo runs with the paper settings expressed in its own units (see
tonemap/peers/RESULTS.md): durand02 --sigma-s 2 % of the larger side, --sigma-r 0.4 ln 10,
--base-contrast ln 5, --original; fattal02 --alpha 0.1 --beta 0.85 --saturation 0.5
--gamma 1 --detail-level 0. blueshift runs at its defaults, which are the same settings.

Needs: pfstools (apt-get install pfstools), numpy, scipy, scikit-image (pip), and one or
more builds of the example `tonemap/examples/1_tonemap_file.rs`:

    cargo build --release -p blueshift-tonemap --example 1_tonemap_file
    python3 benches/scripts/tonemap_vs_pfstmo.py \\
        --bin before=/tmp/1_tonemap_file.before --bin after=target/release/examples/1_tonemap_file \\
        [--data ../shared/data] [--extra]

Images: the four photographs of shared/data (hdr-photos/Desk.exr, MtTamWest.exr,
memorial.hdr and envmap-polyhaven/venice_sunset_1k.hdr) and one synthetic image (1024^2:
gradients, texture and a disc 500x brighter, tinted); --extra adds the two other HDR
environment maps (satara_night_1k.hdr, envmap-kerner/KernerEnvLatLong.exr).
"""
import argparse
import math
import os
import subprocess
import sys
import tempfile

import numpy as np


def read_pfm(path):
    with open(path, "rb") as f:
        magic = f.readline().strip()
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        ch = 3 if magic == b"PF" else 1
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    return np.flipud(data[: w * h * ch].reshape(h, w, ch)).astype(np.float64)


def write_pfm(path, img):
    h, w, _ = img.shape
    with open(path, "wb") as f:
        f.write(b"PF\n%d %d\n-1.0\n" % (w, h))
        f.write(np.flipud(img).astype("<f4").tobytes())


def display_luminance(img):
    y = 0.2126 * img[..., 0] + 0.7152 * img[..., 1] + 0.0722 * img[..., 2]
    y = np.nan_to_num(y, nan=0.0, posinf=1.0, neginf=0.0)
    return np.clip(y, 0.0, 1.0) ** (1 / 2.2)


def synthetic(w=1024, h=1024, seed=1):
    """The synthetic scene of tonemap/peers/compare.py."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / max(w, h)
    lum = 0.01 + 2.0 * x * y + 0.2 * np.abs(np.sin(20 * x)) + 0.05 * np.sin(60 * y) ** 2
    lum[(x - 0.7) ** 2 + (y - 0.3) ** 2 < 0.004] += 500.0
    lum *= 1 + 0.1 * rng.random(lum.shape)
    return np.stack([1.1 * lum, lum, 0.8 * lum], axis=2)


def pfstmo(op, pfm_in, pfm_out, sigma_s):
    if op == "durand":
        cmd = ["pfstmo_durand02", "--sigma-s", f"{sigma_s:.3f}",
               "--sigma-r", f"{0.4 * math.log(10):.6f}",
               "--base-contrast", f"{math.log(5):.6f}", "--original"]
    else:
        cmd = ["pfstmo_fattal02", "--alpha", "0.1", "--beta", "0.85", "--saturation", "0.5",
               "--gamma", "1", "--detail-level", "0"]
    pin = subprocess.run(["pfsinpfm", pfm_in], check=True, capture_output=True).stdout
    mapped = subprocess.run(cmd, input=pin, check=True, capture_output=True).stdout
    subprocess.run(["pfsoutpfm", pfm_out], input=mapped, check=True, capture_output=True)


def compare(y_b, y_p):
    from scipy.ndimage import gaussian_filter
    from skimage.exposure import match_histograms
    from skimage.metrics import structural_similarity as ssim
    matched = match_histograms(y_b, y_p)
    low = gaussian_filter(matched - y_p, 16)
    return (ssim(matched, y_p, data_range=1.0), ssim(y_b, y_p, data_range=1.0),
            float(np.sqrt(np.mean(low ** 2))))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bin", action="append", required=True,
                    help="LABEL=PATH of a 1_tonemap_file build (repeatable)")
    ap.add_argument("--data", default=os.path.join(os.path.dirname(__file__), "../../../shared/data"))
    ap.add_argument("--extra", action="store_true")
    ap.add_argument("--ops", default="durand,fattal")
    a = ap.parse_args()
    bins = [b.split("=", 1) for b in a.bin]
    # The cleaning step needs the `clean` mode of the example: the last build has it.
    cleaner = bins[-1][1]
    photos = ["hdr-photos/Desk.exr", "hdr-photos/MtTamWest.exr", "hdr-photos/memorial.hdr",
              "envmap-polyhaven/venice_sunset_1k.hdr"]
    if a.extra:
        photos += ["envmap-polyhaven/satara_night_1k.hdr", "envmap-kerner/KernerEnvLatLong.exr"]
    tmp = tempfile.mkdtemp(prefix="tonemap-vs-pfstmo-")
    images = [(os.path.basename(p), os.path.join(a.data, p)) for p in photos]
    syn = os.path.join(tmp, "synthetic.pfm")
    write_pfm(syn, synthetic())
    images.append(("synthetic 1024x1024", syn))

    labels = [l for l, _ in bins]
    head = ["image", "operator"] + [f"SSIM matched {l}" for l in labels] \
        + [f"SSIM raw {l}" for l in labels] + [f"low-freq RMS {l}" for l in labels]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for name, path in images:
        if not os.path.exists(path):
            print(f"| {name} | missing: {path} |", flush=True)
            continue
        clean = os.path.join(tmp, "in.pfm")
        subprocess.run([cleaner, path, clean, "clean"], check=True)
        h, w = read_pfm(clean).shape[:2]
        for op in a.ops.split(","):
            ref = os.path.join(tmp, "pfstmo.pfm")
            pfstmo(op, clean, ref, 0.02 * max(w, h))
            y_p = display_luminance(read_pfm(ref))
            rows = []
            for label, exe in bins:
                out = os.path.join(tmp, f"{label}.pfm")
                subprocess.run([exe, clean, out, op], check=True)
                rows.append(compare(display_luminance(read_pfm(out)), y_p))
            cells = [f"{r[0]:.4f}" for r in rows] + [f"{r[1]:.4f}" for r in rows] \
                + [f"{r[2]:.4f}" for r in rows]
            print(f"| {name} | {op} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
