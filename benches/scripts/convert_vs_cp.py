#!/usr/bin/env python3
"""Issue 22 item 5 from outside: `blueshift convert IN out.bsv` against the physical floor of
any conversion, `cp IN copy` of the same file (a read plus a write), and for gzip input
against decompression alone, `gzip -dc IN.gz > /dev/null`.

Writes, in a temporary folder under `--dir` (default: the current folder, so the copies
land on the file system a user converts on), an N^3 float32 volume of noisy values (the
worst case for compression) as:
- `raw`: an Open SciVis raw file (`v_NxNxN_float32.raw`);
- `nrrd`: a raw-encoded NRRD (`encoding: raw`);
- `gzip`: a gzip-encoded NRRD (level 6), and its gzip payload on its own for `gzip -dc`.

Then, for each input, alternates the baseline and `blueshift convert` `--rounds` times. Every
run starts after `sync`, with its input read once (so it comes from the page cache, as for
`cp`) and its output path removed. Prints the median wall and CPU (user + system) times and
the ratio baseline / convert (issue 22's goal: 0.7 or more for raw and NRRD; for gzip,
bounded by decompression). Needs `numpy` and the release binary
(`cargo build --release -p blueshift-cli`). Usage:

    python3 benches/scripts/convert_vs_cp.py [--blueshift target/release/blueshift]
        [--size 256] [--rounds 11] [--inputs raw,nrrd,gzip] [--dir .]
"""
import argparse
import gzip
import os
import statistics
import subprocess
import tempfile
import time

import numpy as np


def timed(cmd, stdout=subprocess.DEVNULL):
    t0 = os.times()
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=stdout, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t
    t1 = os.times()
    cpu = (t1.children_user - t0.children_user) + (t1.children_system - t0.children_system)
    return wall, cpu


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--blueshift", default="target/release/blueshift")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--rounds", type=int, default=11)
    ap.add_argument("--inputs", default="raw,nrrd,gzip")
    ap.add_argument("--dir", default=".")
    a = ap.parse_args()
    bs = os.path.abspath(a.blueshift)
    n = a.size
    with tempfile.TemporaryDirectory(prefix="convert_vs_cp-", dir=a.dir) as d:
        vals = np.random.default_rng(1).random(n**3, dtype=np.float32).tobytes()
        raw = os.path.join(d, f"v_{n}x{n}x{n}_float32.raw")
        with open(raw, "wb") as f:
            f.write(vals)
        header = f"NRRD0004\ntype: float\ndimension: 3\nsizes: {n} {n} {n}\nendian: little\n"
        inputs = {}
        for kind in a.inputs.split(","):
            if kind == "raw":
                inputs[kind] = (raw, ["cp", raw, os.path.join(d, "copy")], None)
            elif kind == "nrrd":
                p = os.path.join(d, "v.nrrd")
                with open(p, "wb") as f:
                    f.write((header + "encoding: raw\n\n").encode())
                    f.write(vals)
                inputs[kind] = (p, ["cp", p, os.path.join(d, "copy")], None)
            elif kind == "gzip":
                payload = gzip.compress(vals, compresslevel=6)
                p = os.path.join(d, "v_gz.nrrd")
                with open(p, "wb") as f:
                    f.write((header + "encoding: gzip\n\n").encode())
                    f.write(payload)
                gz = os.path.join(d, "payload.gz")
                with open(gz, "wb") as f:
                    f.write(payload)
                inputs[kind] = (p, ["gzip", "-dc", gz], gz)
            else:
                raise SystemExit(f"unknown input {kind!r} (raw, nrrd, gzip)")
        out = os.path.join(d, "out.bsv")
        for kind, (src, base_cmd, extra) in inputs.items():
            base, conv = [], []
            for r in range(a.rounds):
                order = ("base", "convert") if r % 2 == 0 else ("convert", "base")
                for which in order:
                    for p in (out, os.path.join(d, "copy")):
                        if os.path.exists(p):
                            os.remove(p)
                    subprocess.run(["sync"], check=True)
                    for p in (src, extra):
                        if p:
                            with open(p, "rb") as f:
                                while f.read(1 << 24):
                                    pass
                    if which == "base":
                        base.append(timed(base_cmd))
                    else:
                        conv.append(timed([bs, "convert", src, out]))
            bw = statistics.median(w for w, _ in base)
            bc = statistics.median(c for _, c in base)
            cw = statistics.median(w for w, _ in conv)
            cc = statistics.median(c for _, c in conv)
            name = "gzip -dc" if kind == "gzip" else "cp"
            print(
                f"{kind} {n}^3: {name} {bw * 1e3:.1f} ms wall ({bc * 1e3:.0f} ms CPU), "
                f"convert {cw * 1e3:.1f} ms wall ({cc * 1e3:.0f} ms CPU), "
                f"ratio {bw / cw:.2f} (medians of {a.rounds}, alternating)"
            )


if __name__ == "__main__":
    main()
