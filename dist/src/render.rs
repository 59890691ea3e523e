//! Distributed renders over a [`Communicator`]: data-parallel (each rank renders its piece
//! of the k-d split, the partial images are composited sort-last), sample-parallel and
//! tile-parallel Monte Carlo, and frame farming. Rank 0 returns the image, the others
//! `None`. After every phase all ranks agree whether every rank succeeded
//! ([`Communicator::first_failed`]), so a failure on one rank (a brick that does not read, a bad
//! setting) stops all of them at that point with an error instead of leaving them waiting.

use blueshift_doppler::part::{
    add_depths, cube_from_rows, cube_optical_depth_part, front_chord_budget,
    optical_depth_part_chorded, render_cube_part, render_doppler_part_chorded,
};
use blueshift_doppler::{
    CubeSpec, DopplerImage, DopplerScene, DopplerSettings, PieceStats, SpectralCube,
};
use blueshift_spectrum::Piece;
use blueshift_tracking::{
    Integrator, Progressive, RayStats, RenderSettings, Scene, pixel_sample, welford_add,
};
use rayon::prelude::*;

use crate::comm::Communicator;
use crate::composite::{Op, composite, exclusive_scan};
use crate::decomp::{Decomposition, Viewpoint};
use crate::{Error, Result};

/// How a render is spread over the ranks (the CLI's `--distributed`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Each rank renders its piece of a k-d split of the volume; sort-last compositing.
    Data,
    /// Each rank takes the sample indices `s` with `s % ranks == rank`.
    Samples,
    /// Each rank renders a band of image rows.
    Tiles,
    /// Each rank renders whole frames of a sequence (round robin).
    Frames,
}

impl std::str::FromStr for Mode {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Ok(match s {
            "data" => Mode::Data,
            "samples" => Mode::Samples,
            "tiles" => Mode::Tiles,
            "frames" => Mode::Frames,
            _ => {
                return Err(Error::parameter(format!(
                    "distributed: unknown mode '{s}' (data, samples, tiles, frames)"
                )));
            }
        })
    }
}

/// Makes every rank agree on the outcome of a phase: the local error on the lowest rank
/// that failed, [`Error::PeerFailed`] on every other rank when any failed (so one message
/// reports the failure), the value when all succeeded.
///
/// # Errors
/// As described.
pub fn agree<T>(comm: &dyn Communicator, phase: &'static str, r: Result<T>) -> Result<T> {
    match (comm.first_failed(r.is_err())?, r) {
        (None, Ok(v)) => Ok(v),
        (Some(first), Err(e)) if first == comm.rank() => Err(e),
        _ => Err(Error::PeerFailed(phase)),
    }
}

/// The frames of `0..count` rank `rank` of `ranks` renders (round robin).
#[must_use]
pub fn frames_of(rank: usize, ranks: usize, count: usize) -> Vec<usize> {
    (rank..count).step_by(ranks.max(1)).collect()
}

/// Rows `[start, end)` of an image of `height` rows for `rank` of `ranks`.
#[must_use]
pub fn rows_of(rank: usize, ranks: usize, height: u32) -> (u32, u32) {
    let h = height as usize;
    ((h * rank / ranks) as u32, (h * (rank + 1) / ranks) as u32)
}

fn check_tracking(settings: &RenderSettings) -> Result<()> {
    settings.validate()?;
    if settings.noise_target.is_some() || settings.timed_frames.is_some() || settings.heatmaps {
        return Err(Error::parameter(
            "distributed tracking renders take a fixed sample count: no noise target, timing \
             protocol or heat maps",
        ));
    }
    Ok(())
}

/// [`prepare`] on this rank alone (its caller agrees on the outcome).
pub(crate) fn prepare_local(
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
) -> Result<Integrator> {
    check_tracking(settings)?;
    Ok(integrator.prepared(scene)?.prepared(scene)?)
}

/// Checks the settings and prepares the integrator as the render loop does (twice: the loop
/// prepares it once more, and that is kept for its bits), every rank agreeing on the outcome.
fn prepare(
    comm: &dyn Communicator,
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
) -> Result<Integrator> {
    let prep = agree(
        comm,
        "preparation",
        check_tracking(settings).and_then(|()| Ok(integrator.prepared(scene)?)),
    )?;
    agree(
        comm,
        "preparation",
        prep.prepared(scene).map_err(Error::from),
    )
}

/// Sample-parallel tracking (any integrator): rank `r` computes the samples `s` with
/// `s % ranks == r` of every pixel and sends their RGBA to rank 0, which adds all samples
/// of each pixel in sample order with the render loop's own arithmetic
/// ([`welford_add`]). So rank 0's buffer (mean and variance) is bit-identical to
/// [`blueshift_tracking::render_progressive`]'s at the same seed, for any rank count.
/// Bytes: every sample's RGBA crosses once (`spp x pixels x 4` values in all).
///
/// # Errors
/// Bad settings, the engine's errors (on any rank: see [`agree`]), communication.
pub fn render_samples(
    comm: &dyn Communicator,
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
) -> Result<Option<Progressive>> {
    let (n, me) = (comm.size(), comm.rank());
    let prep = prepare(comm, scene, integrator, settings)?;
    let (w, h) = (settings.width as usize, settings.height as usize);
    let observer = settings.observer.filter(|o| !o.is_at_rest());
    let mine: Vec<u32> = (0..settings.spp)
        .filter(|s| *s as usize % n == me)
        .collect();
    // Per pixel, this rank's samples in order.
    let local: Vec<f64> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let mut row = Vec::with_capacity(w * mine.len() * 4);
            for x in 0..w {
                for &s in &mine {
                    let v = pixel_sample(
                        scene,
                        &prep,
                        settings,
                        observer.as_ref(),
                        (x as u32, y as u32),
                        s,
                        &mut RayStats::default(),
                    );
                    row.extend(v.map(f64::from));
                }
            }
            row
        })
        .collect();
    agree(comm, "rendering", scene.check_io().map_err(Error::from))?;
    if me != 0 {
        comm.send(0, &local)?;
        return Ok(None);
    }
    let mut parts = vec![local];
    for r in 1..n {
        parts.push(comm.recv(r)?);
    }
    let counts: Vec<usize> = (0..n)
        .map(|r| (0..settings.spp).filter(|s| *s as usize % n == r).count())
        .collect();
    for (r, p) in parts.iter().enumerate() {
        if p.len() != w * h * counts[r] * 4 {
            return Err(Error::comm(format!(
                "samples: {} values from rank {r}, expected {}",
                p.len(),
                w * h * counts[r] * 4
            )));
        }
    }
    let mut mean = vec![[0.0f64; 4]; w * h];
    let mut m2 = vec![[0.0f64; 4]; w * h];
    for i in 0..w * h {
        for s in 0..settings.spp as usize {
            let (r, k) = (s % n, s / n);
            let at = (i * counts[r] + k) * 4;
            let v = parts[r][at..at + 4].iter().map(|&v| v as f32);
            let v: Vec<f32> = v.collect();
            welford_add(
                &mut mean[i],
                &mut m2[i],
                [v[0], v[1], v[2], v[3]],
                (s + 1) as f64,
            );
        }
    }
    Ok(Some(Progressive::from_moments(
        settings.width,
        settings.height,
        settings.spp,
        mean,
        m2,
    )?))
}

/// Tile-parallel tracking (any integrator): rank `r` renders the rows [`rows_of`] gives it,
/// all samples, with the render loop's arithmetic; rank 0 gathers the per-pixel means and
/// squared deviations. Bit-identical to the single-process buffer.
///
/// # Errors
/// As [`render_samples`].
pub fn render_tiles(
    comm: &dyn Communicator,
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
) -> Result<Option<Progressive>> {
    let (n, me) = (comm.size(), comm.rank());
    let prep = prepare(comm, scene, integrator, settings)?;
    let w = settings.width as usize;
    let observer = settings.observer.filter(|o| !o.is_at_rest());
    let (y0, y1) = rows_of(me, n, settings.height);
    let local: Vec<f64> = (y0..y1)
        .into_par_iter()
        .flat_map_iter(|y| {
            let mut row = Vec::with_capacity(w * 8);
            for x in 0..w {
                let (mut mean, mut m2) = ([0.0; 4], [0.0; 4]);
                for s in 0..settings.spp {
                    let v = pixel_sample(
                        scene,
                        &prep,
                        settings,
                        observer.as_ref(),
                        (x as u32, y),
                        s,
                        &mut RayStats::default(),
                    );
                    welford_add(&mut mean, &mut m2, v, f64::from(s + 1));
                }
                row.extend(mean);
                row.extend(m2);
            }
            row
        })
        .collect();
    agree(comm, "rendering", scene.check_io().map_err(Error::from))?;
    if me != 0 {
        comm.send(0, &local)?;
        return Ok(None);
    }
    let (mut mean, mut m2) = (Vec::new(), Vec::new());
    for r in 0..n {
        let part = if r == 0 { local.clone() } else { comm.recv(r)? };
        let (a, b) = rows_of(r, n, settings.height);
        if part.len() != (b - a) as usize * w * 8 {
            return Err(Error::comm(format!("tiles: wrong size from rank {r}")));
        }
        for px in part.chunks_exact(8) {
            mean.push([px[0], px[1], px[2], px[3]]);
            m2.push([px[4], px[5], px[6], px[7]]);
        }
    }
    Ok(Some(Progressive::from_moments(
        settings.width,
        settings.height,
        settings.spp,
        mean,
        m2,
    )?))
}

/// Data-parallel ray marching: each rank marches the samples inside its piece
/// (`Scene::clip`; the global sample positions), the partial premultiplied RGBA images are
/// composited "over" in visibility order with radix-k over the decomposition's factors, and
/// rank 0 adds the background and accumulates the passes. Equal to the single-process
/// image up to rounding: the single process composites step by step in f32, the ranks
/// composite their parts in f64 (the difference is a few f32 ulps times the number of
/// pieces a ray crosses; the tests bound it). Needs early termination off (1) for the
/// bound: a piece cannot know the alpha in front of it.
///
/// # Errors
/// [`Error::Parameter`] for a tracker (not a marcher), a moving observer, a decomposition
/// for another rank count; as [`render_samples`].
pub fn render_marcher_data(
    comm: &dyn Communicator,
    scene: &mut Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
    decomp: &Decomposition,
) -> Result<Option<Progressive>> {
    let (n, me) = (comm.size(), comm.rank());
    let pre = (|| {
        check_tracking(settings)?;
        if decomp.ranks() != n {
            return Err(Error::parameter(format!(
                "decomposition for {} ranks, the world has {n}",
                decomp.ranks()
            )));
        }
        if settings.observer.is_some_and(|o| !o.is_at_rest()) {
            return Err(Error::parameter(
                "data-parallel rendering with a moving observer is not supported",
            ));
        }
        if !matches!(integrator, Integrator::Marcher(_)) {
            return Err(Error::parameter(
                "data-parallel tracking renders the ray marcher (composited) and Woodcock \
                 (rays forwarded: forward::render_woodcock_forwarded); use --distributed \
                 samples or tiles for MDWT",
            ));
        }
        let saved = scene.clip.take();
        let prep = integrator.prepared(scene).and_then(|p| p.prepared(scene));
        scene.clip = saved;
        Ok(prep?)
    })();
    let prep = agree(comm, "preparation", pre)?;
    let background = scene.background;
    let saved = scene.clip.replace(decomp.pieces()[me].clip);
    let order = decomp.visibility_order(Viewpoint::of(&settings.camera));
    let mut position = vec![0; n];
    for (p, &r) in order.iter().enumerate() {
        position[r] = p;
    }
    let (w, h) = (settings.width as usize, settings.height as usize);
    let mut mean = vec![[0.0f64; 4]; w * h];
    let mut m2 = vec![[0.0f64; 4]; w * h];
    let mut result = Ok(());
    let clock = Phases::start(me);
    for s in 0..settings.spp {
        let local: Vec<f64> = (0..h)
            .into_par_iter()
            .flat_map_iter(|y| {
                let scene = &*scene;
                let prep = &prep;
                (0..w).flat_map(move |x| {
                    pixel_sample(
                        scene,
                        prep,
                        settings,
                        None,
                        (x as u32, y as u32),
                        s,
                        &mut RayStats::default(),
                    )
                    .map(f64::from)
                })
            })
            .collect();
        clock.mark("render");
        if let Err(e) = agree(comm, "rendering", scene.check_io().map_err(Error::from)) {
            result = Err(e);
            break;
        }
        clock.mark("wait for all");
        let img = composite(comm, local, 4, Op::Over, decomp.factors(), &position);
        clock.mark("composite");
        match img {
            Ok(Some(img)) => {
                for (i, px) in img.chunks_exact(4).enumerate() {
                    let t = 1.0 - px[3];
                    let v = [
                        (px[0] + t * f64::from(background[0])) as f32,
                        (px[1] + t * f64::from(background[1])) as f32,
                        (px[2] + t * f64::from(background[2])) as f32,
                        px[3] as f32,
                    ];
                    welford_add(&mut mean[i], &mut m2[i], v, f64::from(s + 1));
                }
            }
            Ok(None) => {}
            Err(e) => {
                result = Err(e);
                break;
            }
        }
    }
    scene.clip = saved;
    clock.report();
    result?;
    if me != 0 {
        return Ok(None);
    }
    Ok(Some(Progressive::from_moments(
        settings.width,
        settings.height,
        settings.spp,
        mean,
        m2,
    )?))
}

/// Wall time per phase of a distributed render, printed to stderr per rank when
/// `BLUESHIFT_DIST_TIMING=1` (for the scaling measurements; nothing otherwise).
struct Phases {
    rank: usize,
    on: bool,
    last: std::cell::Cell<(std::time::Instant, f64)>,
    marks: std::cell::RefCell<Vec<(&'static str, f64, f64)>>,
}

/// This process's CPU seconds (user + system, Linux `/proc/self/stat`; 0 elsewhere).
fn cpu_seconds() -> f64 {
    let Ok(s) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the command name (which may hold spaces) start at state (field 3);
    // utime and stime are fields 14 and 15, in clock ticks (100 per second on Linux).
    let rest = s.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

impl Phases {
    fn start(rank: usize) -> Self {
        let on = std::env::var("BLUESHIFT_DIST_TIMING").is_ok_and(|v| v == "1");
        Self {
            rank,
            on,
            last: std::cell::Cell::new((
                std::time::Instant::now(),
                if on { cpu_seconds() } else { 0.0 },
            )),
            marks: std::cell::RefCell::new(Vec::new()),
        }
    }
    fn mark(&self, phase: &'static str) {
        if self.on {
            let now = (std::time::Instant::now(), cpu_seconds());
            let (t0, c0) = self.last.replace(now);
            let wall = now.0.duration_since(t0).as_secs_f64();
            self.marks.borrow_mut().push((phase, wall, now.1 - c0));
        }
    }
    fn report(&self) {
        if self.on {
            let m: Vec<String> = self
                .marks
                .borrow()
                .iter()
                .map(|(p, t, c)| format!("{p} {t:.3} s (cpu {c:.2} s)"))
                .collect();
            // Best effort: a closed stderr is not a failure of the render.
            let _ = std::io::Write::write_fmt(
                &mut std::io::stderr(),
                format_args!("rank {}: {}\n", self.rank, m.join(", ")),
            );
        }
    }
}

/// Encodes per-pixel piece lists as `[count, (start, end, v0, v1) x count, ...]`.
#[must_use]
pub fn encode_pieces(pixels: &[Vec<Piece>]) -> Vec<f64> {
    let mut out =
        Vec::with_capacity(pixels.len() + pixels.iter().map(|p| 4 * p.len()).sum::<usize>());
    for p in pixels {
        out.push(p.len() as f64);
        for q in p {
            out.extend([q.start_nm, q.end_nm, q.value_start, q.value_end]);
        }
    }
    out
}

/// The inverse of [`encode_pieces`] for `pixels` pixels.
///
/// # Errors
/// [`Error::Comm`] for a truncated or malformed message.
pub fn decode_pieces(data: &[f64], pixels: usize) -> Result<Vec<Vec<Piece>>> {
    let bad = || Error::comm("optical depth message: malformed");
    let mut out = Vec::with_capacity(pixels);
    let mut i = 0;
    for _ in 0..pixels {
        let c = *data.get(i).ok_or_else(bad)?;
        if !(c >= 0.0 && c.fract() == 0.0) {
            return Err(bad());
        }
        let c = c as usize;
        let body = data.get(i + 1..i + 1 + 4 * c).ok_or_else(bad)?;
        out.push(
            body.chunks_exact(4)
                .map(|q| Piece {
                    start_nm: q[0],
                    end_nm: q[1],
                    value_start: q[2],
                    value_end: q[3],
                })
                .collect(),
        );
        i += 1 + 4 * c;
    }
    if i != data.len() {
        return Err(bad());
    }
    Ok(out)
}

/// The viewpoint of a Doppler render (the orthographic direction after the observer's
/// aberration, which is the same for every pixel).
fn doppler_viewpoint(settings: &DopplerSettings) -> Viewpoint {
    match Viewpoint::of(&settings.camera) {
        Viewpoint::Direction(_) => Viewpoint::Direction(
            settings
                .ray(0.5 * settings.width as f32, 0.5 * settings.height as f32)
                .dir,
        ),
        eye => eye,
    }
}

/// The optical depth in front of this rank's piece per pixel (row-major): each rank but
/// the last in visibility `order` computes its own piece's depth (`depth`), and an
/// exclusive scan in that order ([`exclusive_scan`], exact piecewise-linear sums) adds the
/// depths of the pieces in front.
///
/// # Errors
/// `depth`'s error on any rank (see [`agree`]); communication.
fn front_depths(
    comm: &dyn Communicator,
    order: &[usize],
    pixels: usize,
    depth: impl FnOnce() -> Result<Vec<Vec<Piece>>>,
) -> Result<Vec<Vec<Piece>>> {
    // The last piece in the order is in front of nothing: its depth is not needed.
    let own = if order.last() == Some(&comm.rank()) {
        Ok(vec![Vec::new(); pixels])
    } else {
        depth()
    };
    let own = agree(comm, "optical depth", own)?;
    let front = exclusive_scan(
        comm,
        order,
        &own,
        vec![Vec::new(); pixels],
        |a, b| a.iter().zip(b).map(|(a, b)| add_depths(a, b)).collect(),
        |v| encode_pieces(v),
        |d| decode_pieces(d, pixels),
    );
    agree(comm, "optical depth scan", front)
}

/// Data-parallel Doppler rendering (see `blueshift_doppler::part`): without absorption
/// the ranks' XYZ images add; with absorption each rank first
/// gives its optical depth per pixel, an exclusive scan in visibility order
/// ([`exclusive_scan`], exact piecewise-linear sums) gives each rank the depth in front of
/// its piece, each renders its segments behind it, and the XYZ images add (radix-k over the
/// decomposition's factors). Exact spectral compositing: equal to the single-process image
/// up to rounding when `merge_tolerance` is 0, within twice the merge tolerance's bound
/// otherwise. The banded integrators compose per band the same way (a depth per band),
/// equal to the single process up to a second-order term of the samples on the pieces'
/// faces (see `blueshift_doppler::part`).
///
/// # Errors
/// As [`render_marcher_data`].
pub fn render_doppler_data(
    comm: &dyn Communicator,
    scene: &DopplerScene,
    settings: &DopplerSettings,
    decomp: &Decomposition,
) -> Result<Option<DopplerImage>> {
    let (n, me) = (comm.size(), comm.rank());
    let pre = if decomp.ranks() == n {
        Ok(())
    } else {
        Err(Error::parameter(format!(
            "decomposition for {} ranks, the world has {n}",
            decomp.ranks()
        )))
    };
    agree(comm, "preparation", pre)?;
    let clip = decomp.pieces()[me].clip;
    let order = decomp.visibility_order(doppler_viewpoint(settings));
    let mut position = vec![0; n];
    for (p, &r) in order.iter().enumerate() {
        position[r] = p;
    }
    let pixels = settings.width as usize * settings.height as usize;
    let clock = Phases::start(me);
    // The depth in front, read as chords: half the sweep's chord budget, shared by the at
    // most n - 1 pieces in front of any other (their strays add); the sweeps behind keep
    // within the other half, so the image keeps the single process's bound.
    let budget = front_chord_budget(settings);
    let front = if scene.absorbs() && n > 1 {
        let eps = budget / (n - 1) as f64;
        let f = front_depths(comm, &order, pixels, || {
            optical_depth_part_chorded(scene, settings, &clip, eps).map_err(Error::from)
        })?;
        clock.mark("depth scan");
        Some(f)
    } else {
        None
    };
    // No depth in front (emission only, or one rank): the sweeps keep their whole budget.
    let front_eps = if front.is_some() { budget } else { 0.0 };
    let part = render_doppler_part_chorded(scene, settings, &clip, front.as_deref(), front_eps);
    clock.mark("render");
    let part = agree(comm, "rendering", part.map_err(Error::from))?;
    clock.mark("wait for all");
    let local: Vec<f64> = part.xyz.iter().flatten().copied().collect();
    let img = composite(comm, local, 3, Op::Add, decomp.factors(), &position)?;
    clock.mark("composite");
    clock.report();
    Ok(img.map(|v| DopplerImage {
        width: settings.width,
        height: settings.height,
        xyz: v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        pieces: PieceStats {
            mean: part.pieces.mean,
            max: part.pieces.max,
            fallback_rays: part.pieces.fallback_rays,
        },
    }))
}

/// Tile-parallel Doppler image: rank `r` renders the rows [`rows_of`] gives it (the whole
/// data on every rank, or every rank's bricks from a `.bsv` through its own cache), rank 0
/// gathers them. The same per-pixel arithmetic as [`blueshift_doppler::render_doppler`]:
/// bit-identical to the single-process image for any integrator, with or without
/// absorption. Bytes: each pixel's XYZ crosses once.
///
/// # Errors
/// The engine's errors (on any rank: see [`agree`]), communication.
pub fn render_doppler_tiles(
    comm: &dyn Communicator,
    scene: &DopplerScene,
    settings: &DopplerSettings,
) -> Result<Option<DopplerImage>> {
    use blueshift_doppler::part::{ImageRows, image_from_rows, render_doppler_rows};
    let (n, me) = (comm.size(), comm.rank());
    let (y0, y1) = rows_of(me, n, settings.height);
    let part = render_doppler_rows(scene, settings, y0..y1).map_err(Error::from);
    let part = agree(comm, "rendering", part)?;
    let encode = |t: &ImageRows| {
        let mut v = vec![t.pieces_sum, t.pieces_max as f64, t.fallback_rays as f64];
        v.extend(t.xyz.iter().flatten());
        v
    };
    if me != 0 {
        comm.send(0, &encode(&part))?;
        return Ok(None);
    }
    let mut tiles = vec![part];
    for r in 1..n {
        let v = comm.recv(r)?;
        let (a, b) = rows_of(r, n, settings.height);
        let want = 3 + 3 * (b - a) as usize * settings.width as usize;
        if v.len() != want {
            return Err(Error::comm(format!(
                "tiles: {} values from rank {r}, expected {want}",
                v.len()
            )));
        }
        tiles.push(ImageRows {
            pieces_sum: v[0],
            pieces_max: v[1] as usize,
            fallback_rays: v[2] as usize,
            xyz: v[3..].chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        });
    }
    Ok(Some(image_from_rows(settings, &tiles)?))
}

/// Tile-parallel spectral cube: rank `r` renders the image rows [`rows_of`] gives it, rank
/// 0 gathers the channel values (f64) and rounds them to the cube's f32 as the
/// single-process cube does: bit-identical to [`blueshift_doppler::render_cube`], with or
/// without absorption. Bytes: `pixels x channels` values cross once.
///
/// # Errors
/// As [`render_doppler_tiles`]; the cube's own checks.
pub fn render_cube_tiles(
    comm: &dyn Communicator,
    scene: &DopplerScene,
    settings: &DopplerSettings,
    spec: &CubeSpec,
) -> Result<Option<SpectralCube>> {
    let (n, me) = (comm.size(), comm.rank());
    let (y0, y1) = rows_of(me, n, settings.height);
    let part = render_cube_part(scene, settings, spec, None, None, y0 as usize..y1 as usize)
        .map_err(Error::from);
    let part = agree(comm, "rendering", part)?;
    if me != 0 {
        comm.send(0, &part)?;
        return Ok(None);
    }
    let row = settings.width as usize * spec.channels;
    let mut all = part;
    for r in 1..n {
        let v = comm.recv(r)?;
        let (a, b) = rows_of(r, n, settings.height);
        if v.len() != (b - a) as usize * row {
            return Err(Error::comm(format!(
                "cube tiles: {} values from rank {r}, expected {}",
                v.len(),
                (b - a) as usize * row
            )));
        }
        all.extend_from_slice(&v);
    }
    Ok(Some(cube_from_rows(settings, spec, &all)?))
}

/// Data-parallel spectral cube: each rank bins the light of the segments inside its piece
/// of the k-d split into the channels, and the partial cubes add (radix-k over the
/// decomposition's factors, the channels of a pixel composited together). Emission-only
/// scenes: equal to the single-process cube up to the rounding of the sums (the f64 channel
/// values are summed in another grouping before the cube's rounding to f32); with line
/// broadening, Gaussians are merged along a ray only within each piece, so the cubes
/// differ within the merge's error (0.25 % of a merged Gaussian's peak, see the doppler
/// crate's cubes). Absorbing
/// scenes compose exactly as [`render_doppler_data`] does: each rank's piece gives its
/// optical depth per pixel, an exclusive scan in visibility order gives the depth in front
/// of each piece, and each piece's rays are marched behind that depth (the single-process
/// front-to-back march over its segments, in closed form). With the merges off
/// (`merge_tolerance` 0) the sum is the single-process cube up to the order of the f64
/// sums; the merges of the depth in front, and of a line's Gaussians along a ray (within
/// each piece only), differ within their bounds.
///
/// # Errors
/// A decomposition for another rank count; as [`render_cube_tiles`].
pub fn render_cube_data(
    comm: &dyn Communicator,
    scene: &DopplerScene,
    settings: &DopplerSettings,
    spec: &CubeSpec,
    decomp: &Decomposition,
) -> Result<Option<SpectralCube>> {
    let (n, me) = (comm.size(), comm.rank());
    let pre = if decomp.ranks() == n {
        Ok(())
    } else {
        Err(Error::parameter(format!(
            "decomposition for {} ranks, the world has {n}",
            decomp.ranks()
        )))
    };
    agree(comm, "preparation", pre)?;
    let clip = decomp.pieces()[me].clip;
    let order = decomp.visibility_order(doppler_viewpoint(settings));
    let mut position = vec![0; n];
    for (p, &r) in order.iter().enumerate() {
        position[r] = p;
    }
    let pixels = settings.width as usize * settings.height as usize;
    let front = if scene.absorbs() && n > 1 {
        Some(front_depths(comm, &order, pixels, || {
            cube_optical_depth_part(scene, settings, spec, &clip).map_err(Error::from)
        })?)
    } else {
        None
    };
    let part = render_cube_part(
        scene,
        settings,
        spec,
        Some(&clip),
        front.as_deref(),
        0..settings.height as usize,
    )
    .map_err(Error::from);
    let part = agree(comm, "rendering", part)?;
    let all = composite(
        comm,
        part,
        spec.channels,
        Op::Add,
        decomp.factors(),
        &position,
    )?;
    match all {
        None => Ok(None),
        Some(v) => Ok(Some(cube_from_rows(settings, spec, &v)?)),
    }
}
