//! Data-parallel Woodcock tracking with rays forwarded between ranks (the approach of Wald
//! et al.'s barney): each rank holds a piece of the volume and tracks every ray whose next
//! tentative collision lies in its piece; a ray whose walk reaches a tentative collision
//! in another piece is sent to the rank that holds it, with its random stream's position,
//! and continues there.
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
//! is still moving. The first round's rays: every rank draws each ray's first tentative
//! collision (no density is needed for it) and keeps the rays whose first collision is in
//! its piece; rays that meet no majorant go to rank 0 as background.
//!
//! Shading reads the data around the collision (the gradient: one voxel, within the
//! pieces' ghost layer); shadow rays would cross every piece, so scenes with shadows are
//! refused (use `samples` or `tiles`).

use blueshift_tracking::{
    Integrator, Progressive, RayStats, RenderSettings, Rng, Scene, WalkStop, observed, primary_ray,
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

/// Values per forwarded ray on the wire.
const RAY_VALUES: usize = 4;
/// Values per finished sample on the wire: pixel, sample, RGBA.
const RESULT_VALUES: usize = 6;

/// Counts of a forwarded render, per rank: what the benchmarks and the note report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ForwardStats {
    /// Exchange rounds until no ray moved.
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

    // The first round: every rank draws each ray's first tentative collision.
    let total = u64::from(settings.width) * u64::from(settings.height);
    let start: Vec<(Option<InFlight>, Option<[f32; 4]>)> = (0..total)
        .into_par_iter()
        .flat_map_iter(|pixel| {
            (0..settings.spp).map(move |sample| {
                let (ray, mut rng) = primary_ray(settings, observer.as_ref(), xy(pixel), sample);
                let stop = woodcock_walk(
                    scene,
                    channel,
                    &ray,
                    &mut rng,
                    None,
                    |_| false,
                    &mut RayStats::default(),
                );
                match stop {
                    WalkStop::Left { t, p } if owner(p) == Some(me) => (
                        Some(InFlight {
                            pixel,
                            sample,
                            t,
                            dim: rng.dimension(),
                        }),
                        None,
                    ),
                    WalkStop::Done(v) if me == 0 => {
                        (None, Some(observed(observer.as_ref(), &ray, v)))
                    }
                    _ => (None, None),
                }
            })
        })
        .collect();
    let mut results: Vec<f64> = Vec::new();
    let mut active: Vec<InFlight> = Vec::new();
    for (i, (f, v)) in start.into_iter().enumerate() {
        if let Some(f) = f {
            active.push(f);
        }
        if let Some(v) = v {
            let spp = u64::from(settings.spp);
            let (pixel, sample) = (i as u64 / spp, i as u64 % spp);
            results.extend([pixel as f64, sample as f64]);
            results.extend(v.map(f64::from));
        }
    }

    loop {
        // Walk every ray this rank holds until it is done or leaves the piece.
        let walked: Vec<(Option<usize>, Vec<f64>)> = active
            .par_iter()
            .map(|f| {
                let (x, y) = xy(f.pixel);
                let (ray, _) = primary_ray(settings, observer.as_ref(), (x, y), f.sample);
                let mut rng = Rng::new(settings.seed, f.pixel, u64::from(f.sample));
                rng.set_dimension(f.dim);
                let stop = woodcock_walk(
                    scene,
                    channel,
                    &ray,
                    &mut rng,
                    Some(f.t),
                    |p| mine.contains(p),
                    &mut RayStats::default(),
                );
                match stop {
                    // Another rank's point (the boxes tile space, so one holds it).
                    WalkStop::Left { t, p } if owner(p).is_some() => (
                        owner(p),
                        vec![
                            f.pixel as f64,
                            f64::from(f.sample),
                            f64::from(t),
                            rng.dimension() as f64,
                        ],
                    ),
                    stop => {
                        let v = match stop {
                            WalkStop::Done(v) => v,
                            WalkStop::Left { .. } => {
                                let [r, g, b] = scene.background;
                                [r, g, b, 0.0]
                            }
                        };
                        let v = observed(observer.as_ref(), &ray, v);
                        let mut out = vec![f.pixel as f64, f64::from(f.sample)];
                        out.extend(v.map(f64::from));
                        (None, out)
                    }
                }
            })
            .collect();
        agree(comm, "tracking", scene.check_io().map_err(Error::from))?;
        let mut outbox = vec![Vec::new(); n];
        for (to, v) in walked {
            match to {
                None => {
                    results.extend(v);
                    stats.finished += 1;
                }
                Some(to) => {
                    stats.forwarded += 1;
                    outbox[to].extend(v);
                }
            }
        }
        // All to all: in step d, send to me + d, receive from me - d.
        active = Vec::new();
        for d in 1..n {
            let (to, from) = ((me + d) % n, (me + n - d) % n);
            let got = comm.send_recv(&outbox[to], to, from)?;
            active.extend(decode_rays(&got, from)?);
        }
        stats.rounds += 1;
        if comm.all_ok(active.is_empty())? {
            break;
        }
    }

    // Gather the finished samples on rank 0 and add them in sample order.
    if me != 0 {
        comm.send(0, &results)?;
        return Ok((None, stats));
    }
    let pixels = usize::try_from(total).map_err(|_| Error::parameter("image too large"))?;
    let spp = settings.spp as usize;
    let mut samples = vec![[f32::NAN; 4]; pixels * spp];
    let mut seen = 0usize;
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
            let (pixel, sample) = (c[0] as usize, c[1] as usize);
            if pixel >= pixels || sample >= spp {
                return Err(Error::comm(format!(
                    "sample {sample} of pixel {pixel} from rank {r}"
                )));
            }
            samples[pixel * spp + sample] = [c[2] as f32, c[3] as f32, c[4] as f32, c[5] as f32];
            seen += 1;
        }
    }
    if seen != pixels * spp {
        return Err(Error::comm(format!(
            "{seen} samples finished, {} expected",
            pixels * spp
        )));
    }
    let mut mean = vec![[0.0f64; 4]; pixels];
    let mut m2 = vec![[0.0f64; 4]; pixels];
    for (i, px) in samples.chunks_exact(spp).enumerate() {
        for (s, v) in px.iter().enumerate() {
            welford_add(&mut mean[i], &mut m2[i], *v, (s + 1) as f64);
        }
    }
    let img = Progressive::from_moments(settings.width, settings.height, settings.spp, mean, m2)?;
    Ok((Some(img), stats))
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
