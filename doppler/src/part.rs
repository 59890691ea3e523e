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
//! ([`optical_depth_part`], a piecewise-linear function of the wavelength, exact); an
//! exclusive scan in visibility order sums the depths in front of each box
//! ([`add_depths`]); then each box renders its segments behind that depth
//! ([`render_doppler_part`] with `front`), with the closed-form integrals of the
//! front-to-back image path, and the partial images add. The result is the single-process
//! image up to rounding, and within the merge tolerance's bound of each (both are within
//! `merge_tolerance` of the exact XYZ per channel times the unattenuated emission, so they
//! differ by at most twice that).

use blueshift_camera::{ClipBox, Observer, Progress, Silent};
use blueshift_spectrum::Piece;
use rayon::prelude::*;

pub use crate::front::add_depths;
use crate::render::{
    Context, DopplerImage, DopplerSettings, PieceStats, Want, integrate_samples, pixel_ray,
};
use crate::{DopplerScene, Error, Result};

/// The XYZ image of the segments inside `clip` (see the module docs). `front`, one entry
/// per pixel (row-major): the optical depth in front of the box along that pixel's ray, for
/// scenes that absorb (the piecewise-linear integrator; `None` is no depth in front).
///
/// # Errors
/// As [`crate::render_doppler`]; [`Error::Parameter`] for a banded integrator on an
/// absorbing scene (its partial images do not compose) or a `front` of the wrong length.
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
    let mut ctx = Context::new(scene, settings)?;
    ctx.clip = Some(*clip);
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
    let tables = match (&ctx.pwl, absorbing) {
        (Some(t), true) => Some(t),
        (None, true) => {
            return Err(Error::parameter(
                "distributed rendering of an absorbing scene needs the piecewise-linear \
                 integrator (banded partial images do not compose)",
            ));
        }
        _ => None,
    };
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
                let out = match tables {
                    Some(t) if s.len() >= 2 => {
                        let f = front.map_or(&[][..], |f| &f[(y * w + x) as usize][..]);
                        crate::front::front_to_back_behind(&ctx, t, &s, f)?
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
                    crate::front::total_depth(&ctx, &s)
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
