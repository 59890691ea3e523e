//! The memory budget: one number of bytes that every large allocation is checked against
//! before it is made.
//!
//! A caller estimates what an operation needs ([`grid_bytes`], [`image_bytes`], or its own
//! sum) and asks [`MemoryBudget::check`]; an estimate over the budget is a [`BudgetError`]
//! naming what needed the memory, the bytes, the budget and the setting that changes it
//! (`--max-memory` in the CLI). Where no estimate is possible, [`try_filled_vec`] reserves
//! fallibly (`try_reserve_exact`) so a failed allocation is an error, not an abort.
//!
//! The default ([`MemoryBudget::machine_default`]) is [`DEFAULT_FRACTION`] (3/4) of physical
//! memory (`MemTotal` of `/proc/meminfo`), or [`FALLBACK_BYTES`] where that is unknown.

use std::borrow::Cow;
use std::fmt;

/// The default budget's share of physical memory, as (numerator, denominator): 3/4.
pub const DEFAULT_FRACTION: (u64, u64) = (3, 4);

/// The default budget where physical memory is unknown (off Linux): 4 GiB.
pub const FALLBACK_BYTES: u64 = 4 << 30;

/// The environment variable the CLI reads when `--max-memory` is not given.
pub const ENV_VAR: &str = "BLUESHIFT_MAX_MEMORY";

/// An estimate that does not fit the budget. Nothing was allocated.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "{what} needs {} but the memory budget is {} ({setting})",
    format_bytes(*needed),
    format_bytes(*budget)
)]
pub struct BudgetError {
    /// What needed the memory, e.g. `this render (volume 2048^3 f32)`.
    pub what: String,
    /// The bytes it needs (saturated at `u64::MAX` when the estimate overflows).
    pub needed: u64,
    /// The budget in bytes.
    pub budget: u64,
    /// The setting that changes the budget (`--max-memory`).
    pub setting: String,
}

impl BudgetError {
    /// The allocator refused `needed` bytes for `what` (a budget of 0 bytes available).
    #[must_use]
    pub fn refused(what: impl Into<String>, needed: u64) -> Self {
        BudgetError {
            what: what.into(),
            needed,
            budget: 0,
            setting: "the allocator refused".to_owned(),
        }
    }
}

/// A number of bytes large allocations must fit in, with the name of the setting that
/// changes it (for the error message).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MemoryBudget {
    bytes: u64,
    setting: Cow<'static, str>,
}

impl Default for MemoryBudget {
    /// [`MemoryBudget::machine_default`].
    fn default() -> Self {
        Self::machine_default()
    }
}

impl fmt::Display for MemoryBudget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ({})", format_bytes(self.bytes), self.setting)
    }
}

impl MemoryBudget {
    /// A budget of `bytes`, changed by `setting` (named in errors).
    #[must_use]
    pub fn new(bytes: u64, setting: impl Into<Cow<'static, str>>) -> Self {
        Self {
            bytes,
            setting: setting.into(),
        }
    }

    /// [`DEFAULT_FRACTION`] of physical memory ([`FALLBACK_BYTES`] where unknown), changed by
    /// `--max-memory`.
    #[must_use]
    pub fn machine_default() -> Self {
        let bytes = crate::cache::physical_memory().map_or(FALLBACK_BYTES, |m| {
            m / DEFAULT_FRACTION.1 * DEFAULT_FRACTION.0
        });
        Self::new(bytes, "--max-memory")
    }

    /// No budget (every estimate fits; fallible allocation still applies).
    #[must_use]
    pub fn unlimited() -> Self {
        Self::new(u64::MAX, "unlimited")
    }

    /// The budget in bytes.
    #[must_use]
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// The setting named in errors.
    #[must_use]
    pub fn setting(&self) -> &str {
        &self.setting
    }

    /// Checks that `needed` bytes for `what` fit the budget.
    ///
    /// # Errors
    /// [`BudgetError`] when `needed` exceeds the budget.
    pub fn check(&self, what: impl fmt::Display, needed: u64) -> Result<(), BudgetError> {
        if needed <= self.bytes {
            Ok(())
        } else {
            Err(BudgetError {
                what: what.to_string(),
                needed,
                budget: self.bytes,
                setting: self.setting.to_string(),
            })
        }
    }

    /// Parses a size: bytes (`1048576`) or a number with a binary suffix `K`, `M`, `G`, `T`
    /// (optionally followed by `B` or `iB`; `1.5G` = 1.5 x 2^30 bytes).
    ///
    /// # Errors
    /// A message saying what is expected.
    pub fn parse_size(s: &str) -> Result<u64, String> {
        let t = s.trim();
        let upper = t.to_ascii_uppercase();
        let body = upper
            .strip_suffix("IB")
            .or_else(|| upper.strip_suffix('B'))
            .unwrap_or(&upper);
        let (num, shift) = match body.chars().last() {
            Some('K') => (&body[..body.len() - 1], 10),
            Some('M') => (&body[..body.len() - 1], 20),
            Some('G') => (&body[..body.len() - 1], 30),
            Some('T') => (&body[..body.len() - 1], 40),
            _ => (body, 0),
        };
        let bad = || format!("'{s}': expected a size such as 8G, 512M or a number of bytes");
        let v: f64 = num.trim().parse().map_err(|_| bad())?;
        if !v.is_finite() || v <= 0.0 {
            return Err(bad());
        }
        let bytes = v * (1u64 << shift) as f64;
        if bytes >= u64::MAX as f64 {
            return Ok(u64::MAX);
        }
        Ok(bytes.round() as u64)
    }
}

/// Bytes of `count` grids of `dims` voxels of `bytes_per_voxel` (saturating at `u64::MAX`).
#[must_use]
pub fn grid_bytes(dims: [usize; 3], bytes_per_voxel: usize, count: usize) -> u64 {
    [dims[0], dims[1], dims[2], bytes_per_voxel, count]
        .iter()
        .try_fold(1u64, |acc, &n| acc.checked_mul(n as u64))
        .unwrap_or(u64::MAX)
}

/// Bytes of an image of `width` x `height` pixels of `bytes_per_pixel` (saturating).
#[must_use]
pub fn image_bytes(width: u64, height: u64, bytes_per_pixel: u64) -> u64 {
    width
        .checked_mul(height)
        .and_then(|n| n.checked_mul(bytes_per_pixel))
        .unwrap_or(u64::MAX)
}

/// A vector of `n` copies of `value`, reserved fallibly: a failed allocation is a
/// [`BudgetError`] naming `what` (with a budget of 0 bytes available), not an abort.
///
/// # Errors
/// When the allocator refuses the reservation.
pub fn try_filled_vec<T: Clone>(n: usize, value: T, what: &str) -> Result<Vec<T>, BudgetError> {
    let mut v = Vec::new();
    v.try_reserve_exact(n).map_err(|_| {
        BudgetError::refused(
            what,
            (n as u64).saturating_mul(std::mem::size_of::<T>() as u64),
        )
    })?;
    v.resize(n, value);
    Ok(v)
}

/// `bytes` in decimal units with one decimal: `34.4 GB`, `512.0 MB`, `900 B`.
#[must_use]
pub fn format_bytes(bytes: u64) -> String {
    if bytes == u64::MAX {
        return "more than 18 EB".to_owned();
    }
    let b = bytes as f64;
    for (unit, scale) in [("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)] {
        if b >= scale {
            return format!("{:.1} {unit}", b / scale);
        }
    }
    format!("{bytes} B")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse() {
        assert_eq!(MemoryBudget::parse_size("512M"), Ok(512 << 20));
        assert_eq!(MemoryBudget::parse_size("8G"), Ok(8 << 30));
        assert_eq!(MemoryBudget::parse_size("8GiB"), Ok(8 << 30));
        assert_eq!(MemoryBudget::parse_size("1000"), Ok(1000));
        assert_eq!(MemoryBudget::parse_size("1.5k"), Ok(1536));
        assert!(MemoryBudget::parse_size("lots").is_err());
        assert!(MemoryBudget::parse_size("-1G").is_err());
        assert!(MemoryBudget::parse_size("0").is_err());
    }

    #[test]
    fn check_names_the_setting() {
        let b = MemoryBudget::new(18_000_000_000, "--max-memory");
        let e = b
            .check(
                "this render (volume 2048^3 f32)",
                grid_bytes([2048; 3], 4, 1),
            )
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "this render (volume 2048^3 f32) needs 34.4 GB but the memory budget is 18.0 GB (--max-memory)"
        );
        assert!(b.check("x", 1).is_ok());
    }
}
