//! Volume data for blueshift: dense grids and named channels, the file formats scientists
//! hand around, macrocells, bricks and levels of detail, out-of-core access, and
//! deterministic synthetic datasets.
//!
//! # Where do I start?
//!
//! - [`read`] loads any supported file (raw with an Open SciVis name, NRRD, MetaImage, legacy
//!   VTK, bricked `.bsv`) into a [`Volume`]: named [`Channel`]s sharing one [`Geometry`].
//! - [`Grid`] is one dense channel of `u8`, `u16`, `f16`, `f32` or [`glam::Vec3`] voxels with
//!   trilinear and nearest sampling in index and world space; [`AnyGrid`] holds any of them.
//! - [`Macrocells::build`] gives the conservative per-cell min/max that majorant grids are
//!   built from; [`Macrocells::intervals`] walks a ray through them.
//! - [`Field`] is what every integrator samples: a dense grid or one level of detail of a
//!   bricked `.bsv` file read through a shared, bounded [`BrickCache`] (bit-identical values);
//!   [`VectorField`] is its velocity counterpart and [`lod_level`] the level-of-detail rule.
//! - [`synth`] makes the test datasets of the papers; [`ooc`] converts a volume into a
//!   bricked file with all levels of detail and samples it through a bounded cache.
//!
//! ```
//! use blueshift_volume::{Geometry, Grid, Macrocells};
//! use glam::Vec3;
//!
//! // A linear ramp: trilinear sampling reproduces it between voxels.
//! let g = Grid::from_fn(Geometry::unit([8, 8, 8]), |x, _, _| x as f32)?;
//! assert_eq!(g.sample_trilinear_index(Vec3::new(2.5, 3.0, 1.0)), 2.5);
//! let cells = Macrocells::build(&g, 4)?;
//! assert_eq!(cells.dims(), [2, 2, 2]);
//! assert_eq!(cells.min_max([0, 0, 0]), (0.0, 4.0)); // voxels 0..=4, the +1 neighbour included
//! # Ok::<(), blueshift_volume::Error>(())
//! ```
//!
//! # Glossary (paper term → type)
//!
//! | paper term | here |
//! |---|---|
//! | scalar field, structured grid, 3D texture (MDWT 4.3) | [`Grid`], [`AnyGrid`] |
//! | channel / species density, temperature, velocity (Doppler §6, MDWT) | [`Channel`] in a [`Volume`] |
//! | macrocell grid, scalar range per macrocell (MDWT 4.3) | [`Macrocells`] |
//! | value range along a ray segment (Open VKL interval) | [`ValueInterval`] |
//! | brick, block of 64^3 (HDR VolVis 6.3) | [`ooc::BrickLayout`] |
//! | multiresolution / LOD level (HDR VolVis 6.3) | [`lod::Pyramid`], [`ooc::BrickedFile::level`] |
//! | out-of-core loading (HDR VolVis 6.3) | [`ooc::BrickedFile`], [`ooc::convert`] |
//! | Galaxy dataset, synthetic hydrogen (Doppler §6, Fig. 12) | [`synth::galaxy`], [`synth::hydrogen_shell`] |
//! | three cubes (MDWT Fig. 3) | [`synth::three_cubes`] |
//!
//! # Conventions
//!
//! Voxels are node-centred and stored x fastest ([`Geometry`]). Velocities are m/s, with a
//! positive radial velocity receding (DESIGN.md). Readers check sizes against [`Limits`]
//! before allocating and return [`Error`], never panic.

pub mod amr;
pub mod budget;
pub mod cache;
mod error;
pub mod field;
mod grid;
pub mod io;
pub mod lod;
mod macrocell;
pub mod ooc;
pub mod synth;
mod volume;

pub use budget::{BudgetError, MemoryBudget};
pub use cache::{BrickCache, BrickSource, CacheStats};
pub use error::{Error, Limits, Result};
pub use field::{
    BrickedField, Field, LevelMap, Lod, MAX_REFINE_STEPS, VectorField, lod_level,
    refine_while_loading, shared_region_levels,
};
pub use grid::{AnyGrid, Geometry, Grid, Interpolant, ScalarType, Voxel};
pub use io::{DiskType, RawSpec, ReadOptions, read, read_with};
pub use macrocell::{DEFAULT_K, Macrocells, ValueInterval, ValueIntervals};
pub use ooc::Sampler;
pub use volume::{Channel, Volume};
