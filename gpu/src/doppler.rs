//! Doppler volume rendering on the GPU, behind the CPU's own types: a
//! [`blueshift_tracking::doppler::DopplerScene`] and
//! [`blueshift_tracking::doppler::DopplerSettings`] (one scene description, two backends).
//!
//! # What runs here
//! The emission-only piecewise-linear integrator (the Doppler paper's Algorithm 2 as
//! `blueshift_tracking::doppler::render_doppler` does it for rays without absorption): one
//! thread per pixel marches its ray back to front with the CPU's step, samples every density,
//! the black body and the velocity field trilinearly, and per segment
//! - adds each line's trapezoid (between its two shifted positions, at least `line_width_nm`
//!   wide, area = the emitted energy) integrated exactly against the piecewise-linear CIE 1931
//!   CMFs (the CPU's table, uploaded; interval by interval, which in f32 avoids the
//!   cancellation of the CPU's prefix-moment differences), and
//! - adds the black body by the trapezoid rule along the ray on the CPU's wavelength grid
//!   (`blackbody_samples` points, each weighted by the XYZ of its hat function, computed on
//!   the host in f64 as the CPU does).
//!
//! With line broadening (`DopplerSettings::broadening`: thermal from the black-body
//! temperature field and each species' atomic mass, and/or a user Gaussian sigma) each line's
//! sweep is the CPU's `emit_line`: the trapezoid when the sweep exceeds 16 sigma, else up to
//! 64 `PwlGaussian`s at the area centroids of equal sub-sweeps. A Gaussian's XYZ is computed
//! in closed form per CMF interval it overlaps (the CMFs are linear there, so only the
//! profile's area and first moment over the interval are needed, from cumulative tables of
//! the unit profile made on the host in f64), in wavelengths relative to the line's position
//! (a piece is `sigma / 4` wide, below what absolute f32 wavelengths resolve), keeping the
//! pieces the CPU keeps (those not wholly outside the wavelength range).
//!
//! The banded integrators (Algorithm 1: `SpectralIntegrator::Banded`, nearest-band and
//! energy-conserving shift) run per sample with the CPU's trapezoid weights. Without
//! absorption the XYZ of the band values is linear in them, so each deposit into band `d`
//! adds the band's CMF integrals (blueshift-spectrum's `BandWeights`, from the host) times its
//! value straight to XYZ, and no per-ray band array is kept. With absorption each ray keeps
//! its band values in a device buffer (`pixels x bands` f32, checked against the storage
//! limits before it is created), attenuated by half of each sample's optical depth before and
//! after its emission as the CPU does.
//!
//! # Absorption with the piecewise-linear integrator
//! The image path of blueshift-tracking's `front_to_back` (`tracking/src/doppler/pwl.rs`),
//! entry `main_absorb`, one thread per pixel: marching from the eye, each ray keeps only the
//! optical depth in front, `tau_front(lambda)`, as a sorted array of linear pieces in its own
//! region of a storage buffer. Per segment it
//! - adds the closed-form XYZ of the segment's emission `E` (line trapezoids, and the black
//!   body by the trapezoid rule along the ray on the `blackbody_samples` grid);
//! - sums the segment's absorption trapezoids (half heights) into one sorted piece list and
//!   merges it into `tau_front` in one pass (`tau_mid`: the same pieces and values as the
//!   CPU's trapezoid-by-trapezoid `add_trapezoid`, up to rounding);
//! - subtracts what `tau_mid` takes, `integral E (1 - exp(-tau_mid)) cmf` over its support,
//!   cut at the breakpoints of `tau`, of `E` and of the CMF table, with exact exponential
//!   moments per sub-interval (by linearity, the black body and each emission line are
//!   integrated separately, which is the CPU's integral of their sum);
//! - adds the other half of the segment's depth, then merges `tau_front` on the CPU's
//!   schedule: the `k`-th merge (when the count passes `max(2 n, 64)`) with tolerance
//!   `merge_tolerance 6 / (pi k)^2`, then, over the budget, merges with 4, 16, ... times the
//!   tolerance (the fallback, counted per ray in [`PieceStats::fallback_rays`]).
//!
//! The device's budget is `min(piece_budget, DEVICE_PIECE_CAP)` pieces ([`DEVICE_PIECE_CAP`]
//! = 1024): with a larger `piece_budget` the fallback starts earlier than on the CPU (reported
//! the same way). Each ray's region holds two arrays of `cap + 2 n_abs + 8` pieces plus
//! `4 n_abs` pieces of scratch (16 bytes a piece, `n_abs` = absorption lines); the image is
//! dispatched in tiles of as many rays as fit in `max_storage_buffer_binding_size`,
//! `max_buffer_size` and [`TILE_BYTES_CAP`] (256 MiB), and refused with
//! [`Error::LimitExceeded`] naming the limit when one ray does not fit
//! ([`absorption_layout`]). Should a segment's sum still need more than a region (a
//! `tau_front` of many disjoint pieces), `tau_front` is merged across its gaps with growing
//! tolerances until it fits (counted as a fallback too). [`PieceStats`] reports
//! `tau_front`'s largest piece count per ray as the CPU's does.
//!
//! ## Single precision
//! Arithmetic is f32 on the device (no `SHADER_F64` needed); the parity tests state the
//! tolerance against the CPU image (`gpu/tests/doppler.rs`). With absorption the scheme is
//! the CPU's, arranged so that f32 loses nothing large:
//! - the transmittance of a sub-interval is taken from its end with the smaller `tau`
//!   (`exp(-tau)` there, times moments of a decaying exponential), so nothing overflows and
//!   the moments stay in `[0, h^(n+1)/(n+1)]`;
//! - the moments `int_0^h x^n exp(-s x) dx` use their series (12 terms, remainder < 2e-10)
//!   for `s h < 1`, where the recurrence would cancel (the CPU switches at 0.05 in f64), and
//!   the recurrence above (< 20 ulp);
//! - CMF and black-body intervals are picked from each sub-interval's midpoint and the next
//!   node is found by index, so rounding cannot stall the walk;
//! - the pixel is `max(emitted - absorbed, 0)`: the rounding of that difference is a few ulp
//!   of the emitted (unattenuated) light, so for optically thick pixels the error is small
//!   against the unattenuated emission (the scale of the CPU's own `merge_tolerance` bound),
//!   not against the remainder. Measured on lavapipe (`gpu/tests/doppler.rs`, 16^3 galaxy,
//!   absorption x 5): worst `|gpu - cpu| / cpu` 7.4e-4 on pixels above 1e-3 of the maximum,
//!   3.7e-4 of `cpu + unattenuated` (the emission-only kernel's worst, 4.6e-4, is on the same
//!   pixel), optically thick (x 1e4) 6.6e-6 of `cpu + unattenuated`; asserted 2e-3.
//!
//!
//! With line broadening and absorption each line's sources (the trapezoid, or its up to 64
//! Gaussians of 32 pieces) are handled one at a time: an absorption line's sources are
//! merged into `tau_front` at half height, one merge pass each (between the two regions), and
//! what `tau_mid` takes from an emission line is integrated piece by piece of its sources
//! (the absorbed light is linear in the emission). The regions then have room for two
//! Gaussians a line (`cap + 66 n_abs + 8` pieces). f32 wavelengths resolve about 6e-5 nm at
//! 656 nm: optical-depth profiles narrower than that (sigma below about 0.1 km/s, or a sweep
//! that narrow) are lost on the device where the CPU keeps them.
//!
//! # Passes (software adapters)
//! lavapipe (llvmpipe) runs a batch of 8 or 16 lanes together and keeps one loop limiter per
//! batch: every iteration of every loop of any lane counts, and after 65535 all loops exit at
//! their next iteration end, silently (a long ray would come out short). So the
//! piecewise-linear kernels are resumable: each lane counts its loop iterations and yields
//! after a budget (30,000 on software adapters, 2^24 on hardware ones), saving its ray's state
//! (the emission-only kernel 20 floats per pixel, the absorbing one 8 pieces at the start of
//! its region), and the host dispatches passes until every ray is done. After each sample or
//! segment a two-iteration probe loop (trip count from the uniform) finds out whether the
//! batch's limiter ran out (divergent lanes add up); if so the host restarts the tile from
//! pass 0 with a budget 4 times smaller, down to 200, and a segment that alone spends the
//! limiter is [`Error::Internal`] naming the loop limit (e.g. broadened H I + C I lines with
//! absorption on the 16^3 galaxy), as is a banded render (one pass) that spends it: never a
//! silently darker image. Hardware adapters have no such limiter.
//!
//! # What is refused
//! [`check_supported`] returns [`Error::Unsupported`] for more than [`MAX_SPECIES`] species;
//! the CLI's `--device auto` falls back to the CPU on it. Settings the CPU itself refuses
//! (broadening with a banded integrator, thermal broadening without a temperature field, a
//! bad sigma or mass) are [`Error::InvalidInput`] with the CPU's message. Picked spectra,
//! traces and spectral cubes stay on the CPU.

use blueshift_spectrum::{
    ATOMIC_MASS_UNIT_KG, BOLTZMANN_J_PER_K, BandLayout, Catalogue, Cmf, PwlGaussian,
    RadiationConstants, Xyz,
};
use blueshift_tracking::Ray;
use blueshift_tracking::doppler::{
    BB_UNIT, BandShift, DopplerImage, DopplerScene, DopplerSettings, PieceStats, SpectralIntegrator,
};
use bytemuck::{Pod, Zeroable};

use crate::context::{GpuContext, WORKGROUP_2D};
use crate::error::{Error, Result};

/// WGSL of the Doppler pipeline.
pub const DOPPLER_WGSL: &str = include_str!("shaders/doppler.wgsl");

/// Most species the device kernel holds per ray.
pub const MAX_SPECIES: usize = 8;

/// Most pieces of the optical depth in front (`tau_front`) a ray keeps on the device with
/// absorption (piecewise-linear integrator): the device's piece budget is
/// `min(piece_budget, DEVICE_PIECE_CAP)`, so with a larger `piece_budget` the budget fallback
/// (coarser merges, counted in [`PieceStats::fallback_rays`]) starts earlier than on the CPU.
pub const DEVICE_PIECE_CAP: usize = 1024;

/// Loop iterations after which a pass of the absorbing kernel yields on a software adapter.
const SOFTWARE_ITER_BUDGET: u32 = 30_000;

/// Loop iterations a software adapter (lavapipe) runs per invocation before it stops every
/// loop (llvmpipe's limiter is 65535); a pass that counts this many is reported as an error.
const SOFTWARE_ITER_LIMIT: u32 = 65_000;

/// `(iterations after which a pass yields, iterations that mean a cut-short pass)` of the
/// resumable piecewise-linear kernels on `ctx`'s adapter.
fn iteration_limits(ctx: &GpuContext) -> (u32, u32) {
    if ctx.is_hardware() {
        (1 << 24, u32::MAX)
    } else {
        (SOFTWARE_ITER_BUDGET, SOFTWARE_ITER_LIMIT)
    }
}

/// Smallest pass budget (loop iterations per lane) tried on a software adapter.
const SOFTWARE_MIN_BUDGET: u32 = 200;

/// A resumable piecewise-linear kernel, dispatched in passes.
struct Passes<'a> {
    pipeline: &'a wgpu::ComputePipeline,
    bind_group: &'a wgpu::BindGroup,
    params: &'a wgpu::Buffer,
    out: &'a wgpu::Buffer,
    groups: [u32; 3],
    n_pix: usize,
    max_seg: usize,
}

impl Passes<'_> {
    /// Dispatches passes until no pixel of `range` is unfinished (w < 0) and returns the
    /// output. On a software adapter a pixel for which `limited` says the loop limiter ran out
    /// (a batch of lanes ran more iterations than the driver allows) restarts the whole range
    /// from pass 0 with a budget 4 times smaller, down to [`SOFTWARE_MIN_BUDGET`].
    fn run(
        &self,
        ctx: &GpuContext,
        params: &mut Params,
        range: std::ops::Range<usize>,
        limited: impl Fn(&[f32; 4]) -> bool,
    ) -> Result<Vec<[f32; 4]>> {
        let (mut budget, _) = iteration_limits(ctx);
        loop {
            params.iter_budget = budget;
            let mut out: Vec<[f32; 4]> = Vec::new();
            for pass in 0.. {
                params.pass_index = to_u32("pass", pass)?;
                ctx.write_buffer(self.params, std::slice::from_ref(params))?;
                ctx.dispatch(self.pipeline, self.bind_group, self.groups)?;
                out = ctx.read_buffer(self.out, self.n_pix)?;
                if !out[range.clone()].iter().any(|p| p[3] < 0.0) {
                    break;
                }
                // Every pass finishes at least one sample of every unfinished ray.
                if pass > self.max_seg + 2 {
                    return Err(Error::Internal(
                        "doppler: rays made no progress between passes".into(),
                    ));
                }
            }
            let cut = out[range.clone()].iter().any(&limited);
            if cut && !ctx.is_hardware() && budget > SOFTWARE_MIN_BUDGET {
                budget = (budget / 4).max(SOFTWARE_MIN_BUDGET);
                continue;
            }
            return Ok(out);
        }
    }
}

/// Most bytes of per-ray piece storage one dispatch uses (the image is rendered in tiles of
/// pixels that fit in it and in the device's storage-buffer limits).
pub const TILE_BYTES_CAP: u64 = 256 << 20;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    nx: u32,
    ny: u32,
    nz: u32,
    nvox: u32,
    nsp: u32,
    n_lines: u32,
    has_bb: u32,
    has_vel: u32,
    model: u32,
    invariant: u32,
    width: u32,
    height: u32,
    step: f32,
    range_lo: f32,
    range_hi: f32,
    min_width: f32,
    cmf_lo: f32,
    cmf_step: f32,
    cmf_n: u32,
    bb_k: u32,
    bb_c1: f32,
    bb_c2: f32,
    shift_mode: u32,
    temp_factor: f32,
    vel_factor: f32,
    off_lambda: u32,
    off_hat: u32,
    bb_factor: f32,
    n_bands: u32,
    band_w: f32,
    off_band_w: u32,
    off_band_c: u32,
    n_abs: u32,
    absorbing: u32,
    abs_factor: f32,
    pix_offset: u32,
    n_pix: u32,
    piece_cap: u32,
    region_l: u32,
    stride: u32,
    merge_tol: f32,
    pass_index: u32,
    iter_budget: u32,
    iter_limit: u32,
    broaden: u32,
    sigma2_user: f32,
    off_kom: u32,
    off_gauss: u32,
    n_gauss: u32,
    probe_n: u32,
    pad3: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PixelRay {
    p0: [f32; 3],
    n_seg: u32,
    dir_idx: [f32; 3],
    len: f32,
    los: [f32; 3],
    pad: f32,
}

fn tracking_err(e: blueshift_tracking::Error) -> Error {
    Error::InvalidInput(e.to_string())
}

/// `Ok` when the GPU integrator covers `scene` + `settings`; otherwise
/// [`Error::Unsupported`] naming the setting (the settings themselves are validated as the CPU
/// does, giving [`Error::InvalidInput`]).
pub fn check_supported(scene: &DopplerScene, settings: &DopplerSettings) -> Result<()> {
    settings.validated_step(scene).map_err(tracking_err)?;
    if !settings.broadening.is_none() {
        // The CPU's own checks first (its errors, not Unsupported).
        broadening_k_over_m(scene, settings)?;
    }
    if scene.species().len() > MAX_SPECIES {
        return Err(Error::Unsupported(format!(
            "{} species (at most {MAX_SPECIES} on the GPU)",
            scene.species().len()
        )));
    }
    Ok(())
}

/// Per species `k / m` ((m/s)^2 per K; 0 without thermal broadening), with the CPU's checks
/// of the broadening settings (blueshift-tracking's `Profiles::new`): the banded integrators
/// refuse broadening, the user sigma must be finite and >= 0, the temperature field
/// non-negative, thermal broadening needs a temperature field and a mass for every species.
fn broadening_k_over_m(scene: &DopplerScene, settings: &DopplerSettings) -> Result<Vec<f64>> {
    let b = &settings.broadening;
    let mut out = vec![0.0; scene.species().len()];
    if b.is_none() {
        return Ok(out);
    }
    if settings.integrator != SpectralIntegrator::PiecewiseLinear {
        return Err(Error::InvalidInput(
            "line broadening (thermal or Gaussian) is implemented in the piecewise-linear \
             integrator only: use the pwl integrator or drop the broadening"
                .into(),
        ));
    }
    if !(b.sigma_m_per_s.is_finite() && b.sigma_m_per_s >= 0.0) {
        return Err(Error::InvalidInput(format!(
            "line sigma {} m/s must be finite and >= 0",
            b.sigma_m_per_s
        )));
    }
    if let Some((_, temp)) = scene.blackbody()
        && let Some((lo, _)) = temp.finite_range()
        && lo < 0.0
    {
        return Err(Error::InvalidInput(format!(
            "the temperature field has negative values (min {lo} K)"
        )));
    }
    if b.thermal {
        if scene.blackbody().is_none() {
            return Err(Error::InvalidInput(
                "thermal broadening needs a temperature field (the scene's black-body \
                 temperature: keep `bb` among the species; a black-body factor of 0 keeps it \
                 dark)"
                    .into(),
            ));
        }
        for (i, sp) in scene.species().iter().enumerate() {
            let m = match b.masses_amu.iter().find(|(n, _)| n == &sp.name) {
                Some(&(_, m)) => m,
                None => Catalogue::parse(&sp.name)
                    .map(Catalogue::atomic_mass_amu)
                    .map_err(|_| {
                        Error::InvalidInput(format!(
                            "species '{}' has no known atomic mass: give one",
                            sp.name
                        ))
                    })?,
            };
            if !(m.is_finite() && m > 0.0) {
                return Err(Error::InvalidInput(format!(
                    "atomic mass {m} of '{}' must be finite and > 0",
                    sp.name
                )));
            }
            out[i] = BOLTZMANN_J_PER_K / (m * ATOMIC_MASS_UNIT_KG);
        }
    }
    Ok(out)
}

/// blueshift-tracking's banded `deposit`: a box of `area` over `[lo, hi)` added to the bands
/// (`(range start, range end, bands)`) as band means.
fn deposit(
    (a, b, n): (f64, f64, usize),
    lo: f64,
    hi: f64,
    area: f64,
    mut add: impl FnMut(usize, f64),
) {
    let bw = (b - a) / n as f64;
    let (l, h) = (lo.max(a), hi.min(b));
    if h <= l || hi <= lo {
        return;
    }
    let height = area / (hi - lo);
    let first = (((l - a) / bw).floor() as usize).min(n - 1);
    for i in first..n {
        let s = a + i as f64 * bw;
        if s >= h {
            break;
        }
        let ov = h.min(s + bw) - l.max(s);
        if ov > 0.0 {
            add(i, height * ov / bw);
        }
    }
}

/// Whether any line absorbs (the absorption factor is > 0 and some species has absorption
/// lines), as the CPU decides.
fn absorbing(scene: &DopplerScene) -> bool {
    scene.factors.absorption > 0.0
        && scene
            .species()
            .iter()
            .any(|sp| !sp.absorption_lines.is_empty())
}

fn to_u32(what: &str, n: usize) -> Result<u32> {
    u32::try_from(n).map_err(|_| Error::InvalidInput(format!("{what} {n} exceeds u32")))
}

/// The rays of every pixel, as `render_doppler` builds them: the pixel centre's camera ray
/// clipped to the box (of the voxel centres, or of the cells), `ceil(len / step)` segments.
fn pixel_rays(scene: &DopplerScene, settings: &DopplerSettings, step: f32) -> Vec<PixelRay> {
    let g = scene.geometry();
    let (mut lo, mut hi) = g.world_bounds();
    if settings.cell_domain {
        lo -= 0.5 * g.spacing;
        hi += 0.5 * g.spacing;
    }
    let (w, h) = (settings.width, settings.height);
    let mut out = Vec::with_capacity(w as usize * h as usize);
    for y in 0..h {
        for x in 0..w {
            let ray: Ray = settings.camera.ray(x as f32 + 0.5, y as f32 + 0.5, w, h);
            let mut pr = PixelRay::zeroed();
            if let Some((t0, t1)) = ray.clip_box(lo, hi) {
                let len = t1 - t0;
                if len > 0.0 {
                    let n_seg = (len / step).ceil().max(1.0);
                    pr.n_seg = n_seg as u32;
                    pr.len = len;
                    pr.p0 = g.world_to_index(ray.at(t0)).to_array();
                    pr.dir_idx = (ray.dir / g.spacing).to_array();
                    pr.los = ray.dir.normalize().to_array();
                }
            }
            out.push(pr);
        }
    }
    out
}

/// Renders the XYZ image of `scene` on the GPU with `settings.integrator` (piecewise linear
/// or banded): the same image as `blueshift_tracking::doppler::render_doppler` within f32
/// rounding (see the module docs for what is supported). The piece statistics are those of
/// `tau_front` with absorption (piecewise linear), zero otherwise, as on the CPU.
pub fn render_doppler_gpu(
    ctx: &GpuContext,
    scene: &DopplerScene,
    settings: &DopplerSettings,
) -> Result<DopplerImage> {
    check_supported(scene, settings)?;
    let step = settings.validated_step(scene).map_err(tracking_err)?;
    let g = scene.geometry();
    let [nx, ny, nz] = g.dims;
    let nvox = g.voxel_count();
    let f = scene.factors;
    let nsp = scene.species().len();
    let bb = scene.blackbody();
    let n_channels = nsp + if bb.is_some() { 2 } else { 0 };
    // Check the largest buffer before building it.
    ctx.check_storage_size(
        "doppler channels",
        (n_channels.max(1) as u64) * (nvox as u64) * 4,
    )?;
    ctx.check_storage_size("doppler velocity", (nvox as u64) * 12)?;
    ctx.check_storage_size(
        "doppler rays",
        u64::from(settings.width) * u64::from(settings.height) * 48,
    )?;
    let mut channels: Vec<f32> = Vec::with_capacity(n_channels.max(1) * nvox);
    for sp in scene.species() {
        channels.extend(sp.density.to_f32_vec());
    }
    if let Some((d, t)) = bb {
        channels.extend(d.to_f32_vec());
        channels.extend(t.to_f32_vec());
    }
    if channels.is_empty() {
        channels.push(0.0);
    }
    let velocity: Vec<f32> = match scene.velocity() {
        Some(v) => v.data().iter().flat_map(|p| p.to_array()).collect(),
        None => vec![0.0; 3],
    };
    let (a, b) = settings.range_nm;
    let (n_bands, nearest) = match settings.integrator {
        SpectralIntegrator::PiecewiseLinear => (0, false),
        SpectralIntegrator::Banded { bands, shift } => (bands, shift == BandShift::Nearest),
    };
    let mut lines: Vec<[f32; 4]> = Vec::new();
    let absorbs = absorbing(scene);
    let pwl_absorbs = absorbs && n_bands == 0;
    // Emission entries, then (banded with absorption) absorption entries: with the nearest
    // shift the CPU's rest-frame band values (each line's box deposited into the bands),
    // otherwise the lines themselves.
    let push_entries = |lines: &mut Vec<[f32; 4]>, emission: bool| {
        let factor = if emission { f.emission } else { f.absorption };
        let bw = (b - a) / n_bands.max(1) as f64;
        let w = settings.line_width_nm;
        for (m, sp) in scene.species().iter().enumerate() {
            let list = if emission {
                &sp.emission_lines
            } else {
                &sp.absorption_lines
            };
            if !nearest {
                for l in list {
                    lines.push([
                        l.centre_nm as f32,
                        (l.strength * factor) as f32,
                        m as f32,
                        0.0,
                    ]);
                }
                continue;
            }
            let mut v = std::collections::BTreeMap::<usize, f64>::new();
            for l in list {
                deposit(
                    (a, b, n_bands),
                    l.centre_nm - 0.5 * w,
                    l.centre_nm + 0.5 * w,
                    l.strength * factor,
                    |i, x| *v.entry(i).or_insert(0.0) += x,
                );
            }
            for (i, x) in v {
                if x > 0.0 {
                    lines.push([(a + (i as f64 + 0.5) * bw) as f32, x as f32, m as f32, 0.0]);
                }
            }
        }
    };
    push_entries(&mut lines, true);
    let n_lines = lines.len();
    if absorbs {
        push_entries(&mut lines, false);
    }
    let n_abs = lines.len() - n_lines;
    if lines.is_empty() {
        lines.push([0.0; 4]);
    }
    // Tables: the CMFs, the black-body grid and its hat functions' XYZ (as the CPU's PwlTables).
    let cmf = Cmf::cie1931_2deg();
    let (c_lo, c_hi) = cmf.range_nm();
    let mut tables: Vec<f32> = Vec::new();
    let mut cmf_n = 0usize;
    for (_, v) in cmf.samples() {
        tables.extend(v.iter().map(|&x| x as f32));
        cmf_n += 1;
    }
    let cmf_step = (c_hi - c_lo) / (cmf_n.max(2) - 1) as f64;
    let k = settings.blackbody_samples;
    let lambdas: Vec<f64> = (0..k)
        .map(|i| a + (b - a) * i as f64 / (k - 1) as f64)
        .collect();
    let off_lambda = tables.len();
    tables.extend(lambdas.iter().map(|&l| l as f32));
    let off_hat = tables.len();
    for i in 0..k {
        let mut x = Xyz::ZERO;
        if i > 0 {
            x += cmf.trapezoid_xyz(lambdas[i - 1], lambdas[i], 0.0, 1.0);
        }
        if i + 1 < k {
            x += cmf.trapezoid_xyz(lambdas[i], lambdas[i + 1], 1.0, 0.0);
        }
        tables.extend(x.to_array().iter().map(|&v| v as f32));
    }
    // Banded: per-band CMF integrals (blueshift-spectrum's BandWeights) and band centres.
    let off_band_w = tables.len();
    let layout = if n_bands > 0 {
        Some(BandLayout::new(a, b, n_bands).map_err(|e| Error::InvalidInput(e.to_string()))?)
    } else {
        None
    };
    if let Some(l) = layout {
        ctx.check_storage_size("doppler tables", (tables.len() + 4 * n_bands) as u64 * 4)?;
        for i in 0..n_bands {
            let s0 = l.band_start_nm(i);
            let x = cmf.trapezoid_xyz(s0, s0 + l.width_nm(), 1.0, 1.0);
            tables.extend(x.to_array().iter().map(|&v| v as f32));
        }
    }
    let off_band_c = tables.len();
    if let Some(l) = layout {
        tables.extend((0..n_bands).map(|i| l.band_centre_nm(i) as f32));
    }
    // Broadening: k / m per species, then the unit Gaussian's knots (x, then g).
    let off_kom = tables.len();
    tables.extend(
        broadening_k_over_m(scene, settings)?
            .iter()
            .map(|&v| v as f32),
    );
    let off_gauss = tables.len();
    let (mut gx, mut gg) = (Vec::<f64>::new(), Vec::<f64>::new());
    let _ = PwlGaussian::default().for_each_piece(0.0, 1.0, 1.0, |lo, hi, v0, v1| {
        if gx.is_empty() {
            gx.push(lo);
            gg.push(v0);
        }
        gx.push(hi);
        gg.push(v1);
        Ok::<(), ()>(())
    });
    // Integrals of g and z g from the first knot to each knot (exact for linear pieces).
    let (mut c0, mut c1) = (vec![0.0f64], vec![0.0f64]);
    for i in 0..gx.len().saturating_sub(1) {
        let (z0, z1, g0, g1) = (gx[i], gx[i + 1], gg[i], gg[i + 1]);
        let d = z1 - z0;
        let sl = (g1 - g0) / d;
        c0.push(c0[i] + d * (g0 + 0.5 * sl * d));
        c1.push(c1[i] + z0 * g0 * d + (z0 * sl + g0) * d * d / 2.0 + sl * d * d * d / 3.0);
    }
    let n_gauss = gx.len();
    for v in [&gx, &gg, &c0, &c1] {
        tables.extend(v.iter().map(|&x| x as f32));
    }
    let (c1l, c2) = RadiationConstants::Codata.values();
    let rays = pixel_rays(scene, settings, step);
    let params = Params {
        nx: to_u32("dims", nx)?,
        ny: to_u32("dims", ny)?,
        nz: to_u32("dims", nz)?,
        nvox: to_u32("voxels", nvox)?,
        nsp: to_u32("species", nsp)?,
        n_lines: to_u32("lines", n_lines)?,
        has_bb: u32::from(bb.is_some()),
        has_vel: u32::from(scene.velocity().is_some()),
        model: u32::from(settings.model == blueshift_spectrum::DopplerModel::Relativistic),
        invariant: u32::from(settings.invariant),
        width: settings.width,
        height: settings.height,
        step,
        range_lo: a as f32,
        range_hi: b as f32,
        min_width: settings.line_width_nm as f32,
        cmf_lo: c_lo as f32,
        cmf_step: cmf_step as f32,
        cmf_n: to_u32("CMF samples", cmf_n)?,
        bb_k: to_u32("black-body samples", k)?,
        // B per nm with lambda in nm: c1L * 1e45 (lambda^5) * 1e-9 (per nm).
        bb_c1: (c1l * 1e36) as f32,
        bb_c2: (c2 * 1e9) as f32,
        shift_mode: u32::from(matches!(
            settings.integrator,
            SpectralIntegrator::Banded {
                shift: BandShift::EnergyConserving,
                ..
            }
        )),
        temp_factor: f.temperature as f32,
        vel_factor: f.velocity as f32,
        off_lambda: to_u32("table offset", off_lambda)?,
        off_hat: to_u32("table offset", off_hat)?,
        bb_factor: (f.blackbody * BB_UNIT) as f32,
        n_bands: to_u32("bands", n_bands)?,
        band_w: ((b - a) / n_bands.max(1) as f64) as f32,
        off_band_w: to_u32("table offset", off_band_w)?,
        off_band_c: to_u32("table offset", off_band_c)?,
        n_abs: to_u32("absorption lines", n_abs)?,
        absorbing: u32::from(absorbs),
        abs_factor: f.absorption as f32,
        pix_offset: 0,
        n_pix: 0,
        piece_cap: 0,
        region_l: 0,
        stride: 0,
        merge_tol: settings.merge_tolerance as f32,
        pass_index: 0,
        iter_budget: 0,
        iter_limit: 0,
        broaden: u32::from(!settings.broadening.is_none()),
        sigma2_user: (settings.broadening.sigma_m_per_s * settings.broadening.sigma_m_per_s) as f32,
        off_kom: to_u32("table offset", off_kom)?,
        off_gauss: to_u32("table offset", off_gauss)?,
        n_gauss: to_u32("Gaussian knots", n_gauss)?,
        probe_n: 2,
        pad3: 0,
    };
    if pwl_absorbs {
        let rays_b = ctx.storage_buffer("doppler rays", &rays)?;
        let bufs = Bufs {
            rays: &rays_b,
            max_segments: rays.iter().map(|r| r.n_seg).max().unwrap_or(0),
            channels: &channels,
            velocity: &velocity,
            tables: &tables,
            lines: &lines,
        };
        return render_absorbing(ctx, settings, params, &bufs, n_abs);
    }
    let entry = if n_bands > 0 { "main_banded" } else { "main" };
    let pipeline = ctx.compute_pipeline("doppler", DOPPLER_WGSL, entry)?;
    let rb = ctx.storage_buffer("doppler rays", &rays)?;
    let cb = ctx.storage_buffer("doppler channels", &channels)?;
    let vb = ctx.storage_buffer("doppler velocity", &velocity)?;
    let tb = ctx.storage_buffer("doppler tables", &tables)?;
    let lb = ctx.storage_buffer("doppler lines", &lines)?;
    let n_pix = rays.len();
    let ob = ctx.storage_buffer_zeroed("doppler xyz", n_pix as u64 * 16)?;
    let pb = ctx.uniform_buffer("doppler params", &params)?;
    let gx = ctx.groups("doppler", settings.width, WORKGROUP_2D)?;
    let gy = ctx.groups("doppler", settings.height, WORKGROUP_2D)?;
    if n_bands > 0 {
        // The per-ray band values when absorbing (n_bands per pixel), else a placeholder.
        let bytes = if absorbs {
            n_pix as u64 * n_bands as u64 * 4
        } else {
            16
        };
        ctx.check_storage_size("doppler band values (pixels x bands)", bytes)?;
        let sb = ctx.storage_buffer_zeroed("doppler band values", bytes)?;
        let bg = ctx.bind_group(&pipeline, 0, &[&rb, &cb, &vb, &tb, &lb, &ob, &pb, &sb])?;
        let mut params = params;
        (_, params.iter_limit) = iteration_limits(ctx);
        ctx.write_buffer(&pb, std::slice::from_ref(&params))?;
        ctx.dispatch(&pipeline, &bg, [gx, gy, 1])?;
    } else {
        // The piecewise-linear kernel runs in passes (see `iteration_limits`), keeping 20
        // floats of state per pixel.
        let bytes = n_pix as u64 * 20 * 4;
        ctx.check_storage_size("doppler ray state (pixels x 20 floats)", bytes)?;
        let sb = ctx.storage_buffer_zeroed("doppler ray state", bytes)?;
        let bg = ctx.bind_group(&pipeline, 0, &[&rb, &cb, &vb, &tb, &lb, &ob, &pb, &sb])?;
        let mut params = params;
        (_, params.iter_limit) = iteration_limits(ctx);
        let max_seg = rays.iter().map(|r| r.n_seg).max().unwrap_or(0) as usize;
        let passes = Passes {
            pipeline: &pipeline,
            bind_group: &bg,
            params: &pb,
            out: &ob,
            groups: [gx, gy, 1],
            n_pix,
            max_seg,
        };
        passes.run(ctx, &mut params, 0..n_pix, |p| p[3] == 2.0)?;
    }
    let out: Vec<[f32; 4]> = ctx.read_buffer(&ob, n_pix)?;
    if let Some(i) = out.iter().position(|p| p[3] == 2.0) {
        return Err(Error::Internal(format!(
            "doppler: pixel ({}, {}) passed the adapter's loop limit (software adapters such \
             as lavapipe stop after 65535 loop iterations per invocation; the banded kernels \
             run in one pass, the piecewise-linear ones per sample): use fewer bands or \
             samples, a hardware GPU, or the CPU",
            i as u32 % settings.width,
            i as u32 / settings.width
        )));
    }
    if let Some(i) = out.iter().position(|p| p[3] != 0.0) {
        return Err(Error::InvalidInput(format!(
            "Doppler shift: pixel ({}, {}) meets a velocity with |v| >= c or a shift <= 0",
            i as u32 % settings.width,
            i as u32 / settings.width
        )));
    }
    Ok(DopplerImage {
        width: settings.width,
        height: settings.height,
        xyz: out
            .iter()
            .map(|p| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])])
            .collect(),
        pieces: PieceStats::default(),
    })
}

/// Host data of the Doppler pipeline (the rays already on the device).
struct Bufs<'a> {
    rays: &'a wgpu::Buffer,
    max_segments: u32,
    channels: &'a [f32],
    velocity: &'a [f32],
    tables: &'a [f32],
    lines: &'a [[f32; 4]],
}

/// Bytes of one ray's piece region for `piece_cap` pieces of `tau_front` and `n_abs`
/// absorption lines (see [`absorption_layout`]).
fn region_floats(piece_cap: usize, n_abs: usize, broaden: bool) -> (usize, usize) {
    let m = n_abs.max(1);
    // Regions A and B hold tau_front (and tau_mid) with room for the segment's breakpoints
    // (at most 2 per absorption line; with broadening 33 per Gaussian, room for two a line)
    // before the merges bring the count back under the cap.
    let per_line = if broaden { 2 * 33 } else { 2 };
    let l = piece_cap + per_line * m + 8;
    // 8 pieces of per-ray state between passes, then A, B, the trapezoids, their end
    // points and their sum (at least one broadened line's 32 pieces).
    (l, 4 * (8 + 2 * l + 2 * m + (2 * m).max(40)))
}

/// The piece layout the GPU uses for the piecewise-linear integrator with absorption:
/// `(pieces of tau_front per ray, bytes per ray, rays per dispatch tile)` for `settings`
/// with `n_abs` absorption lines on a device whose storage limits are `limits`.
///
/// Per ray: `cap = min(piece_budget, DEVICE_PIECE_CAP)` pieces of `tau_front`, two regions
/// of `cap + 2 n_abs + 8` pieces (`cap + 66 n_abs + 8` with line broadening: tau_front, and
/// tau_front plus the segment's half depth), 8 pieces of state and `2 n_abs + max(2 n_abs,
/// 40)` pieces of scratch (the segment's absorption trapezoids, their end points and their
/// sum), 16 bytes per piece. A tile holds as many rays as fit in the smallest of
/// `max_storage_buffer_binding_size`, `max_buffer_size` and [`TILE_BYTES_CAP`].
///
/// # Errors
/// [`Error::LimitExceeded`] naming the limit when not even one ray fits.
pub fn absorption_layout(
    settings: &DopplerSettings,
    n_abs: usize,
    limits: &wgpu::Limits,
) -> Result<(usize, u64, u64)> {
    let cap = settings.piece_budget.min(DEVICE_PIECE_CAP);
    let (_, floats) = region_floats(cap, n_abs, !settings.broadening.is_none());
    let per_ray = floats as u64 * 4;
    let (mut max, mut limit) = (
        TILE_BYTES_CAP,
        "the GPU Doppler tile memory cap TILE_BYTES_CAP",
    );
    if limits.max_storage_buffer_binding_size < max {
        max = limits.max_storage_buffer_binding_size;
        limit = "max_storage_buffer_binding_size";
    }
    if limits.max_buffer_size < max {
        max = limits.max_buffer_size;
        limit = "max_buffer_size";
    }
    let tile = (max / per_ray).min(u64::from(u16::MAX) * 64);
    if tile == 0 {
        return Err(Error::LimitExceeded {
            what: format!(
                "doppler absorption pieces of one ray ({cap} pieces of tau_front, {n_abs} \
                 absorption lines)"
            ),
            limit,
            requested: per_ray,
            max,
        });
    }
    Ok((cap, per_ray, tile))
}

/// The piecewise-linear integrator with absorption: the front-to-back pass per ray, in
/// tiles of pixels (see [`absorption_layout`]).
fn render_absorbing(
    ctx: &GpuContext,
    settings: &DopplerSettings,
    mut params: Params,
    b: &Bufs<'_>,
    n_abs: usize,
) -> Result<DopplerImage> {
    let n_pix = settings.width as usize * settings.height as usize;
    let (cap, per_ray, tile) = absorption_layout(settings, n_abs, &ctx.device().limits())?;
    let (l, floats) = region_floats(cap, n_abs, !settings.broadening.is_none());
    let tile = (tile as usize).min(n_pix).max(1);
    params.piece_cap = to_u32("piece cap", cap)?;
    params.region_l = to_u32("piece region", l)?;
    params.stride = to_u32("piece stride", floats)?;
    params.n_pix = to_u32("pixels", n_pix)?;
    let pipeline = ctx.compute_pipeline("doppler absorption", DOPPLER_WGSL, "main_absorb")?;
    let cb = ctx.storage_buffer("doppler channels", b.channels)?;
    let vb = ctx.storage_buffer("doppler velocity", b.velocity)?;
    let tb = ctx.storage_buffer("doppler tables", b.tables)?;
    let lb = ctx.storage_buffer("doppler lines", b.lines)?;
    let ob = ctx.storage_buffer_zeroed("doppler xyz", n_pix as u64 * 16)?;
    let pb = ctx.uniform_buffer("doppler params", &params)?;
    let sb = ctx.storage_buffer_zeroed("doppler absorption pieces", tile as u64 * per_ray)?;
    let bg = ctx.bind_group(&pipeline, 0, &[b.rays, &cb, &vb, &tb, &lb, &ob, &pb, &sb])?;
    // Software adapters (lavapipe) stop all loops of an invocation after 65535 iterations in
    // all (llvmpipe's loop limiter): the kernel counts its iterations and yields at the
    // budget, the host dispatches passes until every ray of the tile is done. Hardware
    // adapters have no such limit; their passes are long.
    (_, params.iter_limit) = iteration_limits(ctx);
    let max_seg = b.max_segments as usize;
    let mut start = 0usize;
    let mut out: Vec<[f32; 4]> = Vec::new();
    while start < n_pix {
        let count = tile.min(n_pix - start);
        params.pix_offset = to_u32("pixel offset", start)?;
        let gx = ctx.groups("doppler absorption", to_u32("tile", count)?, 64)?;
        let passes = Passes {
            pipeline: &pipeline,
            bind_group: &bg,
            params: &pb,
            out: &ob,
            groups: [gx, 1, 1],
            n_pix,
            max_seg,
        };
        out = passes.run(ctx, &mut params, start..start + count, |p| {
            p[3] >= 0.0 && (p[3] as u32) & 8 != 0
        })?;
        start += count;
    }
    let (mut sum, mut max, mut fallback_rays) = (0.0f64, 0usize, 0usize);
    let mut xyz = Vec::with_capacity(n_pix);
    for (i, p) in out.iter().enumerate() {
        let flags = p[3] as u32;
        if flags & 1 != 0 {
            return Err(Error::InvalidInput(format!(
                "Doppler shift: pixel ({}, {}) meets a velocity with |v| >= c or a shift <= 0",
                i as u32 % settings.width,
                i as u32 / settings.width
            )));
        }
        if flags & 4 != 0 {
            return Err(Error::Internal(format!(
                "doppler absorption: pixel ({}, {}) overflowed its piece region",
                i as u32 % settings.width,
                i as u32 / settings.width
            )));
        }
        if flags & 8 != 0 {
            return Err(Error::Internal(format!(
                "doppler absorption: pixel ({}, {}) needs more loop iterations in one segment \
                 than the adapter's loop limit allows (software adapters such as lavapipe stop \
                 after 65535 per invocation batch): use a hardware GPU or the CPU",
                i as u32 % settings.width,
                i as u32 / settings.width
            )));
        }
        let pieces = (flags >> 4) as usize;
        sum += pieces as f64;
        max = max.max(pieces);
        fallback_rays += usize::from(flags & 2 != 0);
        xyz.push([f64::from(p[0]), f64::from(p[1]), f64::from(p[2])]);
    }
    Ok(DopplerImage {
        width: settings.width,
        height: settings.height,
        xyz,
        pieces: PieceStats {
            mean: sum / n_pix.max(1) as f64,
            max,
            fallback_rays,
        },
    })
}
