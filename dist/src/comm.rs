//! The communicator the compositing schedules run over: point-to-point messages of `f64`
//! and one collective (an error flag), with an in-process implementation over threads
//! ([`ThreadWorld`]) for tests and benchmarks, a counting wrapper ([`Counting`]) that the
//! cost model is checked against, and MPI behind the `mpi` feature (`crate::mpi`).

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};

use crate::{Error, Result};

/// Point-to-point messages between ranks `0..size()`. Messages between one pair of ranks
/// arrive in the order sent (MPI's non-overtaking rule).
pub trait Communicator {
    /// This rank.
    fn rank(&self) -> usize;
    /// The number of ranks.
    fn size(&self) -> usize;
    /// Sends `data` to rank `to`.
    ///
    /// # Errors
    /// [`Error::Comm`] when the peer is gone.
    fn send(&self, to: usize, data: &[f64]) -> Result<()>;
    /// Receives the next message from rank `from`.
    ///
    /// # Errors
    /// [`Error::Comm`] when the peer is gone.
    fn recv(&self, from: usize) -> Result<Vec<f64>>;
    /// Sends `data` to `to` and receives the next message from `from` (deadlock-free: the
    /// send does not wait for the receive).
    ///
    /// # Errors
    /// [`Error::Comm`] when a peer is gone.
    fn send_recv(&self, data: &[f64], to: usize, from: usize) -> Result<Vec<f64>>;
    /// A collective every rank calls at the same point: the lowest rank that passed
    /// `failed = true`, if any. Renders call it after each phase, so a failure on one rank
    /// stops all of them there instead of leaving them waiting for its messages, and only
    /// that rank reports (one message).
    ///
    /// # Errors
    /// [`Error::Comm`] when a peer is gone.
    fn first_failed(&self, failed: bool) -> Result<Option<usize>>;

    /// Whether every rank passed `true` ([`Communicator::first_failed`]).
    ///
    /// # Errors
    /// [`Error::Comm`] when a peer is gone.
    fn all_ok(&self, ok: bool) -> Result<bool> {
        Ok(self.first_failed(!ok)?.is_none())
    }
}

/// An in-process world of `n` ranks, one thread each, over channels.
#[derive(Debug)]
pub struct ThreadWorld;

/// One rank of a [`ThreadWorld`].
#[derive(Debug)]
pub struct ThreadComm {
    rank: usize,
    to: Vec<Sender<Vec<f64>>>,
    from: Vec<Receiver<Vec<f64>>>,
    // The collective's own channels (not counted as messages of the schedules).
    ctl_to: Vec<Sender<usize>>,
    ctl_from: Vec<Receiver<usize>>,
}

impl ThreadWorld {
    /// Runs `f(comm)` on `n` threads, one per rank, and returns their results in rank
    /// order. A rank that panics makes its peers' receives from it fail (their senders
    /// are dropped), and the panic is re-raised here.
    ///
    /// # Panics
    /// Re-raises a rank's panic; `n == 0`.
    pub fn run<T: Send>(n: usize, f: impl Fn(ThreadComm) -> T + Sync) -> Vec<T> {
        assert!(n > 0, "a world needs at least one rank");
        let mut senders: Vec<Vec<Option<Sender<Vec<f64>>>>> = vec![];
        let mut receivers: Vec<Vec<Option<Receiver<Vec<f64>>>>> = vec![];
        let mut ctl_s: Vec<Vec<Option<Sender<usize>>>> = vec![];
        let mut ctl_r: Vec<Vec<Option<Receiver<usize>>>> = vec![];
        for _ in 0..n {
            senders.push((0..n).map(|_| None).collect());
            receivers.push((0..n).map(|_| None).collect());
            ctl_s.push((0..n).map(|_| None).collect());
            ctl_r.push((0..n).map(|_| None).collect());
        }
        // senders[a][b]: a's sender to b; receivers[b][a]: b's receiver from a.
        for a in 0..n {
            for b in 0..n {
                let (s, r) = channel();
                senders[a][b] = Some(s);
                receivers[b][a] = Some(r);
                let (s, r) = channel();
                ctl_s[a][b] = Some(s);
                ctl_r[b][a] = Some(r);
            }
        }
        let comms: Vec<ThreadComm> = (0..n)
            .map(|r| ThreadComm {
                rank: r,
                to: senders[r].iter_mut().map(|s| s.take().unwrap()).collect(),
                from: receivers[r].iter_mut().map(|s| s.take().unwrap()).collect(),
                ctl_to: ctl_s[r].iter_mut().map(|s| s.take().unwrap()).collect(),
                ctl_from: ctl_r[r].iter_mut().map(|s| s.take().unwrap()).collect(),
            })
            .collect();
        std::thread::scope(|s| {
            let handles: Vec<_> = comms
                .into_iter()
                .map(|c| {
                    let f = &f;
                    s.spawn(move || f(c))
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
                .collect()
        })
    }
}

fn gone(rank: usize) -> Error {
    Error::comm(format!("rank {rank} is gone"))
}

impl Communicator for ThreadComm {
    fn rank(&self) -> usize {
        self.rank
    }
    fn size(&self) -> usize {
        self.to.len()
    }
    fn send(&self, to: usize, data: &[f64]) -> Result<()> {
        self.to[to].send(data.to_vec()).map_err(|_| gone(to))
    }
    fn recv(&self, from: usize) -> Result<Vec<f64>> {
        self.from[from].recv().map_err(|_| gone(from))
    }
    fn send_recv(&self, data: &[f64], to: usize, from: usize) -> Result<Vec<f64>> {
        self.send(to, data)?;
        self.recv(from)
    }
    fn first_failed(&self, failed: bool) -> Result<Option<usize>> {
        // Gather to rank 0, which answers everyone: the lowest failed rank, or `size`.
        let n = self.size();
        let mine = if failed { self.rank } else { n };
        let first = if self.rank == 0 {
            let mut first = mine;
            for r in 1..n {
                first = first.min(self.ctl_from[r].recv().map_err(|_| gone(r))?);
            }
            for r in 1..n {
                self.ctl_to[r].send(first).map_err(|_| gone(r))?;
            }
            first
        } else {
            self.ctl_to[0].send(mine).map_err(|_| gone(0))?;
            self.ctl_from[0].recv().map_err(|_| gone(0))?
        };
        Ok((first < n).then_some(first))
    }
}

/// Message and byte counts (all ranks' sends together).
#[derive(Clone, Debug, Default)]
pub struct Counters {
    messages: Arc<AtomicU64>,
    bytes: Arc<AtomicU64>,
}

impl Counters {
    /// Messages sent so far.
    #[must_use]
    pub fn messages(&self) -> u64 {
        self.messages.load(Ordering::Relaxed)
    }
    /// Payload bytes sent so far (8 per `f64`).
    #[must_use]
    pub fn bytes(&self) -> u64 {
        self.bytes.load(Ordering::Relaxed)
    }
}

/// A communicator that counts every point-to-point message it sends into shared
/// [`Counters`] (the collective [`Communicator::first_failed`] is not counted).
#[derive(Debug)]
pub struct Counting<C> {
    inner: C,
    counters: Counters,
}

impl<C: Communicator> Counting<C> {
    /// Wraps `inner`, counting into `counters` (share one between the ranks of a world).
    pub fn new(inner: C, counters: Counters) -> Self {
        Self { inner, counters }
    }
    fn count(&self, data: &[f64]) {
        self.counters.messages.fetch_add(1, Ordering::Relaxed);
        self.counters
            .bytes
            .fetch_add(8 * data.len() as u64, Ordering::Relaxed);
    }
}

impl<C: Communicator> Communicator for Counting<C> {
    fn rank(&self) -> usize {
        self.inner.rank()
    }
    fn size(&self) -> usize {
        self.inner.size()
    }
    fn send(&self, to: usize, data: &[f64]) -> Result<()> {
        self.count(data);
        self.inner.send(to, data)
    }
    fn recv(&self, from: usize) -> Result<Vec<f64>> {
        self.inner.recv(from)
    }
    fn send_recv(&self, data: &[f64], to: usize, from: usize) -> Result<Vec<f64>> {
        self.count(data);
        self.inner.send_recv(data, to, from)
    }
    fn first_failed(&self, failed: bool) -> Result<Option<usize>> {
        self.inner.first_failed(failed)
    }
}
