//! Resource limits shared by every verb: the memory budget (`--max-memory`, or
//! `BLUESHIFT_MAX_MEMORY`, default 3/4 of physical memory) and the cap on `--threads`.

use std::sync::OnceLock;

use anyhow::{Result, bail};
use blueshift_volume::MemoryBudget;

static BUDGET: OnceLock<MemoryBudget> = OnceLock::new();

/// `--threads` may ask for at most this many threads per core
/// (`std::thread::available_parallelism`); more is refused with an error.
pub const MAX_THREADS_PER_CORE: usize = 4;

/// Sets the process's memory budget from `--max-memory` (or `BLUESHIFT_MAX_MEMORY`);
/// the default is [`MemoryBudget::machine_default`].
pub fn init(flag: Option<&str>) -> Result<()> {
    let env = std::env::var(blueshift_volume::budget::ENV_VAR).ok();
    let budget = match (flag, env.as_deref()) {
        (Some(s), _) => MemoryBudget::new(
            MemoryBudget::parse_size(s).map_err(|e| anyhow::anyhow!("--max-memory {e}"))?,
            "--max-memory",
        ),
        (None, Some(s)) if !s.trim().is_empty() => MemoryBudget::new(
            MemoryBudget::parse_size(s)
                .map_err(|e| anyhow::anyhow!("{} {e}", blueshift_volume::budget::ENV_VAR))?,
            "--max-memory",
        ),
        _ => MemoryBudget::machine_default(),
    };
    let _ = BUDGET.set(budget);
    Ok(())
}

/// The process's memory budget.
pub fn budget() -> &'static MemoryBudget {
    BUDGET.get_or_init(MemoryBudget::machine_default)
}

/// Checks an estimate of `bytes` for `what` against the budget.
pub fn check(what: impl std::fmt::Display, bytes: u64) -> Result<()> {
    Ok(budget().check(what, bytes)?)
}

/// A rayon pool of `threads` threads (checked: 1 ..= [`MAX_THREADS_PER_CORE`] x cores),
/// or `None` for the default pool.
pub fn thread_pool(threads: Option<usize>) -> Result<Option<rayon::ThreadPool>> {
    let Some(t) = threads else { return Ok(None) };
    check_threads(t)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(t)
        .build()
        .map_err(|e| anyhow::anyhow!("cannot start worker threads: {e}"))?;
    Ok(Some(pool))
}

/// Refuses `--threads 0` and more than [`MAX_THREADS_PER_CORE`] x cores.
pub fn check_threads(t: usize) -> Result<()> {
    let cores = std::thread::available_parallelism().map_or(1, std::num::NonZero::get);
    let max = MAX_THREADS_PER_CORE * cores;
    if t == 0 {
        bail!("--threads: must be at least 1");
    }
    if t > max {
        bail!("--threads {t}: at most {max} ({MAX_THREADS_PER_CORE} per core, {cores} cores)");
    }
    Ok(())
}
