//! # blueshift-dist: distributed rendering, sort-last
//!
//! Simulations outgrow one machine; the tools that render them at scale (ParaView and VisIt
//! with IceT, yt with mpi4py) split the data over MPI ranks and composite the partial
//! images sort-last. This crate does that for blueshift's engines:
//! - [`Decomposition`]: a k-d split of the volume's voxels over the ranks, each rank's
//!   world box ([`blueshift_camera::ClipBox`], half-open, tiling space) and the
//!   [visibility order](Decomposition::visibility_order) of the pieces for a view;
//! - compositing ([`composite`]): radix-k, with binary swap (all factors 2) and
//!   direct-send (one factor `n`) as its special cases ([`Strategy::auto`] picks by rank
//!   count), for additive XYZ ([`Op::Add`]) and premultiplied RGBA "over" ([`Op::Over`]),
//!   and an [exclusive scan](composite::exclusive_scan) for exact spectral compositing of
//!   Doppler absorption (the optical depth in front of each piece, then additive XYZ);
//!   a cost model ([`cost`]) of messages and bytes;
//! - renders ([`render`]): data-parallel marcher and Doppler, sample-parallel and
//!   tile-parallel Monte Carlo (bit-identical to the single process), frame farming;
//! - data-parallel Woodcock tracking with rays forwarded between ranks ([`forward`]),
//!   bit-identical to the single process;
//! - communicators: the [`Communicator`] trait, in process over threads ([`ThreadWorld`],
//!   used by the tests and benchmarks), counted ([`Counting`]), and MPI (rsmpi) behind the
//!   `mpi` feature (`mpi::MpiComm`), so the default build needs no MPI library.

pub mod comm;
pub mod composite;
pub mod decomp;
mod error;
pub mod forward;
#[cfg(feature = "mpi")]
pub mod mpi;
pub mod render;

pub use comm::{Communicator, Counters, Counting, ThreadComm, ThreadWorld};
pub use composite::{Cost, Op, RADIX_TARGET, Strategy, composite, cost};
pub use decomp::{Decomposition, Piece, Viewpoint};
pub use error::{Error, Result};
pub use render::Mode;
