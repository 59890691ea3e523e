//! A robust 3D DDA (Amanatides & Woo) over the macrocell / majorant grid, and the majorant
//! segment iterator of CONVENTIONS C6 (pbrt's `DDAMajorantIterator`).
//!
//! Robustness: the ray is clipped to the voxel-centre box first; the start cell comes from
//! the clamped entry point; each axis' next crossing is recomputed from the cell boundary
//! (no accumulated increments, so no drift), never moves backwards, and axes the ray is
//! parallel to are never crossed. Rays along axes, grazing rays that touch a face or an edge,
//! and rays starting inside the volume are all handled; the walk is bounded by the number of
//! cells it can cross.

use glam::Vec3;

use crate::Ray;
use crate::majorant::MajorantGrid;

/// The cell layout shared by all channels of a scene: macrocells of `k` voxels per edge
/// over a voxel grid with `geometry` (see `blueshift_volume::Macrocells`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellLayout {
    /// Voxel geometry.
    pub geometry: blueshift_volume::Geometry,
    /// Macrocell edge in voxels.
    pub k: usize,
    /// Macrocells along x, y, z.
    pub dims: [usize; 3],
    /// The box rays are clipped to, in voxel-index coordinates of `geometry`: the voxel
    /// box `[0, dims - 1]`, or for a coarser level of a bricked file the finest level's box
    /// (every level covers the same world box; past the coarse voxel centres, at most half
    /// a coarse voxel, the edge cells extend and samples clamp to the edge voxels).
    pub frame: [Vec3; 2],
}

impl CellLayout {
    /// The layout of macrocells.
    #[must_use]
    pub fn of(m: &blueshift_volume::Macrocells) -> Self {
        let g = *m.geometry();
        CellLayout {
            geometry: g,
            k: m.k(),
            dims: m.dims(),
            frame: [Vec3::ZERO, voxel_box_top(&g)],
        }
    }

    /// The same layout with rays clipped to the world box `lo..hi` (the finest level's
    /// voxel-centre box) instead of the voxel box; the voxel box where `finest` is this
    /// layout's own geometry, so level 0 walks exactly as before.
    #[must_use]
    pub fn framed(mut self, finest: &blueshift_volume::Geometry) -> Self {
        if *finest != self.geometry {
            let (lo, hi) = finest.world_bounds();
            self.frame = [
                self.geometry.world_to_index(lo),
                self.geometry.world_to_index(hi),
            ];
        }
        self
    }

    /// Number of cells.
    #[must_use]
    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// Always false (a layout has at least one cell).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Linear index of cell `c` (x fastest).
    #[inline]
    #[must_use]
    pub fn linear(&self, c: [usize; 3]) -> usize {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }
}

/// One cell crossed by a ray: its linear index and the parameter range inside it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DdaCell {
    /// Linear cell index (x fastest).
    pub cell: usize,
    /// Entry parameter (world length along the unit ray).
    pub t_min: f32,
    /// Exit parameter.
    pub t_max: f32,
}

/// A 3D DDA walk over a [`CellLayout`], yielding the cells a ray crosses in order of
/// increasing `t`, limited to `t <= t_end`.
#[derive(Clone, Debug)]
pub struct Dda {
    layout_dims: [usize; 3],
    cell: [i64; 3],
    step: [i64; 3],
    // Index-space origin in cell units, and reciprocal direction in cell units.
    o: Vec3,
    inv_d: Vec3,
    t: f32,
    t_end: f32,
    budget: usize,
    done: bool,
    /// Per axis, whether the frame reaches past the voxel box below / above: the edge cell
    /// then extends to the frame (its outer face is never crossed; the walk ends at `t_end`).
    open_lo: [bool; 3],
    open_hi: [bool; 3],
}

/// The voxel-centre box's upper corner in index coordinates: `dims - 1`.
fn voxel_box_top(g: &blueshift_volume::Geometry) -> Vec3 {
    Vec3::new(
        (g.dims[0] - 1) as f32,
        (g.dims[1] - 1) as f32,
        (g.dims[2] - 1) as f32,
    )
}

impl Dda {
    /// Starts a walk of `ray` over `layout` for `t` in `[0, t_max]` (clipped to the voxel box).
    #[must_use]
    pub fn new(layout: &CellLayout, ray: &Ray, t_max: f32) -> Self {
        let g = &layout.geometry;
        let kf = layout.k as f32;
        let o = g.world_to_index(ray.origin) / kf;
        let d = ray.dir / g.spacing / kf;
        let top = voxel_box_top(g);
        let n = top / kf;
        let [flo, fhi] = layout.frame;
        let mut dda = Dda {
            layout_dims: layout.dims,
            cell: [0; 3],
            step: [0; 3],
            o,
            inv_d: Vec3::ZERO,
            t: 0.0,
            t_end: 0.0,
            budget: layout.dims.iter().sum::<usize>() + 4,
            done: true,
            open_lo: [flo.x < 0.0, flo.y < 0.0, flo.z < 0.0],
            open_hi: [fhi.x > top.x, fhi.y > top.y, fhi.z > top.z],
        };
        let Some(local) = Ray::new(o, d) else {
            return dda;
        };
        // Clip in cell space: the unnormalised direction keeps t a world length.
        let local = Ray {
            origin: local.origin,
            dir: d,
        };
        let Some((t0, t1)) = clip_unnormalised(&local, flo / kf, fhi / kf) else {
            return dda;
        };
        let t1 = t1.min(t_max);
        if t0 > t1 {
            return dda;
        }
        let p = (o + d * t0).clamp(Vec3::ZERO, n);
        for a in 0..3 {
            let c = p[a].floor();
            let c = if c.is_nan() { 0.0 } else { c };
            dda.cell[a] = (c as i64).clamp(0, layout.dims[a] as i64 - 1);
            dda.step[a] = if d[a] > 0.0 {
                1
            } else if d[a] < 0.0 {
                -1
            } else {
                0
            };
            dda.inv_d[a] = if d[a] != 0.0 { 1.0 / d[a] } else { 0.0 };
        }
        dda.t = t0;
        dda.t_end = t1;
        dda.done = false;
        dda
    }

    #[inline]
    fn next_crossing(&self, a: usize) -> f32 {
        match self.step[a] {
            0 => f32::INFINITY,
            s if (s < 0 && self.cell[a] == 0 && self.open_lo[a])
                || (s > 0 && self.cell[a] == self.layout_dims[a] as i64 - 1 && self.open_hi[a]) =>
            {
                f32::INFINITY
            }
            s => {
                let boundary = (self.cell[a] + i64::from(s > 0)) as f32;
                (boundary - self.o[a]) * self.inv_d[a]
            }
        }
    }
}

impl Iterator for Dda {
    type Item = DdaCell;

    fn next(&mut self) -> Option<DdaCell> {
        if self.done || self.budget == 0 {
            return None;
        }
        self.budget -= 1;
        let tx = self.next_crossing(0);
        let ty = self.next_crossing(1);
        let tz = self.next_crossing(2);
        let (axis, t_cross) = if tx <= ty && tx <= tz {
            (0, tx)
        } else if ty <= tz {
            (1, ty)
        } else {
            (2, tz)
        };
        let t_exit = t_cross.max(self.t).min(self.t_end);
        let d = &self.layout_dims;
        let cell =
            self.cell[0] as usize + d[0] * (self.cell[1] as usize + d[1] * self.cell[2] as usize);
        let out = DdaCell {
            cell,
            t_min: self.t,
            t_max: t_exit,
        };
        if t_exit >= self.t_end {
            self.done = true;
        } else {
            self.cell[axis] += self.step[axis];
            if self.cell[axis] < 0 || self.cell[axis] >= d[axis] as i64 {
                self.done = true;
            }
            self.t = t_exit;
        }
        Some(out)
    }
}

fn clip_unnormalised(ray: &Ray, lo: Vec3, hi: Vec3) -> Option<(f32, f32)> {
    let mut t0 = 0.0f32;
    let mut t1 = f32::INFINITY;
    for a in 0..3 {
        let o = ray.origin[a];
        let d = ray.dir[a];
        if d == 0.0 {
            if o < lo[a] || o > hi[a] {
                return None;
            }
            continue;
        }
        let (mut ta, mut tb) = ((lo[a] - o) / d, (hi[a] - o) / d);
        if ta > tb {
            std::mem::swap(&mut ta, &mut tb);
        }
        t0 = t0.max(ta);
        t1 = t1.min(tb);
    }
    (t0 <= t1 && t1.is_finite()).then_some((t0, t1))
}

/// A stretch of a ray with a constant majorant (pbrt's `RayMajorantSegment`, CONVENTIONS C6).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MajorantSegment {
    /// Entry parameter (world length).
    pub t_min: f32,
    /// Exit parameter.
    pub t_max: f32,
    /// Majorant extinction per unit world length over the segment.
    pub sigma_maj: f32,
    /// Minorant (a lower bound of the extinction); 0 for now, room for residual ratio tracking.
    pub sigma_min: f32,
}

/// The majorant segments of one channel along a ray: a [`Dda`] over its [`MajorantGrid`].
#[derive(Clone, Debug)]
pub struct DdaMajorantIterator<'a> {
    dda: Dda,
    grid: &'a MajorantGrid,
}

impl<'a> DdaMajorantIterator<'a> {
    /// Segments of `ray` over `grid` for `t` in `[0, t_max]`.
    #[must_use]
    pub fn new(grid: &'a MajorantGrid, ray: &Ray, t_max: f32) -> Self {
        DdaMajorantIterator {
            dda: Dda::new(grid.layout(), ray, t_max),
            grid,
        }
    }
}

impl Iterator for DdaMajorantIterator<'_> {
    type Item = MajorantSegment;

    fn next(&mut self) -> Option<MajorantSegment> {
        let c = self.dda.next()?;
        Some(MajorantSegment {
            t_min: c.t_min,
            t_max: c.t_max,
            sigma_maj: self.grid.values()[c.cell],
            sigma_min: 0.0,
        })
    }
}
