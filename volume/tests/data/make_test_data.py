#!/usr/bin/env python3
"""Writes the small test files under volume/tests/data/ from the real datasets in ../shared/data.

Run from the repository root:  python3 volume/tests/data/make_test_data.py /path/to/shared/data
Uses only numpy, gzip and zlib, so the files are written independently of blueshift's own writers.

Provenance of the crops (see ../shared/data/*/SOURCE.md):
- headsq: VTK "headsq" quarter-resolution head scan (pyvista/vtk-data @ 126ee906, Apache-2.0),
  int16 LE, 64x64x93, spacing 3.2 3.2 1.5. Crop x 20..36, y 20..36, z 40..48 (16x16x8).
- carotid: VTK "carotid" flow field (pyvista/vtk-data @ 126ee906, Apache-2.0), legacy VTK binary,
  76x49x45, SCALARS float + VECTORS float, big-endian, origin (100, 80, 1). Crop x 30..38,
  y 20..28, z 20..26 (8x8x6).
"""
import gzip, os, sys, zlib
import numpy as np

src = sys.argv[1] if len(sys.argv) > 1 else "../shared/data"
out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "valid")
os.makedirs(out, exist_ok=True)

# ---- headsq crop -------------------------------------------------------------------------
h = np.fromfile(os.path.join(src, "headsq/headsq_64x64x93_int16le.raw"), dtype="<i2").reshape(93, 64, 64)
c = h[40:48, 20:36, 20:36].copy()  # [z][y][x]
nz, ny, nx = c.shape
raw_name = f"headsq_crop_{nx}x{ny}x{nz}_int16.raw"
c.astype("<i2").tofile(os.path.join(out, raw_name))
# spacing 3.2 3.2 1.5; the crop's origin is the first voxel's world position
org = (20 * 3.2, 20 * 3.2, 40 * 1.5)

def w(name, data):
    with open(os.path.join(out, name), "wb") as f:
        f.write(data)

w("headsq_crop_be.nrrd",
  (f"NRRD0004\n# headsq crop, big-endian raw\ntype: short\ndimension: 3\nsizes: {nx} {ny} {nz}\n"
   f"spacings: 3.2 3.2 1.5\nendian: big\nencoding: raw\n\n").encode() + c.astype(">i2").tobytes())
w("headsq_crop_gzip.nrrd",
  (f"NRRD0005\ntype: int16\ndimension: 3\nspace: left-posterior-superior\nsizes: {nx} {ny} {nz}\n"
   f"space directions: (3.2,0,0) (0,3.2,0) (0,0,1.5)\nspace origin: ({org[0]},{org[1]},{org[2]})\n"
   f"endian: little\nencoding: gzip\n\n").encode() + gzip.compress(c.astype("<i2").tobytes()))
w("headsq_crop.nhdr",
  (f"NRRD0004\ntype: int16\ndimension: 3\nsizes: {nx} {ny} {nz}\nspacings: 3.2 3.2 1.5\n"
   f"endian: little\nencoding: raw\ndata file: {raw_name}\n").encode())
w("headsq_crop.mha",
  (f"ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
   f"CompressedData = True\nOffset = {org[0]} {org[1]} {org[2]}\nElementSpacing = 3.2 3.2 1.5\n"
   f"DimSize = {nx} {ny} {nz}\nElementType = MET_SHORT\nElementDataFile = LOCAL\n").encode()
  + zlib.compress(c.astype("<i2").tobytes()))
w("headsq_crop.mhd",
  (f"ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
   f"CompressedData = False\nElementSpacing = 3.2 3.2 1.5\nDimSize = {nx} {ny} {nz}\n"
   f"ElementType = MET_SHORT\nElementDataFile = {raw_name}\n").encode())
vals = "\n".join(" ".join(str(int(v)) for v in row) for row in c.reshape(-1, nx))
w("headsq_crop_ascii.vtk",
  (f"# vtk DataFile Version 3.0\nheadsq crop\nASCII\nDATASET STRUCTURED_POINTS\nDIMENSIONS {nx} {ny} {nz}\n"
   f"SPACING 3.2 3.2 1.5\nORIGIN {org[0]} {org[1]} {org[2]}\nPOINT_DATA {nx*ny*nz}\n"
   f"SCALARS density short 1\nLOOKUP_TABLE default\n{vals}\n").encode())

# ---- carotid crop ------------------------------------------------------------------------
b = open(os.path.join(src, "carotid-flow/carotid.vtk"), "rb").read()
n = 76 * 49 * 45
s = np.frombuffer(b, dtype=">f4", count=n, offset=182).reshape(45, 49, 76)
v = np.frombuffer(b, dtype=">f4", count=3 * n, offset=670525).reshape(45, 49, 76, 3)
cs = s[20:26, 20:28, 30:38].copy()
cv = v[20:26, 20:28, 30:38].copy()
mz, my, mx = cs.shape
w("carotid_crop_binary.vtk",
  (f"# vtk DataFile Version 3.0\ncarotid crop\nBINARY\nDATASET STRUCTURED_POINTS\nDIMENSIONS {mx} {my} {mz}\n"
   f"SPACING 1 1 1\nORIGIN {100+30} {80+20} {1+20}\nPOINT_DATA {mx*my*mz}\nSCALARS scalars float\n"
   f"LOOKUP_TABLE default\n").encode() + cs.astype(">f4").tobytes()
  + b"\nVECTORS vectors float\n" + cv.astype(">f4").tobytes() + b"\n")
cs.astype("<f4").tofile(os.path.join(out, f"carotid_crop_scalars_{mx}x{my}x{mz}_float32.raw"))
cv.astype("<f4").tofile(os.path.join(out, f"carotid_crop_vectors_{mx}x{my}x{mz}x3_float32.raw"))
w("carotid_crop_vectors.nrrd",
  (f"NRRD0004\ntype: float\ndimension: 4\nsizes: 3 {mx} {my} {mz}\nkinds: 3-vector domain domain domain\n"
   f"spacings: nan 1 1 1\nendian: big\nencoding: raw\n\n").encode() + cv.astype(">f4").tobytes())
print("wrote", sorted(os.listdir(out)))
