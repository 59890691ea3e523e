#!/usr/bin/env python3
"""Writes the small AMR test files the volume crate's `amr` tests read back, with h5py:

- `enzo2/amr2_0000` (+ `.hierarchy`, `.cpu0000`): Enzo output with an 8^3 root grid and one
  level-1 grid over [0.25, 0.75]^3 (8^3 cells), not cosmological (LengthUnits, DensityUnits,
  TimeUnits given), fields Density, x-velocity, Temperature. As Enzo does, the root cells under
  the refined grid hold the average of their 8 children.
- `athena2.athdf`: Athena++ output with an 8^3 root mesh in 4^3 mesh blocks, the block at
  logical location (0, 0, 0) refined into eight level-1 blocks (15 blocks), variables rho,
  press, vel1, vel2, vel3 in dataset `prim`, domain [-1, 1]^3.

Every leaf cell holds f(x, y, z) = 1 + x + 2 y + 3 z + x y z at its centre (computed in
double, stored as float32), the Enzo velocity 10 f and the temperature 100 f, so a reader is
checked cell by cell against the formula. Run: python3 make.py (from this folder).
"""
import os
import h5py
import numpy as np


def f(x, y, z):
    return 1.0 + x + 2.0 * y + 3.0 * z + x * y * z


def centres(lo, n, h, dom_lo):
    """Cell centres (z, y, x order arrays) of a block of n cells from cell index lo."""
    ax = [dom_lo[a] + (lo[a] + np.arange(n[a]) + 0.5) * h[a] for a in range(3)]
    z, y, x = np.meshgrid(ax[2], ax[1], ax[0], indexing="ij")
    return x, y, z


def enzo():
    os.makedirs("enzo2", exist_ok=True)
    with open("enzo2/amr2_0000", "w") as p:
        p.write(
            "InitialTime         = 1.5\n"
            "TopGridRank         = 3\n"
            "TopGridDimensions   = 8 8 8 \n"
            "DomainLeftEdge         = 0 0 0 \n"
            "DomainRightEdge        = 1 1 1 \n"
            "RefineBy               = 2\n"
            "ComovingCoordinates    = 0\n"
            "LengthUnits            = 3e+24\n"
            "DensityUnits           = 1e-27\n"
            "TimeUnits              = 1e+15\n"
            "LeftFaceBoundaryCondition  = 3 3 3\n"
            "RightFaceBoundaryCondition = 3 3 3\n"
            "CurrentTimeIdentifier = 0\n"
            "MaximumRefinementLevel = 1\n"
            "HydroMethod = 0\n"
            "MultiSpecies = 0\n"
            "Gamma = 1.6667\n"
            "VersionNumber = 2.0\n"
            "DualEnergyFormalism = 0\n"
            "NumberOfParticles = 0\n"
        )
    grids = [
        # id, level, lo (cells of its level), n
        (1, 0, (0, 0, 0), (8, 8, 8)),
        (2, 1, (4, 4, 4), (8, 8, 8)),
    ]
    with open("enzo2/amr2_0000.hierarchy", "w") as hf:
        for gid, level, lo, n in grids:
            h = 1.0 / (8 * 2**level)
            left = [lo[a] * h for a in range(3)]
            right = [(lo[a] + n[a]) * h for a in range(3)]
            hf.write(
                f"\nGrid = {gid}\nGridRank          = 3\n"
                f"GridDimension     = {n[0] + 6} {n[1] + 6} {n[2] + 6} \n"
                f"GridStartIndex    = 3 3 3 \n"
                f"GridEndIndex      = {n[0] + 2} {n[1] + 2} {n[2] + 2} \n"
                f"GridLeftEdge      = {left[0]:.17g} {left[1]:.17g} {left[2]:.17g} \n"
                f"GridRightEdge     = {right[0]:.17g} {right[1]:.17g} {right[2]:.17g} \n"
                "Time              = 1.5\nNumberOfBaryonFields = 3\n"
                "BaryonFileName = /somewhere/else/amr2_0000.cpu0000\n"
                "NumberOfParticles   = 0\n"
                f"Pointer: Grid[{gid}]->NextGridThisLevel = 0\n"
                f"Pointer: Grid[{gid}]->NextGridNextLevel = {gid + 1 if gid == 1 else 0}\n"
            )
    with h5py.File("enzo2/amr2_0000.cpu0000", "w") as out:
        fine = None
        for gid, level, lo, n in reversed(grids):
            h = [1.0 / (8 * 2**level)] * 3
            x, y, z = centres(lo, n, h, (0, 0, 0))
            v = f(x, y, z)
            if level == 0 and fine is not None:
                # Covered root cells: the average of their children (Enzo's projection).
                c = fine.reshape(4, 2, 4, 2, 4, 2).mean(axis=(1, 3, 5))
                v[2:6, 2:6, 2:6] = c
            if level == 1:
                fine = v.copy()
            g = out.create_group(f"Grid{gid:08d}")
            g["Density"] = v.astype(">f4")
            g["x-velocity"] = (10.0 * v).astype(">f4")
            g["Temperature"] = (100.0 * v).astype(">f4")


def athena():
    mb = 4
    dom_lo = (-1.0, -1.0, -1.0)
    blocks = []
    for lz in range(2):
        for ly in range(2):
            for lx in range(2):
                if (lx, ly, lz) == (0, 0, 0):
                    for cz in range(2):
                        for cy in range(2):
                            for cx in range(2):
                                blocks.append((1, (cx, cy, cz)))
                else:
                    blocks.append((0, (lx, ly, lz)))
    nb = len(blocks)
    prim = np.zeros((5, nb, mb, mb, mb), dtype=np.float32)
    xf = np.zeros((3, nb, mb + 1), dtype=np.float32)
    xv = np.zeros((3, nb, mb), dtype=np.float32)
    for i, (level, loc) in enumerate(blocks):
        h = [2.0 / (8 * 2**level)] * 3
        lo = [loc[a] * mb for a in range(3)]
        x, y, z = centres(lo, (mb, mb, mb), h, dom_lo)
        v = f(x, y, z)
        prim[0, i] = v
        prim[1, i] = 2.0 * v
        prim[2, i] = -v
        prim[3, i] = x
        prim[4, i] = z
        for a in range(3):
            xf[a, i] = dom_lo[a] + (lo[a] + np.arange(mb + 1)) * h[a]
            xv[a, i] = dom_lo[a] + (lo[a] + np.arange(mb) + 0.5) * h[a]
    with h5py.File("athena2.athdf", "w") as out:
        out.attrs["NumCycles"] = np.int32(10)
        out.attrs["Time"] = np.float64(0.25)
        out.attrs["Coordinates"] = np.bytes_("cartesian")
        out.attrs["RootGridX1"] = np.array([-1.0, 1.0, 1.0])
        out.attrs["RootGridX2"] = np.array([-1.0, 1.0, 1.0])
        out.attrs["RootGridX3"] = np.array([-1.0, 1.0, 1.0])
        out.attrs["RootGridSize"] = np.array([8, 8, 8], dtype=np.int32)
        out.attrs["MeshBlockSize"] = np.array([mb, mb, mb], dtype=np.int32)
        out.attrs["MaxLevel"] = np.int32(1)
        out.attrs["NumMeshBlocks"] = np.int32(nb)
        out.attrs["NumVariables"] = np.array([5], dtype=np.int32)
        out.attrs["DatasetNames"] = np.array([b"prim"], dtype="S21")
        out.attrs["VariableNames"] = np.array(
            [b"rho", b"press", b"vel1", b"vel2", b"vel3"], dtype="S21"
        )
        out["Levels"] = np.array([b[0] for b in blocks], dtype=np.int32)
        out["LogicalLocations"] = np.array([b[1] for b in blocks], dtype=np.int64)
        for a in range(3):
            out[f"x{a + 1}f"] = xf[a]
            out[f"x{a + 1}v"] = xv[a]
        out["prim"] = prim


if __name__ == "__main__":
    os.chdir(os.path.dirname(os.path.abspath(__file__)))
    enzo()
    athena()
