//! Doppler volume rendering on the GPU, behind the CPU's own types: a
//! [`blueshift_doppler::DopplerScene`] and
//! [`blueshift_doppler::DopplerSettings`] (one scene description, two backends).
//!
//! # What runs here
//! The emission-only piecewise-linear integrator (the Doppler paper's Algorithm 2 as
//! `blueshift_doppler::render_doppler` does it for rays without absorption): one
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
//! its band values in a device buffer (`pixels x bands` working floats, checked against the storage
//! limits before it is created), attenuated by half of each sample's optical depth before and
//! after its emission as the CPU does.
//!
//! # Absorption with the piecewise-linear integrator
//! The image path of blueshift-doppler's `front_to_back` (`doppler/src/front.rs`),
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
//! The budget is the CPU's, in two rounds: every ray first runs with
//! `min(piece_budget, DEVICE_PIECE_CAP)` pieces ([`DEVICE_PIECE_CAP`] = 1024, which keeps the
//! tiles large), and where `piece_budget` is larger the rays that needed the fallback there
//! run again with `piece_budget` pieces (up to 2^20; a budget whose region exceeds the
//! storage limits keeps the first round's result, its fallback counted). Each ray's region holds two arrays of `cap + 2 n_abs + 8` pieces plus
//! `4 n_abs` pieces of scratch (16 bytes a piece in f32, 32 in f64, `n_abs` = absorption
//! lines); the image is dispatched in tiles of as many rays as fit in `max_storage_buffer_binding_size`,
//! `max_buffer_size` and [`TILE_BYTES_CAP`] (256 MiB), and refused with
//! [`Error::LimitExceeded`] naming the limit when one ray does not fit
//! ([`absorption_layout`]). Should a segment's sum still need more than a region (a
//! `tau_front` of many disjoint pieces), `tau_front` is merged across its gaps with growing
//! tolerances until it fits (counted as a fallback too). [`PieceStats`] reports
//! `tau_front`'s largest piece count per ray as the CPU's does.
//!
//! ## Precision: f64 where the adapter has it, else a measured f32 scheme
//! Every kernel is one WGSL body written in a working float `fw` ([`shader_source`] prepends
//! the prelude that defines it). [`DopplerPrecision::Auto`] (what [`render_doppler_gpu`] and
//! the CLI's `--gpu-precision auto` use) takes f64 where the adapter has `SHADER_F64`, f32
//! elsewhere; `F32` and `F64` force one ([`render_doppler_gpu_with`]).
//!
//! In both, the volume is sampled exactly as the CPU samples it: the position
//! `world_to_index(origin + dir (t0 + t))` and the nested trilinear lerps in f32, the same
//! operations in the same order (the CPU's grids are f32). Everything after the samples runs
//! in `fw`: shifts, line trapezoids and Gaussians, Planck's law, CMF integrals, the pieces of
//! the optical depth, the exponential moments, the sums, and the output.
//!
//! **f64** (`SHADER_F64`): SPIR-V's GLSL.std.450 has no f64 `exp`, so the prelude writes it
//! out (`k ln 2 + r` reduction with ln 2 split in two, a degree-14 polynomial, `2^k` from k's
//! bits: no `ldexp`, which HLSL lacks for f64; measured 2.2e-16 relative), and `expm1` by the
//! same series below 0.25 (5.4e-16); the exponential moments switch from series to
//! recurrence at `s h = 0.05` as on the CPU. Should the f64 kernel still not compile on some
//! backend, `Auto` takes f32 there (a forced `F64` reports the error). Measured on lavapipe against the
//! CPU (`gpu/tests/doppler.rs`, `f64_kernels_agree_with_the_cpu_to_rounding`): worst 2e-14
//! relative per pixel and channel for emission-only, broadened, banded and (at merge tolerance
//! 0) absorbing renders, the same piece counts; asserted 1e-11 on software adapters. A
//! hardware compiler may fuse the f32 sampling's multiply-adds (WGSL allows it), which moves
//! a sample by an ulp: there the bound is f32's, 1e-5. With a merge tolerance the absorbing
//! kernel differs from the CPU by the algorithms' own tolerance (the device merges where the
//! CPU also leaves out its weakest lines and applies them to first order, with other shares
//! of the budget: both stay within `merge_tolerance` of the unattenuated emission).
//!
//! **f32** (no `SHADER_F64` needed, and faster on GPUs with slow f64; the figures are in
//! the benchmark section of `gpu/README.md`): the parity tests state the tolerance against
//! the CPU image. With absorption the scheme is the CPU's, arranged so that f32 loses
//! nothing large:
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
//!   not against the remainder. Measured on lavapipe (`gpu/tests/doppler.rs`): worst
//!   `|gpu - cpu| / cpu` 1e-5 per pixel and channel (8e-6 banded 400, 3.6e-6 with absorption,
//!   9e-5 broadened with absorption), the absorbed light alone 1.3e-4 of itself, optically
//!   thick (x 1e4) 8.9e-6 of `cpu + unattenuated`; asserted 2e-3. f32 wavelengths resolve
//!   about 6e-5 nm at 656 nm: optical-depth profiles narrower than that (sigma below about
//!   0.1 km/s, or a sweep that narrow) are lost where the CPU and the f64 kernels keep them.
//!
//! With line broadening and absorption each line's sources (the trapezoid, or its up to 64
//! Gaussians of 32 pieces) are handled one at a time: an absorption line's sources are
//! merged into `tau_front` at half height, one merge pass each (between the two regions), and
//! what `tau_mid` takes from an emission line is integrated piece by piece of its sources
//! (the absorbed light is linear in the emission). The regions then have room for two
//! Gaussians a line (`cap + 66 n_abs + 8` pieces).
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
//! limiter is [`Error::Unsupported`] naming the loop limit (e.g. broadened H I + C I lines with
//! absorption on the 16^3 galaxy), as is a banded render (one pass) that spends it: never a
//! silently darker image. Hardware adapters have no such limiter.
//!
//! # What is refused
//! [`check_supported`] returns [`Error::Unsupported`] for more than [`MAX_SPECIES`] species;
//! the CLI's `--device auto` falls back to the CPU on it. Settings the CPU itself refuses
//! (broadening with a banded integrator, thermal broadening without a temperature field, a
//! bad sigma or mass) are [`Error::InvalidInput`] with the CPU's message. Picked spectra,
//! traces and spectral cubes stay on the CPU.

use blueshift_camera::{DeviceKind, Observer, Session, single_pass_done};
use blueshift_doppler::{
    BB_UNIT, BandShift, DopplerImage, DopplerScene, DopplerSession, DopplerSettings, LineEntry,
    LineKind, PieceStats, Prepared, PwlTables, SpectralIntegrator,
};
use blueshift_spectrum::RadiationConstants;
use bytemuck::{Pod, Zeroable};

use crate::context::{GpuContext, WORKGROUP_2D};
use crate::device::Unsupported;
use crate::error::{Error, Result};
use crate::pool::{DevicePool, PoolChannel};

/// WGSL of the Doppler pipeline.
pub const DOPPLER_WGSL: &str = concat!(
    include_str!("shaders/doppler.wgsl"),
    include_str!("shaders/pool.wgsl")
);

/// Prelude of the f32 kernels: the working float `fw` is f32.
const PRELUDE_F32: &str = "\
alias fw = f32;
const SERIES_Z: f32 = 1.0;
const FW_MAX: f32 = 3.0e38;
fn exp_fw(x: f32) -> f32 { return exp(x); }
fn expm1_fw(x: f32) -> f32 {
    if (x < 1e-3) { return x * (1.0 + 0.5 * x); }
    return exp(x) - 1.0;
}
fn ln_fw(x: f32) -> f32 { return log(x); }
fn u2w(u: u32) -> f32 { return bitcast<f32>(u); }
fn w2u(x: f32) -> u32 { return bitcast<u32>(x); }
";

/// Prelude of the f64 kernels: the working float `fw` is f64. SPIR-V's GLSL.std.450 `Exp`
/// takes 16- and 32-bit floats only, so `exp_fw` is written out: `x = k ln 2 + r` with
/// `|r| <= ln 2 / 2` (ln 2 split in two parts so `k ln 2` is exact), `exp(r) = 1 + r tail(r)`
/// with `tail(r) = sum_{j<14} r^j / (j + 1)!` (remainder < 1e-19 relative), times `2^k`
/// built from k's bits (exact; no `ldexp`, which not every shading language has for f64);
/// `expm1(x) = x tail(x)` below 0.25. Above 700 it returns `2 FW_MAX` (which every caller
/// reads as an overflow), below -708 zero. Measured through the kernels against the CPU's
/// f64 on lavapipe: 2e-14 per pixel (`gpu/tests/doppler.rs`).
const PRELUDE_F64: &str = "\
alias fw = f64;
const SERIES_Z: f64 = 0.05;
const FW_MAX: f64 = 1.0e300;
fn exp_tail(r: f64) -> f64 {
    var p: f64 = 1.0 / 87178291200.0;
    p = p * r + 1.0 / 6227020800.0;
    p = p * r + 1.0 / 479001600.0;
    p = p * r + 1.0 / 39916800.0;
    p = p * r + 1.0 / 3628800.0;
    p = p * r + 1.0 / 362880.0;
    p = p * r + 1.0 / 40320.0;
    p = p * r + 1.0 / 5040.0;
    p = p * r + 1.0 / 720.0;
    p = p * r + 1.0 / 120.0;
    p = p * r + 1.0 / 24.0;
    p = p * r + 1.0 / 6.0;
    p = p * r + 0.5;
    return p * r + 1.0;
}
// One factor of `pow2_fw`: `up` (2^bit) or `down` (its inverse) where the bit is set, else 1.
fn pow2_bit(a: u32, bit: u32, neg: bool, up: f64, down: f64) -> f64 {
    if ((a & bit) == 0u) { return 1.0; }
    if (neg) { return down; }
    return up;
}
// 2^k for |k| <= 1023, exactly, from the bits of |k| (straight-line: no loop).
fn pow2_fw(k: i32) -> f64 {
    let a = u32(abs(k));
    let neg = k < 0;
    var f: f64 = 1.0;
    f *= pow2_bit(a, 1u, neg, 2.0, 0.5);
    f *= pow2_bit(a, 2u, neg, 4.0, 0.25);
    f *= pow2_bit(a, 4u, neg, 16.0, 0.0625);
    f *= pow2_bit(a, 8u, neg, 256.0, 0.00390625);
    f *= pow2_bit(a, 16u, neg, 65536.0, 1.52587890625e-5);
    f *= pow2_bit(a, 32u, neg, 4294967296.0, 2.3283064365386963e-10);
    f *= pow2_bit(a, 64u, neg, 1.8446744073709552e19, 5.421010862427522e-20);
    f *= pow2_bit(a, 128u, neg, 3.402823669209385e38, 2.938735877055719e-39);
    f *= pow2_bit(a, 256u, neg, 1.157920892373162e77, 8.636168555094445e-78);
    f *= pow2_bit(a, 512u, neg, 1.3407807929942597e154, 7.458340731200207e-155);
    return f;
}
fn exp_fw(x: f64) -> f64 {
    // Past f64's range: a value planck's `den < FW_MAX` check reads as an overflow.
    if (x > 700.0) { return FW_MAX * 2.0; }
    if (x < -708.0) { return 0.0; }
    let k = floor(x * 1.4426950408889634 + 0.5);
    let r = (x - k * 0.6931471803691238) - k * 1.9082149292705877e-10;
    return (1.0 + r * exp_tail(r)) * pow2_fw(i32(k));
}
fn expm1_fw(x: f64) -> f64 {
    if (abs(x) < 0.25) { return x * exp_tail(x); }
    return exp_fw(x) - 1.0;
}
// ln for 1 <= x <= 1e31: f32's log, then two Newton steps on exp (full f64 precision).
fn ln_fw(x: f64) -> f64 {
    var y = f64(log(f32(x)));
    y = y - 1.0 + x * exp_fw(-y);
    y = y - 1.0 + x * exp_fw(-y);
    return y;
}
fn u2w(u: u32) -> f64 { return f64(u); }
fn w2u(x: f64) -> u32 { return u32(x); }
";

/// The WGSL of the Doppler kernels with working precision f64 (`double`) or f32: a prelude
/// defining the working float `fw` and its helpers, the loop-limiter probe
/// ([`crate::LIMITER_WGSL`]), then [`DOPPLER_WGSL`].
pub fn shader_source(double: bool) -> String {
    let prelude = if double { PRELUDE_F64 } else { PRELUDE_F32 };
    format!("{prelude}\n{}{DOPPLER_WGSL}", crate::LIMITER_WGSL)
}

/// The working precision of the Doppler kernels (everything after the volume samples, which
/// are f32 as on the CPU: shifts, lines, black bodies, pieces, integrals and sums).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DopplerPrecision {
    /// f64 where the adapter has `SHADER_F64`, else f32 (the rule: double precision
    /// where the adapter offers it).
    #[default]
    Auto,
    /// f32 everywhere: fastest on GPUs with slow f64 (most consumer cards run f64 at 1/32 to
    /// 1/64 of the f32 rate); its error against the CPU is measured in the tests and stated in
    /// the module docs.
    F32,
    /// f64 after the samples (which are f32 as on the CPU): agrees with the CPU to rounding
    /// where both run the same algorithm (2e-14 per pixel measured on lavapipe); needs
    /// `SHADER_F64`.
    F64,
}

impl DopplerPrecision {
    /// Parses `auto`, `f32` or `f64`.
    ///
    /// # Errors
    /// [`Error::InvalidInput`] naming the accepted values.
    pub fn parse(text: &str) -> Result<Self> {
        match text.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(Self::Auto),
            "f32" | "single" => Ok(Self::F32),
            "f64" | "double" => Ok(Self::F64),
            other => Err(Error::InvalidInput(format!(
                "GPU precision '{other}': use auto, f32 or f64"
            ))),
        }
    }

    /// Whether the kernels run in f64 on `ctx`.
    ///
    /// # Errors
    /// [`Error::Unsupported`] for [`DopplerPrecision::F64`] without `SHADER_F64`.
    pub fn is_double_on(self, ctx: &GpuContext) -> Result<bool> {
        match self {
            Self::Auto => Ok(ctx.has_f64()),
            Self::F32 => Ok(false),
            Self::F64 if ctx.has_f64() => Ok(true),
            Self::F64 => Err(Error::Unsupported(format!(
                "f64 Doppler kernels: the adapter '{}' has no SHADER_F64 (use f32 or auto)",
                ctx.info().name
            ))),
        }
    }
}

/// The kernels' per-pixel output (X, Y, Z, flags) in f64.
fn read_out(ctx: &GpuContext, buf: &wgpu::Buffer, n: usize, double: bool) -> Result<Vec<[f64; 4]>> {
    if double {
        ctx.read_buffer::<[f64; 4]>(buf, n)
    } else {
        Ok(ctx
            .read_buffer::<[f32; 4]>(buf, n)?
            .iter()
            .map(|p| p.map(f64::from))
            .collect())
    }
}

impl std::str::FromStr for DopplerPrecision {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        Self::parse(s)
    }
}

impl std::fmt::Display for DopplerPrecision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Auto => "auto",
            Self::F32 => "f32",
            Self::F64 => "f64",
        })
    }
}

/// Whether `entry` runs in f64 on `ctx`: as [`DopplerPrecision::is_double_on`], except that
/// `Auto` takes f32 when the f64 kernel does not compile for the adapter's backend (a shading
/// language without some f64 operation); a forced `F64` reports that error.
fn working_precision(ctx: &GpuContext, precision: DopplerPrecision, entry: &str) -> Result<bool> {
    let double = precision.is_double_on(ctx)?;
    if double && precision == DopplerPrecision::Auto {
        return Ok(ctx
            .compute_pipeline("doppler", &shader_source(true), entry)
            .is_ok());
    }
    Ok(double)
}

/// Bytes of a working float.
fn fw_bytes(double: bool) -> u64 {
    if double { 8 } else { 4 }
}

/// Host data for a working-float storage buffer (built in f64, uploaded as the kernel reads it).
enum FwData {
    F32(Vec<f32>),
    F64(Vec<f64>),
}

impl FwData {
    fn new(values: &[f64], double: bool) -> Self {
        if double {
            Self::F64(values.to_vec())
        } else {
            Self::F32(values.iter().map(|&v| v as f32).collect())
        }
    }

    fn upload(&self, ctx: &GpuContext, label: &str) -> Result<wgpu::Buffer> {
        match self {
            Self::F32(v) => ctx.storage_buffer(label, v),
            Self::F64(v) => ctx.storage_buffer(label, v),
        }
    }
}

/// Most species the device kernel holds per ray.
pub const MAX_SPECIES: usize = 8;

/// Pieces of the optical depth in front (`tau_front`) a ray has on the device in the first
/// round with absorption (piecewise-linear integrator): `min(piece_budget, DEVICE_PIECE_CAP)`.
/// With a larger `piece_budget`, rays that needed the fallback at the cap run again with the
/// whole budget, so the fallback ([`PieceStats::fallback_rays`]) is the CPU's.
pub const DEVICE_PIECE_CAP: usize = 1024;

/// Most pieces per ray a rerun at the CPU's budget keeps (larger budgets are held to it).
const MAX_RERUN_BUDGET: usize = 1 << 20;

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
    double: bool,
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
        limited: impl Fn(&[f64; 4]) -> bool,
    ) -> Result<Vec<[f64; 4]>> {
        let (mut budget, _) = iteration_limits(ctx);
        loop {
            params.iter_budget = budget;
            let mut out: Vec<[f64; 4]> = Vec::new();
            for pass in 0.. {
                params.pass_index = to_u32("pass", pass)?;
                ctx.write_buffer(self.params, std::slice::from_ref(params))?;
                ctx.dispatch(self.pipeline, self.bind_group, self.groups)?;
                out = read_out(ctx, self.out, self.n_pix, self.double)?;
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
    vel_factor: f32,
    off_pf: u32,
    cmf_n: u32,
    bb_k: u32,
    shift_mode: u32,
    off_lambda: u32,
    off_hat: u32,
    n_bands: u32,
    off_band_w: u32,
    off_band_c: u32,
    n_abs: u32,
    absorbing: u32,
    pix_offset: u32,
    n_pix: u32,
    piece_cap: u32,
    region_l: u32,
    stride: u32,
    pass_index: u32,
    iter_budget: u32,
    iter_limit: u32,
    broaden: u32,
    off_kom: u32,
    off_gauss: u32,
    n_gauss: u32,
    probe_n: u32,
    g_origin: [f32; 3],
    g_spacing: [f32; 3],
    pad0: u32,
    pad1: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PixelRay {
    origin: [f32; 3],
    t0: f32,
    dir: [f32; 3],
    len: f32,
    los: [f32; 3],
    n_seg: u32,
}

/// [`crate::layout::pod_layouts`] of this module: `Params` and `PixelRay` hold no working
/// float, so both precisions lay them out alike; each is checked.
pub(crate) fn pod_layouts() -> Vec<crate::layout::PodLayout> {
    use crate::layout::pod_layout;
    let mut out = Vec::new();
    for (double, shader) in [
        (false, "doppler.wgsl (f32 prelude)"),
        (true, "doppler.wgsl (f64 prelude)"),
    ] {
        let src = shader_source(double);
        out.push(pod_layout!(Params => "Params", shader, &src, {
            nx, ny, nz, nvox, nsp, n_lines, has_bb, has_vel, model, invariant, width, height,
            step, vel_factor, off_pf, cmf_n, bb_k, shift_mode, off_lambda, off_hat, n_bands,
            off_band_w, off_band_c, n_abs, absorbing, pix_offset, n_pix, piece_cap, region_l,
            stride, pass_index, iter_budget, iter_limit, broaden, off_kom, off_gauss, n_gauss,
            probe_n,
            g_origin as "g_origin_x", g_origin as "g_origin_y" + 4, g_origin as "g_origin_z" + 8,
            g_spacing as "g_spacing_x", g_spacing as "g_spacing_y" + 4,
            g_spacing as "g_spacing_z" + 8,
            pad0, pad1,
        }));
        out.push(pod_layout!(PixelRay => "PixelRay", shader, &src, {
            origin, t0, dir, len, los, n_seg,
        }));
    }
    out
}

fn doppler_err(e: blueshift_doppler::Error) -> Error {
    Error::InvalidInput(e.to_string())
}

/// `Ok` when the GPU integrator covers `scene` + `settings`, else why not (more than
/// [`MAX_SPECIES`] species). Settings the CPU refuses are not this function's business:
/// [`Prepared::new`] refuses them, with the CPU's messages, on both devices.
pub fn supports(
    scene: &DopplerScene,
    settings: &DopplerSettings,
) -> std::result::Result<(), Unsupported> {
    if settings.observer.is_some_and(|o| !o.is_at_rest()) {
        return Err(Unsupported(
            "a moving observer (aberration and its Doppler factor are CPU-only)".into(),
        ));
    }
    crate::pool::per_brick_unsupported(scene.fields().into_iter())?;
    if scene.species().len() > MAX_SPECIES {
        return Err(Unsupported(format!(
            "{} species (at most {MAX_SPECIES} on the GPU)",
            scene.species().len()
        )));
    }
    Ok(())
}

/// `Ok` when the GPU integrator covers `scene` + `settings`: the settings validated and
/// prepared as on the CPU ([`Error::InvalidInput`] with the CPU's message), then
/// [`supports`] ([`Error::Unsupported`]).
pub fn check_supported(scene: &DopplerScene, settings: &DopplerSettings) -> Result<()> {
    Prepared::new(scene, settings).map_err(doppler_err)?;
    Ok(supports(scene, settings)?)
}

fn to_u32(what: &str, n: usize) -> Result<u32> {
    u32::try_from(n).map_err(|_| Error::InvalidInput(format!("{what} {n} exceeds u32")))
}

/// The rays of every pixel, as the CPU samples them ([`Prepared::pixel_ray`]).
fn pixel_rays(prep: &Prepared, scene: &DopplerScene, settings: &DopplerSettings) -> Vec<PixelRay> {
    let (w, h) = (settings.width, settings.height);
    let mut out = Vec::with_capacity(w as usize * h as usize);
    for y in 0..h {
        for x in 0..w {
            let mut pr = PixelRay::zeroed();
            if let (ray, Some(span)) = prep.pixel_ray(scene, settings, x, y) {
                // The kernel samples world_to_index(origin + dir (t0 + t)), as the CPU.
                pr.n_seg = span.n_seg;
                pr.len = span.len;
                pr.origin = ray.origin.to_array();
                pr.t0 = span.t0;
                pr.dir = ray.dir.to_array();
                pr.los = ray.dir.normalize().to_array();
            }
            out.push(pr);
        }
    }
    out
}

/// Renders the XYZ image of `scene` on the GPU with `settings.integrator` (piecewise linear
/// or banded): the same image as `blueshift_doppler::render_doppler`, in f64 where
/// the adapter has `SHADER_F64` and in f32 elsewhere ([`DopplerPrecision::Auto`]; see the
/// module docs for the tolerances and what is supported). The piece statistics are those of
/// `tau_front` with absorption (piecewise linear), zero otherwise, as on the CPU.
pub fn render_doppler_gpu(
    ctx: &GpuContext,
    scene: &DopplerScene,
    settings: &DopplerSettings,
) -> Result<DopplerImage> {
    render_doppler_gpu_with(ctx, scene, settings, DopplerPrecision::Auto)
}

/// [`render_doppler_gpu`] in the working precision `precision` (see [`DopplerPrecision`]).
///
/// # Errors
/// As [`render_doppler_gpu`]; [`Error::Unsupported`] for [`DopplerPrecision::F64`] on an
/// adapter without `SHADER_F64`.
pub fn render_doppler_gpu_with(
    ctx: &GpuContext,
    scene: &DopplerScene,
    settings: &DopplerSettings,
    precision: DopplerPrecision,
) -> Result<DopplerImage> {
    render_doppler_gpu_pooled(ctx, scene, settings, precision).map(|(img, _)| img)
}

/// [`render_doppler_gpu_with`], also saying what the device brick pool held
/// ([`crate::pool`]). A scene whose non-constant bricks exceed the pool fails with the
/// pool's [`Error::LimitExceeded`] ([`crate::pool::is_pool_full`]): a coarser level of
/// detail (`DopplerScene::at_level`) may fit.
pub fn render_doppler_gpu_pooled(
    ctx: &GpuContext,
    scene: &DopplerScene,
    settings: &DopplerSettings,
    precision: DopplerPrecision,
) -> Result<(DopplerImage, crate::pool::PoolStats)> {
    let prep = Prepared::new(scene, settings).map_err(doppler_err)?;
    render_prepared(ctx, scene, settings, &prep, precision, &mut None)
}

/// Progressive levels of detail on the GPU for a scene whose fields are all bricked alike
/// (given at level 0), as `blueshift_doppler::render_doppler_lod` (`bricks` false) or
/// `render_doppler_bricks` (`bricks` true) run them on the CPU, the same passes and
/// observer calls: every image is rendered on the device from one brick pool, a view of
/// it per pass ([`crate::pool::DevicePool::update`]), so a pass uploads only the bricks it
/// adds and the bricks of earlier passes stay while the pool has room. Returns the last
/// image (at `target`) and what the pool held for it.
///
/// # Errors
/// As the CPU's progressive renders and [`render_doppler_gpu_pooled`] (a view whose bricks
/// exceed the pool is the pool's [`Error::LimitExceeded`]).
#[allow(clippy::too_many_arguments)]
pub fn render_doppler_gpu_progressive(
    ctx: &GpuContext,
    scene: &DopplerScene,
    settings: &DopplerSettings,
    target: usize,
    bricks: bool,
    observer: &dyn Observer<DopplerImage>,
    on_step: &mut dyn FnMut(u32, usize, usize),
    precision: DopplerPrecision,
) -> Result<(DopplerImage, crate::pool::PoolStats)> {
    let mut held: Option<DevicePool> = None;
    let mut stats = crate::pool::PoolStats::default();
    let mut image = |s: &DopplerScene| -> Result<DopplerImage> {
        if observer.cancelled() {
            return Err(Error::Cancelled);
        }
        // One level per region for every field (per-field resident views differ while
        // bricks load): what one pool lookup serves.
        let s = &s.shared_regions().map_err(doppler_err)?;
        let prep = Prepared::new(s, settings).map_err(doppler_err)?;
        let (img, st) = render_prepared(ctx, s, settings, &prep, precision, &mut held)?;
        stats = st;
        Ok(img)
    };
    let img = if bricks {
        blueshift_doppler::render_doppler_bricks_with(
            scene, settings, target, observer, on_step, &mut image,
        )?
    } else {
        blueshift_doppler::render_doppler_lod_with(scene, settings, target, observer, &mut image)?
    };
    Ok((img, stats))
}

/// [`render_doppler_gpu_with`] over tables prepared for `scene` and `settings`.
fn render_prepared(
    ctx: &GpuContext,
    scene: &DopplerScene,
    settings: &DopplerSettings,
    prep: &Prepared,
    precision: DopplerPrecision,
    held: &mut Option<DevicePool>,
) -> Result<(DopplerImage, crate::pool::PoolStats)> {
    supports(scene, settings)?;
    let entry = match (settings.integrator, prep.absorbing()) {
        (SpectralIntegrator::Banded { .. }, _) => "main_banded",
        (SpectralIntegrator::PiecewiseLinear, true) => "main_absorb",
        (SpectralIntegrator::PiecewiseLinear, false) => "main",
    };
    let double = working_precision(ctx, precision, entry)?;
    let step = prep.step();
    let g = scene.geometry();
    let [nx, ny, nz] = g.dims;
    let nvox = g.voxel_count();
    let f = scene.factors;
    let nsp = scene.species().len();
    let bb = scene.blackbody();
    let n_channels = nsp + if bb.is_some() { 3 } else { 0 };
    ctx.check_storage_size(
        "doppler rays",
        u64::from(settings.width) * u64::from(settings.height) * 48,
    )?;
    // The device brick pool: the velocity's three components, then the scalar channels
    // (species densities; the black body's density, temperature (thermal broadening) and
    // density x Planck factor, as the CPU's).
    let mut channels: Vec<PoolChannel<'_>> = match scene.velocity() {
        Some(v) => (0..3).map(|a| PoolChannel::Component(v, a)).collect(),
        None => vec![PoolChannel::Zero; 3],
    };
    for sp in scene.species() {
        channels.push(PoolChannel::Scalar(&sp.density));
    }
    if let (Some((d, t)), Some(rho_t)) = (bb, scene.blackbody_rho_t()) {
        channels.extend([d, t, rho_t].map(PoolChannel::Scalar));
    }
    debug_assert_eq!(channels.len(), 3 + n_channels);
    // A pool held from an earlier view of the same fields (a progressive render) keeps
    // its bricks and uploads only the missing ones.
    let pool: &DevicePool = match held {
        Some(p) => {
            p.update(ctx, "doppler volume", &channels)?;
            p
        }
        None => held.insert(crate::pool::upload(ctx, "doppler volume", &channels)?),
    };
    drop(channels);
    let (a, b) = settings.range_nm;
    let n_bands = match settings.integrator {
        SpectralIntegrator::PiecewiseLinear => 0,
        SpectralIntegrator::Banded { bands, .. } => bands,
    };
    let absorbs = prep.absorbing();
    let pwl_absorbs = absorbs && n_bands == 0;
    // Emission entries, then (banded with absorption) absorption entries: the lines, or with
    // the nearest shift the CPU's rest-frame band values.
    let to_row = |e: LineEntry| [e.centre_nm, e.strength, e.species as f64, 0.0];
    let mut lines: Vec<[f64; 4]> = prep
        .line_entries(scene, LineKind::Emission)
        .into_iter()
        .map(to_row)
        .collect();
    let n_lines = lines.len();
    if absorbs {
        lines.extend(
            prep.line_entries(scene, LineKind::Absorption)
                .into_iter()
                .map(to_row),
        );
    }
    let n_abs = lines.len() - n_lines;
    if lines.is_empty() {
        lines.push([0.0; 4]);
    }
    // Tables: the CMFs, the black-body grid and its hat functions' XYZ (the CPU's PwlTables;
    // the banded kernels read the CMF table too).
    let own;
    let pt = match prep.pwl_tables() {
        Some(t) => t,
        None => {
            own = PwlTables::new(settings);
            &own
        }
    };
    let mut tables: Vec<f64> = Vec::new();
    let cmf_n = pt.cmf.len();
    tables.extend(pt.cmf.iter().flatten().copied());
    let (c_lo, cmf_step) = (pt.cmf_lo, pt.cmf_step);
    let k = pt.lambdas.len();
    let off_lambda = tables.len();
    tables.extend(pt.lambdas.iter().copied());
    let off_hat = tables.len();
    tables.extend(pt.hat_xyz.iter().flat_map(|x| x.to_array()));
    // Banded: per-band CMF integrals and band centres (the CPU's BandTables).
    let off_band_w = tables.len();
    if let Some(bt) = prep.band_tables() {
        ctx.check_storage_size(
            "doppler tables",
            (tables.len() + 4 * n_bands) as u64 * fw_bytes(double),
        )?;
        tables.extend(bt.weights().per_band().iter().flatten().copied());
    }
    let off_band_c = tables.len();
    if let Some(bt) = prep.band_tables() {
        tables.extend(bt.centres().iter().copied());
    }
    // Broadening: k / m per species, then the unit Gaussian's knots (x, then g).
    let off_kom = tables.len();
    tables.extend(prep.profiles().k_over_m.iter().copied());
    let off_gauss = tables.len();
    let (mut gx, mut gg) = (Vec::<f64>::new(), Vec::<f64>::new());
    let _ = prep
        .profiles()
        .gauss
        .for_each_piece(0.0, 1.0, 1.0, |lo, hi, v0, v1| {
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
        tables.extend(v.iter().copied());
    }
    let (c1l, c2) = RadiationConstants::Codata.values();
    // The working-precision parameters (the shader's `PFw`, in its order).
    let off_pf = tables.len();
    tables.extend([
        a,
        b,
        settings.line_width_nm,
        c_lo,
        cmf_step,
        // B per nm with lambda in nm: c1L * 1e45 (lambda^5) * 1e-9 (per nm).
        c1l * 1e36,
        c2 * 1e9,
        f.temperature,
        f.blackbody * BB_UNIT,
        (b - a) / n_bands.max(1) as f64,
        settings.merge_tolerance,
        settings.broadening.sigma_m_per_s * settings.broadening.sigma_m_per_s,
    ]);
    let rays = pixel_rays(prep, scene, settings);
    let params = Params {
        nx: to_u32("dims", nx)?,
        ny: to_u32("dims", ny)?,
        nz: to_u32("dims", nz)?,
        // Unused by the kernels since the brick pool (kept for the struct's layout).
        nvox: u32::try_from(nvox).unwrap_or(u32::MAX),
        nsp: to_u32("species", nsp)?,
        n_lines: to_u32("lines", n_lines)?,
        has_bb: u32::from(bb.is_some()),
        has_vel: u32::from(scene.velocity().is_some()),
        model: u32::from(settings.model == blueshift_spectrum::DopplerModel::Relativistic),
        invariant: u32::from(settings.invariant),
        width: settings.width,
        height: settings.height,
        step,
        vel_factor: f.velocity as f32,
        off_pf: to_u32("table offset", off_pf)?,
        cmf_n: to_u32("CMF samples", cmf_n)?,
        bb_k: to_u32("black-body samples", k)?,
        shift_mode: u32::from(matches!(
            settings.integrator,
            SpectralIntegrator::Banded {
                shift: BandShift::EnergyConserving,
                ..
            }
        )),
        off_lambda: to_u32("table offset", off_lambda)?,
        off_hat: to_u32("table offset", off_hat)?,
        n_bands: to_u32("bands", n_bands)?,
        off_band_w: to_u32("table offset", off_band_w)?,
        off_band_c: to_u32("table offset", off_band_c)?,
        n_abs: to_u32("absorption lines", n_abs)?,
        absorbing: u32::from(absorbs),
        pix_offset: 0,
        n_pix: 0,
        piece_cap: 0,
        region_l: 0,
        stride: 0,
        pass_index: 0,
        iter_budget: 0,
        iter_limit: 0,
        broaden: u32::from(!settings.broadening.is_none()),
        off_kom: to_u32("table offset", off_kom)?,
        off_gauss: to_u32("table offset", off_gauss)?,
        n_gauss: to_u32("Gaussian knots", n_gauss)?,
        probe_n: 2,
        g_origin: g.origin.to_array(),
        g_spacing: g.spacing.to_array(),
        pad0: 0,
        pad1: 0,
    };
    let tables = FwData::new(&tables, double);
    let lines_fw = FwData::new(lines.as_flattened(), double);
    if pwl_absorbs {
        let bufs = Bufs {
            rays: &rays,
            pool,
            tables: &tables,
            lines: &lines_fw,
            double,
        };
        return render_absorbing(ctx, settings, params, &bufs, n_abs).map(|img| (img, pool.stats));
    }
    let pipeline = ctx.compute_pipeline("doppler", &shader_source(double), entry)?;
    let rb = ctx.storage_buffer("doppler rays", &rays)?;
    let (cb, vb) = (&pool.pool, &pool.pages);
    let tb = tables.upload(ctx, "doppler tables")?;
    let lb = lines_fw.upload(ctx, "doppler lines")?;
    let n_pix = rays.len();
    let ob = ctx.storage_buffer_zeroed("doppler xyz", n_pix as u64 * 4 * fw_bytes(double))?;
    let pb = ctx.uniform_buffer("doppler params", &params)?;
    let gx = ctx.groups("doppler", settings.width, WORKGROUP_2D)?;
    let gy = ctx.groups("doppler", settings.height, WORKGROUP_2D)?;
    if n_bands > 0 {
        // The per-ray band values when absorbing (n_bands per pixel), else a placeholder.
        let bytes = if absorbs {
            n_pix as u64 * n_bands as u64 * fw_bytes(double)
        } else {
            16
        };
        ctx.check_storage_size("doppler band values (pixels x bands)", bytes)?;
        let sb = ctx.storage_buffer_zeroed("doppler band values", bytes)?;
        let bg = ctx.bind_group(&pipeline, 0, &[&rb, cb, vb, &tb, &lb, &ob, &pb, &sb])?;
        let mut params = params;
        (_, params.iter_limit) = iteration_limits(ctx);
        ctx.write_buffer(&pb, std::slice::from_ref(&params))?;
        ctx.dispatch(&pipeline, &bg, [gx, gy, 1])?;
    } else {
        // The piecewise-linear kernel runs in passes (see `iteration_limits`), keeping 20
        // working floats of state per pixel.
        let bytes = n_pix as u64 * 20 * fw_bytes(double);
        ctx.check_storage_size("doppler ray state (pixels x 20 floats)", bytes)?;
        let sb = ctx.storage_buffer_zeroed("doppler ray state", bytes)?;
        let bg = ctx.bind_group(&pipeline, 0, &[&rb, cb, vb, &tb, &lb, &ob, &pb, &sb])?;
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
            double,
        };
        passes.run(ctx, &mut params, 0..n_pix, |p| p[3] == 2.0)?;
    }
    let out = read_out(ctx, &ob, n_pix, double)?;
    if let Some(i) = out.iter().position(|p| p[3] == 2.0) {
        return Err(Error::Unsupported(format!(
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
    let img = DopplerImage {
        width: settings.width,
        height: settings.height,
        xyz: out.iter().map(|p| [p[0], p[1], p[2]]).collect(),
        pieces: PieceStats::default(),
    };
    Ok((img, pool.stats))
}

/// Host data of the Doppler pipeline.
struct Bufs<'a> {
    rays: &'a [PixelRay],
    /// The device brick pool of the velocity and scalar channels.
    pool: &'a DevicePool,
    tables: &'a FwData,
    lines: &'a FwData,
    /// Whether the kernels run in f64.
    double: bool,
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
/// sum), 16 bytes per piece (f32; [`absorption_layout_fw`] gives f64's 32). A tile holds as
/// many rays as fit in the smallest of `max_storage_buffer_binding_size`, `max_buffer_size`
/// and [`TILE_BYTES_CAP`].
///
/// # Errors
/// [`Error::LimitExceeded`] naming the limit when not even one ray fits.
pub fn absorption_layout(
    settings: &DopplerSettings,
    n_abs: usize,
    limits: &wgpu::Limits,
) -> Result<(usize, u64, u64)> {
    absorption_layout_fw(settings, n_abs, limits, false)
}

/// [`absorption_layout`] with f64 pieces (32 bytes a piece) when `double`.
pub fn absorption_layout_fw(
    settings: &DopplerSettings,
    n_abs: usize,
    limits: &wgpu::Limits,
    double: bool,
) -> Result<(usize, u64, u64)> {
    let cap = settings.piece_budget.min(DEVICE_PIECE_CAP);
    let (per_ray, tile) = tile_layout(cap, n_abs, !settings.broadening.is_none(), limits, double)?;
    Ok((cap, per_ray, tile))
}

/// `(bytes per ray, rays per tile)` for `cap` pieces of `tau_front` per ray.
fn tile_layout(
    cap: usize,
    n_abs: usize,
    broaden: bool,
    limits: &wgpu::Limits,
    double: bool,
) -> Result<(u64, u64)> {
    let (_, floats) = region_floats(cap, n_abs, broaden);
    let per_ray = floats as u64 * fw_bytes(double);
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
    Ok((per_ray, tile))
}

/// The piecewise-linear integrator with absorption: the front-to-back pass per ray, in
/// tiles of pixels (see [`absorption_layout`]). Rays run with the device cap first
/// (`min(piece_budget, DEVICE_PIECE_CAP)` pieces: large tiles); where the budget is larger
/// and a ray needed the cap's fallback, that ray runs again with the CPU's own budget (as
/// many pieces as fit the storage limits), so the fallback is the CPU's.
fn render_absorbing(
    ctx: &GpuContext,
    settings: &DopplerSettings,
    params: Params,
    b: &Bufs<'_>,
    n_abs: usize,
) -> Result<DopplerImage> {
    let n_pix = settings.width as usize * settings.height as usize;
    let dev = DeviceData {
        pipeline: ctx.compute_pipeline(
            "doppler absorption",
            &shader_source(b.double),
            "main_absorb",
        )?,
        pool: b.pool.pool.clone(),
        pages: b.pool.pages.clone(),
        tables: b.tables.upload(ctx, "doppler tables")?,
        lines: b.lines.upload(ctx, "doppler lines")?,
    };
    let cap = settings.piece_budget.min(DEVICE_PIECE_CAP);
    let mut out = absorb_rays(ctx, settings, params, b, &dev, b.rays, cap, n_abs)?;
    if cap < settings.piece_budget {
        // Rays that fell back (bit 2) at the device cap, with no error: again at the budget.
        let again: Vec<usize> = (0..n_pix)
            .filter(|&i| {
                let f = out[i][3] as u32;
                f & 2 != 0 && f & 13 == 0
            })
            .collect();
        if !again.is_empty() {
            let rays: Vec<PixelRay> = again.iter().map(|&i| b.rays[i]).collect();
            let budget = settings.piece_budget.min(MAX_RERUN_BUDGET);
            match absorb_rays(ctx, settings, params, b, &dev, &rays, budget, n_abs) {
                Ok(o) => {
                    for (k, &i) in again.iter().enumerate() {
                        out[i] = o[k];
                    }
                }
                // A budget beyond the storage limits keeps the capped result (its fallback
                // counted in PieceStats), as a budget the device cannot hold.
                Err(Error::LimitExceeded { .. }) => {}
                Err(e) => return Err(e),
            }
        }
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
            return Err(Error::Unsupported(format!(
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
        xyz.push([p[0], p[1], p[2]]);
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

/// Device buffers shared by the passes of [`render_absorbing`].
struct DeviceData {
    pipeline: wgpu::ComputePipeline,
    pool: wgpu::Buffer,
    pages: wgpu::Buffer,
    tables: wgpu::Buffer,
    lines: wgpu::Buffer,
}

/// Runs the absorbing kernel on `rays` with `cap` pieces of `tau_front` per ray, in tiles;
/// returns per ray (X, Y, Z, flags).
#[allow(clippy::too_many_arguments)]
fn absorb_rays(
    ctx: &GpuContext,
    settings: &DopplerSettings,
    mut params: Params,
    b: &Bufs<'_>,
    dev: &DeviceData,
    rays: &[PixelRay],
    cap: usize,
    n_abs: usize,
) -> Result<Vec<[f64; 4]>> {
    let n = rays.len();
    let broaden = !settings.broadening.is_none();
    let (per_ray, tile) = tile_layout(cap, n_abs, broaden, &ctx.device().limits(), b.double)?;
    let (l, floats) = region_floats(cap, n_abs, broaden);
    let tile = (tile as usize).min(n).max(1);
    params.piece_cap = to_u32("piece cap", cap)?;
    params.region_l = to_u32("piece region", l)?;
    params.stride = to_u32("piece stride", floats)?;
    params.n_pix = to_u32("pixels", n)?;
    let rb = ctx.storage_buffer("doppler rays", rays)?;
    let ob = ctx.storage_buffer_zeroed("doppler xyz", n as u64 * 4 * fw_bytes(b.double))?;
    let pb = ctx.uniform_buffer("doppler params", &params)?;
    let sb = ctx.storage_buffer_zeroed("doppler absorption pieces", tile as u64 * per_ray)?;
    let bg = ctx.bind_group(
        &dev.pipeline,
        0,
        &[
            &rb,
            &dev.pool,
            &dev.pages,
            &dev.tables,
            &dev.lines,
            &ob,
            &pb,
            &sb,
        ],
    )?;
    // Software adapters (lavapipe) stop all loops of an invocation after 65535 iterations in
    // all (llvmpipe's loop limiter): the kernel counts its iterations and yields at the
    // budget, the host dispatches passes until every ray of the tile is done. Hardware
    // adapters have no such limit; their passes are long.
    (_, params.iter_limit) = iteration_limits(ctx);
    let max_seg = rays.iter().map(|r| r.n_seg).max().unwrap_or(0) as usize;
    let mut start = 0usize;
    let mut out: Vec<[f64; 4]> = Vec::new();
    while start < n {
        let count = tile.min(n - start);
        params.pix_offset = to_u32("pixel offset", start)?;
        let gx = ctx.groups("doppler absorption", to_u32("tile", count)?, 64)?;
        let passes = Passes {
            pipeline: &dev.pipeline,
            bind_group: &bg,
            params: &pb,
            out: &ob,
            groups: [gx, 1, 1],
            n_pix: n,
            max_seg,
            double: b.double,
        };
        out = passes.run(ctx, &mut params, start..start + count, |p| {
            p[3] >= 0.0 && (p[3] as u32) & 8 != 0
        })?;
        start += count;
    }
    Ok(out)
}

/// A Doppler render session on a GPU: the CPU's [`DopplerSession`] (scene, settings and
/// their [`Prepared`] tables, shared with the CPU integrators) rendered by the GPU kernels
/// in the working precision `precision`; picks, traces and cubes run on the CPU session.
///
/// The device brick pool is kept across renders (a device brick cache,
/// [`crate::pool::DevicePool::update`]): a render after a camera or factor edit uploads no
/// brick of a `.bsv` field again; fields in memory are uploaded per render.
#[derive(Debug)]
pub struct GpuDopplerSession<'c> {
    ctx: &'c GpuContext,
    cpu: DopplerSession,
    precision: DopplerPrecision,
    pool: std::sync::Mutex<Option<DevicePool>>,
}

impl<'c> GpuDopplerSession<'c> {
    /// Prepares `scene` + `settings` as the CPU does and checks that the GPU supports them.
    ///
    /// # Errors
    /// [`Error::InvalidInput`] with the CPU's message; [`Error::Unsupported`] (see
    /// [`supports`]); [`Error::Unsupported`] for [`DopplerPrecision::F64`] without
    /// `SHADER_F64`.
    pub fn new(
        ctx: &'c GpuContext,
        scene: DopplerScene,
        settings: DopplerSettings,
        precision: DopplerPrecision,
    ) -> Result<Self> {
        supports(&scene, &settings)?;
        precision.is_double_on(ctx)?;
        let cpu = DopplerSession::new(scene, settings).map_err(doppler_err)?;
        Ok(Self {
            ctx,
            cpu,
            precision,
            pool: std::sync::Mutex::new(None),
        })
    }

    /// What the device brick pool held for the last render (`None` before the first).
    #[must_use]
    pub fn pool_stats(&self) -> Option<crate::pool::PoolStats> {
        self.pool
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .as_ref()
            .map(|p| p.stats)
    }

    /// The CPU session (scene, settings, prepared tables; picks and traces).
    #[must_use]
    pub fn cpu(&self) -> &DopplerSession {
        &self.cpu
    }

    /// The CPU session, for edits (camera, factors, settings): the next render uses them.
    pub fn cpu_mut(&mut self) -> &mut DopplerSession {
        &mut self.cpu
    }

    /// Renders the XYZ image on the GPU (cancel is polled before the dispatches start).
    ///
    /// # Errors
    /// As [`render_doppler_gpu_with`]; [`Error::Cancelled`].
    pub fn render(&self, observer: &dyn Observer<DopplerImage>) -> Result<DopplerImage> {
        if observer.cancelled() {
            return Err(Error::Cancelled);
        }
        let img = render_prepared(
            self.ctx,
            self.cpu.scene(),
            self.cpu.settings(),
            self.cpu.prepared(),
            self.precision,
            &mut self
                .pool
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner),
        )?
        .0;
        single_pass_done(observer, u64::from(img.height), &img);
        Ok(img)
    }
}

impl Session for GpuDopplerSession<'_> {
    type Image = DopplerImage;
    type Output = DopplerImage;
    type Error = Error;

    fn run(&mut self, observer: &dyn Observer<DopplerImage>) -> Result<DopplerImage> {
        self.render(observer)
    }

    fn device(&self) -> DeviceKind {
        DeviceKind::Gpu
    }
}
