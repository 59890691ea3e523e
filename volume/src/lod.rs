//! Levels of detail: a pyramid down-sampled by two per level (HDR VolVis section 6.3).
//!
//! Coarse voxel `i` along an axis is the mean of fine voxels `2i` and `2i + 1` (the last one
//! clamped to the edge for odd sizes), so level `l + 1` has `ceil(n / 2)` voxels, twice the
//! spacing, and its origin half a fine voxel further in ([`Geometry::downsampled`]). NaN
//! voxels (no data) are left out of the mean; a coarse voxel is NaN only where all eight are,
//! so a missing voxel does not blank its whole region at the coarse levels.

use rayon::prelude::*;

use crate::grid::{AnyGrid, Geometry, Grid, Voxel};
use crate::{Limits, Result};

/// One 2x down-sampling step (box filter over 2 x 2 x 2 voxels), in parallel over z.
pub fn downsample<T: Voxel<Value = f32>>(grid: &Grid<T>) -> Result<Grid<f32>> {
    let g = *grid.geometry();
    let c = g.downsampled();
    let [nx, ny, nz] = g.dims;
    let src = grid.data();
    let mut out = Grid::<f32>::zeros(c, &Limits::no_limits())?;
    let [cx, cy, _] = c.dims;
    out.data_mut()
        .par_chunks_mut(cx * cy)
        .enumerate()
        .for_each(|(z, slice)| {
            downsample_slice(
                |x, y, zz| src[g.index(x, y, zz)].value(),
                [nx, ny, nz],
                z,
                slice,
                [cx, cy],
            );
        });
    Ok(out)
}

/// Fills coarse slice `z` from a fine-voxel accessor; shared by the in-core pyramid and the
/// streaming converter so both give bit-identical levels.
pub(crate) fn downsample_slice(
    fine: impl Fn(usize, usize, usize) -> f32,
    n: [usize; 3],
    z: usize,
    slice: &mut [f32],
    c: [usize; 2],
) {
    for (y, row) in slice[..c[0] * c[1]].chunks_exact_mut(c[0]).enumerate() {
        downsample_row(&fine, n, z, y, row);
    }
}

/// Fills row `y` of coarse slice `z` (`row.len()` coarse voxels) from a fine-voxel accessor.
pub(crate) fn downsample_row(
    fine: impl Fn(usize, usize, usize) -> f32,
    n: [usize; 3],
    z: usize,
    y: usize,
    row: &mut [f32],
) {
    let z0 = 2 * z;
    let z1 = (2 * z + 1).min(n[2] - 1);
    let y0 = 2 * y;
    let y1 = (2 * y + 1).min(n[1] - 1);
    for (x, out) in row.iter_mut().enumerate() {
        let x0 = 2 * x;
        let x1 = (2 * x + 1).min(n[0] - 1);
        let v = [
            fine(x0, y0, z0),
            fine(x1, y0, z0),
            fine(x0, y1, z0),
            fine(x1, y1, z0),
            fine(x0, y0, z1),
            fine(x1, y0, z1),
            fine(x0, y1, z1),
            fine(x1, y1, z1),
        ];
        let s = ((v[0] + v[1]) + (v[2] + v[3])) + ((v[4] + v[5]) + (v[6] + v[7]));
        *out = mean_of_eight(s, v);
    }
}

/// The mean of eight fine voxels whose sum, in [`downsample_row`]'s order, is `s`: `s / 8`,
/// or, where the sum is NaN because some voxels are, the mean of the others (NaN where
/// none is a number). Both down-samplers call it, so they give the same bits.
#[inline]
pub(crate) fn mean_of_eight(s: f32, v: [f32; 8]) -> f32 {
    if !s.is_nan() {
        return s * 0.125;
    }
    let (sum, n) = v
        .iter()
        .filter(|x| !x.is_nan())
        .fold((0.0f32, 0u32), |(s, n), &x| (s + x, n + 1));
    if n == 0 { f32::NAN } else { sum / n as f32 }
}

/// A level-of-detail pyramid of f32 grids; level 0 is the full resolution.
#[derive(Clone, Debug, PartialEq)]
pub struct Pyramid {
    levels: Vec<Grid<f32>>,
}

impl Pyramid {
    /// Builds levels until every dimension is at most `min_edge` (e.g. one 64^3 brick).
    pub fn build(grid: &AnyGrid, min_edge: usize) -> Result<Self> {
        let g0 = match grid {
            AnyGrid::F32(g) => g.clone(),
            other => Grid::from_vec(*other.geometry(), other.to_f32_vec())?,
        };
        let mut levels = vec![g0];
        let min_edge = min_edge.max(1);
        while levels
            .last()
            .is_some_and(|l| l.dims().iter().any(|&d| d > min_edge))
        {
            let next = downsample(levels.last().expect("non-empty"))?;
            levels.push(next);
        }
        Ok(Pyramid { levels })
    }

    /// The levels, finest first.
    #[must_use]
    pub fn levels(&self) -> &[Grid<f32>] {
        &self.levels
    }
}

/// Geometries of all levels for a level-0 geometry, until every dimension is at most
/// `min_edge`.
#[must_use]
pub fn level_geometries(g0: Geometry, min_edge: usize) -> Vec<Geometry> {
    let mut v = vec![g0];
    while v
        .last()
        .is_some_and(|l| l.dims.iter().any(|&d| d > min_edge.max(1)))
    {
        let next = v.last().expect("non-empty").downsampled();
        v.push(next);
    }
    v
}
