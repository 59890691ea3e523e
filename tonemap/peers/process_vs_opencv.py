#!/usr/bin/env python3
"""Issue 24 item 1: the whole `blueshift tonemap` process (start, read, tone map, PNG
written) against OpenCV's operator alone, in process, on an image already read.

Needs the `blueshift` binary (cargo build --release -p blueshift-cli) and PyPI
`opencv-python-headless` and `numpy` (and PyPI `OpenEXR` for the EXR formats). Writes a
3840x2160 image (`exp(6 sin(x/400) cos(y/300))` per pixel with small per-channel
modulations): a Radiance file with `cv2.imwrite` (`--formats hdr`, the default), or a
half-float OpenEXR file with OpenEXR's own writer in PIZ, ZIP (16 lines), ZIPS (1 line) or
no compression (`exr-piz`, `exr-zip`, `exr-zips`, `exr-none`), or a float32 one (the same
names ending in `32`: `exr-zip32`, ...), scan lines or, with `-tiled` after the name
(`exr-piz-tiled`, `exr-piz32-tiled`), 64x64 tiles. Then runs both interleaved,
`--rounds` times each, 2 threads for both, and prints the medians and their ratio. OpenCV
runs on the same pixels (as float32, BGR). Usage:

    python3 tonemap/peers/process_vs_opencv.py [--blueshift target/release/blueshift]
        [--rounds 9] [--ops drago,reinhard]
        [--formats hdr,exr-piz,exr-zip,exr-zips,exr-none,exr-zip32,exr-piz32,exr-piz-tiled]
"""
import argparse, os, statistics, subprocess, tempfile, time

import cv2
import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--blueshift", default="target/release/blueshift")
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--ops", default="drago,reinhard")
    ap.add_argument("--formats", default="hdr")
    a = ap.parse_args()
    cv2.setNumThreads(2)
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "big.hdr")
        w, h = 3840, 2160
        x = np.arange(w)[None, :].astype(np.float32)
        y = np.arange(h)[:, None].astype(np.float32)
        base = np.exp(6 * np.sin(x / 400) * np.cos(y / 300))
        img = np.stack(
            [
                base * (1 + 0.05 * np.sin(x / 37)),
                base * (1 + 0.05 * np.cos(y / 53)),
                base * (1 + 0.03 * np.sin((x + y) / 71)),
            ],
            axis=-1,
        ).astype(np.float32)
        cv2.imwrite(path, img)
        paths = {"hdr": path}
        for fmt in a.formats.split(","):
            if fmt.startswith("exr-"):
                import OpenEXR

                tiled = fmt.endswith("-tiled")
                name = fmt.removesuffix("-tiled")
                f32 = name.endswith("32")
                kind = name[4:-2] if f32 else name[4:]
                comp = {"piz": "PIZ", "zip": "ZIP", "zips": "ZIPS", "none": "NO"}[kind]
                p = os.path.join(d, f"big_{fmt}.exr")
                header = {
                    "compression": getattr(OpenEXR, comp + "_COMPRESSION"),
                    "type": OpenEXR.tiledimage if tiled else OpenEXR.scanlineimage,
                }
                if tiled:
                    tiles = OpenEXR.TileDescription()
                    tiles.xSize, tiles.ySize = 64, 64
                    tiles.mode, tiles.roundingMode = OpenEXR.ONE_LEVEL, OpenEXR.ROUND_DOWN
                    header["tiles"] = tiles
                ty = np.float32 if f32 else np.float16
                planes = {n: img[:, :, i].astype(ty).copy() for i, n in enumerate("RGB")}
                with OpenEXR.File(header, planes) as f:
                    f.write(p)
                paths[fmt] = p
        # OpenCV's image: what cv2.imread gives for the Radiance file (BGR, float32), or the
        # half-float values of the EXR.
        im = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        im_half = img.astype(np.float16).astype(np.float32)[:, :, ::-1].copy()
        peers = {
            "drago": cv2.createTonemapDrago(1.0, 1.0, 0.85),
            "reinhard": cv2.createTonemapReinhard(1.0, 0.0, 0.0, 0.0),
        }
        env = dict(os.environ, RAYON_NUM_THREADS="2")
        for fmt in a.formats.split(","):
            if fmt == "hdr":
                pixels = im
            elif fmt.removesuffix("-tiled").endswith("32"):
                pixels = img[:, :, ::-1].copy()
            else:
                pixels = im_half
            src = paths[fmt]
            for op in a.ops.split(","):
                ours, theirs = [], []
                for _ in range(a.rounds):
                    # The input file read once, untimed, so that the timed run reads it from
                    # the page cache, as OpenCV's operator has its pixels in memory (this
                    # machine's page cache loses pages within seconds).
                    with open(src, "rb") as f:
                        while f.read(1 << 24):
                            pass
                    t = time.perf_counter()
                    subprocess.run(
                        [a.blueshift, "tonemap", src, "--op", op, "--out",
                         os.path.join(d, "o.png")],
                        check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
                    )
                    ours.append(time.perf_counter() - t)
                    t = time.perf_counter()
                    peers[op].process(pixels)
                    theirs.append(time.perf_counter() - t)
                m1, m2 = statistics.median(ours), statistics.median(theirs)
                print(f"{fmt} {op}: blueshift whole process {m1:.3f} s, OpenCV operator alone "
                      f"{m2:.3f} s, ratio {m1 / m2:.2f} (medians of {a.rounds}, interleaved)")


if __name__ == "__main__":
    main()
