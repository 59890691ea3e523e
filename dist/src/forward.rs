//! Data-parallel Woodcock tracking with rays forwarded between ranks (the approach of Wald
//! et al.'s barney): each rank tracks every ray whose next tentative collision lies in its
//! piece of the volume and samples the density there only (bricked files are read lazily,
//! so only that piece's bricks; the majorant grid is the whole volume's, on every rank); a
//! ray whose walk reaches a tentative collision in another piece is sent to the rank that
//! holds it, with its random stream's position, and continues there.
//!
//! The ray's random numbers are counter-based (seed, pixel, sample, dimension) and the
//! majorant grid (a small grid of macrocell maxima) is the same on every rank, so the
//! receiving rank rebuilds the ray and its majorant segments, moves the stream to the
//! forwarded dimension and tests the pending collision: the walk, stopped and resumed any
//! number of times, draws the same numbers as one walk in one process
//! ([`blueshift_tracking::woodcock_walk`]). Rank 0 adds each pixel's samples in sample
//! order with the render loop's arithmetic, so the image (mean and variance) is
//! bit-identical to the single-process render at the same seed, for any rank count.
//!
//! Rounds (bulk synchronous): every rank walks its rays until each is done or has left its
//! piece, the rays that left are exchanged all to all, and the ranks agree whether any ray
//! is still moving. The first round's rays: rank r starts every n-th ray and walks it
//! while its tentative collisions lie in r's piece (the first needs no density), then sends
//! it to the rank whose piece holds the next one.
//!
//! Shading reads the data around the collision (the gradient: one voxel, within the
//! pieces' ghost layer); shadow rays would cross every piece, so scenes with shadows are
//! refused (use `samples` or `tiles`).

use blueshift_tracking::{
    Integrator, Progressive, RayStats, RenderSettings, Scene, WalkStop, observed, primary_ray,
    traces_shadows, welford_add, woodcock_walk,
};
use rayon::prelude::*;

use crate::comm::Communicator;
use crate::decomp::Decomposition;
use crate::render::agree;
use crate::{Error, Result};

/// A ray in flight: which sample of which pixel, the pending tentative collision's ray
/// parameter, and the random stream's dimension after it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct InFlight {
    pixel: u64,
    sample: u32,
    t: f32,
    dim: u64,
}

/// The most bytes of finished samples a pass holds (rank 0 gathers a pass's samples before
/// it adds them in sample order): 256 MiB, 11 million samples.
const PASS_BYTES: u64 = 256 << 20;

/// Values per forwarded ray on the wire.
const RAY_VALUES: usize = 4;
/// Values per finished sample on the wire: the ray index (pixel x spp + sample) and RGBA,
/// two f32s' bits per value ([`sample_values`]).
const RESULT_VALUES: usize = 3;

/// A finished sample on the wire: its ray index, then R and G, B and A, each pair of f32
/// bit patterns in one f64's bits (moved, never computed on, so the bits arrive).
fn sample_values(ray: u64, v: [f32; 4]) -> [f64; RESULT_VALUES] {
    let pair =
        |a: f32, b: f32| f64::from_bits(u64::from(a.to_bits()) << 32 | u64::from(b.to_bits()));
    [ray as f64, pair(v[0], v[1]), pair(v[2], v[3])]
}

/// [`sample_values`] back: the ray index and RGBA.
fn sample_from(c: &[f64]) -> (u64, [f32; 4]) {
    let hi = |x: f64| f32::from_bits((x.to_bits() >> 32) as u32);
    let lo = |x: f64| f32::from_bits(x.to_bits() as u32);
    (c[0] as u64, [hi(c[1]), lo(c[1]), hi(c[2]), lo(c[2])])
}

/// Counts of a forwarded render, per rank: what the benchmarks and the note report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ForwardStats {
    /// Rounds of resumed walks after the first (each after an exchange), over all passes.
    pub rounds: usize,
    /// Rays this rank sent to other ranks, in all rounds.
    pub forwarded: u64,
    /// Samples this rank finished.
    pub finished: u64,
}

/// Data-parallel Woodcock tracking ([`Integrator::Woodcock`]) with rays forwarded between
/// the ranks of `decomp` (see the module docs): rank 0 gets the accumulation,
/// bit-identical to [`blueshift_tracking::render_progressive`]'s at the same seed, and
/// every rank its [`ForwardStats`].
///
/// # Errors
/// Another integrator, a scene whose shading traces shadow rays, a decomposition for
/// another rank count, bad settings; the engine's errors (on any rank: see [`agree`]);
/// communication.
pub fn render_woodcock_forwarded(
    comm: &dyn Communicator,
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
    decomp: &Decomposition,
) -> Result<(Option<Progressive>, ForwardStats)> {
    render_woodcock_forwarded_in_passes(comm, scene, integrator, settings, decomp, PASS_BYTES)
}

/// [`render_woodcock_forwarded`] with passes of samples holding at most `pass_bytes` of
/// finished samples each (at least one sample per pixel): the same image for any
/// `pass_bytes`.
///
/// # Errors
/// As [`render_woodcock_forwarded`].
pub fn render_woodcock_forwarded_in_passes(
    comm: &dyn Communicator,
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
    decomp: &Decomposition,
    pass_bytes: u64,
) -> Result<(Option<Progressive>, ForwardStats)> {
    let (n, me) = (comm.size(), comm.rank());
    let pre = (|| {
        let prep = crate::render::prepare_local(scene, integrator, settings)?;
        let Integrator::Woodcock { channel } = prep else {
            return Err(Error::parameter(
                "data-parallel tracking forwards Woodcock rays only (--method woodcock); \
                 the other trackers distribute by samples or tiles",
            ));
        };
        if traces_shadows(scene) {
            return Err(Error::parameter(
                "shadow rays cross every piece of the volume: data-parallel Woodcock takes \
                 scenes without shadows (use --distributed samples or tiles)",
            ));
        }
        if decomp.ranks() != n {
            return Err(Error::parameter(format!(
                "decomposition for {} ranks, the world has {n}",
                decomp.ranks()
            )));
        }
        Ok(channel)
    })();
    let channel = agree(comm, "preparation", pre)?;
    let observer = settings.observer.filter(|o| !o.is_at_rest());
    let pieces = decomp.pieces();
    let owner = |p: glam::Vec3| pieces.iter().position(|q| q.clip.contains(p));
    let mine = pieces[me].clip;
    let w = settings.width;
    let xy = |pixel: u64| ((pixel % u64::from(w)) as u32, (pixel / u64::from(w)) as u32);
    let mut stats = ForwardStats::default();

    // One walk: ray `i` (pixel x spp + sample) from its start, or resumed at a pending
    // collision `(t, dim)`, while its tentative collisions lie in this rank's piece.
    let total = u64::from(settings.width) * u64::from(settings.height);
    let spp = u64::from(settings.spp);
    let walk = |i: u64, resume: Option<(f32, u64)>| -> Outcome {
        let (pixel, sample) = (i / spp, (i % spp) as u32);
        let (ray, mut rng) = primary_ray(settings, observer.as_ref(), xy(pixel), sample);
        if let Some((_, dim)) = resume {
            rng.set_dimension(dim);
        }
        let stop = woodcock_walk(
            scene,
            channel,
            &ray,
            &mut rng,
            resume.map(|r| r.0),
            |p| mine.contains(p),
            &mut RayStats::default(),
        );
        let v = match stop {
            WalkStop::Done(v) => v,
            WalkStop::Left { t, p } => match owner(p) {
                // Another rank's point (the boxes tile space, so one holds it).
                Some(to) => {
                    let dim = rng.dimension();
                    return Outcome::Fly(
                        to,
                        InFlight {
                            pixel,
                            sample,
                            t,
                            dim,
                        },
                    );
                }
                // Outside every box (rounding at the domain's edge): the background.
                None => {
                    let [r, g, b] = scene.background;
                    [r, g, b, 0.0]
                }
            },
        };
        Outcome::Done(i, observed(observer.as_ref(), &ray, v))
    };
    let pixels = usize::try_from(total).map_err(|_| Error::parameter("image too large"))?;
    let mut mean = vec![[0.0f64; 4]; if me == 0 { pixels } else { 0 }];
    let mut m2 = mean.clone();
    // Passes of samples, in sample order, each holding at most PASS_BYTES of finished
    // samples: the memory stays bounded at any spp and rank 0 still adds every pixel's
    // samples in sample order.
    let per_pass = (pass_bytes / (total.max(1) * RESULT_VALUES as u64 * 8)).clamp(1, spp.max(1));
    let mut s0 = 0;
    while s0 < spp {
        let len = per_pass.min(spp - s0);
        // The ray index of the k-th ray of the pass.
        let ray_of = |k: u64| (k / len) * spp + s0 + k % len;
        // The first round: rank r starts every n-th ray of the pass, walks it while its
        // tentative collisions are in r's piece and sends it on from the first one that is
        // not (to the rank whose piece holds it).
        let count = (total * len).saturating_sub(me as u64).div_ceil(n as u64);
        let mut walked = batch(
            (0..count)
                .into_par_iter()
                .map(|k| walk(ray_of(me as u64 + k * n as u64), None)),
            n,
            me,
        );
        let mut results = Vec::new();
        loop {
            agree(comm, "tracking", scene.check_io().map_err(Error::from))?;
            results.extend(walked.results);
            stats.finished += walked.finished;
            stats.forwarded += walked.forwarded;
            let mut active = walked.keep;
            active.extend(exchange(comm, &walked.outbox)?);
            if comm.all_ok(active.is_empty())? {
                break;
            }
            // Walk every ray this rank now holds until it is done or leaves the piece.
            walked = batch(
                active
                    .par_iter()
                    .map(|f| walk(f.pixel * spp + u64::from(f.sample), Some((f.t, f.dim)))),
                n,
                me,
            );
            stats.rounds += 1;
        }

        // Gather the pass's samples on rank 0 and add them in sample order; the ranks agree
        // on the outcome (a malformed gather stops every rank, not rank 0 alone).
        let gathered = if me != 0 {
            comm.send(0, &results)?;
            Ok(())
        } else {
            let len = len as usize;
            let mut samples = vec![[f32::NAN; 4]; pixels * len];
            let mut filled = vec![false; pixels * len];
            (|| {
                for r in 0..n {
                    let part = if r == 0 {
                        std::mem::take(&mut results)
                    } else {
                        comm.recv(r)?
                    };
                    if !part.len().is_multiple_of(RESULT_VALUES) {
                        return Err(Error::comm(format!(
                            "samples: {} values from rank {r}",
                            part.len()
                        )));
                    }
                    for c in part.chunks_exact(RESULT_VALUES) {
                        let (ray, v) = sample_from(c);
                        let (pixel, sample) = (ray / spp, ray % spp);
                        let k = (sample >= s0 && sample < s0 + len as u64)
                            .then(|| pixel as usize * len + (sample - s0) as usize)
                            .filter(|&k| k < filled.len() && !filled[k]);
                        let Some(k) = k else {
                            return Err(Error::comm(format!(
                                "sample of ray {ray} from rank {r}: outside the pass or twice"
                            )));
                        };
                        samples[k] = v;
                        filled[k] = true;
                    }
                }
                if let Some(k) = filled.iter().position(|f| !f) {
                    return Err(Error::comm(format!(
                        "sample {} of pixel {} never finished",
                        s0 + (k % len) as u64,
                        k / len
                    )));
                }
                // Pixel by pixel (in parallel), each pixel's samples in sample order.
                samples
                    .par_chunks_exact(len)
                    .zip(mean.par_iter_mut().zip(m2.par_iter_mut()))
                    .for_each(|(px, (mean, m2))| {
                        for (j, v) in px.iter().enumerate() {
                            welford_add(mean, m2, *v, (s0 as usize + j + 1) as f64);
                        }
                    });
                Ok(())
            })()
        };
        agree(comm, "gather", gathered)?;
        s0 += len;
    }
    if me != 0 {
        return Ok((None, stats));
    }
    let img = Progressive::from_moments(settings.width, settings.height, settings.spp, mean, m2)?;
    Ok((Some(img), stats))
}

/// The outcomes of walks run in parallel, sorted into one [`Batch`].
fn batch(outcomes: impl ParallelIterator<Item = Outcome>, n: usize, me: usize) -> Batch {
    outcomes
        .fold(
            || Batch::new(n, me),
            |mut b, o| {
                b.add(o);
                b
            },
        )
        .reduce(|| Batch::new(n, me), Batch::join)
}

/// What one walk ends in: the ray sent to a rank, or its sample (ray index, RGBA).
enum Outcome {
    Fly(usize, InFlight),
    Done(u64, [f32; 4]),
}

/// The outcomes of a batch of walks, sorted for the exchange: finished samples on the
/// wire, rays this rank keeps, rays per rank.
struct Batch {
    me: usize,
    results: Vec<f64>,
    keep: Vec<InFlight>,
    outbox: Vec<Vec<f64>>,
    forwarded: u64,
    finished: u64,
}

impl Batch {
    fn new(n: usize, me: usize) -> Batch {
        Batch {
            me,
            results: Vec::new(),
            keep: Vec::new(),
            outbox: vec![Vec::new(); n],
            forwarded: 0,
            finished: 0,
        }
    }

    fn add(&mut self, o: Outcome) {
        match o {
            Outcome::Fly(to, f) if to == self.me => self.keep.push(f),
            Outcome::Fly(to, f) => {
                self.outbox[to].extend(f.values());
                self.forwarded += 1;
            }
            Outcome::Done(i, v) => {
                self.results.extend(sample_values(i, v));
                self.finished += 1;
            }
        }
    }

    fn join(mut self, other: Batch) -> Batch {
        self.results.extend(other.results);
        self.keep.extend(other.keep);
        for (a, b) in self.outbox.iter_mut().zip(other.outbox) {
            a.extend(b);
        }
        self.forwarded += other.forwarded;
        self.finished += other.finished;
        self
    }
}

impl InFlight {
    /// The ray on the wire.
    fn values(&self) -> [f64; RAY_VALUES] {
        [
            self.pixel as f64,
            f64::from(self.sample),
            f64::from(self.t),
            self.dim as f64,
        ]
    }
}

/// All to all (in step d, send to me + d, receive from me - d): the rays `outbox[r]` go to
/// rank r; returns the rays the others sent here.
fn exchange(comm: &dyn Communicator, outbox: &[Vec<f64>]) -> Result<Vec<InFlight>> {
    let (n, me) = (comm.size(), comm.rank());
    let mut got_all = Vec::new();
    for d in 1..n {
        let (to, from) = ((me + d) % n, (me + n - d) % n);
        let got = comm.send_recv(&outbox[to], to, from)?;
        got_all.extend(decode_rays(&got, from)?);
    }
    Ok(got_all)
}

/// The rays of a message from rank `from`.
fn decode_rays(v: &[f64], from: usize) -> Result<Vec<InFlight>> {
    if !v.len().is_multiple_of(RAY_VALUES) {
        return Err(Error::comm(format!(
            "forwarded rays: {} values from rank {from}",
            v.len()
        )));
    }
    Ok(v.chunks_exact(RAY_VALUES)
        .map(|c| InFlight {
            pixel: c[0] as u64,
            sample: c[1] as u32,
            t: c[2] as f32,
            dim: c[3] as u64,
        })
        .collect())
}
