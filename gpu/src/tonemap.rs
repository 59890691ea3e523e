//! Tone mapping on the GPU, mirroring [`blueshift_tonemap::Operator::apply`] with the same
//! parameter structs.
//!
//! What runs where:
//! - The dirty-input rule ([`blueshift_tonemap::CleanImage`]: NaN / negative / Inf
//!   handling, luminance plane) and the image statistics of the global curves (log-average,
//!   maximum) are computed on the CPU by the tonemap crate itself, so both backends see
//!   exactly the same cleaned image and constants.
//! - Global operators (Linear, Drago, Reinhard): the per-pixel curve and recolouring run in
//!   one GPU pass (`shaders/tonemap_global.wgsl`), f32 arithmetic like the CPU.
//! - Durand & Dorsey: the fast bilateral filter runs on the GPU in the CPU's scheme (splat
//!   into a down-sampled grid of intensity levels, separable Gaussian blur of every level,
//!   slice), then the base max (GPU per-row reduction, host fold) and the base's low end
//!   (its 1st percentile over lit pixels, on the host with the tonemap crate's percentile
//!   function, the base read back), then the base compression and the recolouring on the
//!   GPU.
//! - Reinhard local: the key scaling on the CPU (log-average), then the n + 1 Gaussian
//!   blurs (separable, the CPU's kernels), the scale selection (Eq. 7-9) and the
//!   recolouring on the GPU.
//! - Fattal: the attenuation Phi (Gaussian pyramid, Eq. 8) on the CPU with the tonemap
//!   crate's function; the attenuated gradients, their divergence and the Neumann Poisson
//!   solve on the GPU. The solve uses the CPU's scheme, not an iteration: a 2-D DCT-II,
//!   division by the Laplacian's eigenvalues, a DCT-III, each 1-D DCT a dense matrix
//!   product along one axis (O(N (W + H)) work, exact up to f32 rounding; the matrices need
//!   W^2 and H^2 floats within `max_storage_buffer_binding_size`). The display scaling
//!   (percentiles) and recolouring run on the host.
//! - The local operators (Reinhard local, Durand, Fattal) recolour in gamut like the CPU
//!   (`recolour_in_gamut`: the ratio step, then `fit_to_display`).
//!
//! lavapipe stops every loop of an invocation batch after 65535 iterations in all, silently;
//! Durand's splat (each grid cell sums (sigma_s / 4)^2 pixels) and the row min/max (a row
//! of the image) probe for it, and a run that ran out is [`Error::Unsupported`] naming the
//! loop limit (e.g. sigma_s of about 500 pixels or more), never a wrong image. The other
//! shaders' loops are bounded far below the limit (blur radii, 16 scales, DCT sides within
//! the storage limit).
//!
//! Parity (tested in `gpu/tests/tonemap.rs` against the CPU operator on the same image):
//! global operators within 1e-4 relative + 1e-6 absolute per channel; Reinhard local and
//! Durand within 2e-4 relative + 1e-6 absolute; Fattal within 2e-4 relative + 1e-6
//! absolute (the f32 matrix DCT against the CPU's f64 FFT-based DCT; measured largest
//! difference 2e-6 relative on the 32x24 test image; f32 rounding in the O(W + H)-term
//! sums grows roughly with the square root of the side: on real photographs, memorial.hdr
//! 512x768 and Desk.exr 644x874, the largest absolute difference is 2e-5 (at 0.82) and
//! dark values near the percentile black point differ by up to 3.3e-6, so there the bound
//! is 2e-4 relative + 2e-5 absolute) (the blurs and the bilateral grid sum the
//! same terms in the same order; the difference is the GPU's `exp`/`pow` rounding and
//! fused multiply-adds).

use blueshift_camera::{DeviceKind, Observer, Session, single_pass_done};
use blueshift_tonemap::plane::log_average;
use blueshift_tonemap::{CleanImage, Operator, Plane, TonemapSession};
use image::Rgb32FImage;

use crate::context::{GpuContext, WORKGROUP_1D, WORKGROUP_2D};
use crate::error::{Error, Result};

const GLOBAL_WGSL: &str = include_str!("shaders/tonemap_global.wgsl");
const RECOLOUR_WGSL: &str = include_str!("shaders/tonemap_recolour.wgsl");
const SPLAT_WGSL: &str = concat!(
    include_str!("shaders/limiter.wgsl"),
    include_str!("shaders/durand_splat.wgsl")
);
const BLUR_WGSL: &str = include_str!("shaders/blur.wgsl");
const SLICE_WGSL: &str = include_str!("shaders/durand_slice.wgsl");
const COMBINE_WGSL: &str = include_str!("shaders/durand_combine.wgsl");
const MINMAX_WGSL: &str = concat!(
    include_str!("shaders/limiter.wgsl"),
    include_str!("shaders/row_minmax.wgsl")
);
const DODGE_WGSL: &str = include_str!("shaders/reinhard_dodge.wgsl");
const FATTAL_DIV_WGSL: &str = include_str!("shaders/fattal_div.wgsl");
const AXIS_WGSL: &str = include_str!("shaders/axis_transform.wgsl");
const DIVIDE_WGSL: &str = include_str!("shaders/poisson_divide.wgsl");

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PlaneParams {
    w: u32,
    h: u32,
    axis: u32,
    p0: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GlobalParams {
    mode: u32,
    n: u32,
    saturation: f32,
    c0: f32,
    c1: f32,
    c2: f32,
    c3: f32,
    pad: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct RecolourParams {
    n: u32,
    saturation: f32,
    /// Non-zero: `fit_to_display` after the ratio step (the local operators).
    fit: u32,
    p1: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SplatParams {
    w: u32,
    h: u32,
    gw: u32,
    gh: u32,
    z: u32,
    nl: u32,
    lo: f32,
    step: f32,
    cut: f32,
    inv2r2: f32,
    probe_n: u32,
    p1: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct BlurParams {
    w: u32,
    h: u32,
    planes: u32,
    radius: u32,
    horizontal: u32,
    dst_plane: u32,
    p1: u32,
    p2: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SliceParams {
    w: u32,
    h: u32,
    gw: u32,
    gh: u32,
    nl: u32,
    nseg: u32,
    lo: f32,
    step: f32,
    scale: f32,
    p0: u32,
    p1: u32,
    p2: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct CombineParams {
    n: u32,
    bmax: f32,
    gamma: f32,
    p0: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct DodgeParams {
    n_pixels: u32,
    n_scales: u32,
    num: f32,
    epsilon: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct MinMaxParams {
    w: u32,
    h: u32,
    probe_n: u32,
    p1: u32,
}

/// [`crate::layout::pod_layouts`] of this module: each params struct in every shader that
/// reads it (`PlaneParams` in three: the Fattal divergence and the Poisson divide pad where
/// the axis transform reads `axis`).
pub(crate) fn pod_layouts() -> Vec<crate::layout::PodLayout> {
    use crate::layout::pod_layout;
    vec![
        pod_layout!(PlaneParams => "Params", "axis_transform.wgsl", AXIS_WGSL, {
            w, h, axis, p0 as "_p0",
        }),
        pod_layout!(PlaneParams => "Params", "fattal_div.wgsl", FATTAL_DIV_WGSL, {
            w, h, axis as "_p0", p0 as "_p1",
        }),
        pod_layout!(PlaneParams => "Params", "poisson_divide.wgsl", DIVIDE_WGSL, {
            w, h, axis as "_p0", p0 as "_p1",
        }),
        pod_layout!(GlobalParams => "Params", "tonemap_global.wgsl", GLOBAL_WGSL, {
            mode, n, saturation, c0, c1, c2, c3, pad as "_pad",
        }),
        pod_layout!(RecolourParams => "Params", "tonemap_recolour.wgsl", RECOLOUR_WGSL, {
            n, saturation, fit, p1 as "_p1",
        }),
        pod_layout!(SplatParams => "Params", "durand_splat.wgsl (limiter prepended)", SPLAT_WGSL, {
            w, h, gw, gh, z, nl, lo, step, cut, inv2r2, probe_n, p1 as "_p1",
        }),
        pod_layout!(BlurParams => "Params", "blur.wgsl", BLUR_WGSL, {
            w, h, planes, radius, horizontal, dst_plane, p1 as "_p1", p2 as "_p2",
        }),
        pod_layout!(SliceParams => "Params", "durand_slice.wgsl", SLICE_WGSL, {
            w, h, gw, gh, nl, nseg, lo, step, scale, p0 as "_p0", p1 as "_p1", p2 as "_p2",
        }),
        pod_layout!(CombineParams => "Params", "durand_combine.wgsl", COMBINE_WGSL, {
            n, bmax, gamma, p0 as "_p0",
        }),
        pod_layout!(DodgeParams => "Params", "reinhard_dodge.wgsl", DODGE_WGSL, {
            n_pixels, n_scales, num, epsilon,
        }),
        pod_layout!(MinMaxParams => "Params", "row_minmax.wgsl (limiter prepended)", MINMAX_WGSL, {
            w, h, probe_n, p1 as "_p1",
        }),
    ]
}

/// `Ok` when [`GpuTonemapper`] implements `op` on the GPU, else why not (the operator has
/// no GPU implementation; the CPU runs it).
pub fn supports(op: &Operator) -> std::result::Result<(), crate::device::Unsupported> {
    if matches!(
        op,
        Operator::Linear(_)
            | Operator::Drago(_)
            | Operator::Reinhard(_)
            | Operator::ReinhardLocal(_)
            | Operator::Durand(_)
            | Operator::Fattal(_)
    ) {
        Ok(())
    } else {
        Err(crate::device::Unsupported(format!(
            "the {} operator has no GPU implementation",
            op.name()
        )))
    }
}

/// The tone-mapping pipelines, compiled once for a context.
#[derive(Debug)]
pub struct GpuTonemapper<'a> {
    ctx: &'a GpuContext,
    global: wgpu::ComputePipeline,
    recolour: wgpu::ComputePipeline,
    splat: wgpu::ComputePipeline,
    blur: wgpu::ComputePipeline,
    slice: wgpu::ComputePipeline,
    combine: wgpu::ComputePipeline,
    minmax: wgpu::ComputePipeline,
    dodge: wgpu::ComputePipeline,
    fattal_div: wgpu::ComputePipeline,
    axis: wgpu::ComputePipeline,
    divide: wgpu::ComputePipeline,
}

impl<'a> GpuTonemapper<'a> {
    /// Compiles the tone-mapping shaders on `ctx`.
    pub fn new(ctx: &'a GpuContext) -> Result<Self> {
        Ok(Self {
            ctx,
            global: ctx.compute_pipeline("tonemap_global", GLOBAL_WGSL, "main")?,
            recolour: ctx.compute_pipeline("tonemap_recolour", RECOLOUR_WGSL, "main")?,
            splat: ctx.compute_pipeline("durand_splat", SPLAT_WGSL, "main")?,
            blur: ctx.compute_pipeline("blur", BLUR_WGSL, "main")?,
            slice: ctx.compute_pipeline("durand_slice", SLICE_WGSL, "main")?,
            combine: ctx.compute_pipeline("durand_combine", COMBINE_WGSL, "main")?,
            minmax: ctx.compute_pipeline("row_minmax", MINMAX_WGSL, "main")?,
            dodge: ctx.compute_pipeline("reinhard_dodge", DODGE_WGSL, "main")?,
            fattal_div: ctx.compute_pipeline("fattal_div", FATTAL_DIV_WGSL, "main")?,
            axis: ctx.compute_pipeline("axis_transform", AXIS_WGSL, "main")?,
            divide: ctx.compute_pipeline("poisson_divide", DIVIDE_WGSL, "main")?,
        })
    }

    /// Tone-maps `img` like [`Operator::apply`]: same validation, same dirty-input rule,
    /// same output within the module's stated tolerance.
    ///
    /// # Errors
    /// The tonemap crate's errors for bad parameters or an empty image;
    /// GPU errors ([`Error::LimitExceeded`] when an image is too large for the device).
    pub fn apply(&self, op: &Operator, img: &Rgb32FImage) -> Result<Rgb32FImage> {
        op.validate()?;
        if img.width() == 0 || img.height() == 0 {
            return Err(blueshift_tonemap::Error::EmptyImage.into());
        }
        supports(op)?;
        self.apply_clean(op, &CleanImage::new(img))
    }

    /// [`GpuTonemapper::apply`] on an image already cleaned by [`CleanImage`] (its
    /// luminance and statistics are reused; a [`GpuTonemapSession`] cleans once).
    ///
    /// # Errors
    /// As [`GpuTonemapper::apply`].
    pub fn apply_clean(&self, op: &Operator, clean: &CleanImage) -> Result<Rgb32FImage> {
        op.validate()?;
        let img = &clean.image;
        if img.width() == 0 || img.height() == 0 {
            return Err(blueshift_tonemap::Error::EmptyImage.into());
        }
        supports(op)?;
        let n = u32::try_from(u64::from(img.width()) * u64::from(img.height()))
            .map_err(|_| Error::InvalidInput("image has more than 2^32 pixels".into()))?;
        self.ctx
            .check_storage_size("tone-mapped image", u64::from(n) * 12)?;
        let Some((floor, max)) = clean.positive_range else {
            return Ok(Rgb32FImage::new(img.width(), img.height()));
        };
        let lavg = || log_average(&clean.luminance, None).unwrap_or(1.0);
        let mut params = GlobalParams {
            mode: 0,
            n,
            saturation: 1.0,
            c0: 0.0,
            c1: 0.0,
            c2: 0.0,
            c3: 0.0,
            pad: 0.0,
        };
        match op {
            Operator::Linear(p) => {
                let white = p.white.unwrap_or(max);
                params.c0 = p.exposure_stops.exp2() / white;
            }
            Operator::Drago(p) => {
                let lwa = match p.roi {
                    Some(r) => log_average(&clean.luminance, Some((r.x_px, r.y_px, r.radius_px)))
                        .ok_or_else(|| {
                        Error::InvalidInput(format!(
                            "the region of interest {r:?} contains no lit pixel"
                        ))
                    })?,
                    None => lavg(),
                };
                let adaptation = lwa / f64::from(p.exposure_stops).exp2();
                let scaled_max = f64::from(max) / adaptation;
                params.mode = 1;
                params.saturation = p.saturation;
                params.c0 = (1.0 / adaptation) as f32;
                params.c1 = (1.0 / scaled_max) as f32;
                params.c2 = (f64::from(p.bias).ln() / 0.5f64.ln()) as f32;
                params.c3 =
                    (f64::from(p.max_display_luminance) * 0.01 / (scaled_max + 1.0).log10()) as f32;
            }
            Operator::Reinhard(p) => {
                let scale = f64::from(p.key) / lavg();
                let white = p.white.map_or(f64::from(max) * scale, f64::from);
                params.mode = 2;
                params.saturation = p.saturation;
                params.c0 = scale as f32;
                params.c1 = if white.is_finite() {
                    (1.0 / (white * white)) as f32
                } else {
                    0.0
                };
            }
            Operator::ReinhardLocal(p) => {
                let scale = (f64::from(p.key) / lavg()) as f32;
                let scaled = clean.luminance.map(|v| v * scale);
                return self.reinhard_local(clean, &scaled, p);
            }
            Operator::Fattal(p) => {
                let h_log = clean.luminance.map(|v| v.max(floor).ln());
                let phi = blueshift_tonemap::ops::fattal::attenuation(&h_log, p);
                let i = self.fattal_solve(&h_log, &phi)?;
                // The display scaling and recolouring of Operator::apply, on the host.
                let l_out = i.map(f32::exp);
                let lum_out =
                    blueshift_tonemap::ops::fattal::display_stretch(&l_out, &clean.luminance, p);
                return Ok(blueshift_tonemap::plane::recolour_in_gamut(
                    &clean.image,
                    &clean.luminance,
                    &lum_out,
                    p.saturation,
                ));
            }
            Operator::Durand(p) => {
                let log_l = clean.luminance.map(|v| v.max(floor).log10());
                return self.durand(clean, &log_l, p);
            }
        }
        let ctx = self.ctx;
        let rgb = ctx.storage_buffer("tonemap rgb", clean.image.as_raw())?;
        let lum = ctx.storage_buffer("tonemap luminance", &clean.luminance.data)?;
        let out = ctx.storage_buffer_zeroed("tonemap out", u64::from(n) * 12)?;
        let pb = ctx.uniform_buffer("tonemap params", &params)?;
        let bg = ctx.bind_group(&self.global, 0, &[&rgb, &lum, &out, &pb])?;
        ctx.dispatch(
            &self.global,
            &bg,
            [ctx.groups("tonemap", n, WORKGROUP_1D)?, 1, 1],
        )?;
        let data = ctx.read_buffer::<f32>(&out, n as usize * 3)?;
        to_image(img.width(), img.height(), data)
    }

    /// Fattal's compressed log luminance `I`: the attenuated-gradient divergence and the
    /// Neumann Poisson solve on the GPU. The solve is the CPU's scheme (2-D DCT-II,
    /// division by the Laplacian's eigenvalues, DCT-III), with each 1-D DCT done as a dense
    /// matrix product along one axis in f32: exact up to rounding, no iteration.
    fn fattal_solve(&self, h_log: &Plane, phi: &Plane) -> Result<Plane> {
        let ctx = self.ctx;
        let (w, h) = (h_log.width, h_log.height);
        let (w32, h32) = (w as u32, h as u32);
        let n = u64::from(w32) * u64::from(h32);
        ctx.check_storage_size("Fattal DCT matrix (width^2)", (w as u64).pow(2) * 4)?;
        ctx.check_storage_size("Fattal DCT matrix (height^2)", (h as u64).pow(2) * 4)?;
        let dct2 = |len: usize| -> Vec<f32> {
            let mut m = Vec::with_capacity(len * len);
            for k in 0..len {
                for j in 0..len {
                    let a = std::f64::consts::PI * k as f64 * (j as f64 + 0.5) / len as f64;
                    m.push(a.cos() as f32);
                }
            }
            m
        };
        // Inverse (DCT-III scaled by 2/N): u_j = 2/N (X_0 / 2 + sum_k X_k cos(...)).
        let dct3 = |len: usize| -> Vec<f32> {
            let mut m = Vec::with_capacity(len * len);
            for j in 0..len {
                for k in 0..len {
                    let a = std::f64::consts::PI * k as f64 * (j as f64 + 0.5) / len as f64;
                    let wk = if k == 0 { 0.5 } else { 1.0 };
                    m.push((2.0 / len as f64 * wk * a.cos()) as f32);
                }
            }
            m
        };
        let eig = |len: usize| -> Vec<f32> {
            (0..len)
                .map(|k| (2.0 * (std::f64::consts::PI * k as f64 / len as f64).cos() - 2.0) as f32)
                .collect()
        };
        let hb = ctx.storage_buffer("fattal log luminance", &h_log.data)?;
        let pb = ctx.storage_buffer("fattal attenuation", &phi.data)?;
        let a = ctx.storage_buffer_zeroed("fattal a", n * 4)?;
        let b = ctx.storage_buffer_zeroed("fattal b", n * 4)?;
        let (f_w, f_h) = (
            ctx.storage_buffer("dct2 w", &dct2(w))?,
            ctx.storage_buffer("dct2 h", &dct2(h))?,
        );
        let (i_w, i_h) = (
            ctx.storage_buffer("dct3 w", &dct3(w))?,
            ctx.storage_buffer("dct3 h", &dct3(h))?,
        );
        let (cx, cy) = (
            ctx.storage_buffer("eig x", &eig(w))?,
            ctx.storage_buffer("eig y", &eig(h))?,
        );
        let par = |axis: u32| {
            ctx.uniform_buffer(
                "plane params",
                &PlaneParams {
                    w: w32,
                    h: h32,
                    axis,
                    p0: 0,
                },
            )
        };
        let (p0, p1) = (par(0)?, par(1)?);
        let bgs = [
            ctx.bind_group(&self.fattal_div, 0, &[&hb, &pb, &a, &p0])?,
            ctx.bind_group(&self.axis, 0, &[&a, &f_w, &b, &p0])?,
            ctx.bind_group(&self.axis, 0, &[&b, &f_h, &a, &p1])?,
            ctx.bind_group(&self.divide, 0, &[&a, &cx, &cy, &p0])?,
            ctx.bind_group(&self.axis, 0, &[&a, &i_h, &b, &p1])?,
            ctx.bind_group(&self.axis, 0, &[&b, &i_w, &a, &p0])?,
        ];
        let refs: Vec<&wgpu::BindGroup> = bgs.iter().collect();
        let g = [
            ctx.groups("fattal", w32, WORKGROUP_2D)?,
            ctx.groups("fattal", h32, WORKGROUP_2D)?,
            1,
        ];
        let pipes = [
            &self.fattal_div,
            &self.axis,
            &self.axis,
            &self.divide,
            &self.axis,
            &self.axis,
        ];
        let passes: Vec<crate::Pass<'_>> = pipes
            .iter()
            .zip(&refs)
            .map(|(pipeline, bg)| crate::Pass {
                pipeline,
                bind_groups: std::slice::from_ref(bg),
                workgroups: g,
            })
            .collect();
        ctx.run_passes(&passes)?;
        let data = ctx.read_buffer::<f32>(&a, n as usize)?;
        Ok(Plane {
            width: w,
            height: h,
            data,
        })
    }

    fn reinhard_local(
        &self,
        clean: &CleanImage,
        l: &Plane,
        p: &blueshift_tonemap::ReinhardLocalParams,
    ) -> Result<Rgb32FImage> {
        let ctx = self.ctx;
        let (w32, h32) = (l.width as u32, l.height as u32);
        let n = w32 * h32;
        let ns = p.scales;
        let scales: Vec<f32> = (0..=ns).map(|i| p.scale_ratio.powi(i as i32)).collect();
        let alpha1 = 1.0 / (2.0 * std::f32::consts::SQRT_2);
        ctx.check_storage_size("Reinhard centres", u64::from(n) * 4 * (ns as u64 + 1))?;
        let lb = ctx.storage_buffer("reinhard luminance", &l.data)?;
        let tmp = ctx.storage_buffer_zeroed("reinhard blur tmp", u64::from(n) * 4)?;
        let centres =
            ctx.storage_buffer_zeroed("reinhard centres", u64::from(n) * 4 * (ns as u64 + 1))?;
        let g2 = [
            ctx.groups("reinhard", w32, WORKGROUP_2D)?,
            ctx.groups("reinhard", h32, WORKGROUP_2D)?,
            1,
        ];
        let mut bgs = Vec::with_capacity(2 * scales.len());
        for (k, s) in scales.iter().enumerate() {
            let kernel =
                blueshift_tonemap::plane::gaussian_kernel(alpha1 * s / std::f32::consts::SQRT_2);
            let kb = ctx.storage_buffer("reinhard kernel", &kernel)?;
            let params = |horizontal: u32, dst_plane: u32| BlurParams {
                w: w32,
                h: h32,
                planes: 1,
                radius: (kernel.len() / 2) as u32,
                horizontal,
                dst_plane,
                p1: 0,
                p2: 0,
            };
            let ph = ctx.uniform_buffer("blur params", &params(1, 0))?;
            let pv = ctx.uniform_buffer("blur params", &params(0, k as u32))?;
            bgs.push(ctx.bind_group(&self.blur, 0, &[&lb, &kb, &tmp, &ph])?);
            bgs.push(ctx.bind_group(&self.blur, 0, &[&tmp, &kb, &centres, &pv])?);
        }
        let scales_b = ctx.storage_buffer("reinhard scales", &scales)?;
        let lum_out = ctx.storage_buffer_zeroed("reinhard lum out", u64::from(n) * 4)?;
        let dp = ctx.uniform_buffer(
            "dodge params",
            &DodgeParams {
                n_pixels: n,
                n_scales: ns as u32,
                num: 2f32.powf(p.phi) * p.key,
                epsilon: p.epsilon,
            },
        )?;
        bgs.push(ctx.bind_group(&self.dodge, 0, &[&lb, &centres, &scales_b, &lum_out, &dp])?);
        let rgb = ctx.storage_buffer("tonemap rgb", clean.image.as_raw())?;
        let lum = ctx.storage_buffer("tonemap luminance", &clean.luminance.data)?;
        let out = ctx.storage_buffer_zeroed("tonemap out", u64::from(n) * 12)?;
        let rec_p = ctx.uniform_buffer(
            "recolour params",
            &RecolourParams {
                n,
                saturation: p.saturation,
                fit: 1,
                p1: 0,
            },
        )?;
        bgs.push(ctx.bind_group(&self.recolour, 0, &[&rgb, &lum, &lum_out, &out, &rec_p])?);
        let refs: Vec<&wgpu::BindGroup> = bgs.iter().collect();
        let g1 = [ctx.groups("reinhard", n, WORKGROUP_1D)?, 1, 1];
        let mut passes: Vec<crate::Pass<'_>> = (0..2 * scales.len())
            .map(|i| crate::Pass {
                pipeline: &self.blur,
                bind_groups: std::slice::from_ref(&refs[i]),
                workgroups: g2,
            })
            .collect();
        let m = 2 * scales.len();
        passes.push(crate::Pass {
            pipeline: &self.dodge,
            bind_groups: std::slice::from_ref(&refs[m]),
            workgroups: g1,
        });
        passes.push(crate::Pass {
            pipeline: &self.recolour,
            bind_groups: std::slice::from_ref(&refs[m + 1]),
            workgroups: g1,
        });
        ctx.run_passes(&passes)?;
        let data = ctx.read_buffer::<f32>(&out, n as usize * 3)?;
        to_image(w32, h32, data)
    }

    fn durand(
        &self,
        clean: &CleanImage,
        log_l: &Plane,
        p: &blueshift_tonemap::DurandParams,
    ) -> Result<Rgb32FImage> {
        let ctx = self.ctx;
        let (w, h) = (log_l.width, log_l.height);
        let n = (w * h) as u32;
        let sigma_s = p.sigma_spatial_for(w, h);
        let sigma_r = p.sigma_range;
        // The grid as the CPU builds it (blueshift_tonemap::ops::durand::fast_bilateral).
        let (lo, hi) = log_l.min_max();
        let nseg = (((hi - lo) / sigma_r).ceil() as usize).max(1);
        let step = ((hi - lo) / nseg as f32).max(f32::MIN_POSITIVE);
        let levels: Vec<f32> = (0..=nseg).map(|j| lo + step * j as f32).collect();
        let z = ((sigma_s / 4.0).round() as usize).max(1);
        let (gw, gh) = (w.div_ceil(z), h.div_ceil(z));
        let nl = levels.len();
        let grid_len = (gw as u64) * (gh as u64) * (nl as u64) * 2;
        ctx.check_storage_size("Durand bilateral grid", grid_len * 4)?;
        let kernel = blueshift_tonemap::plane::gaussian_kernel(sigma_s / z as f32);
        let radius = (kernel.len() / 2) as u32;

        let input = ctx.storage_buffer("durand log luminance", &log_l.data)?;
        let levels_b = ctx.storage_buffer("durand levels", &levels)?;
        let grid = ctx.storage_buffer_zeroed("durand grid", grid_len * 4)?;
        let grid2 = ctx.storage_buffer_zeroed("durand grid blur", grid_len * 4)?;
        let kernel_b = ctx.storage_buffer("durand kernel", &kernel)?;
        let base = ctx.storage_buffer_zeroed("durand base", u64::from(n) * 4)?;
        let (w32, h32, gw32, gh32, nl32) = (w as u32, h as u32, gw as u32, gh as u32, nl as u32);
        let splat_p = ctx.uniform_buffer(
            "splat params",
            &SplatParams {
                w: w32,
                h: h32,
                gw: gw32,
                gh: gh32,
                z: z as u32,
                nl: nl32,
                lo,
                step,
                cut: 4.0 * sigma_r,
                inv2r2: 1.0 / (2.0 * sigma_r * sigma_r),
                probe_n: 2, // the loop-limiter probe's trip count
                p1: 0,
            },
        )?;
        let blur_p = |horizontal: u32| {
            ctx.uniform_buffer(
                "blur params",
                &BlurParams {
                    w: gw32,
                    h: gh32,
                    planes: 2 * nl32,
                    radius,
                    horizontal,
                    dst_plane: 0,
                    p1: 0,
                    p2: 0,
                },
            )
        };
        let blur_h = blur_p(1)?;
        let blur_v = blur_p(0)?;
        let slice_p = ctx.uniform_buffer(
            "slice params",
            &SliceParams {
                w: w32,
                h: h32,
                gw: gw32,
                gh: gh32,
                nl: nl32,
                nseg: nseg as u32,
                lo,
                step,
                scale: 1.0 / z as f32,
                p0: 0,
                p1: 0,
                p2: 0,
            },
        )?;
        // Set by the splat and row min/max shaders when lavapipe's loop limit ran out.
        let limited = ctx.storage_buffer("durand loop-limit flag", &[0u32])?;
        let bg_splat = ctx.bind_group(
            &self.splat,
            0,
            &[&input, &levels_b, &grid, &splat_p, &limited],
        )?;
        let bg_bh = ctx.bind_group(&self.blur, 0, &[&grid, &kernel_b, &grid2, &blur_h])?;
        let bg_bv = ctx.bind_group(&self.blur, 0, &[&grid2, &kernel_b, &grid, &blur_v])?;
        let bg_slice = ctx.bind_group(&self.slice, 0, &[&input, &grid, &base, &slice_p])?;
        let planes = 2 * nl32;
        let max_z = ctx.limits().max_compute_workgroups_per_dimension;
        if planes > max_z {
            return Err(Error::LimitExceeded {
                what: "Durand bilateral grid levels".into(),
                limit: "max_compute_workgroups_per_dimension",
                requested: planes.into(),
                max: max_z.into(),
            });
        }
        let g_grid = [
            ctx.groups("splat", gw32, WORKGROUP_2D)?,
            ctx.groups("splat", gh32, WORKGROUP_2D)?,
            1,
        ];
        let g_blur = [g_grid[0], g_grid[1], planes];
        let g_img = [
            ctx.groups("slice", w32, WORKGROUP_2D)?,
            ctx.groups("slice", h32, WORKGROUP_2D)?,
            1,
        ];
        ctx.run_passes(&[
            crate::Pass {
                pipeline: &self.splat,
                bind_groups: &[&bg_splat],
                workgroups: g_grid,
            },
            crate::Pass {
                pipeline: &self.blur,
                bind_groups: &[&bg_bh],
                workgroups: g_blur,
            },
            crate::Pass {
                pipeline: &self.blur,
                bind_groups: &[&bg_bv],
                workgroups: g_blur,
            },
            crate::Pass {
                pipeline: &self.slice,
                bind_groups: &[&bg_slice],
                workgroups: g_img,
            },
        ])?;
        // Base min / max: per-row on the GPU, folded in row order here.
        let mm = ctx.storage_buffer_zeroed("row minmax", u64::from(h32) * 8)?;
        let mm_p = ctx.uniform_buffer(
            "minmax params",
            &MinMaxParams {
                w: w32,
                h: h32,
                probe_n: 2, // the loop-limiter probe's trip count
                p1: 0,
            },
        )?;
        let bg_mm = ctx.bind_group(&self.minmax, 0, &[&base, &mm, &mm_p, &limited])?;
        ctx.dispatch(
            &self.minmax,
            &bg_mm,
            [ctx.groups("minmax", h32, WORKGROUP_1D)?, 1, 1],
        )?;
        crate::tracking::check_loop_limit(
            ctx,
            &limited,
            "Durand's bilateral grid (each cell sums sigma_s/4 x sigma_s/4 pixels)",
            "a smaller --sigma-s",
        )?;
        let rows = ctx.read_buffer::<f32>(&mm, h * 2)?;
        let (bmin_all, bmax) = rows
            .chunks_exact(2)
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), r| {
                (a.min(r[0]), b.max(r[1]))
            });
        // The low end of the base range: its BASE_LOW_PERCENTILE-th percentile over lit
        // pixels (luminance > 0), as blueshift_tonemap::ops::durand::durand_log_lit, with the
        // same percentile function; the base is read back for it.
        let base_host = ctx.read_buffer::<f32>(&base, n as usize)?;
        let lit: Vec<f32> = base_host
            .iter()
            .zip(&clean.luminance.data)
            .filter(|(_, l)| **l > 0.0)
            .map(|(b, _)| *b)
            .collect();
        let bmin = if lit.is_empty() {
            bmin_all
        } else {
            blueshift_tonemap::ops::fattal::percentile(
                &lit,
                blueshift_tonemap::ops::durand::BASE_LOW_PERCENTILE,
            )
        };
        let span = (bmax - bmin).max(1e-6);
        let gamma = (p.base_contrast.log10() / span).min(1.0);
        let lum_out = ctx.storage_buffer_zeroed("durand lum out", u64::from(n) * 4)?;
        let comb_p = ctx.uniform_buffer(
            "combine params",
            &CombineParams {
                n,
                bmax,
                gamma,
                p0: 0,
            },
        )?;
        let bg_comb = ctx.bind_group(&self.combine, 0, &[&input, &base, &lum_out, &comb_p])?;
        let rgb = ctx.storage_buffer("tonemap rgb", clean.image.as_raw())?;
        let lum = ctx.storage_buffer("tonemap luminance", &clean.luminance.data)?;
        let out = ctx.storage_buffer_zeroed("tonemap out", u64::from(n) * 12)?;
        let rec_p = ctx.uniform_buffer(
            "recolour params",
            &RecolourParams {
                n,
                saturation: p.saturation,
                fit: 1,
                p1: 0,
            },
        )?;
        let bg_rec = ctx.bind_group(&self.recolour, 0, &[&rgb, &lum, &lum_out, &out, &rec_p])?;
        let g1 = [ctx.groups("durand", n, WORKGROUP_1D)?, 1, 1];
        ctx.run_passes(&[
            crate::Pass {
                pipeline: &self.combine,
                bind_groups: &[&bg_comb],
                workgroups: g1,
            },
            crate::Pass {
                pipeline: &self.recolour,
                bind_groups: &[&bg_rec],
                workgroups: g1,
            },
        ])?;
        let data = ctx.read_buffer::<f32>(&out, n as usize * 3)?;
        to_image(w32, h32, data)
    }
}

fn to_image(w: u32, h: u32, data: Vec<f32>) -> Result<Rgb32FImage> {
    Rgb32FImage::from_raw(w, h, data)
        .ok_or_else(|| Error::Internal("readback size does not match the image".into()))
}

/// One-shot [`GpuTonemapper::apply`] (compiles the shaders each call).
pub fn tonemap(ctx: &GpuContext, op: &Operator, img: &Rgb32FImage) -> Result<Rgb32FImage> {
    GpuTonemapper::new(ctx)?.apply(op, img)
}

/// A tone-mapping session on a GPU: the CPU's [`TonemapSession`] (the image cleaned once,
/// the operator; its edits apply here too) mapped by the pipelines compiled once.
#[derive(Debug)]
pub struct GpuTonemapSession<'c> {
    gpu: GpuTonemapper<'c>,
    cpu: TonemapSession,
}

impl<'c> GpuTonemapSession<'c> {
    /// Compiles the pipelines for `cpu`'s runs; refuses an operator without a GPU
    /// implementation.
    ///
    /// # Errors
    /// [`Error::Unsupported`] (see [`supports`]); GPU errors.
    pub fn new(ctx: &'c GpuContext, cpu: TonemapSession) -> Result<Self> {
        supports(cpu.operator())?;
        Ok(Self {
            gpu: GpuTonemapper::new(ctx)?,
            cpu,
        })
    }

    /// The CPU session (state and edits).
    #[must_use]
    pub fn cpu(&self) -> &TonemapSession {
        &self.cpu
    }

    /// The CPU session, for edits (the operator).
    pub fn cpu_mut(&mut self) -> &mut TonemapSession {
        &mut self.cpu
    }

    /// Tone-maps on the GPU under `observer`.
    ///
    /// # Errors
    /// As [`GpuTonemapper::apply`]; [`Error::Cancelled`].
    pub fn render(&self, observer: &dyn Observer<Rgb32FImage>) -> Result<Rgb32FImage> {
        if observer.cancelled() {
            return Err(Error::Cancelled);
        }
        let img = self
            .gpu
            .apply_clean(self.cpu.operator(), self.cpu.clean())?;
        single_pass_done(observer, u64::from(img.height()), &img);
        Ok(img)
    }
}

impl Session for GpuTonemapSession<'_> {
    type Image = Rgb32FImage;
    type Output = Rgb32FImage;
    type Error = Error;

    fn run(&mut self, observer: &dyn Observer<Rgb32FImage>) -> Result<Rgb32FImage> {
        self.render(observer)
    }

    fn device(&self) -> DeviceKind {
        DeviceKind::Gpu
    }
}
