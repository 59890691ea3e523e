//! Partial renders for sort-last distributed rendering (`blueshift-dist`): the image of the
//! ray segments inside a clip box, and what compositing needs to make the partial images of
//! boxes that tile space into the whole render.
//!
//! A ray's segments are the single-process render's (the same global sample positions from
//! the ray's entry into the whole domain); a box takes the segments whose middle lies in it.
//! Without absorption a pixel's XYZ is the sum of its segments' XYZ, so the partial images
//! add. With absorption (piecewise-linear integrator) a segment's light is attenuated by the
//! optical depth of everything in front of it, which is not a colour: the parts compose
//! exactly in two steps. First each box gives the optical depth of its segments per pixel
//! ([`optical_depth_part`], a piecewise-linear function of the wavelength, exact; for the
//! banded integrators one constant per band, the exponents it attenuates by); an
//! exclusive scan in visibility order sums the depths in front of each box
//! ([`add_depths`]); then each box renders its segments behind that depth
//! ([`render_doppler_part`] with `front`), with the closed-form integrals of the
//! front-to-back image path, and the partial images add. The result is the single-process
//! image up to rounding, and within the merge tolerance's bound of each (both are within
//! `merge_tolerance` of the exact XYZ per channel times the unattenuated emission, so they
//! differ by at most twice that).
//!
//! The banded integrators weigh each sample by the trapezoid rule and attenuate by half its
//! depth before and half after its emission. A sample on a face between two boxes belongs
//! to both, each with its one-sided weight: the light from behind crosses the same total
//! depth, and the sample's emission adds up, but its own emission is attenuated by its own
//! depth split differently (`e_A exp(-(w_A/2 + w_B) tau) + e_B exp(-w_B tau/2)` against
//! `(e_A + e_B) exp(-(w_A + w_B) tau / 2)`). The composite therefore differs from the single
//! process by at most the face samples' emission times `1 - exp(-w tau)`: second order in
//! the step, it vanishes as the step shrinks.

use blueshift_camera::{ClipBox, Observer, Progress, Silent};
use blueshift_spectrum::Piece;
use rayon::prelude::*;

pub use crate::front::add_depths;
use crate::render::{
    Context, DopplerImage, DopplerSettings, PieceStats, Want, integrate_samples, pixel_ray,
};
use crate::{DopplerScene, Error, Result};

/// The XYZ image of the segments inside `clip` (see the module docs). `front`, one entry
/// per pixel (row-major): the optical depth in front of the box along that pixel's ray
/// ([`optical_depth_part`] of the boxes in front, summed), for scenes that absorb (`None`
/// is no depth in front).
///
/// # Errors
/// As [`crate::render_doppler`]; [`Error::Parameter`] for a `front` of the wrong length.
pub fn render_doppler_part(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    clip: &ClipBox,
    front: Option<&[Vec<Piece>]>,
) -> Result<DopplerImage> {
    render_doppler_part_observed(scene, settings, clip, front, &Silent)
}

/// [`render_doppler_part`] under an observer (progress per row, cancel between rows).
///
/// # Errors
/// As [`render_doppler_part`].
pub fn render_doppler_part_observed(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    clip: &ClipBox,
    front: Option<&[Vec<Piece>]>,
    observer: &dyn Observer<DopplerImage>,
) -> Result<DopplerImage> {
    render_part(scene, settings, clip, front, 0.0, observer)
}

/// The share of the piecewise-linear sweep's chord budget (`ln(1 + 3 tol/32)` of optical
/// depth, `front` module docs) that a distributed render spends on the depth in front
/// before it is sent ([`optical_depth_part_chorded`]): half. The sweeps behind take the
/// other half ([`render_doppler_part_chorded`]), so the image keeps the single process's
/// error bound. 0 when `merge_tolerance` is 0 (exact).
#[must_use]
pub fn front_chord_budget(settings: &DopplerSettings) -> f64 {
    0.5 * (crate::front::CHORD_SHARE * settings.merge_tolerance.max(0.0)).ln_1p()
}

/// [`render_doppler_part`] behind a depth in front that strays from the exact one by at
/// most `front_eps` (chords: [`optical_depth_part_chorded`]); the sweeps' own chords keep
/// within the rest of their budget. `front_eps` at most [`front_chord_budget`] keeps the
/// image within the single process's bound.
///
/// # Errors
/// As [`render_doppler_part`].
pub fn render_doppler_part_chorded(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    clip: &ClipBox,
    front: Option<&[Vec<Piece>]>,
    front_eps: f64,
) -> Result<DopplerImage> {
    render_part(scene, settings, clip, front, front_eps, &Silent)
}

fn render_part(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    clip: &ClipBox,
    front: Option<&[Vec<Piece>]>,
    front_eps: f64,
    observer: &dyn Observer<DopplerImage>,
) -> Result<DopplerImage> {
    let mut ctx = Context::new(scene, settings)?;
    ctx.clip = Some(*clip);
    ctx.front_eps = front_eps.max(0.0);
    let (w, h) = (settings.width, settings.height);
    let pixels = w as usize * h as usize;
    if let Some(f) = front
        && f.len() != pixels
    {
        return Err(Error::parameter(format!(
            "front depth: {} pixels given, the image has {pixels}",
            f.len()
        )));
    }
    let absorbing = ctx.absorbing;
    let done = std::sync::atomic::AtomicU64::new(0);
    let rows: Vec<Result<Vec<crate::render::RayOut>>> = (0..h)
        .into_par_iter()
        .map(|y| {
            if observer.cancelled() {
                return Err(Error::Cancelled);
            }
            let mut outs = Vec::with_capacity(w as usize);
            for x in 0..w {
                let s = ctx.sample(&pixel_ray(settings, x, y)?)?;
                let f = front.map_or(&[][..], |f| &f[(y * w + x) as usize][..]);
                let out = match (&ctx.pwl, &ctx.banded) {
                    (Some(t), _) if absorbing && s.len() >= 2 => {
                        crate::front::front_to_back_behind(&ctx, t, &s, f)?
                    }
                    (None, Some(t)) if absorbing && s.len() >= 2 => {
                        crate::banded::integrate_behind(&ctx, t, &s, f)?
                    }
                    _ => integrate_samples(&ctx, &s, Want::Xyz)?,
                };
                outs.push(out);
            }
            observer.progress(Progress {
                done: done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1,
                total: u64::from(h),
                pass: 0,
            });
            Ok(outs)
        })
        .collect();
    scene.check_io()?;
    let mut xyz = Vec::with_capacity(pixels);
    let (mut sum, mut max, mut fb) = (0.0f64, 0usize, 0usize);
    for row in rows {
        for r in row? {
            xyz.push(r.xyz.to_array());
            sum += r.max_pieces as f64;
            max = max.max(r.max_pieces);
            fb += usize::from(r.fallback);
        }
    }
    let image = DopplerImage {
        width: w,
        height: h,
        xyz,
        pieces: PieceStats {
            mean: sum / pixels.max(1) as f64,
            max,
            fallback_rays: fb,
        },
    };
    observer.pass(1, &image, None);
    Ok(image)
}

/// The optical depth of the segments inside `clip`, per pixel (row-major): sorted, disjoint
/// pieces over the wavelength (empty where nothing absorbs). Exact: the sum of every
/// segment's absorption lines as the image path takes them (nothing merged or left out).
///
/// # Errors
/// As [`crate::render_doppler`].
pub fn optical_depth_part(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    clip: &ClipBox,
) -> Result<Vec<Vec<Piece>>> {
    optical_depth_part_chorded(scene, settings, clip, 0.0)
}

/// [`optical_depth_part`] of the piecewise-linear integrator read as chords within `eps` of
/// the exact depth (chords, each within `eps` of it): far fewer pieces to send, add and sweep.
/// A sum of depths so chorded over `m` pieces in front strays by at most `m eps`. The
/// banded integrators' depths (one constant per band) are returned exact.
///
/// # Errors
/// As [`optical_depth_part`].
pub fn optical_depth_part_chorded(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    clip: &ClipBox,
    eps: f64,
) -> Result<Vec<Vec<Piece>>> {
    let mut ctx = Context::new(scene, settings)?;
    ctx.clip = Some(*clip);
    let (w, h) = (settings.width, settings.height);
    if !ctx.absorbing {
        return Ok(vec![Vec::new(); w as usize * h as usize]);
    }
    let rows: Vec<Result<Vec<Vec<Piece>>>> = (0..h)
        .into_par_iter()
        .map(|y| {
            (0..w)
                .map(|x| {
                    let s = ctx.sample(&pixel_ray(settings, x, y)?)?;
                    match &ctx.banded {
                        Some(t) if ctx.pwl.is_none() => Ok(crate::banded::total_depth(&ctx, t, &s)),
                        _ => crate::front::total_depth(&ctx, &s)
                            .map(|p| crate::front::chord_depth(&p, eps)),
                    }
                })
                .collect()
        })
        .collect();
    scene.check_io()?;
    let mut out = Vec::with_capacity(w as usize * h as usize);
    for row in rows {
        out.extend(row?);
    }
    Ok(out)
}

/// Rows `rows` of [`crate::render_doppler`]'s image (an image tile for tile-parallel
/// rendering), with the same arithmetic per pixel: the rows of every tile, put together,
/// are that image bit for bit.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageRows {
    /// XYZ per pixel of the rows, row-major.
    pub xyz: Vec<[f64; 3]>,
    /// The sum over these pixels of the most pieces a ray held (for [`PieceStats::mean`]).
    pub pieces_sum: f64,
    /// The most pieces any of these rays held.
    pub pieces_max: usize,
    /// Rays of these rows that fell back past the piece budget.
    pub fallback_rays: usize,
}

/// Renders image rows `rows` of `settings` (see [`ImageRows`]).
///
/// # Errors
/// As [`crate::render_doppler`]; rows outside the image.
pub fn render_doppler_rows(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    rows: std::ops::Range<u32>,
) -> Result<ImageRows> {
    if rows.start > rows.end || rows.end > settings.height {
        return Err(Error::parameter(format!(
            "rows {}..{} of an image of {} rows",
            rows.start, rows.end, settings.height
        )));
    }
    let ctx = Context::new(scene, settings)?;
    let w = settings.width;
    let out: Vec<Result<Vec<crate::render::RayOut>>> = rows
        .into_par_iter()
        .map(|y| {
            (0..w)
                .map(|x| {
                    integrate_samples(&ctx, &ctx.sample(&pixel_ray(settings, x, y)?)?, Want::Xyz)
                })
                .collect()
        })
        .collect();
    scene.check_io()?;
    let mut r = ImageRows {
        xyz: Vec::new(),
        pieces_sum: 0.0,
        pieces_max: 0,
        fallback_rays: 0,
    };
    for row in out {
        for o in row? {
            r.xyz.push(o.xyz.to_array());
            r.pieces_sum += o.max_pieces as f64;
            r.pieces_max = r.pieces_max.max(o.max_pieces);
            r.fallback_rays += usize::from(o.fallback);
        }
    }
    Ok(r)
}

/// The image of tiles of rows (top to bottom, together every row once), as
/// [`crate::render_doppler`] gives it.
///
/// # Errors
/// [`Error::Parameter`] when the tiles do not make up the image.
pub fn image_from_rows(settings: &DopplerSettings, tiles: &[ImageRows]) -> Result<DopplerImage> {
    let pixels = settings.width as usize * settings.height as usize;
    let got: usize = tiles.iter().map(|t| t.xyz.len()).sum();
    if got != pixels {
        return Err(Error::parameter(format!(
            "image tiles: {got} pixels, the image has {pixels}"
        )));
    }
    let (mut sum, mut max, mut fb) = (0.0f64, 0usize, 0usize);
    let mut xyz = Vec::with_capacity(pixels);
    for t in tiles {
        xyz.extend_from_slice(&t.xyz);
        sum += t.pieces_sum;
        max = max.max(t.pieces_max);
        fb += t.fallback_rays;
    }
    Ok(DopplerImage {
        width: settings.width,
        height: settings.height,
        xyz,
        pieces: PieceStats {
            mean: sum / pixels.max(1) as f64,
            max,
            fallback_rays: fb,
        },
    })
}

/// Image rows `rows` (top row 0) of [`crate::render_cube`]'s cube, each `width x channels`
/// values (x, then channel; f64, before the cube's rounding to f32), from the segments
/// inside `clip` (every segment for `None`). The channels of boxes that tile space add:
/// for an emission-only scene directly (with line broadening, within the error of merging
/// Gaussians along a ray, done here within the box only); for an absorbing one when `front` gives each
/// pixel's optical depth in front of the box ([`cube_optical_depth_part`] of the boxes in
/// front, summed in visibility order), by which the box's spectrum is attenuated before
/// it is binned.
///
/// # Errors
/// As [`crate::render_cube`]; a `front` of the wrong length.
pub fn render_cube_part(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    spec: &crate::CubeSpec,
    clip: Option<&ClipBox>,
    front: Option<&[Vec<Piece>]>,
    rows: std::ops::Range<usize>,
) -> Result<Vec<f64>> {
    let plan = crate::cube::CubePlan::new(settings, spec)?;
    if rows.start > rows.end || rows.end > plan.h {
        return Err(Error::parameter(format!(
            "rows {}..{} of an image of {} rows",
            rows.start, rows.end, plan.h
        )));
    }
    Ok(plan
        .rows(scene, clip, front, rows, &Silent)?
        .into_iter()
        .flatten()
        .collect())
}

/// The optical depth of the segments inside `clip` per pixel of a cube, over the cube's
/// window (as [`optical_depth_part`], with the cube's settings and the depth model its rays
/// march with).
///
/// # Errors
/// As [`crate::render_cube`].
pub fn cube_optical_depth_part(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    spec: &crate::CubeSpec,
    clip: &ClipBox,
) -> Result<Vec<Vec<Piece>>> {
    crate::cube::CubePlan::new(settings, spec)?.optical_depths(scene, clip)
}

/// The cube from the values of every image row (top row first, [`render_cube_part`]'s
/// layout for all rows).
///
/// # Errors
/// [`Error::Parameter`] for the wrong number of values; as [`crate::render_cube`].
pub fn cube_from_rows(
    settings: &DopplerSettings,
    spec: &crate::CubeSpec,
    values: &[f64],
) -> Result<crate::SpectralCube> {
    let plan = crate::cube::CubePlan::new(settings, spec)?;
    let row = plan.w * spec.channels;
    if values.len() != row * plan.h {
        return Err(Error::parameter(format!(
            "cube: {} values, expected {}",
            values.len(),
            row * plan.h
        )));
    }
    plan.assemble(values.chunks_exact(row.max(1)).take(plan.h))
}
