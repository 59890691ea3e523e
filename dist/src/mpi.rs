//! The MPI communicator (rsmpi), behind the `mpi` feature.
//!
//! Messages are `f64` vectors of any length (`MPI_DOUBLE`), received with a probe for the
//! size; [`Communicator::send_recv`] posts the send as an immediate request and then
//! receives, so pairwise exchanges never deadlock; [`Communicator::first_failed`] is an
//! `MPI_Allreduce` with min over the failed ranks.

use mpi::Threading;
use mpi::collective::SystemOperation;
use mpi::environment::Universe;
use mpi::topology::SimpleCommunicator;
use mpi::traits::{Communicator as _, CommunicatorCollectives, Destination, Source};

use crate::comm::Communicator;
use crate::{Error, Result};

/// The world communicator of an MPI job (initialises MPI; finalised when dropped).
pub struct MpiComm {
    // Dropped after `world` (fields drop in order), which finalises MPI.
    world: SimpleCommunicator,
    _universe: Universe,
}

impl std::fmt::Debug for MpiComm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "MpiComm(rank {} of {})",
            self.world.rank(),
            self.world.size()
        )
    }
}

impl MpiComm {
    /// Initialises MPI (once per process).
    ///
    /// # Errors
    /// [`Error::Comm`] when MPI is already initialised or cannot start.
    pub fn init() -> Result<Self> {
        let (universe, level) = mpi::initialize_with_threading(Threading::Serialized)
            .ok_or_else(|| Error::comm("MPI could not be initialised (already initialised?)"))?;
        if level < Threading::Serialized {
            return Err(Error::comm(format!(
                "the MPI library offers thread level {level:?}; blueshift needs Serialized"
            )));
        }
        Ok(Self {
            world: universe.world(),
            _universe: universe,
        })
    }

    /// Ends every rank of the job at once with exit code `code` (`MPI_Abort`).
    pub fn abort(&self, code: i32) -> ! {
        self.world.abort(code)
    }
}

// SAFETY: MPI is initialised with MPI_THREAD_SERIALIZED (checked in `init`), under which any
// thread may make MPI calls as long as no two make them at once. `MpiComm`'s handles are
// plain MPI handles with no thread affinity; holders that share it across threads (the CLI
// keeps it in a `Mutex`) serialise the calls.
#[allow(unsafe_code)]
unsafe impl Send for MpiComm {}

fn rank_of(r: usize) -> i32 {
    i32::try_from(r).unwrap_or(i32::MAX)
}

impl Communicator for MpiComm {
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }
    fn size(&self) -> usize {
        self.world.size() as usize
    }
    fn send(&self, to: usize, data: &[f64]) -> Result<()> {
        self.world.process_at_rank(rank_of(to)).send(data);
        Ok(())
    }
    fn recv(&self, from: usize) -> Result<Vec<f64>> {
        Ok(self
            .world
            .process_at_rank(rank_of(from))
            .receive_vec::<f64>()
            .0)
    }
    fn send_recv(&self, data: &[f64], to: usize, from: usize) -> Result<Vec<f64>> {
        let world = &self.world;
        Ok(mpi::request::scope(|scope| {
            let req = world
                .process_at_rank(rank_of(to))
                .immediate_send(scope, data);
            let (v, _) = world.process_at_rank(rank_of(from)).receive_vec::<f64>();
            req.wait();
            v
        }))
    }
    fn first_failed(&self, failed: bool) -> Result<Option<usize>> {
        let n = self.world.size();
        let mine = if failed { self.world.rank() } else { n };
        let mut first = n;
        self.world
            .all_reduce_into(&mine, &mut first, SystemOperation::min());
        Ok((first < n).then_some(first as usize))
    }
}
