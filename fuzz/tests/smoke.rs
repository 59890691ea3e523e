//! Every fuzz target run over its seed corpus and a fixed number of deterministic mutations
//! of it (a libFuzzer-like mutator with a fixed seed, so a failure reproduces), with:
//! - no panic (caught per input; the input is saved under `target/fuzz-failures/`);
//! - a memory ceiling per input: a counting allocator records the peak of live heap bytes
//!   while the input runs, which must stay under [`CEILING`] (the smoke-test form of
//!   libFuzzer's `-malloc_limit_mb`); a single request above [`REFUSE`] is refused, which
//!   aborts the process after a line naming the target and the input (the mutations are
//!   deterministic: `BLUESHIFT_FUZZ_TARGET` and the input's number reproduce it);
//! - a time guard per input ([`TIME_GUARD`], far above what any input needs).
//!
//! `BLUESHIFT_FUZZ_ITERS` sets the mutations per target (default [`DEFAULT_ITERS`]);
//! `BLUESHIFT_FUZZ_TARGET` runs one target.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use blueshift_fuzz::{TARGETS, Target, workspace_root};

/// Mutations per target.
const DEFAULT_ITERS: usize = 4000;
/// Live heap bytes an input may add at its peak. The seeds are at most a few hundred
/// kilobytes; the largest legitimate use is a gzip NRRD or a scene's spectra.
const CEILING: usize = 256 << 20;
/// A single allocation request above this is refused (the process then aborts).
const REFUSE: usize = 1 << 30;
/// Wall-clock guard per input (a guard against hangs, not a speed measurement).
const TIME_GUARD: Duration = Duration::from_secs(20);

struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
/// The target (index in `TARGETS`) and input (seeds first, then mutations) running now.
static CURRENT_TARGET: AtomicUsize = AtomicUsize::new(usize::MAX);
static CURRENT_INPUT: AtomicUsize = AtomicUsize::new(0);

/// Says which input asked for `size` bytes, without allocating (the allocator calls it).
fn refused(size: usize) {
    use std::fmt::Write as _;
    use std::io::Write as _;
    struct Buf([u8; 160], usize);
    impl std::fmt::Write for Buf {
        fn write_str(&mut self, s: &str) -> std::fmt::Result {
            let n = s.len().min(self.0.len() - self.1);
            self.0[self.1..self.1 + n].copy_from_slice(&s.as_bytes()[..n]);
            self.1 += n;
            Ok(())
        }
    }
    let mut b = Buf([0; 160], 0);
    let name = TARGETS
        .get(CURRENT_TARGET.load(Ordering::Relaxed))
        .map_or("?", |t| t.name);
    let _ = writeln!(
        b,
        "fuzz smoke: {name} input {} asked for {size} bytes (over the refusal limit)",
        CURRENT_INPUT.load(Ordering::Relaxed)
    );
    let _ = std::io::stderr().write_all(&b.0[..b.1]);
}

// SAFETY: forwards to the system allocator unchanged; only counts bytes.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > REFUSE {
            refused(layout.size());
            return std::ptr::null_mut();
        }
        // SAFETY: the caller's contract for `alloc` is passed on.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let live = LIVE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(live, Ordering::Relaxed);
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() > REFUSE {
            refused(layout.size());
            return std::ptr::null_mut();
        }
        // SAFETY: as `alloc`.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            let live = LIVE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(live, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as `alloc`.
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > REFUSE {
            refused(new_size);
            return std::ptr::null_mut();
        }
        // SAFETY: as `alloc`.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            if new_size >= layout.size() {
                let grow = new_size - layout.size();
                let live = LIVE.fetch_add(grow, Ordering::Relaxed) + grow;
                PEAK.fetch_max(live, Ordering::Relaxed);
            } else {
                LIVE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// A small deterministic generator (SplitMix64).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next() % n as u64) as usize
        }
    }
}

/// Tokens a mutation splices in: numbers at the edges of what parsers and allocators take,
/// and structural characters of the text formats.
const TOKENS: &[&[u8]] = &[
    b"0",
    b"-1",
    b"1",
    b"-0",
    b"65536",
    b"4294967296",
    b"99999999",
    b"1e300",
    b"-1e300",
    b"1e-300",
    b"NaN",
    b"nan",
    b"inf",
    b"-inf",
    b"null",
    b"\"\"",
    b"[]",
    b"{}",
    b",",
    b"\n",
    b" ",
    b"\"",
    b"18446744073709551615",
    b"2147483648",
    b"0.0",
    b"1e38",
    b"3.4e39",
];

/// Bytes a mutation writes over one byte.
const BYTES: &[u8] = b"\x00\xff\x7f\x80 09-.e\n\"{}[],:";

/// One libFuzzer-like mutation of `data` (1 to 4 edits).
fn mutate(rng: &mut Rng, data: &[u8]) -> Vec<u8> {
    let mut d = data.to_vec();
    for _ in 0..1 + rng.below(4) {
        let n = d.len();
        match rng.below(8) {
            0 if n > 0 => {
                let i = rng.below(n);
                d[i] ^= 1 << rng.below(8);
            }
            1 if n > 0 => {
                let i = rng.below(n);
                d[i] = BYTES[rng.below(BYTES.len())];
            }
            2 if n > 0 => {
                let i = rng.below(n);
                let len = (1 + rng.below(16)).min(n - i);
                d.drain(i..i + len);
            }
            3 if n > 0 => {
                let i = rng.below(n);
                let len = (1 + rng.below(64)).min(n - i);
                let copy = d[i..i + len].to_vec();
                let at = rng.below(n + 1);
                d.splice(at..at, copy);
            }
            4 => {
                let at = rng.below(n + 1);
                let t = TOKENS[rng.below(TOKENS.len())];
                d.splice(at..at, t.iter().copied());
            }
            5 if n > 0 => {
                // A run of digits (a number in a text header) replaced by a token.
                let starts: Vec<usize> = (0..n)
                    .filter(|&i| d[i].is_ascii_digit() && (i == 0 || !d[i - 1].is_ascii_digit()))
                    .collect();
                if !starts.is_empty() {
                    let s = starts[rng.below(starts.len())];
                    let e = (s..n).find(|&i| !d[i].is_ascii_digit()).unwrap_or(n);
                    let t = TOKENS[rng.below(TOKENS.len())];
                    d.splice(s..e, t.iter().copied());
                }
            }
            6 if n > 0 => d.truncate(rng.below(n)),
            _ if n > 0 => {
                // Overwrite 4 bytes with a little-endian edge value (binary headers).
                let i = rng.below(n);
                let v: u32 = [
                    0,
                    1,
                    0xffff_ffff,
                    0x7fff_ffff,
                    0x8000_0000,
                    0xffff,
                    0x1_0000,
                ][rng.below(7)];
                for (k, b) in v.to_le_bytes().into_iter().enumerate() {
                    if i + k < n {
                        d[i + k] = b;
                    }
                }
            }
            _ => d.push(BYTES[rng.below(BYTES.len())]),
        }
    }
    d
}

/// The seed files of `t` (folders read whole).
fn seeds(t: &Target) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    for s in t.seeds {
        let p = workspace_root().join(s);
        let files: Vec<PathBuf> = if p.is_dir() {
            let mut v: Vec<PathBuf> = std::fs::read_dir(&p)
                .map(|r| {
                    r.flatten()
                        .map(|e| e.path())
                        .filter(|p| p.is_file())
                        .collect()
                })
                .unwrap_or_default();
            v.sort();
            v
        } else {
            vec![p]
        };
        for f in files {
            let bytes = std::fs::read(&f).unwrap_or_else(|e| panic!("seed {}: {e}", f.display()));
            out.push((f, bytes));
        }
    }
    out
}

fn failures_dir() -> PathBuf {
    let d = workspace_root().join("target/fuzz-failures");
    let _ = std::fs::create_dir_all(&d);
    d
}

/// Runs `t` on `input`; a description of what went wrong, if anything did.
fn run_one(t: &Target, input: &[u8]) -> (bool, Option<String>) {
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let start = Instant::now();
    let r = std::panic::catch_unwind(|| (t.run)(input));
    let accepted = matches!(r, Ok(true));
    let took = start.elapsed();
    let peak = PEAK.load(Ordering::Relaxed).saturating_sub(base);
    if let Err(e) = r {
        let msg = e
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| e.downcast_ref::<&str>().map(|s| (*s).to_owned()))
            .unwrap_or_default();
        return (false, Some(format!("panicked: {msg}")));
    }
    if peak > CEILING {
        let why = format!(
            "peak heap {} MiB over the {} MiB ceiling",
            peak >> 20,
            CEILING >> 20
        );
        return (accepted, Some(why));
    }
    if took > TIME_GUARD {
        return (accepted, Some(format!("took {took:?}")));
    }
    (accepted, None)
}

fn save(t: &Target, i: usize, input: &[u8]) -> PathBuf {
    let p = failures_dir().join(format!("{}-{i}", t.name));
    let _ = std::fs::write(&p, input);
    p
}

/// Runs `t` over its seeds and `iters` mutations: the failures, and how many seeds and
/// mutations the reader accepted.
fn fuzz(t: &Target, iters: usize) -> (Vec<String>, usize, usize) {
    let corpus = seeds(t);
    assert!(!corpus.is_empty(), "{}: no seeds", t.name);
    let mut bad = Vec::new();
    let (mut good_seeds, mut good_mutants) = (0, 0);
    CURRENT_TARGET.store(
        TARGETS
            .iter()
            .position(|x| x.name == t.name)
            .unwrap_or(usize::MAX),
        Ordering::Relaxed,
    );
    for (i, (path, bytes)) in corpus.iter().enumerate() {
        CURRENT_INPUT.store(i, Ordering::Relaxed);
        let (ok, why) = run_one(t, bytes);
        good_seeds += usize::from(ok);
        if let Some(why) = why {
            bad.push(format!("{} seed {}: {why}", t.name, path.display()));
            save(t, i, bytes);
        }
    }
    // The seed of the generator is the target's name, so each target's inputs stay the
    // same when targets are added.
    let mut rng = Rng(t.name.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
    }));
    for i in 0..iters {
        let (_, seed) = &corpus[rng.below(corpus.len())];
        let input = mutate(&mut rng, seed);
        CURRENT_INPUT.store(corpus.len() + i, Ordering::Relaxed);
        let (ok, why) = run_one(t, &input);
        good_mutants += usize::from(ok);
        if let Some(why) = why {
            let p = save(t, i, &input);
            bad.push(format!(
                "{} mutation {i}: {why} (input in {})",
                t.name,
                p.display()
            ));
        }
    }
    (bad, good_seeds, good_mutants)
}

#[test]
fn every_reader_survives_its_mutated_corpus() {
    // The counting allocator sees a large allocation: the memory ceiling can fail.
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let v = vec![1u8; 8 << 20];
    std::hint::black_box(&v);
    drop(v);
    assert!(PEAK.load(Ordering::Relaxed).saturating_sub(base) >= 8 << 20);
    // Panics are reported per input; keep the default hook's lines out of the way.
    std::panic::set_hook(Box::new(|_| {}));
    let iters = std::env::var("BLUESHIFT_FUZZ_ITERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(DEFAULT_ITERS);
    let only = std::env::var("BLUESHIFT_FUZZ_TARGET").ok();
    let mut bad = Vec::new();
    for t in TARGETS
        .iter()
        .filter(|t| only.as_deref().is_none_or(|o| o == t.name))
    {
        let start = Instant::now();
        let (b, good_seeds, good_mutants) = fuzz(t, iters);
        eprintln!(
            "{}: {iters} mutations in {:.1?}: {} failed, {good_mutants} accepted; {good_seeds} seeds accepted",
            t.name,
            start.elapsed(),
            b.len()
        );
        // A target none of whose seeds the reader accepts fuzzes only its first checks (a
        // fixture file missing, a seed gone stale).
        if good_seeds == 0 {
            bad.push(format!("{}: the reader accepted none of its seeds", t.name));
        }
        bad.extend(b);
    }
    let _ = std::panic::take_hook();
    assert!(
        bad.is_empty(),
        "{} failing inputs:\n{}",
        bad.len(),
        bad.join("\n")
    );
}

/// The mutator changes its input and is deterministic (the smoke test is reproducible).
#[test]
fn mutations_are_deterministic_and_change_the_input() {
    let seed = b"NRRD0004\ntype: float\nsizes: 2 3 4\n\n".to_vec();
    let run = || {
        let mut rng = Rng(7);
        (0..50).map(|_| mutate(&mut rng, &seed)).collect::<Vec<_>>()
    };
    let a = run();
    assert_eq!(a, run());
    assert!(a.iter().filter(|m| **m != seed).count() >= 45);
}

/// Every target's seeds exist and are read (a renamed test file would leave a target
/// without its corpus).
#[test]
fn every_target_has_seeds() {
    for t in TARGETS {
        let s = seeds(t);
        assert!(!s.is_empty(), "{} has no seeds", t.name);
        assert!(Path::new(workspace_root()).join(t.seeds[0]).exists());
    }
}

/// The committed binary seeds under `fuzz/corpus/` are what [`write_binary_seeds`] makes
/// (so a change of the `.bsv` writer cannot leave the fuzzers on stale files); with
/// `BLUESHIFT_FUZZ_REGENERATE=1` it writes them there instead.
#[test]
fn the_binary_seeds_are_what_their_generator_writes() {
    const FILES: [&str; 4] = [
        "bsv/ramp_f32.bsv",
        "bsv/ramp_u8.bsv",
        "pfm/small.pfm",
        "fits/cube.fits",
    ];
    let committed = workspace_root().join("fuzz/corpus");
    if std::env::var("BLUESHIFT_FUZZ_REGENERATE").is_ok_and(|v| v == "1") {
        write_binary_seeds(&committed);
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    for sub in ["bsv", "pfm", "fits"] {
        std::fs::create_dir_all(dir.path().join(sub)).expect("mkdir");
    }
    write_binary_seeds(dir.path());
    for f in FILES {
        let made = std::fs::read(dir.path().join(f)).expect("made");
        let kept = std::fs::read(committed.join(f)).expect("committed seed");
        assert!(
            made == kept,
            "{f} differs from its generator's output (regenerate it)"
        );
    }
}

/// Writes the binary seeds into `corpus`: two small `.bsv` files (f32 and u8, 4-voxel
/// bricks so that several bricks and levels fit in a few kilobytes), a PFM and a FITS cube
/// header with its data.
fn write_binary_seeds(corpus: &Path) {
    use blueshift_volume::ooc::{self, BrickLayout, GridSource};
    use blueshift_volume::{Geometry, Grid};
    let g = Geometry::unit([9, 6, 5]);
    let f = Grid::<f32>::from_vec(
        g,
        (0..g.voxel_count())
            .map(|i| (i as f32 * 0.37).sin() * 3.0)
            .collect(),
    )
    .expect("grid");
    let u = Grid::<u8>::from_vec(
        g,
        (0..g.voxel_count()).map(|i| (i * 7 % 251) as u8).collect(),
    )
    .expect("grid");
    let layout = BrickLayout { brick: 4, apron: 1 };
    let mut none = |_: u64, _: u64| {};
    ooc::convert(
        &mut GridSource(&f),
        &corpus.join("bsv/ramp_f32.bsv"),
        "density",
        layout,
        &mut none,
    )
    .expect("f32 bsv");
    ooc::convert(
        &mut GridSource(&u),
        &corpus.join("bsv/ramp_u8.bsv"),
        "mask",
        layout,
        &mut none,
    )
    .expect("u8 bsv");
    // PFM: colour, little-endian (negative scale), 3 x 2 pixels.
    let mut pfm = b"PF\n3 2\n-1.0\n".to_vec();
    for i in 0..18 {
        pfm.extend_from_slice(&(i as f32 * 0.25).to_le_bytes());
    }
    std::fs::write(corpus.join("pfm/small.pfm"), pfm).expect("pfm");
    // FITS: a 4 x 3 x 2 float32 cube with a spectral WCS axis.
    let cards = [
        "SIMPLE  =                    T",
        "BITPIX  =                  -32",
        "NAXIS   =                    3",
        "NAXIS1  =                    4",
        "NAXIS2  =                    3",
        "NAXIS3  =                    2",
        "CTYPE3  = 'VRAD    '",
        "CRVAL3  =                  0.0",
        "CDELT3  =                 10.0",
        "CRPIX3  =                  1.0",
        "CUNIT3  = 'km/s    '",
        "BUNIT   = 'erg/s/cm2/sr/(km/s)'",
        "END",
    ];
    let mut fits: Vec<u8> = cards
        .iter()
        .flat_map(|c| format!("{c:<80}").into_bytes())
        .collect();
    fits.resize(2880, b' ');
    for i in 0..24 {
        fits.extend_from_slice(&(i as f32 * 1.5).to_be_bytes());
    }
    fits.resize(2 * 2880, 0);
    std::fs::write(corpus.join("fits/cube.fits"), fits).expect("fits");
}
