//! Macrocells: a coarse grid holding the min/max of a channel over blocks of k^3 voxels
//! (MDWT paper, section 4.3), and the value intervals a ray crosses (Open VKL's
//! `VKLInterval`, CONVENTIONS C6).
//!
//! # Conservative for trilinear interpolation
//!
//! Macrocell `c` along an axis covers the continuous index range `[c k, (c + 1) k]`. A
//! trilinear sample anywhere in that range blends voxels `c k ..= (c + 1) k`, so the cell's
//! min/max is taken over those `k + 1` voxels per axis (the `+1` neighbour is shared with the
//! next cell). Every trilinearly interpolated value inside the cell therefore lies in
//! `[min, max]`. Cells along an axis: `max(1, ceil((n - 1) / k))`. NaN voxels are ignored.
//!
//! The tracking crate turns these value ranges into majorants through a transfer function;
//! the volume crate reports only values (DESIGN: data versus look).

use std::ops::Range;

use glam::Vec3;
use rayon::prelude::*;

use crate::grid::{AnyGrid, Geometry, Grid, Voxel};
use crate::{Error, Result};

/// The default macrocell edge in voxels (the MDWT paper's best-performing 4 x 4 x 4).
pub const DEFAULT_K: usize = 4;

/// Per-cell min/max of one scalar channel over k^3-voxel blocks (plus the shared
/// interpolation neighbour, so the ranges are conservative for trilinear sampling).
#[derive(Clone, Debug, PartialEq)]
pub struct Macrocells {
    k: usize,
    dims: [usize; 3],
    geometry: Geometry,
    min: Vec<f32>,
    max: Vec<f32>,
}

/// A stretch of a ray with the range of values the volume can take there
/// (CONVENTIONS C6; Open VKL `VKLInterval`).
#[derive(Clone, Debug, PartialEq)]
pub struct ValueInterval {
    /// Ray parameter range (world units of the ray direction's length).
    pub t: Range<f32>,
    /// Conservative range of trilinearly interpolated values along `t`.
    pub value: Range<f32>,
    /// The macrocell crossed, `[x, y, z]`.
    pub cell: [usize; 3],
}

/// Min and max of the macrocells of layer `cz` (edge `k`, each covering its `k + 1` voxels
/// per axis) of a volume of `n` voxels; `row(y, z)` gives row `y` of slice `z`. NaN is
/// ignored (a cell of NaN only keeps +inf / -inf). Rows are reduced element-wise first, so
/// the loops vectorise.
pub(crate) fn layer_min_max<'a, V: Copy + 'a>(
    n: [usize; 3],
    k: usize,
    cz: usize,
    row: impl Fn(usize, usize) -> &'a [V],
    value: impl Fn(V) -> f32,
    mn: &mut [f32],
    mx: &mut [f32],
) {
    let cells_x = n[0].saturating_sub(1).div_ceil(k).max(1);
    let cells_y = n[1].saturating_sub(1).div_ceil(k).max(1);
    let z0 = cz * k;
    let z1 = ((cz + 1) * k).min(n[2] - 1);
    let mut lo = vec![f32::INFINITY; n[0]];
    let mut hi = vec![f32::NEG_INFINITY; n[0]];
    for cy in 0..cells_y {
        lo.fill(f32::INFINITY);
        hi.fill(f32::NEG_INFINITY);
        let y0 = cy * k;
        let y1 = ((cy + 1) * k).min(n[1] - 1);
        for z in z0..=z1 {
            for y in y0..=y1 {
                for ((l, h), &v) in lo.iter_mut().zip(hi.iter_mut()).zip(row(y, z)) {
                    let v = value(v);
                    *l = if v < *l { v } else { *l };
                    *h = if v > *h { v } else { *h };
                }
            }
        }
        for cx in 0..cells_x {
            let x0 = cx * k;
            let x1 = ((cx + 1) * k).min(n[0] - 1);
            let (mut a, mut b) = (f32::INFINITY, f32::NEG_INFINITY);
            for x in x0..=x1 {
                a = if lo[x] < a { lo[x] } else { a };
                b = if hi[x] > b { hi[x] } else { b };
            }
            mn[cx + cells_x * cy] = a;
            mx[cx + cells_x * cy] = b;
        }
    }
}

impl Macrocells {
    /// Builds macrocells of edge `k` voxels over a scalar grid, in parallel over z-slabs of
    /// cells. The result does not depend on the thread count (min/max are exact).
    pub fn build<T: Voxel<Value = f32>>(grid: &Grid<T>, k: usize) -> Result<Self> {
        if k == 0 {
            return Err(Error::parameter("macrocell size k must be at least 1"));
        }
        let geometry = *grid.geometry();
        let n = geometry.dims;
        let dims = n.map(|d| d.saturating_sub(1).div_ceil(k).max(1));
        let data = grid.data();
        let layer = dims[0] * dims[1];
        let mut min = vec![f32::INFINITY; layer * dims[2]];
        let mut max = vec![f32::NEG_INFINITY; layer * dims[2]];
        min.par_chunks_mut(layer)
            .zip(max.par_chunks_mut(layer))
            .enumerate()
            .for_each(|(cz, (mn, mx))| {
                let row = |y: usize, z: usize| {
                    let at = geometry.index(0, y, z);
                    &data[at..at + n[0]]
                };
                layer_min_max(n, k, cz, row, |v: T| v.value(), mn, mx);
            });
        Ok(Macrocells {
            k,
            dims,
            geometry,
            min,
            max,
        })
    }

    /// Macrocells from stored min/max tables (cells x fastest, as [`Macrocells::mins`] gives
    /// them) over `geometry` with edge `k`; refuses tables of the wrong length.
    pub fn from_parts(geometry: Geometry, k: usize, min: Vec<f32>, max: Vec<f32>) -> Result<Self> {
        if k == 0 {
            return Err(Error::parameter("macrocell size k must be at least 1"));
        }
        let dims = geometry
            .dims
            .map(|d| d.saturating_sub(1).div_ceil(k).max(1));
        let n = dims[0] * dims[1] * dims[2];
        if min.len() != n || max.len() != n {
            return Err(Error::invalid(format!(
                "macrocell tables hold {} and {} cells, {n} expected",
                min.len(),
                max.len()
            )));
        }
        Ok(Macrocells {
            k,
            dims,
            geometry,
            min,
            max,
        })
    }

    /// [`Macrocells::build`] for any scalar grid; vector grids are refused.
    pub fn build_any(grid: &AnyGrid, k: usize) -> Result<Self> {
        match grid {
            AnyGrid::U8(g) => Self::build(g, k),
            AnyGrid::U16(g) => Self::build(g, k),
            AnyGrid::F16(g) => Self::build(g, k),
            AnyGrid::F32(g) => Self::build(g, k),
            AnyGrid::Vec3(_) => Err(Error::parameter(
                "macrocells are built over scalar channels, not vectors",
            )),
        }
    }

    /// Macrocell edge in voxels.
    #[must_use]
    pub fn k(&self) -> usize {
        self.k
    }

    /// Number of macrocells along x, y, z.
    #[must_use]
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Geometry of the voxel grid the cells were built from.
    #[must_use]
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// Linear index of cell `[x, y, z]` (x fastest).
    #[must_use]
    pub fn cell_linear(&self, c: [usize; 3]) -> usize {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }

    /// `(min, max)` of cell `[x, y, z]`; panics if out of range (use [`Macrocells::dims`]).
    /// A cell whose voxels are all NaN gives `(inf, -inf)`.
    #[must_use]
    pub fn min_max(&self, c: [usize; 3]) -> (f32, f32) {
        let i = self.cell_linear(c);
        (self.min[i], self.max[i])
    }

    /// Value range of cell `[x, y, z]` as `min..max`.
    #[must_use]
    pub fn range(&self, c: [usize; 3]) -> Range<f32> {
        let (a, b) = self.min_max(c);
        a..b
    }

    /// All cell minima, x fastest.
    #[must_use]
    pub fn mins(&self) -> &[f32] {
        &self.min
    }

    /// All cell maxima, x fastest.
    #[must_use]
    pub fn maxs(&self) -> &[f32] {
        &self.max
    }

    /// The cell containing continuous index position `p` (clamped into the grid).
    #[must_use]
    pub fn cell_of_index(&self, p: Vec3) -> [usize; 3] {
        let mut c = [0usize; 3];
        for a in 0..3 {
            let q = (p[a] / self.k as f32).floor();
            c[a] = if q.is_nan() || q < 0.0 {
                0
            } else {
                (q as usize).min(self.dims[a] - 1)
            };
        }
        c
    }

    /// The cell containing world position `p` (clamped into the grid).
    #[must_use]
    pub fn cell_of_world(&self, p: Vec3) -> [usize; 3] {
        self.cell_of_index(self.geometry.world_to_index(p))
    }

    /// World-space box `(min, max)` of cell `c` (the last cell ends at the last voxel).
    #[must_use]
    pub fn cell_world_bounds(&self, c: [usize; 3]) -> (Vec3, Vec3) {
        let n = self.geometry.dims;
        let mut lo = Vec3::ZERO;
        let mut hi = Vec3::ZERO;
        for a in 0..3 {
            lo[a] = (c[a] * self.k) as f32;
            hi[a] = (((c[a] + 1) * self.k).min(n[a] - 1)) as f32;
        }
        (
            self.geometry.index_to_world(lo),
            self.geometry.index_to_world(hi),
        )
    }

    /// The value intervals along the world-space ray `origin + t * dir` for `t` in `t_range`,
    /// one per macrocell crossed, in order of increasing `t` (a 3D DDA, Amanatides & Woo).
    /// The ray is clipped to the grid's voxel-centre box; a ray that misses it yields
    /// nothing.
    #[must_use]
    pub fn intervals(&self, origin: Vec3, dir: Vec3, t_range: Range<f32>) -> ValueIntervals<'_> {
        // Index space: p_i(t) = o_i + t d_i, with cells of size k.
        let o = self.geometry.world_to_index(origin) / self.k as f32;
        let d = dir / self.geometry.spacing / self.k as f32;
        let n = self.geometry.dims;
        let hi = Vec3::new(
            n[0].saturating_sub(1) as f32,
            n[1].saturating_sub(1) as f32,
            n[2].saturating_sub(1) as f32,
        ) / self.k as f32;
        let (mut t0, mut t1) = (t_range.start, t_range.end);
        let mut ok = o.is_finite() && d.is_finite() && t0.is_finite() && !t1.is_nan();
        for a in 0..3 {
            if !ok {
                break;
            }
            if d[a] == 0.0 {
                if o[a] < 0.0 || o[a] > hi[a] {
                    ok = false;
                }
            } else {
                let ta = (0.0 - o[a]) / d[a];
                let tb = (hi[a] - o[a]) / d[a];
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        }
        ok &= t0 <= t1;
        // Standard 3D DDA state (Amanatides & Woo) in cell units.
        let mut cell = [0i64; 3];
        let mut step = [0i64; 3];
        let mut t_max = [f32::INFINITY; 3];
        let mut t_delta = [f32::INFINITY; 3];
        if ok {
            let p = o + d * t0;
            for a in 0..3 {
                let mut q = p[a].floor();
                // On a face while moving backwards, the cell being entered is the lower one.
                if d[a] < 0.0 && p[a] == q {
                    q -= 1.0;
                }
                let c = (q.max(0.0) as i64).min(self.dims[a] as i64 - 1);
                cell[a] = c;
                if d[a] > 0.0 {
                    step[a] = 1;
                    t_delta[a] = 1.0 / d[a];
                    t_max[a] = ((c + 1) as f32 - o[a]) / d[a];
                } else if d[a] < 0.0 {
                    step[a] = -1;
                    t_delta[a] = -1.0 / d[a];
                    t_max[a] = (c as f32 - o[a]) / d[a];
                }
            }
        }
        ValueIntervals {
            cells: self,
            cell,
            step,
            t_max,
            t_delta,
            t: t0,
            t_end: t1,
            done: !ok,
        }
    }
}

/// Iterator returned by [`Macrocells::intervals`].
#[derive(Debug)]
pub struct ValueIntervals<'a> {
    cells: &'a Macrocells,
    cell: [i64; 3],
    step: [i64; 3],
    t_max: [f32; 3],
    t_delta: [f32; 3],
    t: f32,
    t_end: f32,
    done: bool,
}

impl Iterator for ValueIntervals<'_> {
    type Item = ValueInterval;

    fn next(&mut self) -> Option<ValueInterval> {
        if self.done {
            return None;
        }
        let t_next = self.t_max[0].min(self.t_max[1]).min(self.t_max[2]);
        let t_exit = t_next.min(self.t_end).max(self.t);
        let c = self.cell.map(|v| v as usize);
        let (lo, hi) = self.cells.min_max(c);
        let iv = ValueInterval {
            t: self.t..t_exit,
            value: lo..hi,
            cell: c,
        };
        if t_exit >= self.t_end {
            self.done = true;
        } else {
            // Step every axis whose face is crossed here (edges and corners at once).
            for a in 0..3 {
                if self.t_max[a] <= t_next {
                    self.cell[a] += self.step[a];
                    self.t_max[a] += self.t_delta[a];
                    if self.cell[a] < 0 || self.cell[a] >= self.cells.dims[a] as i64 {
                        self.done = true;
                    }
                }
            }
        }
        self.t = t_exit;
        Some(iv)
    }
}
