//! The renderer: a pinhole camera in the observer's frame, inverse aberration, environment
//! lookup, Doppler colour shift and searchlight; a velocity ramp; a simple PNG encoding.

use std::mem::MaybeUninit;
use std::ops::Range;

use glam::DVec3;
use image::{Rgb32FImage, RgbImage};
use rayon::prelude::*;

use crate::colour::DopplerColourTable;
use crate::envmap::{Environment, check_size};
use crate::error::{Error, Result};
use crate::fast::{Corners, EquirectTexels};
use crate::lorentz::{Velocity, searchlight_integrated, unit};

/// A pinhole camera in the observer's frame (C8: plain settings with `Default`).
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// Viewing direction (need not be normalised).
    pub look: DVec3,
    /// Approximate up direction (made orthogonal to `look`; if parallel, `+Z` or `+X` is used).
    pub up: DVec3,
    /// Vertical field of view in degrees, in `(0, 180)`.
    pub fov_y_deg: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

impl Default for Camera {
    fn default() -> Self {
        Self {
            look: DVec3::NEG_Z,
            up: DVec3::Y,
            fov_y_deg: 90.0,
            width: 640,
            height: 360,
        }
    }
}

/// Which relativistic effects to render.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Effects {
    /// Aberration of light (geometry).
    pub aberration: bool,
    /// Doppler colour shift (spectral, integral kept).
    pub doppler: bool,
    /// Searchlight: integrated radiance times `D^4` (with `doppler`: `D^5` per wavelength).
    pub searchlight: bool,
}

impl Effects {
    /// All three effects.
    pub const ALL: Self = Self {
        aberration: true,
        doppler: true,
        searchlight: true,
    };
    /// Only aberration.
    pub const ABERRATION: Self = Self {
        aberration: true,
        doppler: false,
        searchlight: false,
    };

    /// Parses a comma-separated list of `aberration`, `doppler`, `searchlight` (or `all`,
    /// `none`).
    pub fn parse(list: &str) -> Result<Self> {
        let mut e = Self::default();
        for item in list.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            match item {
                "aberration" => e.aberration = true,
                "doppler" => e.doppler = true,
                "searchlight" => e.searchlight = true,
                "all" => e = Self::ALL,
                "none" => {}
                _ => {
                    return Err(Error::Effect {
                        name: item.to_owned(),
                    });
                }
            }
        }
        Ok(e)
    }
}

/// The camera's orthonormal frame and the image-plane half extents.
#[derive(Clone, Copy, Debug)]
pub struct CameraFrame {
    forward: DVec3,
    right: DVec3,
    up: DVec3,
    half_w: f64,
    half_h: f64,
    width: u32,
    height: u32,
}

impl CameraFrame {
    /// Validates the camera and builds its frame.
    pub fn new(cam: &Camera) -> Result<Self> {
        check_size(cam.width, cam.height)?;
        if !(cam.fov_y_deg > 0.0 && cam.fov_y_deg < 180.0) {
            return Err(Error::param(
                "vertical field of view (degrees)",
                cam.fov_y_deg,
                "must be in (0, 180)",
            ));
        }
        let forward = unit(cam.look, "look direction length")?;
        let up0 = unit(cam.up, "up direction length")?;
        let mut right = forward.cross(up0);
        if right.length() < 1e-9 {
            let alt = if forward.z.abs() < 0.9 {
                DVec3::Z
            } else {
                DVec3::X
            };
            right = forward.cross(alt);
        }
        let right = right.normalize();
        let up = right.cross(forward);
        let half_h = (0.5 * cam.fov_y_deg.to_radians()).tan();
        let half_w = half_h * f64::from(cam.width) / f64::from(cam.height);
        Ok(Self {
            forward,
            right,
            up,
            half_w,
            half_h,
            width: cam.width,
            height: cam.height,
        })
    }

    /// The orthonormal frame `(forward, right, up)`: unit vectors, `up = right x forward`.
    #[must_use]
    pub fn basis(&self) -> (DVec3, DVec3, DVec3) {
        (self.forward, self.right, self.up)
    }

    /// Image-plane half extents `(half_w, half_h)` at unit distance:
    /// `half_h = tan(fov_y / 2)`, `half_w = half_h * width / height`.
    #[must_use]
    pub fn half_extents(&self) -> (f64, f64) {
        (self.half_w, self.half_h)
    }

    /// The observer-frame unit viewing direction through pixel centre `(x, y)` (row 0 at
    /// the top).
    #[must_use]
    pub fn pixel_direction(&self, x: f64, y: f64) -> DVec3 {
        self.direction_at(self.screen_x(x), self.screen_y(y))
    }

    /// The image-plane coordinate of column `x`'s centre at unit distance.
    #[inline]
    fn screen_x(&self, x: f64) -> f64 {
        (2.0 * (x + 0.5) / f64::from(self.width) - 1.0) * self.half_w
    }

    /// The image-plane coordinate of row `y`'s centre at unit distance.
    #[inline]
    fn screen_y(&self, y: f64) -> f64 {
        (1.0 - 2.0 * (y + 0.5) / f64::from(self.height)) * self.half_h
    }

    #[inline]
    fn direction_at(&self, sx: f64, sy: f64) -> DVec3 {
        (self.forward + sx * self.right + sy * self.up).normalize()
    }
}

/// The scene-frame direction seen through pixel `(x, y)`: inverse aberration of the pixel's
/// observer-frame direction when `effects.aberration`, else that direction itself.
pub fn scene_direction(
    cam: &Camera,
    velocity: Velocity,
    effects: Effects,
    x: u32,
    y: u32,
) -> Result<DVec3> {
    let frame = CameraFrame::new(cam)?;
    let d = frame.pixel_direction(f64::from(x), f64::from(y));
    Ok(if effects.aberration {
        velocity.observer_to_scene(d)
    } else {
        d
    })
}

/// Renders one frame: for every pixel, the observer-frame direction, its scene-frame
/// direction (inverse aberration), the environment's radiance there, the Doppler colour
/// shift `K(D)` and the searchlight factor `D^4`, as selected. `table` defaults to
/// [`DopplerColourTable::global`]. Rows are rendered in parallel; the result does not depend
/// on the thread count.
///
/// The per-pixel work has no logarithm and no libm inverse trigonometry: `K(D)` comes from
/// the table uniform in `D` ([`DopplerColourTable::apply_linear_d`], within
/// [`crate::LINEAR_D_MAX_ERROR`] of the exact matrix), and an equirectangular map is looked
/// up with [`crate::fast_atan2`] (within [`crate::ATAN2_MAX_ERROR_RAD`] of the exact
/// angles). Aberration, the Doppler factor and the searchlight factor are the exact
/// formulas, and cube maps and the checker are sampled as [`Environment::sample`] does.
pub fn render(
    env: &Environment,
    cam: &Camera,
    velocity: Velocity,
    effects: Effects,
    table: Option<&DopplerColourTable>,
) -> Result<Rgb32FImage> {
    let frame = CameraFrame::new(cam)?;
    let table = if effects.doppler {
        Some(table.unwrap_or_else(|| DopplerColourTable::global()))
    } else {
        None
    };
    let (w, h) = (cam.width, cam.height);
    let sx: Vec<f64> = (0..w).map(|x| frame.screen_x(f64::from(x))).collect();
    let equirect = match env {
        Environment::Equirect(m) => Some(EquirectTexels::new(m)),
        _ => None,
    };
    let kernel = Kernel::new(&frame, env, equirect, velocity, effects, table);
    let (wu, hu) = (w as usize, h as usize);
    // Written once, never zeroed first: zeroing a full-HD frame's 25 MB costs a twentieth
    // of the frame (a tenth on one thread).
    let len = wu * hu * 3;
    let mut buf: Vec<f32> = Vec::with_capacity(len);
    // Bands of TILE rows in parallel, each walked in TILE x TILE blocks: a block's pixels
    // look up one compact patch of the map, which stays in cache, where a whole row's
    // lookups follow a curve across many map rows and miss the cache at almost every pixel.
    let sy: Vec<f64> = (0..h).map(|y| frame.screen_y(f64::from(y))).collect();
    buf.spare_capacity_mut()[..len]
        .par_chunks_mut(wu * 3 * TILE)
        .enumerate()
        .for_each_init(
            || Box::new(Work::default()),
            |work, (band, rows)| {
                let y0 = band * TILE;
                let nrows = rows.len() / (3 * wu);
                for x0 in (0..wu).step_by(TILE) {
                    let x1 = (x0 + TILE).min(wu);
                    kernel.run(rows, wu, x0..x1, &sx[x0..x1], &sy[y0..y0 + nrows], work);
                }
            },
        );
    // SAFETY: the capacity is at least `len`, and the loop above has written every one of
    // the first `len` elements: its bands cover all rows, its blocks all columns of a band,
    // and `Kernel::run` writes every pixel of a block's rows (`Kernel::back` writes all `n`
    // pixels of its run, `n` being the run's length). A panic in the loop leaves the length
    // at 0.
    #[allow(unsafe_code)]
    unsafe {
        buf.set_len(len);
    }
    Rgb32FImage::from_raw(w, h, buf)
        .ok_or_else(|| Error::param("image size", f64::from(w), "buffer mismatch"))
}

/// The side of the blocks [`render`] walks the image in, pixels.
const TILE: usize = 32;

/// The per-pixel work of [`render`] on runs of at most [`TILE`] pixels of one row, in
/// stages that each loop over the run on structure-of-arrays lanes: directions and Doppler
/// factors, map coordinates, texel fetches, colour. Each stage's body is short, branch-free
/// where it is arithmetic, and its iterations independent, so the compiler vectorises the
/// arithmetic stages and the processor overlaps many pixels instead of waiting on one
/// pixel's long chain of divisions and polynomials.
///
/// Every lane computes exactly the operations, in the order, of the scalar formulas
/// ([`CameraFrame::pixel_direction`], [`Velocity::observer_to_scene`],
/// [`Velocity::doppler_factor_observer`], the map lookup, [`DopplerColourTable::apply_linear_d`],
/// [`searchlight_integrated`]), so the image is the same bit for bit whether the stages run as
/// vector instructions or not (`tests/render.rs` checks it against those formulas). On x86-64
/// processors with AVX2 the same code is compiled a second time for AVX2 (four `f64` lanes
/// instead of two) and chosen at run time; IEEE arithmetic gives the same results either way
/// (Rust never fuses a multiply and an add on its own).
struct Kernel<'a> {
    frame: &'a CameraFrame,
    env: &'a Environment,
    equirect: Option<EquirectTexels<'a>>,
    /// `(u, b, 1 / gamma)` of the inverse aberration (unit velocity, `-speed`), `None`
    /// when it is off or the observer is at rest (the identity).
    aberration: Option<(DVec3, f64, f64)>,
    beta: DVec3,
    gamma: f64,
    shade: bool,
    searchlight: bool,
    table: Option<&'a DopplerColourTable>,
    #[cfg(target_arch = "x86_64")]
    avx2: bool,
}

impl<'a> Kernel<'a> {
    fn new(
        frame: &'a CameraFrame,
        env: &'a Environment,
        equirect: Option<EquirectTexels<'a>>,
        velocity: Velocity,
        effects: Effects,
        table: Option<&'a DopplerColourTable>,
    ) -> Self {
        let speed = velocity.speed();
        // `Velocity::aberrate` with sign -1, its loop-invariant part computed once.
        let aberration = (effects.aberration && speed != 0.0)
            .then(|| (velocity.beta() / speed, -speed, 1.0 / velocity.gamma()));
        Self {
            frame,
            env,
            equirect,
            aberration,
            beta: velocity.beta(),
            gamma: velocity.gamma(),
            shade: effects.doppler || effects.searchlight,
            searchlight: effects.searchlight,
            table,
            #[cfg(target_arch = "x86_64")]
            avx2: std::arch::is_x86_feature_detected!("avx2"),
        }
    }

    /// One block of pixels: columns `cols` of the rows in `rows` (RGB, `width` pixels a
    /// row), `sx` the columns' image-plane x coordinates and `sy` the rows' (at most
    /// [`TILE`]), `work` the thread's scratch state. Every row's front stages run first
    /// ([`Self::front`], which asks for the block's map texels ahead), then every row's back
    /// stages ([`Self::back`]), so the texels arrive while the block's arithmetic runs.
    fn run(
        &self,
        rows: &mut [MaybeUninit<f32>],
        width: usize,
        cols: Range<usize>,
        sx: &[f64],
        sy: &[f64],
        work: &mut Work,
    ) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: the processor has AVX2 (detected in `Kernel::new`), the only
            // requirement of `run_avx2`.
            #[allow(unsafe_code)]
            unsafe {
                self.run_avx2(rows, width, cols, sx, sy, work);
            }
            return;
        }
        self.block(rows, width, cols, sx, sy, work);
    }

    /// [`Self::block`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn run_avx2(
        &self,
        rows: &mut [MaybeUninit<f32>],
        width: usize,
        cols: Range<usize>,
        sx: &[f64],
        sy: &[f64],
        work: &mut Work,
    ) {
        self.block(rows, width, cols, sx, sy, work);
    }

    #[inline(always)]
    fn block(
        &self,
        rows: &mut [MaybeUninit<f32>],
        width: usize,
        cols: Range<usize>,
        sx: &[f64],
        sy: &[f64],
        work: &mut Work,
    ) {
        let Work { lanes, scratch } = work;
        for (l, &y) in lanes.iter_mut().zip(sy) {
            self.front(l, scratch, sx, y);
        }
        for (r, l) in lanes[..sy.len()].iter().enumerate() {
            let row = &mut rows[3 * (r * width + cols.start)..3 * (r * width + cols.end)];
            self.back(l, scratch, row);
        }
    }

    /// [`Self::front`] then [`Self::back`] on one run of pixels: `row` their RGB output,
    /// `sx` their image-plane x coordinates, `sy` the row's.
    #[cfg(test)]
    fn stages(&self, row: &mut [MaybeUninit<f32>], sx: &[f64], sy: f64) {
        let (mut l, mut scratch) = (Lanes::default(), Scratch::default());
        self.front(&mut l, &mut scratch, sx, sy);
        self.back(&l, &mut scratch, row);
    }

    /// The stages of one run of at most [`TILE`] pixels up to the map lookup: directions,
    /// Doppler factors and, for an equirectangular map, the bilinear corners (whose texels
    /// are asked for) or else the scene directions.
    #[inline(always)]
    fn front(&self, l: &mut Lanes, scratch: &mut Scratch, sx: &[f64], sy: f64) {
        // Every stage runs over all TILE lanes (a constant trip count, which the vectoriser
        // needs); lanes past the run repeat its last pixel and are not written.
        let n = sx.len().min(TILE);
        l.n = n;
        if n == 0 {
            return;
        }
        let mut lanes = [sx[n - 1]; TILE];
        lanes[..n].copy_from_slice(&sx[..n]);
        let sx = &lanes;
        let (f, r, up) = (self.frame.forward, self.frame.right, self.frame.up);
        let su = sy * up;
        // Observer-frame directions: (forward + sx right + sy up), normalised as glam does
        // (times the reciprocal of the length).
        let [dx, dy, dz] = &mut l.dir;
        for i in 0..TILE {
            let s = sx[i];
            let (px, py, pz) = (
                (f.x + s * r.x) + su.x,
                (f.y + s * r.y) + su.y,
                (f.z + s * r.z) + su.z,
            );
            let k = 1.0 / ((px * px + py * py) + pz * pz).sqrt();
            (dx[i], dy[i], dz[i]) = (px * k, py * k, pz * k);
        }
        if self.shade {
            let (b, g) = (self.beta, self.gamma);
            for i in 0..TILE {
                l.dop[i] = 1.0 / (g * (1.0 - ((b.x * dx[i] + b.y * dy[i]) + b.z * dz[i])));
            }
        }
        if let Some((u, b, inv_gamma)) = self.aberration {
            for i in 0..TILE {
                let (x, y, z) = (dx[i], dy[i], dz[i]);
                let c = (x * u.x + y * u.y) + z * u.z;
                let (qx, qy, qz) = (x - c * u.x, y - c * u.y, z - c * u.z);
                let inv = 1.0 / (1.0 + b * c);
                let par = (c + b) * inv;
                let g = inv * inv_gamma;
                let (ox, oy, oz) = (par * u.x + qx * g, par * u.y + qy * g, par * u.z + qz * g);
                let k = 1.0 / ((ox * ox + oy * oy) + oz * oz).sqrt();
                (dx[i], dy[i], dz[i]) = (ox * k, oy * k, oz * k);
            }
        }
        if let Some(m) = &self.equirect {
            let [ux, uy] = &mut scratch.uv;
            for i in 0..TILE {
                (ux[i], uy[i]) = m.coords(DVec3::new(dx[i], dy[i], dz[i]));
            }
            m.corners_lanes(ux, uy, &mut l.corners);
            m.prefetch(&l.corners, n);
        }
    }

    /// The stages of one run after [`Self::front`]: texels, colour shift, searchlight, and
    /// the run's RGB output `row`.
    #[inline(always)]
    fn back(&self, l: &Lanes, scratch: &mut Scratch, row: &mut [MaybeUninit<f32>]) {
        let n = l.n;
        // Red, green and blue per lane (lanes past `n`: arbitrary, never written out).
        let Scratch { texel, rgb, .. } = scratch;
        match &self.equirect {
            Some(m) => m.gather_lanes(&l.corners, n, texel, rgb),
            None => {
                let [dx, dy, dz] = &l.dir;
                for i in 0..n {
                    let c = self.env.sample(DVec3::new(dx[i], dy[i], dz[i]));
                    (rgb[0][i], rgb[1][i], rgb[2][i]) = (c[0], c[1], c[2]);
                }
            }
        }
        let dop = &l.dop;
        if let Some(t) = self.table {
            #[cfg(target_arch = "x86_64")]
            if self.avx2 {
                // SAFETY: the processor has AVX2 (detected in `Kernel::new`), the only
                // requirement of the variant.
                #[allow(unsafe_code)]
                unsafe {
                    t.apply_linear_d_lanes_avx2(dop, rgb);
                }
            } else {
                t.apply_linear_d_lanes(dop, rgb);
            }
            #[cfg(not(target_arch = "x86_64"))]
            t.apply_linear_d_lanes(dop, rgb);
        }
        if self.searchlight {
            // Factors first, then channel by channel: unit-stride loops that vectorise.
            let mut f = [0.0_f32; TILE];
            for i in 0..TILE {
                f[i] = searchlight_integrated(dop[i]) as f32;
            }
            for c in rgb.iter_mut() {
                for i in 0..TILE {
                    c[i] *= f[i];
                }
            }
        }
        // Channel by channel: gathering a pixel's three floats into an array first and
        // copying it out makes the copy's 8-byte load wait on two 4-byte stores.
        for (i, out) in row.chunks_exact_mut(3).take(n).enumerate() {
            out[0].write(rgb[0][i]);
            out[1].write(rgb[1][i]);
            out[2].write(rgb[2][i]);
        }
    }
}

/// A thread's state for [`Kernel::run`]: one [`Lanes`] per row of a block, and the scratch
/// arrays of the stages.
#[derive(Clone, Debug)]
struct Work {
    lanes: [Lanes; TILE],
    scratch: Scratch,
}

impl Default for Work {
    fn default() -> Self {
        Self {
            lanes: [Lanes::default(); TILE],
            scratch: Scratch::default(),
        }
    }
}

/// A thread's scratch arrays for [`Kernel::front`] and [`Kernel::back`], reused from run to
/// run: zeroing them per run cost a twentieth of the frame. Their contents between stages
/// mean nothing.
#[derive(Clone, Copy, Debug)]
struct Scratch {
    /// Equirectangular coordinates per lane.
    uv: [[f64; TILE]; 2],
    /// Texels per corner, channel and lane.
    texel: [[[f32; TILE]; 3]; 4],
    /// Red, green and blue per lane.
    rgb: [[f32; TILE]; 3],
}

impl Default for Scratch {
    fn default() -> Self {
        Self {
            uv: [[0.0; TILE]; 2],
            texel: [[[0.0; TILE]; 3]; 4],
            rgb: [[0.0; TILE]; 3],
        }
    }
}

/// One run's state between [`Kernel::front`] and [`Kernel::back`].
#[derive(Clone, Copy, Debug)]
struct Lanes {
    /// Pixels in the run (at most [`TILE`]).
    n: usize,
    /// Scene-frame directions per lane (x, y, z).
    dir: [[f64; TILE]; 3],
    /// Doppler factors (1 when neither colour shift nor searchlight is on).
    dop: [f64; TILE],
    /// The equirectangular map's corners, when the map is one.
    corners: Corners<TILE>,
}

impl Default for Lanes {
    fn default() -> Self {
        Self {
            n: 0,
            dir: [[0.0; TILE]; 3],
            dop: [1.0; TILE],
            corners: Corners::default(),
        }
    }
}

/// The fraction of the image's pixels whose Doppler colour shift has no answer in an RGB
/// map: the visible window then sees only ultraviolet or infrared that an RGB triple's
/// spectrum (380-780 nm) does not hold, `K(D)` is zero and the pixel is black whatever the
/// map holds (the black disc ahead at `beta = 0.9`: `D` above about 780 / 360, or behind,
/// below about 380 / 830). Counted with `table` (default [`DopplerColourTable::global`]),
/// the one the render uses. 0 when `effects.doppler` is off.
pub fn out_of_map_fraction(
    cam: &Camera,
    velocity: Velocity,
    effects: Effects,
    table: Option<&DopplerColourTable>,
) -> Result<f64> {
    if !effects.doppler {
        return Ok(0.0);
    }
    let table = table.unwrap_or_else(|| DopplerColourTable::global());
    let frame = CameraFrame::new(cam)?;
    let mut outside = 0u64;
    for y in 0..cam.height {
        for x in 0..cam.width {
            let d = frame.pixel_direction(f64::from(x), f64::from(y));
            if table.is_black_linear_d(velocity.doppler_factor_observer(d)) {
                outside += 1;
            }
        }
    }
    Ok(outside as f64 / (f64::from(cam.width) * f64::from(cam.height)))
}

/// The speeds of a ramp `start:end:frames` (for example `0:0.99:60`): `frames` values
/// evenly spaced from `start` to `end` inclusive, each in `[0, 1)`.
pub fn parse_ramp(spec: &str) -> Result<Vec<f64>> {
    let parts: Vec<&str> = spec.split(':').collect();
    let bad = |reason| Error::param("ramp start:end:frames", f64::NAN, reason);
    if parts.len() != 3 {
        return Err(bad("expected START:END:FRAMES, for example 0:0.99:60"));
    }
    let start: f64 = parts[0]
        .trim()
        .parse()
        .map_err(|_| bad("START is not a number"))?;
    let end: f64 = parts[1]
        .trim()
        .parse()
        .map_err(|_| bad("END is not a number"))?;
    let n: usize = parts[2]
        .trim()
        .parse()
        .map_err(|_| bad("FRAMES is not a whole number"))?;
    if !(1..=100_000).contains(&n) {
        return Err(Error::param(
            "ramp frames",
            n as f64,
            "must be in 1..=100000",
        ));
    }
    for b in [start, end] {
        if !(b.is_finite() && (0.0..1.0).contains(&b)) {
            return Err(Error::param("ramp speed |beta|", b, "must be in [0, 1)"));
        }
    }
    Ok((0..n)
        .map(|k| {
            if n == 1 {
                start
            } else if k == n - 1 {
                end
            } else {
                start + (end - start) * k as f64 / (n - 1) as f64
            }
        })
        .collect())
}

/// Renders a velocity ramp along `direction`: one frame per speed, calling `sink` with the
/// frame index, speed and image (so frames can be written as they are made).
pub fn ramp(
    env: &Environment,
    cam: &Camera,
    direction: DVec3,
    speeds: &[f64],
    effects: Effects,
    mut sink: impl FnMut(usize, f64, Rgb32FImage) -> Result<()>,
) -> Result<()> {
    for (k, &b) in speeds.iter().enumerate() {
        let v = Velocity::along(direction, b)?;
        sink(k, b, render(env, cam, v, effects, None)?)?;
    }
    Ok(())
}

/// A display image: linear RGB times `2^exposure`, clipped to `[0, 1]`, sRGB-encoded to 8 bit.
#[must_use]
pub fn to_srgb8(img: &Rgb32FImage, exposure_stops: f64) -> RgbImage {
    let k = exposure_stops.exp2();
    let mut out = RgbImage::new(img.width(), img.height());
    for (o, p) in out.pixels_mut().zip(img.pixels()) {
        for c in 0..3 {
            let v = blueshift_spectrum::srgb_encode((f64::from(p.0[c]) * k).clamp(0.0, 1.0));
            o.0[c] = (v * 255.0).round().clamp(0.0, 255.0) as u8;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envmap::Checker;

    /// One pixel by the scalar formulas the kernel's lanes restate.
    fn scalar_pixel(
        frame: &CameraFrame,
        env: &Environment,
        velocity: Velocity,
        effects: Effects,
        x: u32,
        y: u32,
    ) -> [f32; 3] {
        let table = DopplerColourTable::global();
        let d_obs = frame.pixel_direction(f64::from(x), f64::from(y));
        let d = if effects.aberration {
            velocity.observer_to_scene(d_obs)
        } else {
            d_obs
        };
        let mut rgb = match env {
            Environment::Equirect(m) => {
                let t = EquirectTexels::new(m);
                t.fetch(t.coords(d))
            }
            _ => env.sample(d),
        };
        let dop = velocity.doppler_factor_observer(d_obs);
        if effects.doppler {
            rgb = table.apply_linear_d(dop, rgb);
        }
        if effects.searchlight {
            let f = searchlight_integrated(dop) as f32;
            rgb = rgb.map(|c| c * f);
        }
        rgb
    }

    /// The vectorised lanes (AVX2 where the processor has it, and the baseline build) give
    /// the scalar formulas' bits at every pixel, for partial blocks at the right and bottom
    /// edges too.
    #[test]
    fn lanes_equal_the_scalar_formulas_bit_for_bit() {
        let checker = Environment::Checker(Checker::default());
        let equirect = Environment::Equirect(checker.to_equirect(256, 128).unwrap());
        let cube = Environment::Cube(checker.to_cube(32).unwrap());
        let cam = Camera {
            look: DVec3::new(0.3, -0.2, -1.0),
            width: 75,
            height: 41,
            fov_y_deg: 120.0,
            ..Camera::default()
        };
        let frame = CameraFrame::new(&cam).unwrap();
        let sets = [Effects::default(), Effects::ABERRATION, Effects::ALL];
        for env in [&equirect, &cube] {
            for beta in [
                DVec3::ZERO,
                DVec3::new(0.0, 0.0, -0.9),
                DVec3::new(0.5, 0.3, 0.6),
            ] {
                let v = Velocity::new(beta).unwrap();
                for fx in sets {
                    let img = render(env, &cam, v, fx, None).unwrap();
                    let equi = match env {
                        Environment::Equirect(m) => Some(EquirectTexels::new(m)),
                        _ => None,
                    };
                    let table = fx.doppler.then(DopplerColourTable::global);
                    let kernel = Kernel::new(&frame, env, equi, v, fx, table);
                    for y in 0..cam.height {
                        let sy = frame.screen_y(f64::from(y));
                        let sx: Vec<f64> = (0..cam.width)
                            .map(|x| frame.screen_x(f64::from(x)))
                            .collect();
                        // NaN until written: a pixel the lanes miss fails below.
                        let mut base = vec![MaybeUninit::new(f32::NAN); 3 * cam.width as usize];
                        for (out, xs) in base.chunks_mut(3 * TILE).zip(sx.chunks(TILE)) {
                            kernel.stages(out, xs, sy);
                        }
                        for x in 0..cam.width {
                            let want = scalar_pixel(&frame, env, v, fx, x, y).map(f32::to_bits);
                            let got = img.get_pixel(x, y).0.map(f32::to_bits);
                            assert_eq!(got, want, "pixel ({x}, {y}), beta {beta}, {fx:?}");
                            let i = 3 * x as usize;
                            // SAFETY: every element was initialised when `base` was made.
                            #[allow(unsafe_code)]
                            let b = [i, i + 1, i + 2]
                                .map(|j| unsafe { base[j].assume_init() }.to_bits());
                            assert_eq!(b, want, "baseline lanes, pixel ({x}, {y})");
                        }
                    }
                }
            }
        }
    }
}
