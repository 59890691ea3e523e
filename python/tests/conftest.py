"""Shared helpers: the CLI to compare against and an independent NRRD writer."""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _find_cli():
    env = os.environ.get("BLUESHIFT_CLI")
    if env:
        return env
    for p in ("target/debug/blueshift", "target/release/blueshift"):
        if (ROOT / p).exists():
            return str(ROOT / p)
    return None


@pytest.fixture(scope="session")
def cli():
    path = _find_cli()
    if path is None:
        pytest.skip("no blueshift binary (set BLUESHIFT_CLI or cargo build)")

    def run(*args, json_out=False):
        out = subprocess.run([path, *map(str, args)], capture_output=True, text=True)
        if out.returncode != 0:
            raise AssertionError(f"blueshift {' '.join(map(str, args))} failed:\n{out.stderr}")
        return json.loads(out.stdout.strip().splitlines()[-1]) if json_out else out

    return run


def write_nrrd(path, arr_xyz, spacing=(1.0, 1.0, 1.0), origin=(0.0, 0.0, 0.0)):
    """A detached NRRD of a float32 [x, y, z] (or [x, y, z, 3]) array, written here
    independently of blueshift (x fastest on disk)."""
    a = np.asarray(arr_xyz, dtype="<f4")
    vector = a.ndim == 4
    raw = Path(path).with_suffix(".raw")
    if vector:
        data = np.ascontiguousarray(a.transpose(2, 1, 0, 3))
        sizes = f"3 {a.shape[0]} {a.shape[1]} {a.shape[2]}"
        kinds = "vector domain domain domain"
        dirs = f"none ({spacing[0]},0,0) (0,{spacing[1]},0) (0,0,{spacing[2]})"
        dim = 4
    else:
        data = np.ascontiguousarray(a.T)
        sizes = f"{a.shape[0]} {a.shape[1]} {a.shape[2]}"
        kinds = "domain domain domain"
        dirs = f"({spacing[0]},0,0) (0,{spacing[1]},0) (0,0,{spacing[2]})"
        dim = 3
    raw.write_bytes(data.tobytes())
    Path(path).write_text(
        "NRRD0004\n"
        "type: float\n"
        f"dimension: {dim}\n"
        "space: right-anterior-superior\n"
        f"sizes: {sizes}\n"
        f"space directions: {dirs}\n"
        f"kinds: {kinds}\n"
        "endian: little\n"
        "encoding: raw\n"
        f"space origin: ({origin[0]},{origin[1]},{origin[2]})\n"
        f"data file: {raw.name}\n"
    )
    return path


def read_png(path):
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"))


def read_csv(path):
    rows = Path(path).read_text().strip().splitlines()[1:]
    return np.array([[float(v) for v in r.split(",")] for r in rows])
