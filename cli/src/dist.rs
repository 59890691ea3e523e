//! `--distributed MODE`: a render spread over the ranks of an MPI job (`mpirun -np N
//! blueshift render|doppler ... --distributed data|samples|tiles|frames`), through
//! `blueshift-dist`. Needs a build with the `mpi` feature; without it the flag is refused
//! with the one line saying how to build it.
//!
//! Rank 0 writes the image (every rank writes its own frames in `frames` mode). A failure on
//! any rank stops all of them: the distributed renders agree on success after every phase
//! (an `MPI_Allreduce` of the lowest failed rank), that rank prints its error and every rank
//! exits 1; a rank that dies outright makes `mpirun` end the job.

use anyhow::{Result, bail};
use blueshift_dist::Mode;

/// The mode of `--distributed`, parsed.
pub fn mode(flag: Option<&str>) -> Result<Option<Mode>> {
    Ok(match flag {
        None => None,
        Some(s) => Some(s.trim().parse::<Mode>()?),
    })
}

/// The compositing factors of `--compositing` for `ranks` ranks: `auto` (binary swap for
/// powers of two, radix-k otherwise; [`blueshift_dist::Strategy::auto`]), `direct-send`,
/// `binary-swap`, or radix-k factors `K1,K2,...` (bottom round first).
pub fn factors(flag: &str, ranks: usize) -> Result<Vec<usize>> {
    use blueshift_dist::Strategy;
    let s = match flag.trim() {
        "auto" => Strategy::auto(ranks),
        "direct-send" => Strategy::DirectSend,
        "binary-swap" => Strategy::BinarySwap,
        list => Strategy::RadixK(
            list.split(',')
                .map(|k| k.trim().parse::<usize>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| {
                    anyhow::anyhow!(
                        "--compositing {list:?}: expected auto, direct-send, binary-swap or \
                         radix-k factors like 4,2"
                    )
                })?,
        ),
    };
    s.factors(ranks)
        .map_err(|e| anyhow::anyhow!("--compositing: {e}"))
}

/// An error every rank already knows about (another rank failed and printed why): the
/// process exits 1 without a message of its own.
#[derive(Debug)]
pub struct Quiet;

impl std::fmt::Display for Quiet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("another rank failed")
    }
}

impl std::error::Error for Quiet {}

/// A distributed render's error for the CLI: [`Quiet`] for a peer's failure, the error
/// prefixed with this rank otherwise.
pub fn error(e: blueshift_dist::Error, rank: usize) -> anyhow::Error {
    match e {
        blueshift_dist::Error::PeerFailed(_) => {
            mark_peer_failed();
            anyhow::Error::new(Quiet)
        }
        e => anyhow::anyhow!("rank {rank}: {e}"),
    }
}

#[cfg(feature = "mpi")]
mod world {
    use std::sync::Mutex;

    use anyhow::Result;
    use blueshift_dist::mpi::MpiComm;

    static COMM: Mutex<Option<MpiComm>> = Mutex::new(None);

    /// Runs `f` with the job's communicator (MPI initialised on first use).
    pub fn with<T>(f: impl FnOnce(&MpiComm) -> Result<T>) -> Result<T> {
        let mut g = COMM
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if g.is_none() {
            *g = Some(MpiComm::init()?);
        }
        f(g.as_ref().expect("initialised above"))
    }

    /// Finalises MPI if it was initialised (at the end of `main`).
    pub fn finalize() {
        let mut g = COMM
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        g.take();
    }
}

#[cfg(feature = "mpi")]
pub use world::finalize;

/// Finalises MPI if it was initialised (nothing without the `mpi` feature).
#[cfg(not(feature = "mpi"))]
pub fn finalize() {}

/// Runs `f(comm)` with the MPI world.
#[cfg(feature = "mpi")]
pub fn with_comm<T>(f: impl FnOnce(&dyn blueshift_dist::Communicator) -> Result<T>) -> Result<T> {
    world::with(|c| f(c))
}

/// Refused: this build has no MPI.
#[cfg(not(feature = "mpi"))]
pub fn with_comm<T>(_f: impl FnOnce(&dyn blueshift_dist::Communicator) -> Result<T>) -> Result<T> {
    bail!(
        "--distributed needs a blueshift built with MPI: install MPI (Debian: apt-get install \
         openmpi-bin libopenmpi-dev libclang-dev) and build with `cargo build --release -p \
         blueshift-cli --features mpi`"
    )
}

/// Whether this rank renders frame `k` (`frames` mode: round robin; otherwise every frame).
pub fn keeps_frame(mode: Option<Mode>, k: usize) -> Result<bool> {
    if mode != Some(Mode::Frames) {
        return Ok(true);
    }
    with_comm(|c| Ok(k % c.size() == c.rank()))
}

/// Refuses a mode the command does not have.
pub fn check_mode(mode: Option<Mode>, allowed: &[Mode], command: &str) -> Result<()> {
    if let Some(m) = mode
        && !allowed.contains(&m)
    {
        bail!(
            "--distributed {}: `{command}` distributes {}",
            name(m),
            allowed
                .iter()
                .map(|m| name(*m))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok(())
}

fn name(m: Mode) -> &'static str {
    match m {
        Mode::Data => "data",
        Mode::Samples => "samples",
        Mode::Tiles => "tiles",
        Mode::Frames => "frames",
    }
}

/// A tracking render (`data`: the marcher composited, Woodcock with rays forwarded;
/// `samples` or `tiles`: any integrator): rank 0 gets the accumulation.
pub fn tracking(
    mode: Mode,
    mut scene: blueshift_tracking::Scene,
    integrator: &blueshift_tracking::Integrator,
    settings: &blueshift_tracking::RenderSettings,
    compositing: &str,
) -> Result<Option<blueshift_tracking::Progressive>> {
    use blueshift_dist::render::{render_marcher_data, render_samples, render_tiles};
    with_comm(|c| {
        let r = match mode {
            Mode::Samples => render_samples(c, &scene, integrator, settings),
            Mode::Tiles => render_tiles(c, &scene, integrator, settings),
            Mode::Data => {
                let g = *scene.geometry();
                let f = factors(compositing, c.size())?;
                let d = blueshift_dist::Decomposition::new(g.dims, g.origin, g.spacing, &f)
                    .map_err(|e| anyhow::anyhow!("{e}"))?;
                if let blueshift_tracking::Integrator::Woodcock { .. } = integrator {
                    // Rays forwarded between the pieces (barney's approach).
                    blueshift_dist::forward::render_woodcock_forwarded(
                        c, &scene, integrator, settings, &d,
                    )
                    .map(|(img, _)| img)
                } else {
                    render_marcher_data(c, &mut scene, integrator, settings, &d)
                }
            }
            Mode::Frames => return Ok(None),
        };
        r.map_err(|e| error(e, c.rank()))
    })
}

/// A distributed Doppler image (`data` or `tiles`): rank 0 gets it.
pub fn doppler(
    mode: Mode,
    scene: &blueshift_doppler::DopplerScene,
    settings: &blueshift_doppler::DopplerSettings,
    compositing: &str,
) -> Result<Option<blueshift_doppler::DopplerImage>> {
    use blueshift_dist::render::{render_doppler_data, render_doppler_tiles};
    with_comm(|c| {
        let r = match mode {
            Mode::Tiles => render_doppler_tiles(c, scene, settings),
            _ => render_doppler_data(
                c,
                scene,
                settings,
                &doppler_decomposition(scene, c.size(), compositing)?,
            ),
        };
        r.map_err(|e| error(e, c.rank()))
    })
}

/// A distributed spectral cube (`data`: pieces of the volume add, absorbing ones behind the
/// depth in front of them;
/// `tiles`: image rows, any scene): rank 0 gets it.
pub fn cube(
    mode: Mode,
    scene: &blueshift_doppler::DopplerScene,
    settings: &blueshift_doppler::DopplerSettings,
    spec: &blueshift_doppler::CubeSpec,
    compositing: &str,
) -> Result<Option<blueshift_doppler::SpectralCube>> {
    use blueshift_dist::render::{render_cube_data, render_cube_tiles};
    with_comm(|c| {
        let r = match mode {
            Mode::Tiles => render_cube_tiles(c, scene, settings, spec),
            _ => render_cube_data(
                c,
                scene,
                settings,
                spec,
                &doppler_decomposition(scene, c.size(), compositing)?,
            ),
        };
        r.map_err(|e| error(e, c.rank()))
    })
}

/// The k-d split of a Doppler scene's domain over `ranks` ranks.
fn doppler_decomposition(
    scene: &blueshift_doppler::DopplerScene,
    ranks: usize,
    compositing: &str,
) -> Result<blueshift_dist::Decomposition> {
    let g = *scene.geometry();
    let f = factors(compositing, ranks)?;
    blueshift_dist::Decomposition::new(g.dims, g.origin, g.spacing, &f)
        .map_err(|e| anyhow::anyhow!("{e}"))
}

/// Set when a collective step during loading learnt that another rank failed (that rank
/// prints why): `main` exits 1 without a second message.
static PEER_FAILED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Records that another rank failed and reports it (this rank then says nothing, not even
/// `interrupted` when mpirun ends it for that failure).
pub fn mark_peer_failed() {
    PEER_FAILED.store(true, std::sync::atomic::Ordering::Relaxed);
}

/// Whether another rank failed during a collective step (of loading or of a render).
pub fn peer_failed() -> bool {
    PEER_FAILED.load(std::sync::atomic::Ordering::Relaxed)
}

/// Loads a scene for `--distributed data` so that AMR fields read only this rank's blocks:
/// the union of its k-d pieces over the field's levels for the job's rank count (the
/// decomposition the render then makes at the level it picks, `compositing`'s factors),
/// each with its ghost layer, through
/// [`blueshift_volume::amr::with_scope`]; the fields' statistics (value range, least
/// positive value, non-finite count: what automatic transfer-function ranges and the input
/// checks read) are all-reduced so every rank sees the single process's. A rank that fails
/// to read its blocks fails every rank there (the other inputs are taken to read the same
/// on every rank: a file only one rank cannot read makes the others wait). The fields named
/// in `whole` are read whole (a pass over the whole field follows: the mean velocity).
/// Rank 0 prints `AMR blocks read per rank (of N): B0 B1 ...` when AMR fields were opened.
pub fn load_scoped<T>(
    compositing: &str,
    whole: &[String],
    load: impl FnOnce() -> Result<T>,
) -> Result<T> {
    use blueshift_volume::amr::{AmrStats, ReadScope, Region, with_scope};
    let compositing = compositing.to_owned();
    let whole = whole.to_vec();
    let region = move |name: &str, levels: &[blueshift_volume::Geometry]| -> Option<Region> {
        if whole.iter().any(|w| w == name) {
            return None;
        }
        with_comm(|c| {
            let f = factors(&compositing, c.size())?;
            // The union of this rank's pieces over the levels a render may pick (each level
            // splits its own voxels, so the pieces differ from level to level), each with
            // its ghost layer: the voxels its samples read (the blocks are chosen with a
            // root cell's margin beyond that).
            let mut out: Option<Region> = None;
            for g in levels {
                let d = blueshift_dist::Decomposition::new(g.dims, g.origin, g.spacing, &f)
                    .map_err(|e| anyhow::anyhow!("{e}"))?;
                let p = &d.pieces()[c.rank()];
                let (lo, hi) = (p.read_lo(), p.read_hi(g.dims));
                let at = |i: [usize; 3], side: f64| {
                    glam::DVec3::from_array([0, 1, 2].map(|a| {
                        f64::from(g.origin[a]) + (i[a] as f64 + side) * f64::from(g.spacing[a])
                    }))
                };
                let (a, b) = (at(lo, 0.0), at(hi, -1.0));
                out = Some(match out {
                    None => Region::new(a, b),
                    Some(r) => Region::new(r.lo.min(a), r.hi.max(b)),
                });
            }
            Ok(out)
        })
        // No decomposition: read the whole field (the render then refuses the same way).
        .ok()
        .flatten()
    };
    let reduce = |r: blueshift_volume::Result<AmrStats>| -> blueshift_volume::Result<AmrStats> {
        let failed = r.is_err();
        // Ok(stats) when every rank read its blocks; Err(lowest failed rank is this one).
        let out = with_comm(|c| {
            let first = c.first_failed(failed).map_err(|e| anyhow::anyhow!("{e}"))?;
            Ok(match first {
                Some(f) => Err(f == c.rank()),
                None => Ok(all_combine(
                    c,
                    r.as_ref().ok().copied().unwrap_or_default(),
                )?),
            })
        });
        match (r, out) {
            (Ok(_), Ok(Ok(s))) => Ok(s),
            // The lowest rank that failed says why.
            (Err(e), Ok(Err(true))) => Err(e),
            (_, Ok(Err(_))) => {
                mark_peer_failed();
                Err(blueshift_volume::Error::Invalid(
                    "another rank failed to read its AMR blocks".into(),
                ))
            }
            (Err(e), _) => Err(e),
            (Ok(_), Err(e)) => Err(blueshift_volume::Error::Invalid(format!("{e}"))),
        }
    };
    let scope = ReadScope::new(Box::new(region), Box::new(reduce));
    let (out, (read, total)) = with_scope(scope, load);
    let out = out?;
    if total > 0 {
        // One line from rank 0 (lines of several ranks interleave under mpirun).
        with_comm(|c| {
            let e = |e: blueshift_dist::Error| anyhow::anyhow!("{e}");
            if c.rank() == 0 {
                let mut all = vec![read.to_string()];
                for r in 1..c.size() {
                    let v = c.recv(r).map_err(e)?;
                    all.push(v.first().map_or(0, |&x| x as usize).to_string());
                }
                errln!("AMR blocks read per rank (of {total}): {}", all.join(" "));
            } else {
                c.send(0, &[read as f64]).map_err(e)?;
            }
            Ok(())
        })?;
    }
    Ok(out)
}

/// The statistics of every rank combined ([`blueshift_volume::amr::AmrStats::combine`]),
/// on every rank: gathered on rank 0 and sent back.
fn all_combine(
    c: &dyn blueshift_dist::Communicator,
    s: blueshift_volume::amr::AmrStats,
) -> Result<blueshift_volume::amr::AmrStats> {
    use blueshift_volume::amr::AmrStats;
    let enc = |s: &AmrStats| -> Vec<f64> {
        let (lo, hi) = s.range.unwrap_or((0.0, 0.0));
        vec![
            f64::from(lo),
            f64::from(hi),
            f64::from(u8::from(s.range.is_some())),
            f64::from(s.positive_min.unwrap_or(0.0)),
            f64::from(u8::from(s.positive_min.is_some())),
            s.non_finite as f64,
        ]
    };
    let dec = |v: &[f64]| -> Result<AmrStats> {
        if v.len() != 6 {
            bail!("AMR statistics: {} values from a peer", v.len());
        }
        Ok(AmrStats {
            range: (v[2] != 0.0).then_some((v[0] as f32, v[1] as f32)),
            positive_min: (v[4] != 0.0).then_some(v[3] as f32),
            non_finite: v[5] as u64,
        })
    };
    let e = |e: blueshift_dist::Error| anyhow::anyhow!("{e}");
    if c.rank() == 0 {
        // Every peer's message is received and every peer answered (an empty answer: the
        // statistics did not decode), so no rank waits on a failure here.
        let mut all = Ok(s);
        for r in 1..c.size() {
            let got = c.recv(r).map_err(e)?;
            all = match (all, dec(&got)) {
                (Ok(a), Ok(b)) => Ok(AmrStats::combine(a, b)),
                (Err(x), _) | (_, Err(x)) => Err(x),
            };
        }
        let v = all.as_ref().map(enc).unwrap_or_default();
        for r in 1..c.size() {
            c.send(r, &v).map_err(e)?;
        }
        all
    } else {
        c.send(0, &enc(&s)).map_err(e)?;
        dec(&c.recv(0).map_err(e)?)
    }
}
