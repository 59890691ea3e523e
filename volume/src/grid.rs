//! Dense 3D grids, their geometry, and trilinear / nearest sampling.

use std::fmt::Debug;
use std::ops::{Add, Mul};

use glam::Vec3;
use half::f16;

use crate::{Error, Limits, Result};

/// Where a grid sits in the world: voxel counts, the world position of voxel `[0, 0, 0]`
/// and the distance between neighbouring voxel centres.
///
/// Voxels are node-centred (as in VTK and NRRD's default): voxel `[i, j, k]` sits at world
/// position `origin + spacing * (i, j, k)`, so the grid covers
/// `origin ..= origin + spacing * (dims - 1)`. Units are whatever the file says (mm for CT,
/// code lengths for simulations); synthetic datasets document theirs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Geometry {
    /// Number of voxels along x, y, z (x fastest in memory).
    pub dims: [usize; 3],
    /// World position of voxel `[0, 0, 0]`.
    pub origin: Vec3,
    /// Distance between voxel centres along x, y, z (positive, finite).
    pub spacing: Vec3,
}

impl Geometry {
    /// A geometry with origin 0 and spacing 1, so world and index space coincide.
    #[must_use]
    pub fn unit(dims: [usize; 3]) -> Self {
        Geometry {
            dims,
            origin: Vec3::ZERO,
            spacing: Vec3::ONE,
        }
    }

    /// Checks that every dimension is at least 1 and spacing and origin are finite, with
    /// positive spacing.
    pub fn validate(&self) -> Result<()> {
        if self.dims.contains(&0) {
            return Err(Error::invalid(format!(
                "dimensions {:?} contain a zero",
                self.dims
            )));
        }
        if !self.spacing.is_finite() || self.spacing.min_element() <= 0.0 {
            return Err(Error::invalid(format!(
                "spacing {} must be finite and positive",
                self.spacing
            )));
        }
        if !self.origin.is_finite() {
            return Err(Error::invalid(format!(
                "origin {} must be finite",
                self.origin
            )));
        }
        Ok(())
    }

    /// Total number of voxels (saturating).
    #[must_use]
    pub fn voxel_count(&self) -> usize {
        self.dims[0]
            .saturating_mul(self.dims[1])
            .saturating_mul(self.dims[2])
    }

    /// Linear index of voxel `[x, y, z]` (x fastest).
    #[inline]
    #[must_use]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        x + self.dims[0] * (y + self.dims[1] * z)
    }

    /// Converts a world position to continuous index coordinates (voxel centres at integers).
    #[inline]
    #[must_use]
    pub fn world_to_index(&self, world: Vec3) -> Vec3 {
        (world - self.origin) / self.spacing
    }

    /// Converts continuous index coordinates to a world position.
    #[inline]
    #[must_use]
    pub fn index_to_world(&self, index: Vec3) -> Vec3 {
        self.origin + index * self.spacing
    }

    /// World-space bounds `(min, max)` of the voxel centres.
    #[must_use]
    pub fn world_bounds(&self) -> (Vec3, Vec3) {
        let d = Vec3::new(
            (self.dims[0] - 1) as f32,
            (self.dims[1] - 1) as f32,
            (self.dims[2] - 1) as f32,
        );
        (self.origin, self.origin + d * self.spacing)
    }

    /// The geometry of the next coarser level of detail: `ceil(dims / 2)` voxels, twice the
    /// spacing, and the origin moved by half a fine voxel, because each coarse voxel is the
    /// mean of fine voxels `2i` and `2i + 1` (see [`crate::lod`]).
    #[must_use]
    pub fn downsampled(&self) -> Geometry {
        Geometry {
            dims: self.dims.map(|d| d.div_ceil(2)),
            origin: self.origin + 0.5 * self.spacing,
            spacing: self.spacing * 2.0,
        }
    }
}

/// The in-memory voxel types. On-disk types map onto these as described in
/// [`crate::io::DiskType`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ScalarType {
    /// Unsigned 8-bit integer.
    U8,
    /// Unsigned 16-bit integer.
    U16,
    /// IEEE half-precision float (`half::f16`).
    F16,
    /// IEEE single-precision float.
    F32,
    /// Three interleaved f32 components (a vector field, e.g. velocity).
    Vec3,
}

impl ScalarType {
    /// Bytes per voxel in memory.
    #[must_use]
    pub fn size_bytes(self) -> usize {
        match self {
            ScalarType::U8 => 1,
            ScalarType::U16 | ScalarType::F16 => 2,
            ScalarType::F32 => 4,
            ScalarType::Vec3 => 12,
        }
    }

    /// Short lower-case name: `u8`, `u16`, `f16`, `f32`, `vec3f32`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            ScalarType::U8 => "u8",
            ScalarType::U16 => "u16",
            ScalarType::F16 => "f16",
            ScalarType::F32 => "f32",
            ScalarType::Vec3 => "vec3f32",
        }
    }
}

/// A value that trilinear interpolation can blend: `f32` for scalar grids, [`Vec3`] for
/// vector grids.
pub trait Interpolant: Copy + Debug + Add<Output = Self> + Mul<f32, Output = Self> {}
impl Interpolant for f32 {}
impl Interpolant for Vec3 {}

/// A voxel type a [`Grid`] can hold: u8, u16, f16, f32 or [`Vec3`].
pub trait Voxel: Copy + Debug + Send + Sync + Default + PartialEq + 'static {
    /// What sampling returns: `f32` for scalars, `Vec3` for vectors.
    type Value: Interpolant;
    /// The matching [`ScalarType`].
    const TYPE: ScalarType;
    /// The voxel as a sampling value (integers convert exactly, without rescaling).
    fn value(self) -> Self::Value;
}

impl Voxel for u8 {
    type Value = f32;
    const TYPE: ScalarType = ScalarType::U8;
    #[inline]
    fn value(self) -> f32 {
        f32::from(self)
    }
}
impl Voxel for u16 {
    type Value = f32;
    const TYPE: ScalarType = ScalarType::U16;
    #[inline]
    fn value(self) -> f32 {
        f32::from(self)
    }
}
impl Voxel for f16 {
    type Value = f32;
    const TYPE: ScalarType = ScalarType::F16;
    #[inline]
    fn value(self) -> f32 {
        self.to_f32()
    }
}
impl Voxel for f32 {
    type Value = f32;
    const TYPE: ScalarType = ScalarType::F32;
    #[inline]
    fn value(self) -> f32 {
        self
    }
}
impl Voxel for Vec3 {
    type Value = Vec3;
    const TYPE: ScalarType = ScalarType::Vec3;
    #[inline]
    fn value(self) -> Vec3 {
        self
    }
}

/// A dense 3D grid of voxels with its [`Geometry`], x fastest in memory.
///
/// The invariant `data.len() == dims.x * dims.y * dims.z` is kept by the constructors.
#[derive(Clone, Debug, PartialEq)]
pub struct Grid<T> {
    geometry: Geometry,
    data: Vec<T>,
}

impl<T: Voxel> Grid<T> {
    /// Wraps `data` (x fastest); refuses a length that does not match `geometry.dims` or an
    /// invalid geometry.
    pub fn from_vec(geometry: Geometry, data: Vec<T>) -> Result<Self> {
        geometry.validate()?;
        let n = geometry.dims[0]
            .checked_mul(geometry.dims[1])
            .and_then(|n| n.checked_mul(geometry.dims[2]));
        if n != Some(data.len()) {
            return Err(Error::invalid(format!(
                "{} voxels given for dimensions {:?}",
                data.len(),
                geometry.dims
            )));
        }
        Ok(Grid { geometry, data })
    }

    /// A grid filled with `T::default()` (zero); checks `geometry` against [`Limits`] first.
    pub fn zeros(geometry: Geometry, limits: &Limits) -> Result<Self> {
        geometry.validate()?;
        let n = limits.check(geometry.dims, std::mem::size_of::<T>())?;
        Ok(Grid {
            geometry,
            data: crate::budget::try_filled_vec(
                usize::try_from(n).map_err(|_| Error::Limits(format!("{n} voxels overflow")))?,
                T::default(),
                "a grid",
            )?,
        })
    }

    /// A grid whose voxel `[x, y, z]` is `f(x, y, z)`, filled in parallel over z slices.
    pub fn from_fn(
        geometry: Geometry,
        f: impl Fn(usize, usize, usize) -> T + Sync,
    ) -> Result<Self> {
        use rayon::prelude::*;
        let mut g = Self::zeros(geometry, &Limits::no_limits())?;
        let [nx, ny, _] = geometry.dims;
        g.data
            .par_chunks_mut(nx * ny)
            .enumerate()
            .for_each(|(z, slice)| {
                for y in 0..ny {
                    for x in 0..nx {
                        slice[x + nx * y] = f(x, y, z);
                    }
                }
            });
        Ok(g)
    }

    /// The grid's geometry.
    #[must_use]
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// Replaces origin and spacing (dims must stay the same).
    pub fn set_geometry(&mut self, geometry: Geometry) -> Result<()> {
        geometry.validate()?;
        if geometry.dims != self.geometry.dims {
            return Err(Error::parameter(format!(
                "new dims {:?} differ from the grid's {:?}",
                geometry.dims, self.geometry.dims
            )));
        }
        self.geometry = geometry;
        Ok(())
    }

    /// Voxel counts along x, y, z.
    #[must_use]
    pub fn dims(&self) -> [usize; 3] {
        self.geometry.dims
    }

    /// All voxels, x fastest.
    #[must_use]
    pub fn data(&self) -> &[T] {
        &self.data
    }

    /// All voxels, mutable (the length cannot change).
    pub fn data_mut(&mut self) -> &mut [T] {
        &mut self.data
    }

    /// Takes the voxel buffer out.
    #[must_use]
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }

    /// Voxel `[x, y, z]`; `None` outside the grid.
    #[must_use]
    pub fn get(&self, x: usize, y: usize, z: usize) -> Option<T> {
        let [nx, ny, nz] = self.geometry.dims;
        (x < nx && y < ny && z < nz).then(|| self.data[self.geometry.index(x, y, z)])
    }

    /// Voxel `[x, y, z]` as its sampling value, with indices clamped to the grid (clamp to
    /// edge).
    #[inline]
    #[must_use]
    pub fn value_clamped(&self, x: i64, y: i64, z: i64) -> T::Value {
        let [nx, ny, nz] = self.geometry.dims;
        let cx = x.clamp(0, nx as i64 - 1) as usize;
        let cy = y.clamp(0, ny as i64 - 1) as usize;
        let cz = z.clamp(0, nz as i64 - 1) as usize;
        self.data[self.geometry.index(cx, cy, cz)].value()
    }

    /// Trilinear interpolation at continuous index coordinates (voxel centres at integers).
    /// Positions outside the grid are clamped to its edge; NaN coordinates give the value
    /// of voxel `[0, 0, 0]`.
    #[inline]
    #[must_use]
    pub fn sample_trilinear_index(&self, p: Vec3) -> T::Value {
        let [nx, ny, nz] = self.geometry.dims;
        let ([x0, y0, z0], t) = clamped_cell(p, self.geometry.dims);
        let x1 = (x0 + 1).min(nx - 1);
        let y1 = (y0 + 1).min(ny - 1);
        let z1 = (z0 + 1).min(nz - 1);
        let g = &self.geometry;
        let d = &self.data;
        let v = |x, y, z| d[g.index(x, y, z)].value();
        let lerp = |a: T::Value, b: T::Value, t: f32| a * (1.0 - t) + b * t;
        let c00 = lerp(v(x0, y0, z0), v(x1, y0, z0), t.x);
        let c10 = lerp(v(x0, y1, z0), v(x1, y1, z0), t.x);
        let c01 = lerp(v(x0, y0, z1), v(x1, y0, z1), t.x);
        let c11 = lerp(v(x0, y1, z1), v(x1, y1, z1), t.x);
        lerp(lerp(c00, c10, t.y), lerp(c01, c11, t.y), t.z)
    }

    /// Nearest-voxel sampling at continuous index coordinates (rounds half away from zero,
    /// clamps to the grid).
    #[inline]
    #[must_use]
    pub fn sample_nearest_index(&self, p: Vec3) -> T::Value {
        let r = p.round();
        let c = |v: f32| if v.is_nan() { 0 } else { v as i64 };
        self.value_clamped(c(r.x), c(r.y), c(r.z))
    }

    /// Trilinear interpolation at a world position.
    #[inline]
    #[must_use]
    pub fn sample_trilinear(&self, world: Vec3) -> T::Value {
        self.sample_trilinear_index(self.geometry.world_to_index(world))
    }

    /// Nearest-voxel sampling at a world position.
    #[inline]
    #[must_use]
    pub fn sample_nearest(&self, world: Vec3) -> T::Value {
        self.sample_nearest_index(self.geometry.world_to_index(world))
    }
}

/// The trilinear cell of continuous index coordinates `p` in a grid of `dims` voxels: `p`
/// clamped to `[0, dims - 1]` per axis (NaN to 0), the cell's lower corner and the weights
/// `p - corner`. The corner is the clamped coordinate's floor, computed by truncation (the
/// coordinate is never negative, and at or above 2^24 an `f32` is an integer): the same bits
/// as `floor`, without the libm call `floor` costs on the x86-64 baseline, which has no
/// rounding instruction. The corner is at most `dims - 1` on every axis, also where a side
/// is too long for `f32` to hold its last index exactly.
#[inline(always)]
pub(crate) fn clamped_cell(p: Vec3, dims: [usize; 3]) -> ([usize; 3], Vec3) {
    let [nx, ny, nz] = dims;
    let max = Vec3::new((nx - 1) as f32, (ny - 1) as f32, (nz - 1) as f32);
    // `max(ZERO)` first so NaN maps to 0.
    let p = p.max(Vec3::ZERO).min(max);
    let p = Vec3::new(
        if p.x.is_nan() { 0.0 } else { p.x },
        if p.y.is_nan() { 0.0 } else { p.y },
        if p.z.is_nan() { 0.0 } else { p.z },
    );
    // `min`: past 2^24 voxels a side, `(n - 1) as f32` can round up to `n`.
    let c = [
        (p.x as usize).min(nx - 1),
        (p.y as usize).min(ny - 1),
        (p.z as usize).min(nz - 1),
    ];
    let t = p - Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32);
    (c, t)
}

/// A grid of any supported voxel type, for code that loads files of unknown type.
#[derive(Clone, Debug, PartialEq)]
pub enum AnyGrid {
    /// Unsigned 8-bit scalars.
    U8(Grid<u8>),
    /// Unsigned 16-bit scalars.
    U16(Grid<u16>),
    /// Half-precision scalars.
    F16(Grid<f16>),
    /// Single-precision scalars.
    F32(Grid<f32>),
    /// f32 3-vectors (velocity and other vector fields).
    Vec3(Grid<Vec3>),
}

macro_rules! dispatch {
    ($self:expr, $g:ident => $e:expr) => {
        match $self {
            AnyGrid::U8($g) => $e,
            AnyGrid::U16($g) => $e,
            AnyGrid::F16($g) => $e,
            AnyGrid::F32($g) => $e,
            AnyGrid::Vec3($g) => $e,
        }
    };
}

impl AnyGrid {
    /// The grid's geometry.
    #[must_use]
    pub fn geometry(&self) -> &Geometry {
        dispatch!(self, g => g.geometry())
    }

    /// The voxel type.
    #[must_use]
    pub fn scalar_type(&self) -> ScalarType {
        match self {
            AnyGrid::U8(_) => ScalarType::U8,
            AnyGrid::U16(_) => ScalarType::U16,
            AnyGrid::F16(_) => ScalarType::F16,
            AnyGrid::F32(_) => ScalarType::F32,
            AnyGrid::Vec3(_) => ScalarType::Vec3,
        }
    }

    /// Replaces origin and spacing (dims must stay the same).
    pub fn set_geometry(&mut self, geometry: Geometry) -> Result<()> {
        dispatch!(self, g => g.set_geometry(geometry))
    }

    /// True for the vector variant.
    #[must_use]
    pub fn is_vector(&self) -> bool {
        matches!(self, AnyGrid::Vec3(_))
    }

    /// Scalar value of voxel at linear index `i`; vector grids give the vector's length.
    #[inline]
    #[must_use]
    pub fn scalar_at(&self, i: usize) -> f32 {
        match self {
            AnyGrid::U8(g) => g.data[i].value(),
            AnyGrid::U16(g) => g.data[i].value(),
            AnyGrid::F16(g) => g.data[i].value(),
            AnyGrid::F32(g) => g.data[i],
            AnyGrid::Vec3(g) => g.data[i].length(),
        }
    }

    /// Trilinear sample at continuous index coordinates as a scalar; vector grids give the
    /// length of the interpolated vector.
    #[must_use]
    pub fn sample_scalar_index(&self, p: Vec3) -> f32 {
        match self {
            AnyGrid::U8(g) => g.sample_trilinear_index(p),
            AnyGrid::U16(g) => g.sample_trilinear_index(p),
            AnyGrid::F16(g) => g.sample_trilinear_index(p),
            AnyGrid::F32(g) => g.sample_trilinear_index(p),
            AnyGrid::Vec3(g) => g.sample_trilinear_index(p).length(),
        }
    }

    /// A copy of the scalar values as f32 (vector grids: lengths).
    #[must_use]
    pub fn to_f32_vec(&self) -> Vec<f32> {
        (0..self.geometry().voxel_count())
            .map(|i| self.scalar_at(i))
            .collect()
    }

    /// Minimum and maximum of the finite scalar values (vector grids: lengths); `None` if no
    /// value is finite.
    #[must_use]
    pub fn finite_range(&self) -> Option<(f32, f32)> {
        let n = self.geometry().voxel_count();
        let mut lo = f32::INFINITY;
        let mut hi = f32::NEG_INFINITY;
        for i in 0..n {
            let v = self.scalar_at(i);
            if v.is_finite() {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        (lo <= hi).then_some((lo, hi))
    }

    /// Refuses NaN or ±Inf anywhere (any component of a vector).
    pub fn reject_non_finite(&self) -> Result<()> {
        let g = *self.geometry();
        let bad = |i: usize, value: f32| {
            let [nx, ny, _] = g.dims;
            Err(Error::NonFinite {
                value,
                x: i % nx,
                y: (i / nx) % ny,
                z: i / (nx * ny),
            })
        };
        match self {
            AnyGrid::F16(grid) => {
                for (i, v) in grid.data.iter().enumerate() {
                    if !v.is_finite() {
                        return bad(i, v.to_f32());
                    }
                }
            }
            AnyGrid::F32(grid) => {
                for (i, v) in grid.data.iter().enumerate() {
                    if !v.is_finite() {
                        return bad(i, *v);
                    }
                }
            }
            AnyGrid::Vec3(grid) => {
                for (i, v) in grid.data.iter().enumerate() {
                    if let Some(c) = v.to_array().into_iter().find(|c| !c.is_finite()) {
                        return bad(i, c);
                    }
                }
            }
            AnyGrid::U8(_) | AnyGrid::U16(_) => {}
        }
        Ok(())
    }
}

macro_rules! from_grid {
    ($t:ty, $v:ident) => {
        impl From<Grid<$t>> for AnyGrid {
            fn from(g: Grid<$t>) -> Self {
                AnyGrid::$v(g)
            }
        }
    };
}
from_grid!(u8, U8);
from_grid!(u16, U16);
from_grid!(f16, F16);
from_grid!(f32, F32);
from_grid!(Vec3, Vec3);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clamped_cell_is_the_floor_and_stays_inside_the_grid() {
        // The floor of the clamped coordinate, against `f32::floor`.
        for i in 0..20_000 {
            let x = i as f32 * 0.0137 - 3.0;
            let ([c, _, _], t) = clamped_cell(Vec3::new(x, 0.5, 0.5), [200, 2, 2]);
            let p = x.clamp(0.0, 199.0);
            assert_eq!(c as f32, p.floor(), "x = {x}");
            assert_eq!(t.x.to_bits(), (p - p.floor()).to_bits(), "x = {x}");
        }
        // NaN and values below the grid go to 0, with +0 weights.
        let (c, t) = clamped_cell(Vec3::new(f32::NAN, -3.0, f32::NEG_INFINITY), [4, 4, 4]);
        assert_eq!(c, [0, 0, 0]);
        assert_eq!(t.to_array().map(f32::to_bits), [0; 3]);
        // A side of 2^24 + 4 voxels: its last index, 2^24 + 3, rounds up to 2^24 + 4 in f32.
        let n = (1usize << 24) + 4;
        assert_eq!((n - 1) as f32 as usize, n);
        let (c, _) = clamped_cell(Vec3::new(f32::INFINITY, 0.0, 0.0), [n, 1, 1]);
        assert_eq!(c[0], n - 1);
    }
}
