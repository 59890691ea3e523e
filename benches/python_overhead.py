"""Python-call overhead against the CLI for the same Doppler render, measured in one run.

    python benches/python_overhead.py --cli target/release/blueshift [--size 256] [--runs 5]

Both sides load the Enzo scene file (scenes/enzo-moving7.json), render SIZE x SIZE with the
piecewise-linear integrator and produce the display image: the CLI as a process (start,
load, render, write EXR + PNG), Python through `blueshift.doppler.Scene.read(...).render`
in this interpreter. Prints the median wall time of each and the ratio Python / CLI (a
ratio near 1 means the binding adds nothing measurable). Build both in release for a fair
figure: `cargo build --release -p blueshift-cli` and `pip install ./python`.
"""

import argparse
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import blueshift
from blueshift import doppler

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "enzo-moving7.json"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cli", default=str(ROOT / "target" / "release" / "blueshift"))
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--runs", type=int, default=5)
    a = ap.parse_args()
    cli_t, py_t = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(a.runs):
            out = Path(tmp) / f"r{k}.exr"
            t0 = time.perf_counter()
            subprocess.run([a.cli, "doppler", "--scene", str(SCENE), "--width", str(a.size), "--height", str(a.size),
                            "--out", str(out)], check=True, capture_output=True)
            cli_t.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            doppler.Scene.read(SCENE).render(width=a.size, height=a.size)
            py_t.append(time.perf_counter() - t0)
    c, p = statistics.median(cli_t), statistics.median(py_t)
    print(f"blueshift {blueshift.__version__}: {a.size}x{a.size} Enzo Doppler render, median of {a.runs}")
    print(f"  CLI     {c * 1e3:8.1f} ms")
    print(f"  Python  {p * 1e3:8.1f} ms")
    print(f"  ratio Python / CLI = {p / c:.3f}")


if __name__ == "__main__":
    main()
