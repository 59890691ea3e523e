//! Adaptive mesh refinement (AMR) data as simulation codes write it: a hierarchy of blocks
//! (an integer box of cells at a level, refined by a fixed ratio per level), read natively
//! from Enzo and Athena++ output, and sampled without resampling to one grid.
//!
//! # The reconstruction (continuous across blocks and levels)
//!
//! A cell is a *leaf* when no block of the next finer level covers it (Enzo keeps the
//! average of the children in covered cells; they are skipped). Every leaf cell `c` of
//! level `L` carries a tent (hat) basis function of its own width, `w_c(p) = prod_axes
//! max(0, 1 - |p - x_c| / h_L)`, and the field is the normalised sum
//!
//! ```text
//! f(p) = sum_c w_c(p) v_c / sum_c w_c(p)
//! ```
//!
//! over the leaf cells of every level (the basis-function method of Wald et al., "A
//! Simple and Practical Method for Interactive Ray Tracing of AMR Data", 2020). It is
//! continuous everywhere (a ratio of continuous functions whose denominator is at least
//! 1/8: the leaf cell containing `p` weighs at least that), so renders show no seam at block
//! or level boundaries; inside a region of one level it is exactly trilinear interpolation
//! of the cell-centred values, and at the domain's faces it clamps as the dense sampler
//! does. No ghost cells are needed: neighbours are found wherever they live.
//!
//! # Rendering
//!
//! An [`AmrField`] is a [`BrickSource`] ([`AmrField::source`]): level `j` of its pyramid is
//! the uniform grid of AMR level `max_level - j` (level 0 the finest), and its bricks are
//! the reconstruction evaluated at their voxel centres, made on demand and kept in the
//! shared [`crate::BrickCache`]. Every integrator that samples a [`crate::Field`] renders
//! AMR data through it. Each brick region is sampled at the level of the finest data it
//! holds ([`BrickSource::region_levels`]), so a region of root cells is one coarse brick,
//! and the clump at level 7 is read at level 7: nothing is resampled to one resolution.
//! The stored macrocells bound the reconstruction from the leaf cells directly, so a
//! majorant grid never needs a dense pass.
//!
//! # Reading a region
//!
//! One rank of a data-parallel render samples only a box ([`Region`]: its piece plus a
//! ghost layer). [`Hierarchy::field_within`] reads just the blocks whose tents, grown by one
//! root cell, reach that box; the others are absent and never evaluated, so inside the box
//! samples and bricks are bit-identical to the whole field's. [`open_field_within`] reduces
//! the ranks' [`AmrStats`] collectively so that every rank serves the whole field's.

mod athena;
mod enzo;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::DVec3;

use crate::cache::{BrickSource, next_uid};
use crate::grid::{Geometry, Grid};
use crate::macrocell::Macrocells;
use crate::ooc::BrickLayout;
use crate::{Error, Limits, Result};

/// Brick edge of AMR sources' pyramids (own voxels; one apron voxel per side).
pub const AMR_BRICK: usize = 32;

/// The most blocks a hierarchy may have.
pub const MAX_BLOCKS: usize = 1 << 22;
/// The most levels a hierarchy may have.
pub const MAX_LEVELS: u32 = 24;

/// Bytes a render keeps per brick of an AMR field's finest level (the level each brick's
/// region is sampled at, computed and then held), for [`Hierarchy::field_within`]'s check.
const BRICK_TABLE_BYTES: u64 = 2;

/// One block of a hierarchy: an integer box of cells at a level.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Block {
    /// Refinement level (0: the root grid).
    pub level: u32,
    /// First cell, in cells of its level counted from the domain's low corner.
    pub lo: [i64; 3],
    /// Cells per axis.
    pub dims: [usize; 3],
}

impl Block {
    /// One past the last cell, per axis.
    #[must_use]
    pub fn hi(&self) -> [i64; 3] {
        [0, 1, 2]
            .map(|a| self.lo[a].saturating_add(i64::try_from(self.dims[a]).unwrap_or(i64::MAX)))
    }

    /// Number of cells.
    #[must_use]
    pub fn cells(&self) -> usize {
        self.dims.iter().fold(1usize, |a, &d| a.saturating_mul(d))
    }
}

/// A field of a hierarchy: its name in the file, and its unit after conversion.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldInfo {
    /// The code's own name (`Density`, `x-velocity`, `rho`, `vel1`, ...).
    pub name: String,
    /// The unit of the values served (proper cgs where the code's units are known, else
    /// `code`).
    pub unit: String,
    /// Code value times this gives the served value.
    pub to_unit: f64,
}

/// Which code wrote a hierarchy, and how to read a field's blocks.
#[derive(Clone, Debug)]
enum Reader {
    Enzo(enzo::Files),
    Athena(athena::Files),
    /// Built in memory ([`Hierarchy::new`]): fields come with their values.
    Memory,
}

/// An AMR hierarchy: the domain, the blocks, the fields and units. Field data is read per
/// field ([`Hierarchy::field`]).
#[derive(Clone, Debug)]
pub struct Hierarchy {
    /// The code that wrote it (`Enzo`, `Athena++`).
    pub code: &'static str,
    /// The file opened.
    pub path: PathBuf,
    /// Low corner of the domain (code length).
    pub domain_lo: DVec3,
    /// High corner of the domain (code length).
    pub domain_hi: DVec3,
    /// Cells of the root grid per axis.
    pub root_dims: [usize; 3],
    /// Refinement ratio between levels.
    pub ratio: u32,
    /// The blocks.
    pub blocks: Vec<Block>,
    /// The fields.
    pub fields: Vec<FieldInfo>,
    /// Simulation time (code units).
    pub time: f64,
    /// Redshift of a cosmological run.
    pub redshift: Option<f64>,
    /// One code length in proper cm, when known.
    pub length_unit_cm: Option<f64>,
    reader: Reader,
}

/// True when `path` is AMR output this module reads: an Enzo parameter file (a sibling
/// `<path>.hierarchy` exists) or an Athena++ `.athdf` file.
#[must_use]
pub fn is_amr(path: &Path) -> bool {
    path.extension().is_some_and(|e| e == "athdf") || enzo::hierarchy_path(path).is_file()
}

impl Hierarchy {
    /// Opens Enzo output (the parameter file, with `.hierarchy` and the HDF5 grid files
    /// beside it) or an Athena++ `.athdf` file.
    ///
    /// # Errors
    /// A missing or malformed file, a hierarchy that is not properly formed (blocks outside
    /// the domain, levels not refined by the stated ratio), more than [`MAX_BLOCKS`].
    pub fn open(path: &Path) -> Result<Hierarchy> {
        let h = if path.extension().is_some_and(|e| e == "athdf") {
            guarded(path, || athena::open(path))?
        } else if enzo::hierarchy_path(path).is_file() {
            guarded(path, || enzo::open(path))?
        } else {
            return Err(Error::unsupported(format!(
                "{}: not AMR output this reader knows (an Enzo parameter file with its \
                 .hierarchy beside it, or an Athena++ .athdf file)",
                path.display()
            )));
        };
        h.validate()?;
        Ok(h)
    }

    /// A hierarchy built in memory (for tests, synthetic data and converters): fields are
    /// made with [`AmrField::new`] from their values.
    ///
    /// # Errors
    /// As [`Hierarchy::open`]'s checks: blocks outside the domain, a bad ratio or domain.
    pub fn new(
        domain_lo: DVec3,
        domain_hi: DVec3,
        root_dims: [usize; 3],
        ratio: u32,
        blocks: Vec<Block>,
    ) -> Result<Hierarchy> {
        let h = Hierarchy {
            code: "memory",
            path: PathBuf::from("(memory)"),
            domain_lo,
            domain_hi,
            root_dims,
            ratio,
            blocks,
            fields: Vec::new(),
            time: 0.0,
            redshift: None,
            length_unit_cm: None,
            reader: Reader::Memory,
        };
        h.validate()?;
        Ok(h)
    }

    fn validate(&self) -> Result<()> {
        if self.blocks.is_empty() {
            return Err(Error::invalid(format!(
                "{}: the hierarchy has no blocks",
                self.path.display()
            )));
        }
        if self.blocks.len() > MAX_BLOCKS {
            return Err(Error::Limits(format!(
                "{}: {} blocks, more than {MAX_BLOCKS}",
                self.path.display(),
                self.blocks.len()
            )));
        }
        if !(2..=16).contains(&self.ratio) {
            return Err(Error::invalid(format!(
                "refinement ratio {} (2..=16)",
                self.ratio
            )));
        }
        let size = self.domain_hi - self.domain_lo;
        if !size.is_finite() || size.min_element() <= 0.0 || !self.domain_lo.is_finite() {
            return Err(Error::invalid(format!(
                "domain {:?}..{:?} is empty or not finite",
                self.domain_lo, self.domain_hi
            )));
        }
        if self.root_dims.contains(&0) || self.root_dims.iter().any(|&d| d > 1 << 20) {
            return Err(Error::invalid(format!("root grid {:?}", self.root_dims)));
        }
        let finest = self.max_level().min(MAX_LEVELS);
        let f = (self.ratio as usize).checked_pow(finest);
        if f.is_none_or(|f| self.root_dims.iter().any(|d| d.checked_mul(f).is_none())) {
            return Err(Error::Limits(format!(
                "{}: level {finest} of a {:?} root grid refined by {} overflows the cell count",
                self.path.display(),
                self.root_dims,
                self.ratio
            )));
        }
        for (i, b) in self.blocks.iter().enumerate() {
            if b.level > MAX_LEVELS {
                return Err(Error::Limits(format!(
                    "block {i}: level {} beyond {MAX_LEVELS}",
                    b.level
                )));
            }
            let n = self.level_dims(b.level);
            for a in 0..3 {
                if b.dims[a] == 0 || b.lo[a] < 0 || b.hi()[a] > n[a] as i64 {
                    return Err(Error::invalid(format!(
                        "block {i} (level {}, cells {:?}..{:?}) lies outside the domain's {:?} cells",
                        b.level,
                        b.lo,
                        b.hi(),
                        n
                    )));
                }
            }
        }
        Ok(())
    }

    /// The finest level.
    #[must_use]
    pub fn max_level(&self) -> u32 {
        self.blocks.iter().map(|b| b.level).max().unwrap_or(0)
    }

    /// Refuses a hierarchy whose finest level, as a grid of bricks, needs per-brick tables
    /// ([`BRICK_TABLE_BYTES`] a brick) beyond `limits`: a few deep blocks in a small file
    /// can make that grid astronomically large.
    fn check_brick_tables(&self, limits: &Limits) -> Result<()> {
        let level = self.max_level();
        let dims = self.level_dims(level);
        let nb = AmrField::layout().bricks(dims);
        let bytes = nb
            .iter()
            .try_fold(1u64, |n, &b| n.checked_mul(b as u64))
            .and_then(|n| n.checked_mul(BRICK_TABLE_BYTES));
        match bytes {
            Some(b) if b <= limits.max_alloc_bytes => Ok(()),
            _ => Err(Error::Limits(format!(
                "{}: the finest level ({level}) spans {}x{}x{} cells, {}x{}x{} bricks of \
                 {AMR_BRICK}^3, whose tables need {} bytes, more than the allocation limit \
                 of {} bytes",
                self.path.display(),
                dims[0],
                dims[1],
                dims[2],
                nb[0],
                nb[1],
                nb[2],
                bytes.map_or_else(|| "more than 2^64".to_string(), |b| b.to_string()),
                limits.max_alloc_bytes
            ))),
        }
    }

    /// Cells per axis of the whole domain at `level`.
    #[must_use]
    pub fn level_dims(&self, level: u32) -> [usize; 3] {
        let f = (self.ratio as usize).saturating_pow(level);
        self.root_dims.map(|d| d.saturating_mul(f))
    }

    /// Cell size at `level` (code length).
    #[must_use]
    pub fn cell_size(&self, level: u32) -> DVec3 {
        let n = self.level_dims(level);
        (self.domain_hi - self.domain_lo) / DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64)
    }

    /// The uniform grid of `level`: voxel centres at the cell centres.
    #[must_use]
    pub fn level_geometry(&self, level: u32) -> Geometry {
        let h = self.cell_size(level);
        Geometry {
            dims: self.level_dims(level),
            origin: (self.domain_lo + h * 0.5).as_vec3(),
            spacing: h.as_vec3(),
        }
    }

    /// The field read when none is named: the gas density (`Density`, `rho`, `density` or
    /// `dens`), else the first.
    ///
    /// # Errors
    /// The hierarchy has no fields.
    pub fn default_field(&self) -> Result<&str> {
        ["Density", "rho", "density", "dens"]
            .iter()
            .copied()
            .find(|n| self.fields.iter().any(|f| f.name == *n))
            .or_else(|| self.fields.first().map(|f| f.name.as_str()))
            .ok_or_else(|| Error::invalid(format!("{}: no fields", self.path.display())))
    }

    /// The field named `name` (its info).
    ///
    /// # Errors
    /// No such field; the message lists the fields there are.
    pub fn field_info(&self, name: &str) -> Result<&FieldInfo> {
        self.fields.iter().find(|f| f.name == name).ok_or_else(|| {
            Error::parameter(format!(
                "{}: no field '{name}' (fields: {})",
                self.path.display(),
                self.fields
                    .iter()
                    .map(|f| f.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })
    }

    /// Reads field `name` of every block, converted to [`FieldInfo::unit`], checked against
    /// `limits` (the total cells count as one channel): [`Hierarchy::field_within`] with no
    /// region.
    ///
    /// # Errors
    /// As [`Hierarchy::field_within`].
    pub fn field(&self, name: &str, limits: &Limits) -> Result<AmrField> {
        self.field_within(name, limits, None)
    }

    /// Which blocks can influence the reconstruction inside `region` (all of them for
    /// `None`): a block is needed when the tent of any of its cells, grown by one root cell
    /// (`centre ± (h + root cell)` per axis, the margin [`AmrField`]'s macrocells use),
    /// meets the closed box. Geometry only; no data is read.
    #[must_use]
    pub fn needed_blocks(&self, region: Option<&Region>) -> Vec<bool> {
        let Some(r) = region else {
            return vec![true; self.blocks.len()];
        };
        let grow = self.cell_size(0);
        self.blocks
            .iter()
            .map(|b| {
                let h = self.cell_size(b.level);
                (0..3).all(|a| {
                    // First cell's centre minus its tent, last cell's centre plus its tent.
                    let lo = self.domain_lo[a] + (b.lo[a] as f64 - 0.5) * h[a] - grow[a];
                    let hi = self.domain_lo[a] + (b.hi()[a] as f64 + 0.5) * h[a] + grow[a];
                    hi >= r.lo[a] && lo <= r.hi[a]
                })
            })
            .collect()
    }

    /// Reads field `name` of the blocks that can influence samples inside `region` (every
    /// block for `None`; see [`Hierarchy::needed_blocks`]), converted to
    /// [`FieldInfo::unit`], checked against `limits` (the cells read count as one
    /// channel). The other blocks are never read: they are absent from the field
    /// ([`AmrField::is_present`]), which inside `region` samples, and makes bricks,
    /// bit-identical to the whole field's. Enzo's grid files are opened only when a needed
    /// grid lives in them; Athena++'s dataset is read in slabs of consecutive needed blocks.
    ///
    /// # Errors
    /// No such field, a region that is not finite or has `lo > hi`, a missing, malformed or
    /// truncated file holding a needed block (the message names the file), a block whose
    /// data has another shape than the hierarchy says, more cells than `limits` allow.
    pub fn field_within(
        &self,
        name: &str,
        limits: &Limits,
        region: Option<Region>,
    ) -> Result<AmrField> {
        let info = self.field_info(name)?.clone();
        if let Some(r) = &region {
            r.check()?;
        }
        let needed = self.needed_blocks(region.as_ref());
        let cells: u64 = self
            .blocks
            .iter()
            .zip(&needed)
            .filter(|(_, n)| **n)
            .map(|(b, _)| b.cells() as u64)
            .sum();
        limits.check([usize::try_from(cells).unwrap_or(usize::MAX), 1, 1], 4)?;
        self.check_brick_tables(limits)?;
        let mut values = match &self.reader {
            Reader::Enzo(f) => enzo::read_field(f, self, &info.name, &needed)?,
            Reader::Athena(f) => guarded(&self.path, || {
                athena::read_field(f, self, &info.name, &needed)
            })?,
            Reader::Memory => {
                return Err(Error::parameter(
                    "an in-memory hierarchy's fields are made with AmrField::new",
                ));
            }
        };
        if info.to_unit != 1.0 {
            for v in values.iter_mut().flat_map(|b| b.iter_mut()) {
                *v = (f64::from(*v) * info.to_unit) as f32;
            }
        }
        AmrField::from_parts(self, info, values, needed)
    }
}

/// A box in world (code-length) coordinates, closed: what one rank of a data-parallel
/// render samples (its k-d piece plus a ghost layer), given to
/// [`Hierarchy::field_within`] so that only the blocks that can reach it are read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Region {
    /// Low corner.
    pub lo: DVec3,
    /// High corner.
    pub hi: DVec3,
}

impl Region {
    /// The box `lo..=hi`.
    #[must_use]
    pub fn new(lo: DVec3, hi: DVec3) -> Region {
        Region { lo, hi }
    }

    /// Whether `p` lies in the closed box.
    #[must_use]
    pub fn contains(&self, p: DVec3) -> bool {
        p.cmpge(self.lo).all() && p.cmple(self.hi).all()
    }

    fn check(&self) -> Result<()> {
        if !self.lo.is_finite() || !self.hi.is_finite() || self.lo.cmpgt(self.hi).any() {
            return Err(Error::parameter(format!(
                "region {:?}..{:?} is not finite or has lo > hi",
                self.lo, self.hi
            )));
        }
        Ok(())
    }
}

/// The value statistics of a field's present blocks (every cell, leaf or covered), which
/// set a transfer function's automatic range. A distributed render all-reduces each rank's
/// with [`AmrStats::combine`] and applies the result with [`AmrField::with_stats`], so every
/// rank sees the whole field's.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AmrStats {
    /// Least and greatest finite value (`None`: no finite value).
    pub range: Option<(f32, f32)>,
    /// Least positive finite value.
    pub positive_min: Option<f32>,
    /// NaN and infinite values counted.
    pub non_finite: u64,
}

impl AmrStats {
    /// The statistics of the union of two sets of values (min, max, min, sum): the
    /// reduction's operator. Associative and commutative; [`AmrStats::default`] is its
    /// identity. Blocks read by two ranks count twice in `non_finite`, so a reduced count
    /// is an upper bound that is zero exactly when the whole field's is.
    #[must_use]
    pub fn combine(a: AmrStats, b: AmrStats) -> AmrStats {
        let opt = |x: Option<f32>, y: Option<f32>, f: fn(f32, f32) -> f32| match (x, y) {
            (Some(x), Some(y)) => Some(f(x, y)),
            (x, None) => x,
            (None, y) => y,
        };
        AmrStats {
            range: match (a.range, b.range) {
                (Some((a0, a1)), Some((b0, b1))) => Some((a0.min(b0), a1.max(b1))),
                (r, None) | (None, r) => r,
            },
            positive_min: opt(a.positive_min, b.positive_min, f32::min),
            non_finite: a.non_finite.saturating_add(b.non_finite),
        }
    }

    fn of<'a>(values: impl Iterator<Item = &'a f32>) -> AmrStats {
        let mut s = AmrStats::default();
        for &v in values {
            if !v.is_finite() {
                s.non_finite += 1;
                continue;
            }
            s.range = Some(s.range.map_or((v, v), |(a, b)| (a.min(v), b.max(v))));
            if v > 0.0 {
                s.positive_min = Some(s.positive_min.map_or(v, |m| m.min(v)));
            }
        }
        s
    }
}

/// One field of a hierarchy, in memory, with each cell's leaf flag: what the
/// reconstruction and the brick source sample.
#[derive(Debug)]
pub struct AmrField {
    info: FieldInfo,
    domain_lo: DVec3,
    domain_hi: DVec3,
    root_dims: [usize; 3],
    ratio: u32,
    max_level: u32,
    blocks: Vec<Block>,
    /// Values per block, x fastest (empty for an absent block).
    values: Vec<Vec<f32>>,
    /// Whether each block's values were read (see [`Hierarchy::field_within`]).
    present: Vec<bool>,
    /// Leaf flag per cell of each block (not covered by the next level).
    leaf: Vec<Vec<bool>>,
    /// Present block indices per level: the blocks the reconstruction evaluates.
    present_by_level: Vec<Vec<u32>>,
    /// `present_by_level` indexed by place, per level.
    present_index: Vec<LevelIndex>,
    uid: u64,
    geometries: Vec<Geometry>,
    stats: AmrStats,
}

impl AmrField {
    /// A field from its blocks' values (x fastest, in the hierarchy's block order).
    ///
    /// # Errors
    /// A block's value count differs from its cell count.
    pub fn new(h: &Hierarchy, info: FieldInfo, values: Vec<Vec<f32>>) -> Result<AmrField> {
        AmrField::new_within(h, info, values, None)
    }

    /// A field from all its blocks' values, keeping only those of the blocks `region`
    /// needs ([`Hierarchy::needed_blocks`]): the others are dropped and absent, as
    /// [`Hierarchy::field_within`] would leave them. For in-memory hierarchies and tests.
    ///
    /// # Errors
    /// As [`AmrField::new`]; a region that is not finite or has `lo > hi`.
    pub fn new_within(
        h: &Hierarchy,
        info: FieldInfo,
        mut values: Vec<Vec<f32>>,
        region: Option<Region>,
    ) -> Result<AmrField> {
        if let Some(r) = &region {
            r.check()?;
        }
        let needed = h.needed_blocks(region.as_ref());
        if values.len() == h.blocks.len() {
            for (i, (b, v)) in h.blocks.iter().zip(&values).enumerate() {
                if v.len() != b.cells() {
                    return Err(Error::invalid(format!(
                        "block {i}: {} values for {:?} cells",
                        v.len(),
                        b.dims
                    )));
                }
            }
            for (v, n) in values.iter_mut().zip(&needed) {
                if !n {
                    *v = Vec::new();
                }
            }
        }
        AmrField::from_parts(h, info, values, needed)
    }

    /// A field from the values of the `present` blocks (the others' values empty).
    fn from_parts(
        h: &Hierarchy,
        info: FieldInfo,
        values: Vec<Vec<f32>>,
        present: Vec<bool>,
    ) -> Result<AmrField> {
        if values.len() != h.blocks.len() || present.len() != h.blocks.len() {
            return Err(Error::invalid(format!(
                "{} blocks of data for {} blocks",
                values.len(),
                h.blocks.len()
            )));
        }
        for (i, ((b, v), &p)) in h.blocks.iter().zip(&values).zip(&present).enumerate() {
            if v.len() != if p { b.cells() } else { 0 } {
                return Err(Error::invalid(format!(
                    "block {i}: {} values for {:?} cells",
                    v.len(),
                    b.dims
                )));
            }
        }
        let max_level = h.max_level();
        let mut by_level = vec![Vec::new(); max_level as usize + 1];
        for (i, b) in h.blocks.iter().enumerate() {
            by_level[b.level as usize].push(i as u32);
        }
        let r = i64::from(h.ratio);
        let mut leaf: Vec<Vec<bool>> = h.blocks.iter().map(|b| vec![true; b.cells()]).collect();
        // Each child block clears the parent cells it covers: the parents found by place
        // (a scan of every parent per child is quadratic in the block count).
        let mut parents = Vec::new();
        for (level, ids) in by_level.iter().enumerate() {
            let Some(children) = by_level.get(level + 1) else {
                continue;
            };
            let index = LevelIndex::new(&h.blocks, ids);
            for &c in children {
                let c = h.blocks[c as usize];
                // Parent cells whose r^3 children lie inside the child block.
                let lo = [0, 1, 2].map(|a| (c.lo[a] + r - 1).div_euclid(r));
                let hi = [0, 1, 2].map(|a| c.hi()[a].div_euclid(r));
                index.query(&h.blocks, lo, hi, &mut parents);
                for &i in &parents {
                    let (i, b) = (i as usize, &h.blocks[i as usize]);
                    let lo = [0, 1, 2].map(|a| lo[a].max(b.lo[a]));
                    let hi = [0, 1, 2].map(|a| hi[a].min(b.hi()[a]));
                    if (0..3).any(|a| lo[a] >= hi[a]) {
                        continue;
                    }
                    for z in lo[2]..hi[2] {
                        for y in lo[1]..hi[1] {
                            for x in lo[0]..hi[0] {
                                let l = local(b, [x, y, z]);
                                leaf[i][l] = false;
                            }
                        }
                    }
                }
            }
        }
        let stats = AmrStats::of(values.iter().flatten());
        let present_by_level: Vec<Vec<u32>> = by_level
            .into_iter()
            .map(|ids| {
                ids.iter()
                    .copied()
                    .filter(|&i| present[i as usize])
                    .collect()
            })
            .collect();
        let present_index = present_by_level
            .iter()
            .map(|ids| LevelIndex::new(&h.blocks, ids))
            .collect();
        let geometries = (0..=max_level).rev().map(|l| h.level_geometry(l)).collect();
        Ok(AmrField {
            info,
            domain_lo: h.domain_lo,
            domain_hi: h.domain_hi,
            root_dims: h.root_dims,
            ratio: h.ratio,
            max_level,
            blocks: h.blocks.clone(),
            values,
            present,
            leaf,
            present_by_level,
            present_index,
            uid: next_uid(),
            geometries,
            stats,
        })
    }

    /// Whether block `i`'s values were read (every block of a field read without a region;
    /// the blocks the region needs otherwise). An absent block is never evaluated.
    #[must_use]
    pub fn is_present(&self, i: usize) -> bool {
        self.present.get(i).copied().unwrap_or(false)
    }

    /// How many blocks' values were read.
    #[must_use]
    pub fn blocks_read(&self) -> usize {
        self.present.iter().filter(|&&p| p).count()
    }

    /// The statistics of the present blocks' values, or those set by
    /// [`AmrField::with_stats`].
    #[must_use]
    pub fn stats(&self) -> AmrStats {
        self.stats
    }

    /// This field serving `stats` as its value statistics (the brick source's finite range,
    /// positive minimum and non-finite count): a distributed render sets every rank's to
    /// the all-reduced ones ([`AmrStats::combine`]), so transfer functions' automatic
    /// ranges agree with the single process's.
    #[must_use]
    pub fn with_stats(mut self, stats: AmrStats) -> AmrField {
        self.stats = stats;
        self
    }

    /// The field's name and unit.
    #[must_use]
    pub fn info(&self) -> &FieldInfo {
        &self.info
    }

    /// The blocks.
    #[must_use]
    pub fn blocks(&self) -> &[Block] {
        &self.blocks
    }

    /// Block `i`'s values, x fastest (empty when the block is absent).
    #[must_use]
    pub fn block_values(&self, i: usize) -> &[f32] {
        &self.values[i]
    }

    /// Whether cell `c` (x fastest) of block `i` is a leaf.
    #[must_use]
    pub fn is_leaf(&self, i: usize, c: usize) -> bool {
        self.leaf[i][c]
    }

    /// The finest level.
    #[must_use]
    pub fn max_level(&self) -> u32 {
        self.max_level
    }

    fn level_dims(&self, level: u32) -> [usize; 3] {
        let f = (self.ratio as usize).saturating_pow(level);
        self.root_dims.map(|d| d.saturating_mul(f))
    }

    fn cell_size(&self, level: u32) -> DVec3 {
        let n = self.level_dims(level);
        (self.domain_hi - self.domain_lo) / DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64)
    }

    /// The reconstruction at world point `p` (see the module docs).
    #[must_use]
    pub fn sample(&self, p: DVec3) -> f32 {
        let all: Vec<&[u32]> = self.present_by_level.iter().map(Vec::as_slice).collect();
        self.eval(p, &all)
    }

    /// The reconstruction at `p` from the candidate blocks of each level.
    fn eval(&self, p: DVec3, cands: &[&[u32]]) -> f32 {
        let (mut sw, mut sv) = (0.0f64, 0.0f64);
        for (level, blocks) in cands.iter().enumerate() {
            if blocks.is_empty() {
                continue;
            }
            let h = self.cell_size(level as u32);
            let u = (p - self.domain_lo) / h - 0.5;
            let i0 = u.floor();
            let f = u - i0;
            let i0 = [i0.x as i64, i0.y as i64, i0.z as i64];
            for corner in 0..8 {
                let bit = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
                let mut w = 1.0;
                for a in 0..3 {
                    w *= if bit[a] == 1 { f[a] } else { 1.0 - f[a] };
                }
                if w <= 0.0 {
                    continue;
                }
                let cell = [0, 1, 2].map(|a| i0[a] + bit[a] as i64);
                for &bi in *blocks {
                    let b = &self.blocks[bi as usize];
                    if (0..3).all(|a| cell[a] >= b.lo[a] && cell[a] < b.hi()[a]) {
                        let l = local(b, cell);
                        if self.leaf[bi as usize][l] {
                            sw += w;
                            sv += w * f64::from(self.values[bi as usize][l]);
                        }
                        break;
                    }
                }
            }
        }
        if sw > 0.0 { (sv / sw) as f32 } else { 0.0 }
    }

    /// Present blocks per level whose cells' tents reach the world box `lo..hi`.
    fn candidates(&self, lo: DVec3, hi: DVec3) -> Vec<Vec<u32>> {
        let mut near = Vec::new();
        self.present_index
            .iter()
            .enumerate()
            .map(|(level, index)| {
                let h = self.cell_size(level as u32);
                // The cells whose tents can reach lo..hi, with a cell to spare; the exact
                // test below decides.
                let cell_lo = [0, 1, 2]
                    .map(|a| ((lo[a] - self.domain_lo[a]) / h[a] - 0.5).floor() as i64 - 1);
                let cell_hi =
                    [0, 1, 2].map(|a| ((hi[a] - self.domain_lo[a]) / h[a] + 0.5).ceil() as i64 + 2);
                index.query(&self.blocks, cell_lo, cell_hi, &mut near);
                near.iter()
                    .copied()
                    .filter(|&i| {
                        let b = &self.blocks[i as usize];
                        (0..3).all(|a| {
                            let b0 = self.domain_lo[a] + (b.lo[a] as f64 - 0.5) * h[a];
                            let b1 = self.domain_lo[a] + (b.hi()[a] as f64 + 0.5) * h[a];
                            b1 >= lo[a] && b0 <= hi[a]
                        })
                    })
                    .collect()
            })
            .collect()
    }

    /// yt's covering grid at `level`: each cell of the uniform grid of that level takes the
    /// value of the finest block of level `<= level` that covers it (coarser cells repeat),
    /// with Enzo's averaged parent values where no block of `level` reaches. Absent blocks
    /// ([`AmrField::is_present`]) are skipped: only a field read whole gives yt's grid.
    ///
    /// # Errors
    /// A level above the finest, or a grid larger than `limits`.
    pub fn covering_grid(&self, level: u32, limits: &Limits) -> Result<Grid<f32>> {
        if level > self.max_level {
            return Err(Error::parameter(format!(
                "level {level}: the hierarchy's finest is {}",
                self.max_level
            )));
        }
        let g = Geometry {
            dims: self.level_dims(level),
            origin: (self.domain_lo + self.cell_size(level) * 0.5).as_vec3(),
            spacing: self.cell_size(level).as_vec3(),
        };
        let mut out = Grid::<f32>::zeros(g, limits)?;
        let [nx, ny, _] = g.dims;
        let data = out.data_mut();
        for l in 0..=level {
            let f = i64::from(self.ratio).pow(level - l);
            for &bi in &self.present_by_level[l as usize] {
                let b = &self.blocks[bi as usize];
                let v = &self.values[bi as usize];
                for z in b.lo[2] * f..b.hi()[2] * f {
                    for y in b.lo[1] * f..b.hi()[1] * f {
                        for x in b.lo[0] * f..b.hi()[0] * f {
                            let c = local(b, [x / f, y / f, z / f]);
                            data[x as usize + nx * (y as usize + ny * z as usize)] = v[c];
                        }
                    }
                }
            }
        }
        Ok(out)
    }

    /// The reconstruction sampled on the uniform grid of `level` (voxel centres at that
    /// level's cell centres).
    ///
    /// # Errors
    /// A level above the finest, or a grid larger than `limits`.
    pub fn resample(&self, level: u32, limits: &Limits) -> Result<Grid<f32>> {
        if level > self.max_level {
            return Err(Error::parameter(format!(
                "level {level}: the hierarchy's finest is {}",
                self.max_level
            )));
        }
        let j = (self.max_level - level) as usize;
        let g = self.geometries[j];
        let mut out = Grid::<f32>::zeros(g, limits)?;
        let [nx, ny, _] = g.dims;
        let layout = Self::layout();
        let bricks = layout.bricks(g.dims);
        let b = layout.brick;
        let s = layout.stored_edge();
        let a = layout.apron;
        let data = out.data_mut();
        for bz in 0..bricks[2] {
            for by in 0..bricks[1] {
                for bx in 0..bricks[0] {
                    let idx = (bx + bricks[0] * (by + bricks[1] * bz)) as u64;
                    let brick = self.read_brick(j, idx)?;
                    for z in bz * b..((bz + 1) * b).min(g.dims[2]) {
                        for y in by * b..((by + 1) * b).min(ny) {
                            for x in bx * b..((bx + 1) * b).min(nx) {
                                let t = [x - bx * b + a, y - by * b + a, z - bz * b + a];
                                data[x + nx * (y + ny * z)] = brick[t[0] + s * (t[1] + s * t[2])];
                            }
                        }
                    }
                }
            }
        }
        Ok(out)
    }

    /// This field as a brick source (see the module docs).
    #[must_use]
    pub fn source(self: &Arc<Self>) -> Arc<dyn BrickSource> {
        Arc::new(AmrSource(self.clone()))
    }

    /// Brick `idx` of pyramid level `j`, allocated.
    fn read_brick(&self, j: usize, idx: u64) -> Result<Vec<f32>> {
        let s = Self::layout().stored_edge();
        let mut v = vec![0.0; s * s * s];
        self.read_brick_into(j, idx, &mut v)?;
        Ok(v)
    }

    /// Pyramid level `j` (0 the finest) of this field.
    fn pyramid_level(&self, j: usize) -> Result<u32> {
        if j > self.max_level as usize {
            return Err(Error::parameter(format!(
                "level {j} of an AMR field with {} levels",
                self.max_level + 1
            )));
        }
        Ok(self.max_level - j as u32)
    }

    fn layout() -> BrickLayout {
        BrickLayout {
            brick: AMR_BRICK,
            apron: 1,
        }
    }

    fn read_brick_into(&self, j: usize, idx: u64, out: &mut [f32]) -> Result<()> {
        self.pyramid_level(j)?;
        let g = self.geometries[j];
        let layout = Self::layout();
        let nb = layout.bricks(g.dims);
        let count = (nb[0] * nb[1] * nb[2]) as u64;
        if idx >= count {
            return Err(Error::parameter(format!(
                "brick {idx} of level {j} ({count} bricks)"
            )));
        }
        let s = layout.stored_edge();
        if out.len() != s * s * s {
            return Err(Error::invalid(format!(
                "brick buffer of {} values, {} expected",
                out.len(),
                s * s * s
            )));
        }
        let idx = idx as usize;
        let bi = [idx % nb[0], (idx / nb[0]) % nb[1], idx / (nb[0] * nb[1])];
        let (b, a) = (layout.brick as i64, layout.apron as i64);
        let n = g.dims;
        // Exact world coordinates of this level's voxel centres (f64, not the f32 geometry).
        let h = self.cell_size(self.max_level - j as u32);
        let exact = |axis: usize, t: usize| -> f64 {
            let v = (bi[axis] as i64 * b - a + t as i64).clamp(0, n[axis] as i64 - 1);
            self.domain_lo[axis] + (v as f64 + 0.5) * h[axis]
        };
        let lo = DVec3::new(exact(0, 0), exact(1, 0), exact(2, 0));
        let hi = DVec3::new(exact(0, s - 1), exact(1, s - 1), exact(2, s - 1));
        let cands = self.candidates(lo, hi);
        let cands: Vec<&[u32]> = cands.iter().map(Vec::as_slice).collect();
        for z in 0..s {
            let pz = exact(2, z);
            for y in 0..s {
                let py = exact(1, y);
                for x in 0..s {
                    out[x + s * (y + s * z)] = self.eval(DVec3::new(exact(0, x), py, pz), &cands);
                }
            }
        }
        Ok(())
    }

    /// For each brick of pyramid level `j`, the coarsest pyramid level that holds every
    /// value there (the level of the finest block whose cells reach it), never finer than `j`.
    fn region_levels(&self, j: usize) -> Option<Vec<u8>> {
        let g = *self.geometries.get(j)?;
        let layout = Self::layout();
        let nb = layout.bricks(g.dims);
        let b = layout.brick as f64;
        let coarsest = self.max_level as usize;
        let mut out = vec![u8::try_from(coarsest).unwrap_or(u8::MAX); nb[0] * nb[1] * nb[2]];
        for blk in &self.blocks {
            let pj = (self.max_level - blk.level) as usize;
            let want = u8::try_from(pj.max(j)).unwrap_or(u8::MAX);
            let h = self.cell_size(blk.level);
            // The block's cells' tents, in voxels of level j, then bricks (plus the apron).
            let mut r0 = [0usize; 3];
            let mut r1 = [0usize; 3];
            for a in 0..3 {
                let w0 = self.domain_lo[a] + (blk.lo[a] as f64 - 0.5) * h[a];
                let w1 = self.domain_lo[a] + (blk.hi()[a] as f64 + 0.5) * h[a];
                let to_v = |w: f64| (w - f64::from(g.origin[a])) / f64::from(g.spacing[a]);
                let v0 = (to_v(w0) - 1.0).floor().max(0.0);
                let v1 = (to_v(w1) + 1.0).ceil().max(0.0);
                r0[a] = ((v0 / b) as usize).min(nb[a] - 1);
                r1[a] = ((v1 / b) as usize).min(nb[a] - 1);
            }
            for z in r0[2]..=r1[2] {
                for y in r0[1]..=r1[1] {
                    for x in r0[0]..=r1[0] {
                        let o = &mut out[x + nb[0] * (y + nb[1] * z)];
                        *o = (*o).min(want);
                    }
                }
            }
        }
        Some(out)
    }

    /// Macrocells of pyramid level `j` bounding the reconstruction sampled at any level of
    /// a region (see [`BrickSource::macrocells_bound_all_levels`]): each leaf cell's value
    /// widens every macrocell its tent reaches, the tent grown by one root cell. Only
    /// present blocks contribute: inside the region a field was read for they still bound
    /// it (every block reaching the region is present), outside it macrocells may be empty
    /// (min > max) and bound nothing.
    fn macrocells(&self, j: usize, k: usize) -> Result<Macrocells> {
        self.pyramid_level(j)?;
        if k == 0 {
            return Err(Error::parameter("macrocell size k must be at least 1"));
        }
        let g = self.geometries[j];
        let n = g.dims;
        let dims = n.map(|d| d.saturating_sub(1).div_ceil(k).max(1));
        let cells = dims[0] * dims[1] * dims[2];
        let mut min = Vec::new();
        let mut max = Vec::new();
        min.try_reserve_exact(cells)
            .and_then(|()| max.try_reserve_exact(cells))
            .map_err(|_| Error::Limits(format!("{cells} macrocells do not fit in memory")))?;
        min.resize(cells, f32::INFINITY);
        max.resize(cells, f32::NEG_INFINITY);
        let grow = self.cell_size(0);
        for (bi, blk) in self.blocks.iter().enumerate() {
            if !self.present[bi] {
                continue;
            }
            let h = self.cell_size(blk.level);
            let vals = &self.values[bi];
            let leaf = &self.leaf[bi];
            for z in 0..blk.dims[2] {
                for y in 0..blk.dims[1] {
                    for x in 0..blk.dims[0] {
                        let c = x + blk.dims[0] * (y + blk.dims[1] * z);
                        if !leaf[c] {
                            continue;
                        }
                        let v = vals[c];
                        let cell = [x, y, z];
                        let mut m0 = [0usize; 3];
                        let mut m1 = [0usize; 3];
                        for a in 0..3 {
                            let centre = self.domain_lo[a]
                                + ((blk.lo[a] + cell[a] as i64) as f64 + 0.5) * h[a];
                            let to_v =
                                |w: f64| (w - f64::from(g.origin[a])) / f64::from(g.spacing[a]);
                            let v0 = to_v(centre - h[a] - grow[a]).floor().max(0.0) as usize;
                            let v1 = (to_v(centre + h[a] + grow[a]).ceil().max(0.0) as usize)
                                .min(n[a] - 1);
                            m0[a] = (v0.saturating_sub(1) / k).min(dims[a] - 1);
                            m1[a] = (v1 / k).min(dims[a] - 1);
                        }
                        for mz in m0[2]..=m1[2] {
                            for my in m0[1]..=m1[1] {
                                let row = dims[0] * (my + dims[1] * mz);
                                for mx in m0[0]..=m1[0] {
                                    let i = row + mx;
                                    min[i] = min[i].min(v);
                                    max[i] = max[i].max(v);
                                }
                            }
                        }
                    }
                }
            }
        }
        Macrocells::from_parts(g, k, min, max)
    }
}

/// Runs an HDF5 read, turning a panic inside the third-party parser (on malformed data it
/// has not foreseen) into an error for `path`: a bad file never takes the process down.
fn guarded<T>(path: &Path, f: impl FnOnce() -> Result<T>) -> Result<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or_else(|_| {
        Err(Error::invalid(format!(
            "{}: the HDF5 reader failed on malformed data",
            path.display()
        )))
    })
}

/// The blocks of one level found by place: a grid of buckets (of `edge` cells per axis),
/// each listing the blocks that overlap it. The edge starts at the level's thinnest block
/// extent per axis, so a bucket meets at most two blocks per axis of a level whose blocks do
/// not overlap, and doubles while the buckets a level's blocks cover would number more than
/// a few per block.
#[derive(Clone, Debug, Default)]
struct LevelIndex {
    edge: [i64; 3],
    buckets: std::collections::HashMap<[i64; 3], Vec<u32>>,
}

impl LevelIndex {
    /// The index of blocks `ids` (all of one level).
    fn new(blocks: &[Block], ids: &[u32]) -> LevelIndex {
        let Some(&first) = ids.first() else {
            return LevelIndex::default();
        };
        let mut edge = [0, 1, 2].map(|a| blocks[first as usize].dims[a]);
        for &i in ids {
            let d = blocks[i as usize].dims;
            edge = [0, 1, 2].map(|a| edge[a].min(d[a]));
        }
        let mut edge = edge.map(|e| i64::try_from(e.max(1)).unwrap_or(i64::MAX));
        let budget = (ids.len() as u64).saturating_mul(8).max(1 << 16);
        loop {
            let covered = ids.iter().try_fold(0u64, |n, &i| {
                let span = Self::span(&edge, blocks[i as usize].lo, blocks[i as usize].hi());
                let k = (0..3).fold(1u64, |k, a| {
                    k.saturating_mul((span.1[a] - span.0[a] + 1).max(0) as u64)
                });
                Some(n.saturating_add(k)).filter(|&n| n <= budget)
            });
            if covered.is_some() || edge.iter().all(|&e| e >= 1 << 40) {
                break;
            }
            edge = edge.map(|e| e.saturating_mul(2));
        }
        let mut buckets: std::collections::HashMap<[i64; 3], Vec<u32>> =
            std::collections::HashMap::new();
        for &i in ids {
            let b = &blocks[i as usize];
            let (s0, s1) = Self::span(&edge, b.lo, b.hi());
            for z in s0[2]..=s1[2] {
                for y in s0[1]..=s1[1] {
                    for x in s0[0]..=s1[0] {
                        buckets.entry([x, y, z]).or_default().push(i);
                    }
                }
            }
        }
        LevelIndex { edge, buckets }
    }

    /// The first and last bucket per axis of the cells `lo..hi` (empty where `lo >= hi`).
    fn span(edge: &[i64; 3], lo: [i64; 3], hi: [i64; 3]) -> ([i64; 3], [i64; 3]) {
        let first = [0, 1, 2].map(|a| lo[a].div_euclid(edge[a]));
        let last = [0, 1, 2].map(|a| hi[a].saturating_sub(1).div_euclid(edge[a]));
        (first, last)
    }

    /// The blocks that may overlap cells `lo..hi` (a superset: whole buckets), in `out`,
    /// ascending and each once.
    fn query(&self, blocks: &[Block], lo: [i64; 3], hi: [i64; 3], out: &mut Vec<u32>) {
        out.clear();
        if self.buckets.is_empty() || (0..3).any(|a| lo[a] >= hi[a]) {
            return;
        }
        let (s0, s1) = Self::span(&self.edge, lo, hi);
        let k = (0..3).fold(1u64, |k, a| {
            k.saturating_mul((s1[a] - s0[a] + 1).max(0) as u64)
        });
        if k > self.buckets.len() as u64 {
            // A box wider than the occupied buckets: test the occupied ones.
            for (key, ids) in &self.buckets {
                if (0..3).all(|a| (s0[a]..=s1[a]).contains(&key[a])) {
                    out.extend_from_slice(ids);
                }
            }
        } else {
            for z in s0[2]..=s1[2] {
                for y in s0[1]..=s1[1] {
                    for x in s0[0]..=s1[0] {
                        if let Some(ids) = self.buckets.get(&[x, y, z]) {
                            out.extend_from_slice(ids);
                        }
                    }
                }
            }
        }
        out.sort_unstable();
        out.dedup();
        out.retain(|&i| {
            let b = &blocks[i as usize];
            (0..3).all(|a| b.lo[a] < hi[a] && b.hi()[a] > lo[a])
        });
    }
}

/// Cell `cell` (in cells of the block's level) of block `b`, x fastest.
#[inline]
fn local(b: &Block, cell: [i64; 3]) -> usize {
    let [x, y, z] = [0, 1, 2].map(|a| (cell[a] - b.lo[a]) as usize);
    x + b.dims[0] * (y + b.dims[1] * z)
}

/// An [`AmrField`] as a [`BrickSource`].
#[derive(Debug)]
struct AmrSource(Arc<AmrField>);

impl BrickSource for AmrSource {
    fn uid(&self) -> u64 {
        self.0.uid
    }

    fn layout(&self) -> BrickLayout {
        AmrField::layout()
    }

    fn geometries(&self) -> &[Geometry] {
        &self.0.geometries
    }

    fn read_brick(&self, level: usize, idx: u64) -> Result<Vec<f32>> {
        self.0.read_brick(level, idx)
    }

    fn read_brick_into(&self, level: usize, idx: u64, out: &mut [f32]) -> Result<()> {
        self.0.read_brick_into(level, idx, out)
    }

    fn stored_macrocells(&self, level: usize, k: usize) -> Result<Option<Macrocells>> {
        self.0.macrocells(level, k).map(Some)
    }

    fn finite_range(&self) -> Option<(f32, f32)> {
        self.0.stats.range
    }

    fn non_finite(&self) -> u64 {
        self.0.stats.non_finite
    }

    fn positive_min(&self) -> Option<f32> {
        self.0.stats.positive_min
    }

    fn region_levels(&self, level: usize) -> Option<Vec<u8>> {
        self.0.region_levels(level)
    }

    fn macrocells_bound_all_levels(&self) -> bool {
        true
    }
}

/// One line per level, block and field of a hierarchy: what `blueshift info` prints.
#[must_use]
pub fn describe(h: &Hierarchy) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{}: {} AMR, {} blocks, {} levels (ratio {}), root grid {}x{}x{}",
        h.path.display(),
        h.code,
        h.blocks.len(),
        h.max_level() + 1,
        h.ratio,
        h.root_dims[0],
        h.root_dims[1],
        h.root_dims[2]
    );
    let _ = writeln!(
        s,
        "  domain [{:.6}, {:.6}, {:.6}] .. [{:.6}, {:.6}, {:.6}] code length{}",
        h.domain_lo.x,
        h.domain_lo.y,
        h.domain_lo.z,
        h.domain_hi.x,
        h.domain_hi.y,
        h.domain_hi.z,
        h.length_unit_cm
            .map(|l| format!(" (1 code length = {l:.6e} cm, proper)"))
            .unwrap_or_default()
    );
    let _ = writeln!(
        s,
        "  time {:.6} code{}",
        h.time,
        h.redshift
            .map(|z| format!(", redshift {z:.6}"))
            .unwrap_or_default()
    );
    for l in 0..=h.max_level() {
        let bl: Vec<&Block> = h.blocks.iter().filter(|b| b.level == l).collect();
        let cells: usize = bl.iter().map(|b| b.cells()).sum();
        let n = h.level_dims(l);
        let dx = h.cell_size(l);
        let _ = writeln!(
            s,
            "  level {l}: {} blocks, {cells} cells, cell {:.6e} (uniform {}x{}x{})",
            bl.len(),
            dx.x,
            n[0],
            n[1],
            n[2]
        );
    }
    for f in &h.fields {
        let _ = writeln!(s, "  field {} [{}]", f.name, f.unit);
    }
    s
}

/// Parses `v` as three numbers separated by white space.
fn three<T: std::str::FromStr>(v: &str, what: &str) -> Result<[T; 3]> {
    let parts: Vec<T> = v
        .split_whitespace()
        .map(|t| t.parse::<T>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| Error::invalid(format!("{what} = '{v}': not three numbers")))?;
    <[T; 3]>::try_from(parts)
        .map_err(|_| Error::invalid(format!("{what} = '{v}': not three numbers")))
}

/// Opens field `name` of the AMR output at `path` (its default field when `None`: the gas
/// density, `Density`, `rho` or `density`, else the first) as a [`BrickedField`] at the
/// finest level, each region sampled at its own data's level, read through `cache`.
/// Returns the field's name with it. [`open_field_within`] with no region and no reduction.
///
/// [`BrickedField`]: crate::BrickedField
///
/// # Errors
/// As [`Hierarchy::open`] and [`Hierarchy::field`].
pub fn open_field(
    path: &Path,
    name: Option<&str>,
    cache: Arc<crate::BrickCache>,
    limits: &Limits,
) -> Result<(String, crate::BrickedField)> {
    let scope = SCOPE.with(|s| s.borrow().clone());
    match scope {
        None => open_field_within(path, name, cache, limits, None, &|s| s),
        Some(scope) => {
            let (name, field, read) =
                open_region(path, name, cache, limits, &*scope.region, &*scope.reduce)?;
            let (r, t) = scope.blocks.get();
            scope.blocks.set((r + read.0, t + read.1));
            Ok((name, field))
        }
    }
}

/// The region of a data-parallel rank for field `name` (`None`: read it whole), from the
/// geometries of the field's levels, finest first (the pyramid levels a render may pick:
/// each splits its own voxels over the ranks).
pub type RegionOf = dyn Fn(&str, &[Geometry]) -> Option<Region>;
/// The collective reduction of the ranks' statistics ([`open_field_within`]).
pub type Reduce = dyn Fn(Result<AmrStats>) -> Result<AmrStats>;

/// How [`open_field`] reads AMR fields on this thread while [`with_scope`] runs: only the
/// blocks of `region` (given the field's finest-level geometry: the k-d piece of a
/// data-parallel rank, with its ghost layer), the statistics reduced over the ranks by
/// `reduce` (the collective contract of [`open_field_within`]). Scene loaders call
/// [`open_field`], so a scene loaded inside the scope reads only this rank's blocks.
pub struct ReadScope {
    region: Box<RegionOf>,
    reduce: Box<Reduce>,
    blocks: std::cell::Cell<(usize, usize)>,
}

impl ReadScope {
    /// A scope from the region rule and the reduction.
    pub fn new(region: Box<RegionOf>, reduce: Box<Reduce>) -> ReadScope {
        ReadScope {
            region,
            reduce,
            blocks: std::cell::Cell::new((0, 0)),
        }
    }
}

impl std::fmt::Debug for ReadScope {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ReadScope")
            .field("blocks", &self.blocks.get())
            .finish_non_exhaustive()
    }
}

thread_local! {
    static SCOPE: std::cell::RefCell<Option<std::rc::Rc<ReadScope>>> =
        const { std::cell::RefCell::new(None) };
}

/// Runs `f` with AMR fields opened on this thread through `scope` (see [`ReadScope`]);
/// returns its result with the blocks read and the blocks of the fields opened (summed
/// over the fields).
pub fn with_scope<T>(scope: ReadScope, f: impl FnOnce() -> T) -> (T, (usize, usize)) {
    let scope = std::rc::Rc::new(scope);
    let prev = SCOPE.with(|s| s.borrow_mut().replace(scope.clone()));
    struct Restore(Option<std::rc::Rc<ReadScope>>);
    impl Drop for Restore {
        fn drop(&mut self) {
            let prev = self.0.take();
            SCOPE.with(|s| *s.borrow_mut() = prev);
        }
    }
    let restore = Restore(prev);
    let out = f();
    drop(restore);
    (out, scope.blocks.get())
}

/// [`open_field`] for one rank of a data-parallel render: reads only the blocks `region`
/// needs ([`Hierarchy::field_within`]), and serves the statistics `reduce` returns.
///
/// # The collective contract
/// `reduce` is called exactly once, whatever happens: with `Ok` of this rank's statistics
/// ([`AmrField::stats`]) when the hierarchy opened and the region's field was read, with
/// `Err` of the failure otherwise, so that peers in a collective reduction never wait for
/// a rank that failed. A distributed caller all-reduces there (with
/// [`AmrStats::combine`], and a flag saying whether any rank failed), returning `Ok` of
/// the global statistics when every rank succeeded and `Err` otherwise (its own error, or
/// one naming the rank that failed); the field then serves the returned statistics
/// ([`AmrField::with_stats`]), so transfer functions' automatic ranges match the single
/// process's. A single process passes `&|s| s`.
///
/// # Errors
/// As [`open_field`], or the error `reduce` returns. Should `reduce` return `Ok` for a
/// failed read, a [`Error::Invalid`] saying so.
pub fn open_field_within(
    path: &Path,
    name: Option<&str>,
    cache: Arc<crate::BrickCache>,
    limits: &Limits,
    region: Option<Region>,
    reduce: &dyn Fn(Result<AmrStats>) -> Result<AmrStats>,
) -> Result<(String, crate::BrickedField)> {
    open_region(path, name, cache, limits, &|_, _| region, reduce).map(|(n, f, _)| (n, f))
}

/// [`open_field_within`] with the region given by the field's finest-level geometry;
/// returns the blocks read and the hierarchy's blocks with the field.
fn open_region(
    path: &Path,
    name: Option<&str>,
    cache: Arc<crate::BrickCache>,
    limits: &Limits,
    region_of: &dyn Fn(&str, &[Geometry]) -> Option<Region>,
    reduce: &dyn Fn(Result<AmrStats>) -> Result<AmrStats>,
) -> Result<(String, crate::BrickedField, (usize, usize))> {
    let read = (|| {
        let h = Hierarchy::open(path)?;
        let name = match name {
            Some(n) => n.to_owned(),
            None => h.default_field()?.to_owned(),
        };
        let levels: Vec<Geometry> = (0..=h.max_level())
            .rev()
            .map(|l| h.level_geometry(l))
            .collect();
        let region = region_of(&name, &levels);
        let field = h.field_within(&name, limits, region)?;
        Ok((name, field))
    })();
    let (read, stats) = match read {
        Ok((name, field)) => {
            let stats = field.stats();
            (Some((name, field)), Ok(stats))
        }
        Err(e) => (None, Err(e)),
    };
    let stats = reduce(stats)?;
    let Some((name, field)) = read else {
        return Err(Error::invalid(format!(
            "{}: the read failed, yet the reduction returned statistics",
            path.display()
        )));
    };
    let blocks = (field.blocks_read(), field.blocks().len());
    let field = Arc::new(field.with_stats(stats));
    let bricked = crate::BrickedField::new(field.source(), cache, 0)?;
    Ok((name, bricked, blocks))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_deep_block(root: [usize; 3], ratio: u32, level: u32) -> Result<Hierarchy> {
        Hierarchy::new(
            DVec3::ZERO,
            DVec3::ONE,
            root,
            ratio,
            vec![
                Block {
                    level: 0,
                    lo: [0, 0, 0],
                    dims: root,
                },
                Block {
                    level,
                    lo: [0, 0, 0],
                    dims: [8, 8, 8],
                },
            ],
        )
    }

    /// A small file with one deep block: a finest level whose cell count overflows is
    /// refused when the hierarchy is read, and one whose brick tables exceed the
    /// allocation limit when a field is read (before anything is allocated).
    #[test]
    fn deep_levels_are_refused_before_their_brick_tables_are_made() {
        // 8 * 16^16 = 2^67 cells per axis.
        let e = one_deep_block([8, 8, 8], 16, 16).unwrap_err();
        assert!(matches!(e, Error::Limits(_)), "{e}");
        assert!(e.to_string().contains("overflows"), "{e}");
        let limits = Limits {
            max_alloc_bytes: 1 << 30,
            ..Limits::default()
        };
        // Level 14 of 8^3: 131072^3 cells, 4096^3 bricks of 32^3, 2 bytes each: 128 GiB.
        let h = one_deep_block([8, 8, 8], 2, 14).unwrap();
        let e = h.check_brick_tables(&limits).unwrap_err();
        assert!(matches!(e, Error::Limits(_)), "{e}");
        assert!(e.to_string().contains("4096x4096x4096 bricks"), "{e}");
        // Level 10: 256^3 bricks, 32 MiB of tables.
        let h = one_deep_block([8, 8, 8], 2, 10).unwrap();
        h.check_brick_tables(&limits).unwrap();
    }

    /// A level of one wide block and many one-cell blocks: the thinnest extent (1) would
    /// make the wide block cover more buckets than the level has blocks, so the edge
    /// doubles until it does not; queries still give exactly the overlapping blocks.
    #[test]
    fn a_wide_block_among_small_ones_widens_the_buckets_and_queries_stay_exact() {
        let mut blocks = vec![Block {
            level: 0,
            lo: [0, 0, 0],
            dims: [512, 512, 64],
        }];
        for i in 0..100i64 {
            blocks.push(Block {
                level: 0,
                lo: [600 + 2 * i, 3 * i, i % 7],
                dims: [1, 1, 1],
            });
        }
        let ids: Vec<u32> = (0..blocks.len() as u32).collect();
        let index = LevelIndex::new(&blocks, &ids);
        assert!(index.edge.iter().all(|&e| e > 1), "{:?}", index.edge);
        let total: usize = index.buckets.values().map(Vec::len).sum();
        assert!(total <= (1 << 16) + 8 * blocks.len(), "{total}");
        let mut got = Vec::new();
        for (lo, hi) in [
            ([0, 0, 0], [1, 1, 1]),
            ([500, 0, 0], [700, 400, 8]),
            ([601, 0, 0], [602, 400, 64]),
            ([-5, -5, -5], [1000, 1000, 1000]),
            ([900, 900, 0], [901, 901, 1]),
        ] {
            index.query(&blocks, lo, hi, &mut got);
            let want: Vec<u32> = ids
                .iter()
                .copied()
                .filter(|&i| {
                    let b = &blocks[i as usize];
                    (0..3).all(|a| b.lo[a] < hi[a] && b.hi()[a] > lo[a])
                })
                .collect();
            assert_eq!(got, want, "{lo:?}..{hi:?}");
        }
    }

    /// A hierarchy of blocks of many sizes (1 to 5 cells per axis) on three levels, each
    /// level's blocks disjoint, placed by a fixed-seed generator: leaf flags and
    /// candidate blocks found by place ([`LevelIndex`]) equal those of a scan of every
    /// block.
    #[test]
    fn blocks_found_by_place_equal_a_scan_of_every_block() {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = |n: u64| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed % n
        };
        let root = [12usize, 10, 9];
        let mut blocks = vec![Block {
            level: 0,
            lo: [0, 0, 0],
            dims: root,
        }];
        for level in 1..=2u32 {
            let n = root.map(|d| d * (1 << level));
            // Disjoint blocks: each in its own cell of a lattice of 6-cell cells.
            for z in 0..n[2] / 6 {
                for y in 0..n[1] / 6 {
                    for x in 0..n[0] / 6 {
                        if next(3) == 0 {
                            continue;
                        }
                        let dims = [0, 1, 2].map(|_| 1 + next(5) as usize);
                        let lo = [x, y, z].map(|c| 6 * c as i64).map(|c| c + next(2) as i64);
                        blocks.push(Block { level, lo, dims });
                    }
                }
            }
        }
        let h = Hierarchy::new(DVec3::ZERO, DVec3::new(1.2, 1.0, 0.9), root, 2, blocks).unwrap();
        let values = h.blocks.iter().map(|b| vec![1.0; b.cells()]).collect();
        let info = FieldInfo {
            name: "g".into(),
            unit: "code".into(),
            to_unit: 1.0,
        };
        let f = AmrField::new(&h, info, values).unwrap();
        // Leaf flags: a cell is covered when a block of the next level holds all its
        // children.
        for (i, b) in h.blocks.iter().enumerate() {
            for z in 0..b.dims[2] {
                for y in 0..b.dims[1] {
                    for x in 0..b.dims[0] {
                        let c = [x, y, z].map(|v| v as i64);
                        let cell = [0, 1, 2].map(|a| b.lo[a] + c[a]);
                        let covered = h.blocks.iter().any(|k| {
                            k.level == b.level + 1
                                && (0..3)
                                    .all(|a| k.lo[a] <= 2 * cell[a] && 2 * cell[a] + 2 <= k.hi()[a])
                        });
                        let l = local(b, cell);
                        assert_eq!(f.is_leaf(i, l), !covered, "block {i} cell {cell:?}");
                    }
                }
            }
        }
        assert!(
            f.leaf.iter().flatten().any(|l| !l),
            "some cells are covered"
        );
        // Candidates of boxes of many sizes and places, some outside the domain.
        for _ in 0..300 {
            let lo = DVec3::new(
                next(1400) as f64 / 1000.0 - 0.1,
                next(1200) as f64 / 1000.0 - 0.1,
                next(1100) as f64 / 1000.0 - 0.1,
            );
            let hi = lo + DVec3::new(1.0, 1.0, 1.0) * (next(400) as f64 / 1000.0);
            let got = f.candidates(lo, hi);
            for (level, ids) in f.present_by_level.iter().enumerate() {
                let h = f.cell_size(level as u32);
                let want: Vec<u32> = ids
                    .iter()
                    .copied()
                    .filter(|&i| {
                        let b = &f.blocks[i as usize];
                        (0..3).all(|a| {
                            let b0 = f.domain_lo[a] + (b.lo[a] as f64 - 0.5) * h[a];
                            let b1 = f.domain_lo[a] + (b.hi()[a] as f64 + 0.5) * h[a];
                            b1 >= lo[a] && b0 <= hi[a]
                        })
                    })
                    .collect();
                assert_eq!(got[level], want, "level {level}, box {lo}..{hi}");
            }
        }
    }
}
