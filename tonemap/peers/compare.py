#!/usr/bin/env python3
"""Compare blueshift's tone-mapping operators with pfstmo and OpenCV.

Needs: the `blueshift` binary (cargo build --release -p blueshift-cli), Debian's
`pfstools` + `pfstmo` (apt-get install pfstools pfstmo) and PyPI `opencv-python-headless`,
`numpy`, `scikit-image`. Missing peers are reported and skipped.

For every image (the real photographs in shared/data/hdr-photos plus synthetic ones) and
operator, it runs blueshift's CLI (PFM output: display-linear floats), the pfstmo tool
with the same parameters, and OpenCV's TonemapDrago; then it computes SSIM of display
luminance (clamped to [0, 1], encoded with gamma 1/2.2) against each peer, and the wall
time of each command (one run, same machine). Usage:

    python3 tonemap/peers/compare.py [--blueshift target/release/blueshift] [--data DIR]
                                     [--big]   # adds an 8-megapixel synthetic image
"""
import argparse, math, os, shutil, subprocess, sys, tempfile, time
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

def lum(img):
    if img.shape[2] == 1:
        return img[:, :, 0]
    return 0.2126 * img[:, :, 0] + 0.7152 * img[:, :, 1] + 0.0722 * img[:, :, 2]

def display(img):
    y = np.nan_to_num(lum(img), nan=0.0, posinf=1.0, neginf=0.0)
    return np.clip(y, 0, 1) ** (1 / 2.2)

def ssim(a, b):
    from skimage.metrics import structural_similarity
    return structural_similarity(a, b, data_range=1.0)

def synthetic(w, h, seed=1):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / max(w, h)
    l = 0.01 + 2.0 * x * y + 0.2 * np.abs(np.sin(20 * x)) + 0.05 * np.sin(60 * y) ** 2
    l[(x - 0.7) ** 2 + (y - 0.3) ** 2 < 0.004] += 500.0
    l *= 1 + 0.1 * rng.random(l.shape)
    return np.stack([1.1 * l, l, 0.8 * l], axis=2)

def timed(cmd, **kw):
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, **kw)
    return time.perf_counter() - t

# (blueshift args, pfstmo command) with matched parameters.
OPS = {
    "drago": (["--op", "drago", "--bias", "0.85"], ["pfstmo_drago03", "--bias", "0.85"]),
    "reinhard": (["--op", "reinhard", "--key", "0.18"], ["pfstmo_reinhard02", "--key", "0.18"]),
    "reinhard-local": (["--op", "reinhard-local", "--key", "0.18", "--phi", "8", "--epsilon", "0.05"],
                       ["pfstmo_reinhard02", "--scales", "--key", "0.18", "--phi", "8", "--range", "8", "--lower", "1", "--upper", "43"]),
    # pfstmo_durand02 works in natural log: its sigma_r is in ln units and its base contrast
    # is the target base range in ln units (5 means e^5 = 148:1, not 5:1); its default
    # sigma_s is a fixed 40 px and it applies a colour-correction exponent unless
    # --original. The paper's settings (log10 sigma_r 0.4, base contrast 5:1, sigma_s 2 %
    # of the image size, colour ratios kept) are therefore passed as ln(10) * 0.4, ln(5),
    # 0.02 * max(w, h) and --original; "{sigma_s}" is filled in per image.
    "durand": (["--op", "durand", "--sigma-r", "0.4", "--contrast", "5"],
               ["pfstmo_durand02", "--sigma-s", "{sigma_s}", "--sigma-r", f"{0.4 * math.log(10):.6f}",
                "--base-contrast", f"{math.log(5):.6f}", "--original"]),
    "fattal": (["--op", "fattal", "--alpha", "0.1", "--beta", "0.85", "--saturation", "0.5"],
               ["pfstmo_fattal02", "--alpha", "0.1", "--beta", "0.85", "--saturation", "0.5", "--gamma", "1", "--detail-level", "0"]),
}

def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--blueshift", default="target/release/blueshift")
    ap.add_argument("--data", default=os.path.join(os.path.dirname(__file__), "../../../shared/data/hdr-photos"))
    ap.add_argument("--big", action="store_true")
    a = ap.parse_args()
    have_pfs = shutil.which("pfsin") is not None
    try:
        import cv2
    except ImportError:
        cv2 = None
    tmp = tempfile.mkdtemp(prefix="blueshift-peers-")
    images = []
    for name in ["Desk.exr", "MtTamWest.exr", "memorial.hdr"]:
        p = os.path.join(a.data, name)
        if os.path.exists(p):
            images.append((name, p))
    syn = os.path.join(tmp, "synthetic_1mp.pfm"); write_pfm(syn, synthetic(1024, 1024)); images.append(("synthetic 1 MP", syn))
    if a.big:
        big = os.path.join(tmp, "synthetic_8mp.pfm"); write_pfm(big, synthetic(3464, 2309, 2)); images.append(("synthetic 8 MP", big))
    print("| image | operator | SSIM vs pfstmo | SSIM vs OpenCV | blueshift s | pfstmo s | OpenCV s |")
    print("|---|---|---|---|---|---|---|")
    for name, path in images:
        # Peers read a PFM copy of the input (pfsin handles EXR/HDR too, but one format keeps I/O equal).
        pfm_in = os.path.join(tmp, "in.pfm")
        subprocess.run([a.blueshift, "tonemap", path, "--op", "linear", "--white", "1", "--out", pfm_in], check=True, stdout=subprocess.DEVNULL)
        pfs_in = os.path.join(tmp, "in.pfs")
        if have_pfs:
            with open(pfs_in, "wb") as f:
                subprocess.run(["pfsinpfm", pfm_in], check=True, stdout=f)
        hdr = read_pfm(pfm_in).astype(np.float32)
        sigma_s = f"{0.02 * max(hdr.shape[0], hdr.shape[1]):.3f}"
        for op, (bargs, pargs) in OPS.items():
            out_b = os.path.join(tmp, "b.pfm")
            tb = timed([a.blueshift, "tonemap", pfm_in, *bargs, "--out", out_b])
            yb = display(read_pfm(out_b))
            s_p = t_p = s_c = t_c = float("nan")
            if have_pfs:
                out_p = os.path.join(tmp, "p.pfs"); out_pp = os.path.join(tmp, "p.pfm")
                with open(pfs_in, "rb") as fi, open(out_p, "wb") as fo:
                    cmd = [x.replace("{sigma_s}", sigma_s) for x in pargs]
                    t = time.perf_counter(); subprocess.run(cmd, stdin=fi, stdout=fo, stderr=subprocess.DEVNULL, check=True); t_p = time.perf_counter() - t
                with open(out_p, "rb") as fi:
                    subprocess.run(["pfsoutpfm", out_pp], stdin=fi, check=True)
                s_p = ssim(yb, display(read_pfm(out_pp)))
            if cv2 is not None and op == "drago":
                bgr = np.ascontiguousarray(hdr[:, :, ::-1])
                tm = cv2.createTonemapDrago(gamma=1.0, saturation=1.0, bias=0.85)
                t = time.perf_counter(); res = tm.process(bgr); t_c = time.perf_counter() - t
                s_c = ssim(yb, display(res[:, :, ::-1].astype(np.float64)))
            print(f"| {name} | {op} | {s_p:.3f} | {s_c:.3f} | {tb:.2f} | {t_p:.2f} | {t_c:.2f} |", flush=True)
    shutil.rmtree(tmp)

if __name__ == "__main__":
    sys.exit(main())
