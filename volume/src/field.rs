//! The one field-source abstraction every integrator samples through: a dense in-memory
//! grid, or one level of detail of bricked data (a `.bsv` file, or bricks derived from
//! others) read through a bounded [`BrickCache`].
//!
//! Sampling a bricked level gives the same `f32`, bit for bit, as trilinear sampling of the
//! dense grid of that level: the same clamping, the same interpolation in the same order,
//! and the apron of each brick repeats exactly the voxels the dense sampler would read.
//!
//! # Levels of detail (HDR VolVis section 6.3)
//!
//! [`lod_level`] states the rule: the coarsest level whose voxel spacing is at most the
//! footprint of one pixel where the volume is nearest to the camera, so no sample of the
//! view is under-resolved and a zoomed-out view reads coarse bricks only.

use std::cell::RefCell;
use std::sync::Arc;

use glam::Vec3;

use crate::cache::{BrickCache, BrickSource, next_uid};
use crate::grid::{AnyGrid, Geometry, Grid};
use crate::macrocell::Macrocells;
use crate::ooc::BrickLayout;
use crate::{Error, Limits, Result};

/// A scalar field: dense, or one level of bricked data.
#[derive(Clone, Debug)]
pub enum Field {
    /// An in-memory grid.
    Dense(AnyGrid),
    /// One level of detail of bricked data behind a shared cache.
    Bricked(BrickedField),
}

impl From<AnyGrid> for Field {
    fn from(g: AnyGrid) -> Self {
        Field::Dense(g)
    }
}

impl<T: crate::Voxel> From<Grid<T>> for Field
where
    AnyGrid: From<Grid<T>>,
{
    fn from(g: Grid<T>) -> Self {
        Field::Dense(g.into())
    }
}

impl From<BrickedField> for Field {
    fn from(b: BrickedField) -> Self {
        Field::Bricked(b)
    }
}

impl Field {
    /// Geometry of the sampled grid (of the chosen level for bricked data).
    #[must_use]
    pub fn geometry(&self) -> &Geometry {
        match self {
            Field::Dense(g) => g.geometry(),
            Field::Bricked(b) => &b.geometry,
        }
    }

    /// True for a dense vector grid (bricked data is always scalar).
    #[must_use]
    pub fn is_vector(&self) -> bool {
        matches!(self, Field::Dense(g) if g.is_vector())
    }

    /// The dense grid, if this field is one.
    #[must_use]
    pub fn as_dense(&self) -> Option<&AnyGrid> {
        match self {
            Field::Dense(g) => Some(g),
            Field::Bricked(_) => None,
        }
    }

    /// The bricked level, if this field is one.
    #[must_use]
    pub fn as_bricked(&self) -> Option<&BrickedField> {
        match self {
            Field::Dense(_) => None,
            Field::Bricked(b) => Some(b),
        }
    }

    /// Trilinear sample at continuous index coordinates, clamped to the grid (vector grids:
    /// the length of the interpolated vector). A brick that cannot be read gives 0 and is
    /// reported by [`Field::check_io`].
    #[inline]
    #[must_use]
    pub fn sample_scalar_index(&self, p: Vec3) -> f32 {
        match self {
            Field::Dense(g) => g.sample_scalar_index(p),
            Field::Bricked(b) => b.sample_index(p),
        }
    }

    /// Voxel at linear index `i` (x fastest) as a scalar (vector grids: the length); a
    /// bricked voxel is read through the cache (0 if its brick cannot be read, kept for
    /// [`Field::check_io`]).
    #[must_use]
    pub fn scalar_at(&self, i: usize) -> f32 {
        match self {
            Field::Dense(g) => g.scalar_at(i),
            Field::Bricked(b) => {
                let [nx, ny, _] = b.geometry.dims;
                b.voxel([i % nx, (i / nx) % ny, i / (nx * ny)])
                    .unwrap_or_else(|e| {
                        b.cache.record_error(&e);
                        0.0
                    })
            }
        }
    }

    /// Macrocells of edge `k` (stored in the `.bsv` file when it has them for `k`; otherwise
    /// built brick by brick through the cache, never holding the whole level).
    pub fn macrocells(&self, k: usize) -> Result<Macrocells> {
        match self {
            Field::Dense(g) => Macrocells::build_any(g, k),
            Field::Bricked(b) => b.macrocells(k),
        }
    }

    /// Range of the finite values.
    #[must_use]
    pub fn finite_range(&self) -> Option<(f32, f32)> {
        match self {
            Field::Dense(g) => g.finite_range(),
            Field::Bricked(b) => b.source.finite_range(),
        }
    }

    /// Smallest positive and largest finite value, where some value is positive (for
    /// logarithmic axes).
    #[must_use]
    pub fn positive_range(&self) -> Option<(f32, f32)> {
        match self {
            Field::Dense(g) => {
                let (mut lo, mut hi) = (f32::INFINITY, 0.0f32);
                for k in 0..g.geometry().voxel_count() {
                    let v = g.scalar_at(k);
                    if v.is_finite() && v > 0.0 {
                        lo = lo.min(v);
                        hi = hi.max(v);
                    }
                }
                (hi > 0.0).then_some((lo, hi))
            }
            Field::Bricked(b) => {
                let lo = b.source.positive_min()?;
                let (_, hi) = b.source.finite_range()?;
                Some((lo, hi))
            }
        }
    }

    /// Geometry of the finest level (the field's own for dense grids): cameras frame this,
    /// so every level of detail is seen through the same view.
    #[must_use]
    pub fn finest_geometry(&self) -> &Geometry {
        match self {
            Field::Dense(g) => g.geometry(),
            Field::Bricked(b) => &b.source.geometries()[0],
        }
    }

    /// The type voxels are held in (bricked data: decoded f32).
    #[must_use]
    pub fn scalar_type(&self) -> crate::ScalarType {
        match self {
            Field::Dense(g) => g.scalar_type(),
            Field::Bricked(_) => crate::ScalarType::F32,
        }
    }

    /// Calls `f` on the field's voxels block by block: the whole grid at once for a dense
    /// field (x fastest), each brick's own voxels for a bricked one (read past the cache, so
    /// a pass over the volume does not evict what the renderer holds).
    pub fn for_each_block(&self, mut f: impl FnMut(&[f32])) -> Result<()> {
        match self {
            Field::Dense(g) => {
                f(&g.to_f32_vec());
                Ok(())
            }
            Field::Bricked(b) => {
                let nb = b.bricks;
                let mut own = Vec::new();
                for idx in 0..(nb[0] * nb[1] * nb[2]) as u64 {
                    b.own_voxels(idx, &mut own)?;
                    f(&own);
                }
                Ok(())
            }
        }
    }

    /// Mean of the voxels (0 for none). A field sampled at a level per region (adaptive
    /// data) is averaged region by region at each region's own level, each coarse voxel
    /// weighted by the base voxels it stands for, so an AMR field's mean costs its data's
    /// size, not its finest level's.
    pub fn mean(&self) -> Result<f64> {
        if let Field::Bricked(b) = self
            && b.regions.is_some()
        {
            let (mut s, mut n) = (0.0f64, 0.0f64);
            let (mut v, mut w) = (Vec::new(), Vec::new());
            for r in 0..b.region_count() {
                b.region_samples(r, &mut v, &mut w)?;
                for (&x, &k) in v.iter().zip(&w) {
                    s += f64::from(x) * k;
                    n += k;
                }
            }
            return Ok(if n == 0.0 { 0.0 } else { s / n });
        }
        let (mut s, mut n) = (0.0f64, 0usize);
        self.for_each_block(|v| {
            s += v.iter().map(|&x| f64::from(x)).sum::<f64>();
            n += v.len();
        })?;
        Ok(if n == 0 { 0.0 } else { s / n as f64 })
    }

    /// Mean weighted by `weights` voxel by voxel (same geometry; bricked fields: same
    /// layout); `None` when the weights sum to 0.
    pub fn weighted_mean(&self, weights: &Field) -> Result<Option<f64>> {
        let (mut s, mut w) = (0.0f64, 0.0f64);
        let mut acc = |v: &[f32], d: &[f32]| {
            for (&a, &b) in v.iter().zip(d) {
                s += f64::from(a) * f64::from(b);
                w += f64::from(b);
            }
        };
        match (self, weights) {
            (Field::Bricked(a), Field::Bricked(b))
                if a.bricks == b.bricks
                    && a.layout == b.layout
                    && a.regions.is_some()
                    && a.level_map().map(LevelMap::levels)
                        == b.level_map().map(LevelMap::levels) =>
            {
                let (mut x, mut y, mut k, mut k2) =
                    (Vec::new(), Vec::new(), Vec::new(), Vec::new());
                for r in 0..a.region_count() {
                    a.region_samples(r, &mut x, &mut k)?;
                    b.region_samples(r, &mut y, &mut k2)?;
                    for ((&p, &q), &n) in x.iter().zip(&y).zip(&k) {
                        s += f64::from(p) * f64::from(q) * n;
                        w += f64::from(q) * n;
                    }
                }
            }
            (Field::Bricked(a), Field::Bricked(b))
                if a.bricks == b.bricks && a.layout == b.layout =>
            {
                let nb = a.bricks;
                let (mut x, mut y) = (Vec::new(), Vec::new());
                for idx in 0..(nb[0] * nb[1] * nb[2]) as u64 {
                    a.own_voxels(idx, &mut x)?;
                    b.own_voxels(idx, &mut y)?;
                    acc(&x, &y);
                }
            }
            (Field::Dense(_), Field::Dense(_)) => {
                let (v, d) = (
                    self.to_dense(&Limits::no_limits())?,
                    weights.to_dense(&Limits::no_limits())?,
                );
                acc(&v.to_f32_vec(), &d.to_f32_vec());
            }
            _ => {
                return Err(Error::parameter(
                    "a weighted mean needs both fields in memory or both bricked alike",
                ));
            }
        }
        Ok((w > 0.0).then(|| s / w))
    }

    /// Refuses NaN or infinite values (bricked files count them when written).
    pub fn reject_non_finite(&self) -> Result<()> {
        match self {
            Field::Dense(g) => g.reject_non_finite(),
            Field::Bricked(b) => match b.source.non_finite() {
                0 => Ok(()),
                n => Err(Error::invalid(format!(
                    "{n} voxels are NaN or infinite in the bricked data"
                ))),
            },
        }
    }

    /// The first brick read that failed while sampling, as an error (dense fields: `Ok`).
    pub fn check_io(&self) -> Result<()> {
        match self {
            Field::Dense(_) => Ok(()),
            Field::Bricked(b) => b.cache.take_error(),
        }
    }

    /// The `edge^3` voxels from `lo` (x fastest) into `out`, each index clamped to the grid
    /// (`out[l]` is voxel `min(lo + l, dims - 1)` per axis): the block a device brick pool
    /// holds, with the clamped neighbours trilinear sampling reads. Vector grids give
    /// lengths; a bricked level is read through the cache, each source brick looked up once.
    pub fn read_block(&self, lo: [usize; 3], edge: usize, out: &mut [f32]) -> Result<()> {
        check_block(self.geometry(), lo, edge, out)?;
        match self {
            Field::Dense(g) => {
                let n = g.geometry().dims;
                fill_block(n, lo, edge, out, |x0, x1, y, z, row| {
                    let at = x0 + n[0] * (y + n[1] * z);
                    for (i, o) in row.iter_mut().enumerate().take(x1 - x0) {
                        *o = g.scalar_at(at + i);
                    }
                    Ok(())
                })
            }
            Field::Bricked(b) => b.read_block(lo, edge, out),
        }
    }

    /// The values as f32, x fastest (vector grids: lengths); a bricked level is loaded whole
    /// (what the GPU backends upload; checked against the default [`Limits`]).
    pub fn dense_f32(&self) -> Result<Vec<f32>> {
        match self {
            Field::Dense(g) => Ok(g.to_f32_vec()),
            Field::Bricked(b) => Ok(b.load(&Limits::default())?.into_vec()),
        }
    }

    /// The field as a dense grid: the grid itself, or its level loaded whole (checked
    /// against `limits` before allocating).
    pub fn to_dense(&self, limits: &Limits) -> Result<AnyGrid> {
        match self {
            Field::Dense(g) => Ok(g.clone()),
            Field::Bricked(b) => b.load(limits).map(AnyGrid::from),
        }
    }
}

/// A vector field (velocity): a dense `Vec3` grid, or three scalar fields (bricked files hold
/// scalars). Both sample bit-identically for the same voxels.
#[derive(Clone, Debug)]
pub enum VectorField {
    /// An in-memory vector grid.
    Dense(Grid<Vec3>),
    /// x, y and z components.
    Components(Box<[Field; 3]>),
}

impl From<Grid<Vec3>> for VectorField {
    fn from(g: Grid<Vec3>) -> Self {
        VectorField::Dense(g)
    }
}

impl VectorField {
    /// Geometry of the field.
    #[must_use]
    pub fn geometry(&self) -> &Geometry {
        match self {
            VectorField::Dense(g) => g.geometry(),
            VectorField::Components(c) => c[0].geometry(),
        }
    }

    /// Trilinear sample at continuous index coordinates.
    #[inline]
    #[must_use]
    pub fn sample_index(&self, p: Vec3) -> Vec3 {
        match self {
            VectorField::Dense(g) => g.sample_trilinear_index(p),
            VectorField::Components(c) => Vec3::new(
                c[0].sample_scalar_index(p),
                c[1].sample_scalar_index(p),
                c[2].sample_scalar_index(p),
            ),
        }
    }

    /// The largest speed (dense: over the voxels; components: a bound from each component's
    /// range), m/s in the field's units.
    #[must_use]
    pub fn max_speed(&self) -> f64 {
        match self {
            VectorField::Dense(g) => g
                .data()
                .iter()
                .fold(0.0f64, |m, x| m.max(f64::from(x.length()))),
            VectorField::Components(c) => c
                .iter()
                .map(|f| {
                    f.finite_range()
                        .map_or(0.0, |(lo, hi)| f64::from(lo.abs().max(hi.abs())))
                })
                .map(|m| m * m)
                .sum::<f64>()
                .sqrt(),
        }
    }

    /// The dense grid, if this field is one.
    #[must_use]
    pub fn as_dense(&self) -> Option<&Grid<Vec3>> {
        match self {
            VectorField::Dense(g) => Some(g),
            VectorField::Components(_) => None,
        }
    }

    /// The field as a dense vector grid (components loaded whole, checked against `limits`).
    pub fn to_dense(&self, limits: &Limits) -> Result<Grid<Vec3>> {
        match self {
            VectorField::Dense(g) => Ok(g.clone()),
            VectorField::Components(c) => {
                let g = *c[0].geometry();
                limits.check(g.dims, 12)?;
                let parts = [
                    c[0].to_dense(limits)?,
                    c[1].to_dense(limits)?,
                    c[2].to_dense(limits)?,
                ];
                let n = g.voxel_count();
                let data = (0..n)
                    .map(|i| {
                        Vec3::new(
                            parts[0].scalar_at(i),
                            parts[1].scalar_at(i),
                            parts[2].scalar_at(i),
                        )
                    })
                    .collect();
                Grid::from_vec(g, data)
            }
        }
    }

    /// The vectors as x, y, z f32 triples, x fastest (components are loaded whole).
    pub fn dense_xyz(&self) -> Result<Vec<f32>> {
        match self {
            VectorField::Dense(g) => Ok(g.data().iter().flat_map(|p| p.to_array()).collect()),
            VectorField::Components(_) => Ok(self
                .to_dense(&Limits::default())?
                .data()
                .iter()
                .flat_map(|p| p.to_array())
                .collect()),
        }
    }

    /// Component `axis` (0 x, 1 y, 2 z) of the `edge^3` voxels from `lo`, clamped as
    /// [`Field::read_block`] clamps.
    pub fn read_block(
        &self,
        axis: usize,
        lo: [usize; 3],
        edge: usize,
        out: &mut [f32],
    ) -> Result<()> {
        if axis > 2 {
            return Err(Error::parameter(format!("vector component {axis}")));
        }
        match self {
            VectorField::Dense(g) => {
                check_block(g.geometry(), lo, edge, out)?;
                let n = g.geometry().dims;
                let data = g.data();
                fill_block(n, lo, edge, out, |x0, x1, y, z, row| {
                    let at = x0 + n[0] * (y + n[1] * z);
                    for (o, v) in row.iter_mut().zip(&data[at..at + (x1 - x0)]) {
                        *o = v[axis];
                    }
                    Ok(())
                })
            }
            VectorField::Components(c) => c[axis].read_block(lo, edge, out),
        }
    }

    /// The first failed brick read of any component.
    pub fn check_io(&self) -> Result<()> {
        match self {
            VectorField::Dense(_) => Ok(()),
            VectorField::Components(c) => c.iter().try_for_each(Field::check_io),
        }
    }
}

/// `m` widened so each cell bounds the samples of levels up to `top` levels coarser taken
/// inside it. A coarse voxel is the mean of the fine voxels it covers (`lod::downsample_row`),
/// and a sample of level `L` at fine index `p` blends coarse voxels covering fine voxels
/// within `1.5 * 2^L` of `p`: so each cell takes the min and max of the cells within
/// `ceil(1.5 * 2^top / k)` of it per axis (separable), widened by a relative 1e-6 for the
/// means' f32 rounding.
fn widen_for_levels(m: &Macrocells, top: usize) -> Result<Macrocells> {
    let k = m.k();
    let reach = (3usize << top).div_ceil(2).div_ceil(k);
    let d = m.dims();
    let (mut lo, mut hi) = (m.mins().to_vec(), m.maxs().to_vec());
    let stride = [1, d[0], d[0] * d[1]];
    for a in 0..3 {
        let (src_lo, src_hi) = (lo.clone(), hi.clone());
        for i in 0..lo.len() {
            let c = (i / stride[a]) % d[a];
            let (from, to) = (c.saturating_sub(reach), (c + reach).min(d[a] - 1));
            let base = i - c * stride[a];
            let (mut a_lo, mut a_hi) = (f32::INFINITY, f32::NEG_INFINITY);
            for j in from..=to {
                a_lo = a_lo.min(src_lo[base + j * stride[a]]);
                a_hi = a_hi.max(src_hi[base + j * stride[a]]);
            }
            lo[i] = a_lo;
            hi[i] = a_hi;
        }
    }
    for v in lo.iter_mut().filter(|v| v.is_finite()) {
        *v -= v.abs() * 1e-6;
    }
    for v in hi.iter_mut().filter(|v| v.is_finite()) {
        *v += v.abs() * 1e-6;
    }
    Macrocells::from_parts(*m.geometry(), k, lo, hi)
}

/// Checks a block request of [`Field::read_block`]: `lo` inside the grid, `out` of `edge^3`.
fn check_block(g: &Geometry, lo: [usize; 3], edge: usize, out: &[f32]) -> Result<()> {
    if edge == 0 || lo.iter().zip(g.dims).any(|(&l, n)| l >= n) {
        return Err(Error::parameter(format!(
            "block of edge {edge} at {lo:?} outside a {:?} grid",
            g.dims
        )));
    }
    if edge.checked_pow(3) != Some(out.len()) {
        return Err(Error::parameter(format!(
            "block of edge {edge} into {} values",
            out.len()
        )));
    }
    Ok(())
}

/// Fills the clamped block: `row(x0, x1, y, z, out)` writes voxels `x0..x1` of row `(y, z)`
/// (in bounds) to the start of `out`; the clamped tail of each row repeats its last voxel.
fn fill_block(
    n: [usize; 3],
    lo: [usize; 3],
    edge: usize,
    out: &mut [f32],
    mut row: impl FnMut(usize, usize, usize, usize, &mut [f32]) -> Result<()>,
) -> Result<()> {
    let x1 = (lo[0] + edge).min(n[0]);
    let w = x1 - lo[0];
    for (j, dst) in out.chunks_exact_mut(edge).enumerate() {
        let (ly, lz) = (j % edge, j / edge);
        let y = (lo[1] + ly).min(n[1] - 1);
        let z = (lo[2] + lz).min(n[2] - 1);
        row(lo[0], x1, y, z, &mut dst[..w])?;
        let last = dst[w - 1];
        dst[w..].fill(last);
    }
    Ok(())
}

/// Slots of recently used bricks per thread (direct-mapped by source identity).
const RECENT: usize = 16;

type Recent = [Option<(u64, u32, u64, Arc<[f32]>)>; RECENT];

thread_local! {
    static RECENT_BRICKS: RefCell<Recent> = const { RefCell::new([const { None }; RECENT]) };
}

/// One level of detail of a [`BrickSource`], sampled through a shared [`BrickCache`].
///
/// Each sampling thread keeps the brick it used last for this source, so coherent samples
/// along a ray touch neither the cache's lock nor a reference count.
#[derive(Clone, Debug)]
pub struct BrickedField {
    source: Arc<dyn BrickSource>,
    cache: Arc<BrickCache>,
    level: usize,
    geometry: Geometry,
    layout: BrickLayout,
    bricks: [usize; 3],
    /// `source.uid()`, kept so the per-sample slot lookup makes no virtual call.
    uid: u64,
    /// Levels of detail per region of this level ([`BrickedField::per_region`]).
    regions: Option<Arc<LevelMap>>,
}

/// A level of detail per region of a field's finest sampled level (HDR VolVis section 6.3
/// chooses a level per brick): each region is one brick of that level, and a sample takes
/// the level of the region its position falls in.
#[derive(Debug)]
pub struct LevelMap {
    /// Regions per axis.
    dims: [usize; 3],
    /// Edge of a region in voxels of the base level (the source's brick).
    edge: usize,
    /// The level of each region (x fastest).
    levels: Vec<u8>,
    /// The source at every level from the base to the coarsest used.
    fields: Vec<BrickedField>,
}

impl LevelMap {
    /// The level of each region, x fastest.
    #[must_use]
    pub fn levels(&self) -> &[u8] {
        &self.levels
    }

    /// Regions per axis.
    #[must_use]
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Edge of a region in voxels of the base level (the source's brick).
    #[must_use]
    pub fn edge(&self) -> usize {
        self.edge
    }

    /// The source at every level from the base (index 0) to the coarsest any region
    /// samples, each one level everywhere.
    #[must_use]
    pub fn fields(&self) -> &[BrickedField] {
        &self.fields
    }

    /// Whether `other` samples the same level at every point: the same regions, levels and
    /// level geometries (fields of one pyramid cut alike, perhaps different channels).
    #[must_use]
    pub fn same_regions(&self, other: &LevelMap) -> bool {
        self.dims == other.dims
            && self.edge == other.edge
            && self.levels == other.levels
            && self.fields.len() == other.fields.len()
            && self
                .fields
                .iter()
                .zip(&other.fields)
                .all(|(a, b)| a.geometry == b.geometry)
    }

    /// Regions sampled at each level (index = level offset from the base).
    #[must_use]
    pub fn histogram(&self) -> Vec<usize> {
        let mut h = vec![0; self.fields.len()];
        for &l in &self.levels {
            h[usize::from(l)] += 1;
        }
        h
    }
}

impl BrickedField {
    /// Level `level` of `source`, read through `cache`.
    pub fn new(source: Arc<dyn BrickSource>, cache: Arc<BrickCache>, level: usize) -> Result<Self> {
        let geometry = *source.geometries().get(level).ok_or_else(|| {
            Error::parameter(format!(
                "level {level} of a bricked volume with {} levels",
                source.geometries().len()
            ))
        })?;
        let layout = source.layout();
        let field = BrickedField {
            bricks: layout.bricks(geometry.dims),
            uid: source.uid(),
            source,
            cache,
            level,
            geometry,
            layout,
            regions: None,
        };
        // Adaptive sources (AMR) sample each region at the level of its own data.
        match field.source.region_levels(level) {
            Some(r) if r.iter().any(|&l| usize::from(l) > level) => field.with_levels(r),
            _ => Ok(field),
        }
    }

    /// This field with the absolute level `levels[i]` (clamped to this level and the
    /// coarsest) in region `i` (one brick of this level each, x fastest).
    fn with_levels(mut self, levels: Vec<u8>) -> Result<Self> {
        let base = self.level;
        let last = self.levels() - 1;
        let mut top = 0usize;
        let levels: Vec<u8> = levels
            .into_iter()
            .map(|l| {
                let l = usize::from(l).clamp(base, last) - base;
                top = top.max(l);
                u8::try_from(l).unwrap_or(u8::MAX)
            })
            .collect();
        let plain = BrickedField {
            regions: None,
            ..self.clone()
        };
        let fields = (0..=top)
            .map(|l| {
                if l == 0 {
                    Ok(plain.clone())
                } else {
                    plain.plain_at_level(base + l)
                }
            })
            .collect::<Result<Vec<_>>>()?;
        self.regions = Some(Arc::new(LevelMap {
            dims: self.bricks,
            edge: self.layout.brick,
            levels,
            fields,
        }));
        Ok(self)
    }

    /// The same source at another level, one level everywhere (no regions).
    fn plain_at_level(&self, level: usize) -> Result<Self> {
        let geometry = *self.source.geometries().get(level).ok_or_else(|| {
            Error::parameter(format!(
                "level {level} of a bricked volume with {} levels",
                self.source.geometries().len()
            ))
        })?;
        Ok(BrickedField {
            bricks: self.layout.bricks(geometry.dims),
            level,
            geometry,
            regions: None,
            ..self.clone()
        })
    }

    /// This field with a level of detail per region (one brick of this level each):
    /// `pick(lo, hi)` gives the level, counted from the finest, for the region's world box
    /// (clamped to this level and the coarsest). A sample in a region of level `L` is the
    /// trilinear sample of level `L` at the same world point; geometry, macrocells and the
    /// index space stay this level's, and the macrocells are widened to bound every
    /// region's coarser samples (see [`BrickedField::macrocells`]).
    ///
    /// # Errors
    /// A level the source does not have.
    pub fn per_region(&self, mut pick: impl FnMut(Vec3, Vec3) -> usize) -> Result<Self> {
        let base = self.level;
        let last = self.levels() - 1;
        let edge = self.layout.brick;
        let dims = self.bricks;
        let n = self.geometry.dims;
        let native = self.source.region_levels(base);
        let mut levels = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
        for rz in 0..dims[2] {
            for ry in 0..dims[1] {
                for rx in 0..dims[0] {
                    let r = [rx, ry, rz];
                    let lo = r.map(|c| (c * edge) as f32);
                    let hi = [0, 1, 2].map(|a| (((r[a] + 1) * edge).min(n[a]) - 1) as f32);
                    let w0 = self.geometry.index_to_world(Vec3::from(lo));
                    let w1 = self.geometry.index_to_world(Vec3::from(hi));
                    let mut l = pick(w0.min(w1), w0.max(w1)).clamp(base, last);
                    // Never finer than an adaptive source's own data there.
                    if let Some(n) = &native {
                        l = l.max(usize::from(n[levels.len()]));
                    }
                    levels.push(u8::try_from(l).unwrap_or(u8::MAX));
                }
            }
        }
        BrickedField {
            regions: None,
            ..self.clone()
        }
        .with_levels(levels)
    }

    /// This field with the absolute level `levels[i]` in region `i` (one brick of this
    /// level each, x fastest; clamped to this level and the coarsest, and never finer than
    /// an adaptive source's own data).
    ///
    /// # Errors
    /// A list of the wrong length.
    pub fn with_region_levels(&self, levels: &[u8]) -> Result<Self> {
        let n = self.bricks.iter().product::<usize>();
        if levels.len() != n {
            return Err(Error::parameter(format!(
                "{} region levels for {n} regions",
                levels.len()
            )));
        }
        let native = self.source.region_levels(self.level);
        let levels = levels
            .iter()
            .enumerate()
            .map(|(i, &l)| native.as_ref().map_or(l, |n| l.max(n[i])))
            .collect();
        BrickedField {
            regions: None,
            ..self.clone()
        }
        .with_levels(levels)
    }

    /// The absolute level each region of this field samples (one brick of this level
    /// each, x fastest).
    #[must_use]
    pub fn region_levels(&self) -> Vec<u8> {
        let n = self.bricks.iter().product::<usize>();
        let base = u8::try_from(self.level).unwrap_or(u8::MAX);
        match &self.regions {
            Some(m) => m.levels.iter().map(|&l| base.saturating_add(l)).collect(),
            None => vec![base; n],
        }
    }

    /// This field with every region's level of detail `k` levels coarser, clamped to the
    /// coarsest (a per-region view that holds fewer bricks: what a bounded device pool
    /// falls back on); a field without per-region levels is returned as it is. The second
    /// value says whether any region is coarser than with `k - 1` (false for `k` 0 and once
    /// every region is at the coarsest: a caller stepping `k` up stops there).
    ///
    /// # Errors
    /// As [`BrickedField::per_region`].
    pub fn coarser_regions(&self, k: usize) -> Result<(Self, bool)> {
        let Some(m) = &self.regions else {
            return Ok((self.clone(), false));
        };
        let last = self.levels() - 1;
        let mut moved = false;
        let levels: Vec<u8> = m
            .levels
            .iter()
            .map(|&l| {
                let from = self.level + usize::from(l);
                let to = (from + k).min(last);
                // Coarser than with k - 1.
                moved |= k > 0 && from + k - 1 < last;
                u8::try_from(to).unwrap_or(u8::MAX)
            })
            .collect();
        let plain = BrickedField {
            regions: None,
            ..self.clone()
        };
        Ok((plain.with_levels(levels)?, moved))
    }

    /// [`BrickedField::per_region`] by what the cache holds now (HDR VolVis 6.3's
    /// progressive refinement while bricks load): each region (one brick of this level)
    /// takes the finest level, from this one to the coarsest, whose brick holding the
    /// region's centre is in the cache, and the coarsest level where none is (it is read on
    /// demand). Returns the field and how many regions sample this level itself.
    ///
    /// # Errors
    /// As [`BrickedField::per_region`].
    pub fn resident_regions(&self) -> Result<(Self, usize)> {
        let geoms = self.source.geometries().to_vec();
        let edge = self.layout.brick;
        let (base, last) = (self.level, self.levels() - 1);
        let mut at_base = 0;
        let field = self.per_region(|lo, hi| {
            let centre = (lo + hi) * 0.5;
            let level = (base..=last)
                .find(|&l| {
                    let g = &geoms[l];
                    let nb = g.dims.map(|n| n.div_ceil(edge));
                    let i = g.world_to_index(centre);
                    let b: [usize; 3] = std::array::from_fn(|a| {
                        let c = (i[a].max(0.0) / edge as f32) as usize;
                        c.min(nb[a] - 1)
                    });
                    let idx = (b[0] + nb[0] * (b[1] + nb[1] * b[2])) as u64;
                    self.cache.contains(&*self.source, l, idx)
                })
                .unwrap_or(last);
            if level == base {
                at_base += 1;
            }
            level
        })?;
        Ok((field, at_base))
    }

    /// The coarsest level any sample of this field reads: the largest of its per-region
    /// levels ([`BrickedField::per_region`]), else its level.
    #[must_use]
    pub fn coarsest_sampled_level(&self) -> usize {
        // The map holds levels relative to this field's own.
        self.regions
            .as_deref()
            .and_then(|m| m.levels().iter().max())
            .map_or(self.level, |&l| self.level + usize::from(l))
    }

    /// Bricks of this level per axis.
    #[must_use]
    pub fn brick_counts(&self) -> [usize; 3] {
        self.bricks
    }

    /// How many bricks of this level the cache holds now: the regions
    /// [`BrickedField::resident_regions`] would put at this level (a region is one brick of
    /// it), counted without building a field.
    #[must_use]
    pub fn resident_count(&self) -> usize {
        let n = self.bricks.iter().product::<usize>() as u64;
        (0..n)
            .filter(|&b| self.cache.contains(&*self.source, self.level, b))
            .count()
    }

    /// Whether every brick that `rays` need is in the cache now: for each region they cross
    /// (as [`BrickedField::bricks_along`] finds them), the brick of the level that region
    /// samples, as [`BrickedField::prefetch_along`] queues them.
    #[must_use]
    pub fn resident_along(&self, rays: &[(Vec3, Vec3)]) -> bool {
        let mut along = Vec::new();
        rays.iter().all(|&(o, d)| {
            along.clear();
            self.bricks_along(o, d, &mut along);
            along.iter().all(|&r| {
                let (f, b) = self.region_brick(r);
                f.cache.contains(&*f.source, f.level, b)
            })
        })
    }

    /// The per-region levels of detail, when [`BrickedField::per_region`] made this field.
    #[must_use]
    pub fn level_map(&self) -> Option<&LevelMap> {
        self.regions.as_deref()
    }

    /// The same source at another level.
    pub fn at_level(&self, level: usize) -> Result<Self> {
        Self::new(self.source.clone(), self.cache.clone(), level)
    }

    /// The level sampled.
    #[must_use]
    pub fn level(&self) -> usize {
        self.level
    }

    /// Number of levels the source has.
    #[must_use]
    pub fn levels(&self) -> usize {
        self.source.geometries().len()
    }

    /// The brick source.
    #[must_use]
    pub fn source(&self) -> &Arc<dyn BrickSource> {
        &self.source
    }

    /// The cache sampled through.
    #[must_use]
    pub fn cache(&self) -> &Arc<BrickCache> {
        &self.cache
    }

    /// Linear index of the brick holding voxel `v` of this level.
    #[inline]
    fn brick_index(&self, v: [usize; 3]) -> u64 {
        let b = self.layout.brick;
        let nb = self.bricks;
        ((v[0] / b) + nb[0] * ((v[1] / b) + nb[1] * (v[2] / b))) as u64
    }

    /// Geometry of the sampled level.
    #[must_use]
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// Runs `f` on brick `idx`, from this thread's recent slot or the cache.
    #[inline]
    fn with_brick<R>(&self, idx: u64, f: impl FnOnce(&[f32]) -> R) -> Result<R> {
        let uid = self.uid;
        let lvl = self.level as u32;
        let slot = (uid as usize) % RECENT;
        RECENT_BRICKS.with(|r| {
            let mut r = r.borrow_mut();
            if let Some((u, l, i, b)) = &r[slot]
                && *u == uid
                && *l == lvl
                && *i == idx
            {
                return Ok(f(b));
            }
            let b = self.cache.get(self.source.as_ref(), self.level, idx)?;
            let out = f(&b);
            r[slot] = Some((uid, lvl, idx, b));
            Ok(out)
        })
    }

    /// Trilinear sample at continuous index coordinates of this level (clamped), exactly as
    /// [`Grid::sample_trilinear_index`] computes it. A brick that cannot be read gives 0 and
    /// its failure is kept for [`Field::check_io`].
    #[inline]
    #[must_use]
    pub fn sample_index(&self, p: Vec3) -> f32 {
        self.try_sample_index(p).unwrap_or_else(|e| {
            self.cache.record_error(&e);
            0.0
        })
    }

    /// [`BrickedField::sample_index`], returning a read failure.
    #[inline]
    pub fn try_sample_index(&self, p: Vec3) -> Result<f32> {
        if let Some(m) = &self.regions {
            let [nx, ny, nz] = self.geometry.dims;
            let c = |v: f32, n: usize| {
                if v.is_nan() {
                    0
                } else {
                    (v.max(0.0) as usize).min(n - 1)
                }
            };
            let r = [c(p.x, nx), c(p.y, ny), c(p.z, nz)].map(|v| v / m.edge);
            let l = m.levels[r[0] + m.dims[0] * (r[1] + m.dims[1] * r[2])];
            if l != 0 {
                let f = &m.fields[usize::from(l)];
                let w = self.geometry.index_to_world(p);
                return f.try_sample_index(f.geometry.world_to_index(w));
            }
        }
        let (v0, t) = crate::grid::clamped_cell(p, self.geometry.dims);
        let (b, a, s) = (
            self.layout.brick,
            self.layout.apron,
            self.layout.stored_edge(),
        );
        // v0 + 1 lies in the apron, which repeats the edge voxel exactly where the dense
        // sampler clamps.
        let l = v0.map(|c| c % b + a);
        self.with_brick(self.brick_index(v0), |brick| {
            let v = |dx: usize, dy: usize, dz: usize| {
                brick[(l[0] + dx) + s * ((l[1] + dy) + s * (l[2] + dz))]
            };
            let lerp = |a: f32, b: f32, t: f32| a * (1.0 - t) + b * t;
            let c00 = lerp(v(0, 0, 0), v(1, 0, 0), t.x);
            let c10 = lerp(v(0, 1, 0), v(1, 1, 0), t.x);
            let c01 = lerp(v(0, 0, 1), v(1, 0, 1), t.x);
            let c11 = lerp(v(0, 1, 1), v(1, 1, 1), t.x);
            lerp(lerp(c00, c10, t.y), lerp(c01, c11, t.y), t.z)
        })
    }

    /// [`Field::read_block`] of this level: each source brick the block meets is looked up
    /// in the cache once per row run and copied row by row.
    pub fn read_block(&self, lo: [usize; 3], edge: usize, out: &mut [f32]) -> Result<()> {
        check_block(&self.geometry, lo, edge, out)?;
        let (b, a, s) = (
            self.layout.brick,
            self.layout.apron,
            self.layout.stored_edge(),
        );
        let mut held: Option<(u64, Arc<[f32]>)> = None;
        fill_block(self.geometry.dims, lo, edge, out, |x0, x1, y, z, row| {
            let mut x = x0;
            while x < x1 {
                let idx = self.brick_index([x, y, z]);
                let end = ((x / b + 1) * b).min(x1);
                if held.as_ref().is_none_or(|(i, _)| *i != idx) {
                    let brick = self.cache.get(self.source.as_ref(), self.level, idx)?;
                    held = Some((idx, brick));
                }
                if let Some((_, brick)) = &held {
                    let from = (x % b + a) + s * ((y % b + a) + s * (z % b + a));
                    row[x - x0..end - x0].copy_from_slice(&brick[from..from + (end - x)]);
                }
                x = end;
            }
            Ok(())
        })
    }

    /// Voxel `v` of this level (in bounds), through the cache.
    fn voxel(&self, v: [usize; 3]) -> Result<f32> {
        let (b, a, s) = (
            self.layout.brick,
            self.layout.apron,
            self.layout.stored_edge(),
        );
        let l = v.map(|c| c % b + a);
        let brick = self
            .cache
            .get(self.source.as_ref(), self.level, self.brick_index(v))?;
        Ok(brick[l[0] + s * (l[1] + s * l[2])])
    }

    /// The own voxels (no apron) of brick `idx`, x fastest, into `out` (read past the cache).
    /// Number of regions (bricks of this level).
    fn region_count(&self) -> usize {
        self.bricks.iter().product()
    }

    /// Region `r`'s values at its own level and, for each, how many voxels of this level it
    /// stands for (1 at this level; without regions, brick `r`'s own voxels).
    fn region_samples(&self, r: usize, vals: &mut Vec<f32>, weights: &mut Vec<f64>) -> Result<()> {
        vals.clear();
        weights.clear();
        let l = self
            .regions
            .as_ref()
            .map_or(0, |m| usize::from(m.levels[r]));
        if l == 0 {
            self.own_voxels(r as u64, vals)?;
            weights.resize(vals.len(), 1.0);
            return Ok(());
        }
        let m = self.regions.as_ref().expect("l > 0 only with regions");
        let coarse = &m.fields[l];
        let (b, n) = (self.layout.brick, self.geometry.dims);
        let nb = self.bricks;
        let ri = [r % nb[0], (r / nb[0]) % nb[1], r / (nb[0] * nb[1])];
        let lo = ri.map(|c| c * b);
        let hi = [0, 1, 2].map(|a| ((ri[a] + 1) * b).min(n[a]));
        let f = 1usize << l;
        let cn = coarse.geometry.dims;
        let c0 = lo.map(|x| x / f);
        let c1 = [0, 1, 2].map(|a| hi[a].div_ceil(f).min(cn[a]));
        for cz in c0[2]..c1[2] {
            for cy in c0[1]..c1[1] {
                for cx in c0[0]..c1[0] {
                    let c = [cx, cy, cz];
                    // Base voxels of this coarse voxel inside the region.
                    let k: usize = (0..3)
                        .map(|a| {
                            let (x0, x1) = (c[a] * f, (c[a] + 1) * f);
                            x1.min(hi[a]).saturating_sub(x0.max(lo[a]))
                        })
                        .product();
                    if k > 0 {
                        vals.push(coarse.voxel(c)?);
                        weights.push(k as f64);
                    }
                }
            }
        }
        Ok(())
    }

    fn own_voxels(&self, idx: u64, out: &mut Vec<f32>) -> Result<()> {
        let (b, a, s) = (
            self.layout.brick,
            self.layout.apron,
            self.layout.stored_edge(),
        );
        let nb = self.bricks;
        let i = idx as usize;
        let (bx, by, bz) = (i % nb[0], (i / nb[0]) % nb[1], i / (nb[0] * nb[1]));
        let n = self.geometry.dims;
        let brick = self.source.read_brick(self.level, idx)?;
        out.clear();
        let w = ((bx + 1) * b).min(n[0]) - bx * b;
        for z in 0..((bz + 1) * b).min(n[2]) - bz * b {
            for y in 0..((by + 1) * b).min(n[1]) - by * b {
                let from = a + s * ((y + a) + s * (z + a));
                out.extend_from_slice(&brick[from..from + w]);
            }
        }
        Ok(())
    }

    /// Macrocells of edge `k`: stored ones if the source has them, else built brick by brick.
    pub fn macrocells(&self, k: usize) -> Result<Macrocells> {
        let m = self.level_macrocells(k)?;
        if self.source.macrocells_bound_all_levels() {
            return Ok(m);
        }
        match &self.regions {
            Some(map) if map.fields.len() > 1 => widen_for_levels(&m, map.fields.len() - 1),
            _ => Ok(m),
        }
    }

    /// Macrocells of this level's own voxels.
    fn level_macrocells(&self, k: usize) -> Result<Macrocells> {
        if let Some(m) = self.source.stored_macrocells(self.level, k)? {
            return Ok(m);
        }
        if k == 0 {
            return Err(Error::parameter("macrocell size k must be at least 1"));
        }
        let g = self.geometry;
        let n = g.dims;
        let dims = n.map(|d| d.saturating_sub(1).div_ceil(k).max(1));
        let cells = dims[0] * dims[1] * dims[2];
        let mut min = Vec::new();
        let mut max = Vec::new();
        min.try_reserve_exact(cells)
            .and_then(|()| max.try_reserve_exact(cells))
            .map_err(|_| Error::Limits(format!("{cells} macrocells do not fit in memory")))?;
        // Cells z-layer by layer, voxels in order: coherent, so each brick is fetched once
        // per layer of cells it holds.
        for cz in 0..dims[2] {
            for cy in 0..dims[1] {
                for cx in 0..dims[0] {
                    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                    for z in cz * k..=((cz + 1) * k).min(n[2] - 1) {
                        for y in cy * k..=((cy + 1) * k).min(n[1] - 1) {
                            for x in cx * k..=((cx + 1) * k).min(n[0] - 1) {
                                let v = self.voxel([x, y, z])?;
                                lo = lo.min(v);
                                hi = hi.max(v);
                            }
                        }
                    }
                    min.push(lo);
                    max.push(hi);
                }
            }
        }
        Macrocells::from_parts(g, k, min, max)
    }

    /// The whole level as a dense f32 grid (checked against `limits`).
    pub fn load(&self, limits: &Limits) -> Result<Grid<f32>> {
        let g = self.geometry;
        let mut out = Grid::<f32>::zeros(g, limits)?;
        let [nx, ny, nz] = g.dims;
        let (b, a, s) = (
            self.layout.brick,
            self.layout.apron,
            self.layout.stored_edge(),
        );
        let nb = self.bricks;
        let data = out.data_mut();
        for bz in 0..nb[2] {
            for by in 0..nb[1] {
                for bx in 0..nb[0] {
                    let idx = (bx + nb[0] * (by + nb[1] * bz)) as u64;
                    let brick = self.source.read_brick(self.level, idx)?;
                    for z in bz * b..((bz + 1) * b).min(nz) {
                        for y in by * b..((by + 1) * b).min(ny) {
                            let from = a + s * ((y - by * b + a) + s * (z - bz * b + a));
                            let w = ((bx + 1) * b).min(nx) - bx * b;
                            let dst = bx * b + nx * (y + ny * z);
                            data[dst..dst + w].copy_from_slice(&brick[from..from + w]);
                        }
                    }
                }
            }
        }
        Ok(out)
    }

    /// Queues on the I/O thread of each field's cache the bricks of `fields` along `rays`
    /// (world-space origin and direction), ray by ray and, per ray, field by field, each brick
    /// once: the order a render meets them, so it finds them loaded. Fields sharing a cache
    /// are one prefetch job (a later prefetch on that cache replaces it).
    pub fn prefetch_along(fields: &[&BrickedField], rays: &[(Vec3, Vec3)]) {
        let mut groups: Vec<(Arc<BrickCache>, crate::cache::PrefetchList)> = Vec::new();
        let mut seen = std::collections::HashSet::new();
        let mut along = Vec::new();
        for &(o, d) in rays {
            for f in fields {
                along.clear();
                f.bricks_along(o, d, &mut along);
                let at = match groups.iter().position(|(c, _)| Arc::ptr_eq(c, &f.cache)) {
                    Some(i) => i,
                    None => {
                        groups.push((f.cache.clone(), Vec::new()));
                        groups.len() - 1
                    }
                };
                for &r in &along {
                    // The brick the render reads for region `r`: at the region's own level.
                    let (g, b) = f.region_brick(r);
                    if seen.insert((g.source.uid(), g.level, b)) {
                        groups[at].1.push((g.source.clone(), g.level, b));
                    }
                }
            }
        }
        for (cache, items) in groups {
            cache.prefetch_items(items);
        }
    }

    /// The field and brick that region `r` (brick `r` of this level) is sampled from: brick
    /// `r` itself, or, where the region samples a coarser level ([`LevelMap`]), the brick of
    /// that level holding the region's centre.
    fn region_brick(&self, r: u64) -> (&BrickedField, u64) {
        let Some(m) = &self.regions else {
            return (self, r);
        };
        let l = m.levels.get(r as usize).copied().unwrap_or(0);
        let Some(coarse) = m.fields.get(usize::from(l)).filter(|_| l != 0) else {
            return (self, r);
        };
        let i = r as usize;
        let ri = [
            i % m.dims[0],
            (i / m.dims[0]) % m.dims[1],
            i / (m.dims[0] * m.dims[1]),
        ];
        let n = self.geometry.dims;
        let centre =
            Vec3::from_array([0, 1, 2].map(|a| (ri[a] * m.edge + m.edge / 2).min(n[a] - 1) as f32));
        let w = self.geometry.index_to_world(centre);
        let c = coarse.geometry.world_to_index(w) / coarse.layout.brick as f32;
        let nb = coarse.bricks;
        let c = [0, 1, 2].map(|a| {
            if c[a].is_nan() {
                0
            } else {
                (c[a].max(0.0) as usize).min(nb[a] - 1)
            }
        });
        (coarse, (c[0] + nb[0] * (c[1] + nb[1] * c[2])) as u64)
    }

    /// The bricks a ray crosses at this level, in the order it meets them (a 3D DDA over the
    /// brick grid, front to back), for [`BrickCache::prefetch`]. `origin` and `dir` are in
    /// world space.
    pub fn bricks_along(&self, origin: Vec3, dir: Vec3, out: &mut Vec<u64>) {
        let g = self.geometry;
        let (lo, hi) = g.world_bounds();
        let (lo, hi) = (lo.min(hi), lo.max(hi));
        let inv = dir.recip();
        let t0 = (lo - origin) * inv;
        let t1 = (hi - origin) * inv;
        let tmin = t0.min(t1).max_element().max(0.0);
        let tmax = t0.max(t1).min_element();
        if tmin
            .partial_cmp(&tmax)
            .is_none_or(std::cmp::Ordering::is_gt)
        {
            return;
        }
        let b = self.layout.brick as f32;
        let nb = self.bricks;
        let to_brick = |w: Vec3| g.world_to_index(w) / b;
        let start = to_brick(origin + dir * tmin);
        let end = to_brick(origin + dir * tmax);
        let mut cell = [0, 1, 2].map(|a| (start[a].max(0.0) as usize).min(nb[a] - 1) as i64);
        let d = end - start;
        let len = d.length();
        let step = [0, 1, 2].map(|a| if d[a] > 0.0 { 1i64 } else { -1 });
        let mut t_next = [0f32; 3];
        let mut t_delta = [0f32; 3];
        for a in 0..3 {
            if d[a].abs() < 1e-12 {
                t_next[a] = f32::INFINITY;
                t_delta[a] = f32::INFINITY;
            } else {
                let boundary = if step[a] > 0 {
                    cell[a] as f32 + 1.0
                } else {
                    cell[a] as f32
                };
                t_delta[a] = 1.0 / d[a].abs();
                t_next[a] = (boundary - start[a]) / d[a];
            }
        }
        let max_steps = nb[0] + nb[1] + nb[2] + 3;
        for _ in 0..max_steps {
            out.push(
                (cell[0] as usize + nb[0] * (cell[1] as usize + nb[1] * cell[2] as usize)) as u64,
            );
            let a = if t_next[0] <= t_next[1] && t_next[0] <= t_next[2] {
                0
            } else if t_next[1] <= t_next[2] {
                1
            } else {
                2
            };
            if t_next[a] > 1.0 || len == 0.0 {
                break;
            }
            cell[a] += step[a];
            if cell[a] < 0 || cell[a] >= nb[a] as i64 {
                break;
            }
            t_next[a] += t_delta[a];
        }
    }
}

/// Most quick passes [`refine_while_loading`] renders.
pub const MAX_REFINE_STEPS: u32 = 16;

/// How long [`refine_while_loading`] waits for another brick before it gives up, seconds.
const REFINE_WAIT_SECONDS: f64 = 0.2;

/// The loop of progressive refinement brick by brick while bricks load (HDR VolVis section
/// 6.3), which every engine's progressive render shares. While the bricks of `fields` along
/// `rays` ([`BrickedField::resident_along`]) are not all in their caches, it waits (up to
/// 0.2 s, polling every 20 ms the cheap [`BrickedField::resident_count`]) for more bricks of
/// the fields' own level, then builds the engine's view of what is loaded (`view()`: the
/// view, how many regions sample the fields' own level, and how many regions there are; see
/// [`BrickedField::resident_regions`]) and renders it (`pass(step, view, at_level,
/// regions)`), steps numbered from `first`. It stops when those bricks are loaded, when no
/// brick arrived in 0.2 s (a cache budget smaller than the view), when every region is at
/// the fields' level, when `cancelled()`, or after [`MAX_REFINE_STEPS`] passes, and returns
/// the number of the last step rendered (`first - 1` when none was, `first` taken as at
/// least 1).
///
/// # Errors
/// The first error of `view` or `pass`.
pub fn refine_while_loading<V, E>(
    fields: &[&BrickedField],
    rays: &[(Vec3, Vec3)],
    first: u32,
    mut view: impl FnMut() -> std::result::Result<(V, usize, usize), E>,
    mut pass: impl FnMut(u32, V, usize, usize) -> std::result::Result<(), E>,
    cancelled: impl Fn() -> bool,
) -> std::result::Result<u32, E> {
    let first = first.max(1);
    let mut step = first - 1;
    let mut last = None;
    let count = || fields.iter().map(|f| f.resident_count()).sum::<usize>();
    while step + 1 - first < MAX_REFINE_STEPS
        && !cancelled()
        && !fields.iter().all(|f| f.resident_along(rays))
    {
        let waited = std::time::Instant::now();
        while last == Some(count())
            && waited.elapsed().as_secs_f64() <= REFINE_WAIT_SECONDS
            && !cancelled()
        {
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        let now = count();
        if last == Some(now) {
            break;
        }
        last = Some(now);
        let (v, at_level, regions) = view()?;
        if at_level == regions {
            break;
        }
        step += 1;
        pass(step, v, at_level, regions)?;
    }
    Ok(step)
}

/// One level per region for several fields cut into the same regions: the coarsest any of
/// them samples there ([`BrickedField::region_levels`]), applied to each
/// ([`BrickedField::with_region_levels`]), so every field samples the same level at every
/// point (what one GPU pool lookup serves). Fields whose regions differ in number are
/// returned as they are.
///
/// # Errors
/// As [`BrickedField::with_region_levels`].
pub fn shared_region_levels(fields: &[&BrickedField]) -> Result<Vec<BrickedField>> {
    let all: Vec<Vec<u8>> = fields.iter().map(|f| f.region_levels()).collect();
    let same_cut = fields.windows(2).all(|w| w[0].bricks == w[1].bricks);
    if !same_cut || all.windows(2).all(|w| w[0] == w[1]) {
        return Ok(fields.iter().map(|f| (*f).clone()).collect());
    }
    let shared: Vec<u8> = (0..all[0].len())
        .map(|i| all.iter().map(|l| l[i]).max().unwrap_or(0))
        .collect();
    fields
        .iter()
        .map(|f| f.with_region_levels(&shared))
        .collect()
}

/// The level of detail for a view (HDR VolVis section 6.3): the coarsest level whose voxel
/// spacing (the smallest axis) is at most `footprint`, the world size of one pixel where the
/// volume is nearest to the camera. `levels` geometries, finest first; 0 when `footprint` is
/// not positive and finite.
#[must_use]
pub fn lod_level(levels: &[Geometry], footprint: f32) -> usize {
    if !(footprint.is_finite() && footprint > 0.0) {
        return 0;
    }
    levels
        .iter()
        .rposition(|g| g.spacing.abs().min_element() <= footprint)
        .unwrap_or(0)
}

/// Which level of detail a renderer samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Lod {
    /// The finest level (the same image as in core).
    #[default]
    Exact,
    /// The level [`lod_level`] picks for the view.
    Auto,
    /// This level (clamped to the coarsest).
    Level(usize),
    /// A level per brick ([`BrickedField::per_region`]): each brick of the finest level takes
    /// the level [`lod_level`] picks for the pixel footprint where that brick is nearest to
    /// the eye (HDR VolVis section 6.3), so far bricks are read coarse and near ones fine.
    Brick,
}

impl Lod {
    /// The level for a source of `levels` (finest first) seen with pixel `footprint`.
    #[must_use]
    pub fn pick(self, levels: &[Geometry], footprint: f32) -> usize {
        let last = levels.len().saturating_sub(1);
        match self {
            Lod::Exact => 0,
            Lod::Auto => lod_level(levels, footprint),
            Lod::Level(l) => l.min(last),
            // The base level; the bricks choose theirs (`BrickedField::per_region`).
            Lod::Brick => 0,
        }
    }
}

impl std::str::FromStr for Lod {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "exact" | "finest" => Ok(Lod::Exact),
            "auto" => Ok(Lod::Auto),
            "brick" | "per-brick" => Ok(Lod::Brick),
            n => n.parse().map(Lod::Level).map_err(|_| {
                Error::parameter(format!(
                    "level of detail '{s}': use exact, auto, brick or a level number (0 = finest)"
                ))
            }),
        }
    }
}

impl std::fmt::Display for Lod {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Lod::Exact => f.write_str("exact"),
            Lod::Auto => f.write_str("auto"),
            Lod::Level(l) => write!(f, "{l}"),
            Lod::Brick => f.write_str("brick"),
        }
    }
}

/// Bricks computed voxel by voxel from one or two sources of the same layout and geometry
/// (a unit conversion `f(a)`, or a black body's emission `f(density, temperature)`), cached
/// like file bricks.
pub struct CombinedSource {
    uid: u64,
    a: BrickedField,
    b: Option<BrickedField>,
    f: Box<dyn Fn(f32, f32) -> f32 + Send + Sync>,
    range: Option<(f32, f32)>,
    positive_min: Option<f32>,
    non_finite: u64,
}

impl std::fmt::Debug for CombinedSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CombinedSource")
            .field("uid", &self.uid)
            .finish_non_exhaustive()
    }
}

impl CombinedSource {
    /// `f(a, b)` voxel by voxel; `a` and `b` must share layout and geometry. The result's
    /// value range is unknown.
    pub fn new(
        a: &BrickedField,
        b: &BrickedField,
        f: impl Fn(f32, f32) -> f32 + Send + Sync + 'static,
    ) -> Result<Arc<Self>> {
        if a.layout != b.layout {
            return Err(Error::parameter(format!(
                "combined bricked fields must share their brick layout: bricks of {} (apron {}) \
                 and of {} (apron {}); convert both with the same --brick",
                a.layout.brick, a.layout.apron, b.layout.brick, b.layout.apron
            )));
        }
        if a.source.geometries() != b.source.geometries() {
            return Err(Error::parameter(
                "combined bricked fields must share their geometry (dims, origin, spacing)",
            ));
        }
        Ok(Arc::new(CombinedSource {
            uid: next_uid(),
            a: a.clone(),
            b: Some(b.clone()),
            f: Box::new(f),
            range: None,
            positive_min: None,
            non_finite: a.source.non_finite() + b.source.non_finite(),
        }))
    }

    /// `f(a)` voxel by voxel for a non-decreasing `f` (a unit conversion), so the value
    /// range is `f` of `a`'s.
    pub fn monotone(a: &BrickedField, f: impl Fn(f32) -> f32 + Send + Sync + 'static) -> Arc<Self> {
        let range = a.source.finite_range().map(|(lo, hi)| (f(lo), f(hi)));
        let positive_min = a.source.positive_min().map(&f).filter(|v| *v > 0.0);
        Arc::new(CombinedSource {
            uid: next_uid(),
            a: a.clone(),
            b: None,
            f: Box::new(move |x, _| f(x)),
            range,
            positive_min,
            non_finite: a.source.non_finite(),
        })
    }

    /// This source at `a`'s level, through `a`'s cache.
    pub fn field(self: Arc<Self>) -> Result<BrickedField> {
        let (cache, level) = (self.a.cache.clone(), self.a.level);
        BrickedField::new(self, cache, level)
    }
}

impl BrickSource for CombinedSource {
    fn uid(&self) -> u64 {
        self.uid
    }
    fn layout(&self) -> BrickLayout {
        self.a.layout
    }
    fn geometries(&self) -> &[Geometry] {
        self.a.source.geometries()
    }
    fn read_brick(&self, level: usize, idx: u64) -> Result<Vec<f32>> {
        let s = self.a.layout.stored_edge();
        let mut v = vec![0f32; s * s * s];
        self.read_brick_into(level, idx, &mut v)?;
        Ok(v)
    }
    fn read_brick_into(&self, level: usize, idx: u64, out: &mut [f32]) -> Result<()> {
        let x = self.a.cache.get(self.a.source.as_ref(), level, idx)?;
        if x.len() != out.len() {
            return Err(Error::invalid("brick buffer of the wrong size"));
        }
        match &self.b {
            Some(b) => {
                let y = b.cache.get(b.source.as_ref(), level, idx)?;
                for ((o, &p), &q) in out.iter_mut().zip(x.iter()).zip(y.iter()) {
                    *o = (self.f)(p, q);
                }
            }
            None => {
                for (o, &p) in out.iter_mut().zip(x.iter()) {
                    *o = (self.f)(p, p);
                }
            }
        }
        Ok(())
    }
    fn finite_range(&self) -> Option<(f32, f32)> {
        self.range
    }
    fn non_finite(&self) -> u64 {
        self.non_finite
    }
    fn positive_min(&self) -> Option<f32> {
        self.positive_min
    }
    fn region_levels(&self, level: usize) -> Option<Vec<u8>> {
        // The finer of the inputs' levels, region by region.
        let a = self.a.source.region_levels(level)?;
        match &self.b {
            None => Some(a),
            Some(b) => {
                let b = b.source.region_levels(level)?;
                Some(a.iter().zip(&b).map(|(x, y)| *x.min(y)).collect())
            }
        }
    }
    fn stored_macrocells(&self, level: usize, k: usize) -> Result<Option<Macrocells>> {
        // A non-decreasing map of one input keeps its bounds' order.
        if self.b.is_some() {
            return Ok(None);
        }
        let Some(m) = self.a.source.stored_macrocells(level, k)? else {
            return Ok(None);
        };
        let f = |v: f32| if v.is_finite() { (self.f)(v, v) } else { v };
        let lo = m.mins().iter().map(|&v| f(v)).collect();
        let hi = m.maxs().iter().map(|&v| f(v)).collect();
        Macrocells::from_parts(*m.geometry(), m.k(), lo, hi).map(Some)
    }
    fn macrocells_bound_all_levels(&self) -> bool {
        self.b.is_none() && self.a.source.macrocells_bound_all_levels()
    }
}
