//! The bounded brick cache every out-of-core field samples through (HDR VolVis section 6.3).
//!
//! One [`BrickCache`] is shared by every channel of a scene: its budget is in bytes of decoded
//! (f32) bricks, whatever the number of channels. Bricks are loaded on demand (the sampling
//! thread reads the brick outside the cache's lock, so threads wait on the disk in parallel;
//! a thread that needs a brick another thread is reading waits for that read)
//! and, when asked, ahead of need by one I/O thread ([`BrickCache::prefetch`]) in the order
//! the renderer expects to meet them. The least recently used brick is evicted first.
//!
//! Memory: the cache holds at most `budget` bytes of bricks (at least one brick, whatever the
//! budget). On top of it each sampling thread keeps its most recent brick per field (see
//! [`crate::field`]), so the peak is `budget + threads x fields x brick bytes`.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::fmt;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Condvar, Mutex, Weak};

use crate::grid::Geometry;
use crate::macrocell::Macrocells;
use crate::ooc::BrickLayout;
use crate::{Error, Result};

/// Most levels of detail a source may have (a 2^32 edge needs 27 levels of 64^3 bricks).
pub const MAX_LEVELS: usize = 32;

static NEXT_UID: AtomicU64 = AtomicU64::new(1);

/// A fresh identity for a brick source (cache keys and per-thread brick slots use it).
pub(crate) fn next_uid() -> u64 {
    NEXT_UID.fetch_add(1, Ordering::Relaxed)
}

/// Bricked data at several levels of detail: a `.bsv` file ([`crate::ooc::BrickedFile`]) or
/// bricks computed from other sources (for example a black body's density times the Planck
/// factor of its temperature).
pub trait BrickSource: Send + Sync + fmt::Debug {
    /// Identity of this source in caches (unique per process, see `next_uid`).
    fn uid(&self) -> u64;
    /// Brick edge and apron.
    fn layout(&self) -> BrickLayout;
    /// Geometry of every level, finest first.
    fn geometries(&self) -> &[Geometry];
    /// The `(B + 2A)^3` decoded voxels of brick `idx` (x fastest over bricks) of `level`.
    fn read_brick(&self, level: usize, idx: u64) -> Result<Vec<f32>>;
    /// [`BrickSource::read_brick`] into `out` (`(B + 2A)^3` values); sources override it to
    /// read without allocating (the cache reuses evicted bricks' memory through it).
    fn read_brick_into(&self, level: usize, idx: u64, out: &mut [f32]) -> Result<()> {
        let v = self.read_brick(level, idx)?;
        if v.len() != out.len() {
            return Err(Error::invalid(format!(
                "brick {idx} of level {level}: {} voxels, {} expected",
                v.len(),
                out.len()
            )));
        }
        out.copy_from_slice(&v);
        Ok(())
    }
    /// Stored macrocells of `level` for edge `k`, when the source has them.
    fn stored_macrocells(&self, _level: usize, _k: usize) -> Result<Option<Macrocells>> {
        Ok(None)
    }
    /// Range of the finite level-0 values (`None`: none, or unknown).
    fn finite_range(&self) -> Option<(f32, f32)>;
    /// Number of NaN or infinite level-0 voxels.
    fn non_finite(&self) -> u64;
    /// Smallest positive finite level-0 value (`None`: none, or unknown).
    fn positive_min(&self) -> Option<f32> {
        None
    }
    /// For each brick of `level` (x fastest), the coarsest level that holds all of the
    /// source's detail there, when the source knows it (adaptive data: an AMR hierarchy's
    /// region of root cells needs no finer level). [`crate::BrickedField::new`] samples each
    /// region at that level, and [`crate::BrickedField::per_region`] never goes finer.
    fn region_levels(&self, _level: usize) -> Option<Vec<u8>> {
        None
    }
    /// True when [`BrickSource::stored_macrocells`] of a level already bound the samples of
    /// every coarser level a region may take, so they need no widening.
    fn macrocells_bound_all_levels(&self) -> bool {
        false
    }
}

type Key = (u64, u32, u64);

/// Evicted bricks a cache keeps for reuse, at most a quarter of its budget (memory beyond
/// the budget; see `Inner::spare`).
pub const SPARE_BRICKS: usize = 8;

#[derive(Debug, Default)]
struct Inner {
    map: HashMap<Key, (Arc<[f32]>, u64)>,
    lru: BTreeMap<u64, Key>,
    /// Evicted bricks no one else holds, kept for the next read (at most [`SPARE_BRICKS`]):
    /// reusing them keeps the allocator from fragmenting under constant eviction.
    spare: Vec<Arc<[f32]>>,
    used: usize,
    peak: usize,
    tick: u64,
    error: Option<String>,
    /// Bricks a thread is reading now: others wait for it instead of reading them again.
    loading: HashSet<Key>,
}

/// A brick marked as being read (in [`Inner::loading`]) until dropped, when the threads
/// waiting for it are woken, whether the read succeeded, failed or panicked.
struct Loading<'a> {
    cache: &'a BrickCache,
    key: Key,
}

impl Drop for Loading<'_> {
    fn drop(&mut self) {
        self.cache.lock().loading.remove(&self.key);
        self.cache.loaded.notify_all();
    }
}

impl Inner {
    fn touch(&mut self, key: Key) -> Option<Arc<[f32]>> {
        self.tick += 1;
        let tick = self.tick;
        let e = self.map.get_mut(&key)?;
        self.lru.remove(&e.1);
        e.1 = tick;
        self.lru.insert(tick, key);
        Some(e.0.clone())
    }

    fn insert(&mut self, key: Key, data: Arc<[f32]>, budget: usize) {
        let bytes = data.len() * 4;
        // Evict until the new brick fits (a lone brick always stays).
        while self.used + bytes > budget {
            let Some((_, old)) = self.lru.pop_first() else {
                break;
            };
            if let Some((mut d, _)) = self.map.remove(&old) {
                self.used -= d.len() * 4;
                let room = (self.spare.len() + 1) * d.len() * 4 <= budget / 4;
                if self.spare.len() < SPARE_BRICKS && room && Arc::get_mut(&mut d).is_some() {
                    self.spare.push(d);
                }
            }
        }
        self.tick += 1;
        self.lru.insert(self.tick, key);
        self.map.insert(key, (data, self.tick));
        self.used += bytes;
        self.peak = self.peak.max(self.used);
    }
}

/// What a cache has done since it was made (or since [`BrickCache::reset_stats`]).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CacheStats {
    /// Bricks read from their source, per level (index = level).
    pub reads: Vec<u64>,
    /// Of those, bricks read by the prefetch thread.
    pub prefetched: u64,
    /// Lookups served from the cache.
    pub hits: u64,
    /// Bytes of decoded bricks held now.
    pub resident_bytes: usize,
    /// Most bytes of decoded bricks held at once.
    pub peak_bytes: usize,
    /// Bricks held now.
    pub resident_bricks: usize,
}

impl CacheStats {
    /// Bricks read over all levels.
    #[must_use]
    pub fn total_reads(&self) -> u64 {
        self.reads.iter().sum()
    }
}

/// Bricks to load, `(source, level, brick)` in load order.
pub type PrefetchList = Vec<(Arc<dyn BrickSource>, usize, u64)>;

struct Job {
    bricks: PrefetchList,
    generation: u64,
}

/// A bounded, thread-safe cache of decoded bricks shared by every field of a scene.
pub struct BrickCache {
    budget: usize,
    inner: Mutex<Inner>,
    /// Signalled when a brick being read is done ([`Loading`]).
    loaded: Condvar,
    reads: [AtomicU64; MAX_LEVELS],
    prefetched: AtomicU64,
    hits: AtomicU64,
    generation: AtomicU64,
    io: Mutex<Option<mpsc::Sender<Job>>>,
}

impl fmt::Debug for BrickCache {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("BrickCache")
            .field("budget", &self.budget)
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

/// Default cache budget: a quarter of physical memory (Linux `/proc/meminfo`), 1 GiB where
/// that cannot be read.
#[must_use]
pub fn default_budget() -> usize {
    physical_memory().map_or(1 << 30, |m| usize::try_from(m / 4).unwrap_or(usize::MAX))
}

/// Physical memory in bytes, where the system says (Linux).
#[must_use]
pub fn physical_memory() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = s.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kb.checked_mul(1024)
}

impl BrickCache {
    /// A cache holding at most `budget_bytes` of decoded bricks (at least one brick).
    #[must_use]
    pub fn new(budget_bytes: usize) -> Arc<Self> {
        Arc::new(BrickCache {
            budget: budget_bytes,
            inner: Mutex::new(Inner::default()),
            loaded: Condvar::new(),
            reads: std::array::from_fn(|_| AtomicU64::new(0)),
            prefetched: AtomicU64::new(0),
            hits: AtomicU64::new(0),
            generation: AtomicU64::new(0),
            io: Mutex::new(None),
        })
    }

    /// The budget in bytes.
    #[must_use]
    pub fn budget(&self) -> usize {
        self.budget
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        // A panic while holding the lock leaves the maps consistent (every mutation is
        // complete before the next can panic), so a poisoned lock is still usable.
        self.inner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Brick `idx` of `level` of `source`, from the cache or read now.
    pub fn get(&self, source: &dyn BrickSource, level: usize, idx: u64) -> Result<Arc<[f32]>> {
        let key = (source.uid(), level as u32, idx);
        let mut inner = self.lock();
        loop {
            if let Some(b) = inner.touch(key) {
                self.hits.fetch_add(1, Ordering::Relaxed);
                return Ok(b);
            }
            if !inner.loading.contains(&key) {
                break;
            }
            // Another thread is reading this brick: wait for it rather than read it twice.
            inner = self
                .loaded
                .wait(inner)
                .unwrap_or_else(std::sync::PoisonError::into_inner);
        }
        inner.loading.insert(key);
        drop(inner);
        let _loading = Loading { cache: self, key };
        // Read outside the lock: other threads keep sampling (and reading) meanwhile.
        let data = self.read_new(source, level, idx)?;
        self.reads[level.min(MAX_LEVELS - 1)].fetch_add(1, Ordering::Relaxed);
        self.lock().insert(key, data.clone(), self.budget);
        Ok(data)
    }

    /// Reads a brick into a spare evicted brick's memory, or a new allocation.
    fn read_new(&self, source: &dyn BrickSource, level: usize, idx: u64) -> Result<Arc<[f32]>> {
        let s = source.layout().stored_edge();
        let n = s * s * s;
        let spare = {
            let mut inner = self.lock();
            let at = inner.spare.iter().position(|b| b.len() == n);
            at.map(|i| inner.spare.swap_remove(i))
        };
        let mut data: Arc<[f32]> = spare.unwrap_or_else(|| std::iter::repeat_n(0.0, n).collect());
        let out = Arc::get_mut(&mut data).ok_or_else(|| Error::invalid("shared spare brick"))?;
        source.read_brick_into(level, idx, out)?;
        Ok(data)
    }

    /// Whether brick `idx` of `level` of `source` is held now.
    #[must_use]
    pub fn contains(&self, source: &dyn BrickSource, level: usize, idx: u64) -> bool {
        self.lock()
            .map
            .contains_key(&(source.uid(), level as u32, idx))
    }

    /// Counters and memory use.
    #[must_use]
    pub fn stats(&self) -> CacheStats {
        let inner = self.lock();
        let mut reads: Vec<u64> = self
            .reads
            .iter()
            .map(|r| r.load(Ordering::Relaxed))
            .collect();
        while reads.len() > 1 && reads.last() == Some(&0) {
            reads.pop();
        }
        CacheStats {
            reads,
            prefetched: self.prefetched.load(Ordering::Relaxed),
            hits: self.hits.load(Ordering::Relaxed),
            resident_bytes: inner.used,
            peak_bytes: inner.peak,
            resident_bricks: inner.map.len(),
        }
    }

    /// Zeroes the counters (the resident bricks stay; the peak restarts from them).
    pub fn reset_stats(&self) {
        for r in &self.reads {
            r.store(0, Ordering::Relaxed);
        }
        self.prefetched.store(0, Ordering::Relaxed);
        self.hits.store(0, Ordering::Relaxed);
        let mut inner = self.lock();
        inner.peak = inner.used;
    }

    /// Drops every brick (a cold cache) and stops any prefetch in flight.
    pub fn clear(&self) {
        self.generation.fetch_add(1, Ordering::Relaxed);
        let mut inner = self.lock();
        inner.map.clear();
        inner.lru.clear();
        inner.used = 0;
    }

    /// Records the first failure of a read made where no error can be returned (a sample in
    /// an integrator's inner loop); [`BrickCache::take_error`] hands it on.
    pub fn record_error(&self, e: &Error) {
        let mut inner = self.lock();
        if inner.error.is_none() {
            inner.error = Some(e.to_string());
        }
    }

    /// The first recorded read failure since the last call, as an error.
    pub fn take_error(&self) -> Result<()> {
        match self.lock().error.take() {
            Some(msg) => Err(Error::invalid(format!("reading a brick failed: {msg}"))),
            None => Ok(()),
        }
    }

    /// Loads `bricks` of `level` of `source` in this order on the cache's I/O thread, ahead of
    /// the renderer. Prefetching never evicts: it stops once the budget is full, so a frame
    /// larger than the cache does not thrash. A later call (or [`BrickCache::clear`]) replaces
    /// the work still queued.
    pub fn prefetch(
        self: &Arc<Self>,
        source: Arc<dyn BrickSource>,
        level: usize,
        bricks: Vec<u64>,
    ) {
        let items = bricks
            .into_iter()
            .map(|b| (source.clone(), level, b))
            .collect();
        self.prefetch_items(items);
    }

    /// [`BrickCache::prefetch`] of bricks of several sources and levels, `(source, level,
    /// brick)` in load order (one job: it replaces the work still queued as a whole).
    pub fn prefetch_items(self: &Arc<Self>, bricks: PrefetchList) {
        let generation = self.generation.fetch_add(1, Ordering::Relaxed) + 1;
        let job = Job { bricks, generation };
        let mut io = self
            .io
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let job = match io.as_ref() {
            Some(tx) => match tx.send(job) {
                Ok(()) => return,
                Err(mpsc::SendError(job)) => job,
            },
            None => job,
        };
        let (tx, rx) = mpsc::channel::<Job>();
        let weak: Weak<BrickCache> = Arc::downgrade(self);
        let spawned = std::thread::Builder::new()
            .name("blueshift-brick-io".into())
            .spawn(move || io_thread(&weak, &rx));
        if spawned.is_ok() && tx.send(job).is_ok() {
            *io = Some(tx);
        }
    }
}

fn io_thread(cache: &Weak<BrickCache>, rx: &mpsc::Receiver<Job>) {
    while let Ok(job) = rx.recv() {
        for (source, level, idx) in &job.bricks {
            let (level, idx) = (*level, *idx);
            let Some(c) = cache.upgrade() else { return };
            if c.generation.load(Ordering::Relaxed) != job.generation {
                break;
            }
            let key = (source.uid(), level as u32, idx);
            {
                let mut inner = c.lock();
                if inner.map.contains_key(&key) || inner.loading.contains(&key) {
                    continue;
                }
                let s = source.layout().stored_edge();
                if inner.used + s * s * s * 4 > c.budget {
                    break;
                }
                inner.loading.insert(key);
            }
            let _loading = Loading { cache: &c, key };
            match c.read_new(source.as_ref(), level, idx) {
                Ok(data) => {
                    c.reads[level.min(MAX_LEVELS - 1)].fetch_add(1, Ordering::Relaxed);
                    c.prefetched.fetch_add(1, Ordering::Relaxed);
                    let mut inner = c.lock();
                    if !inner.map.contains_key(&key) {
                        inner.insert(key, data, c.budget);
                    }
                }
                // The renderer meets the same brick and reports the failure itself.
                Err(_) => break,
            }
        }
    }
}
