// Doppler volume rendering, emission-only piecewise-linear integrator (the Doppler paper's
// Algorithm 2 as blueshift-tracking's `pwl.rs` does it for rays without absorption): one
// thread per pixel marches its ray back to front; per segment each line of each species
// emits the trapezoid between its two shifted positions (area = emitted energy), whose XYZ is
// integrated exactly against the piecewise-linear CIE 1931 CMFs; black bodies are sampled on
// a fixed wavelength grid at both ends of the segment (trapezoid rule along the ray), each
// grid sample weighted by the XYZ of its hat function (precomputed on the host in f64).

// `fw` is the working float: the host prepends a prelude (`doppler::shader_source`) that
// defines it as f64 (adapters with SHADER_F64) or f32, with `exp_fw`, `u2w` / `w2u` (a count
// stored in a working-float buffer) and `SERIES_Z` (where `exp_moments` switches from its
// series to the recurrence). Sampling the volume stays f32 as on the CPU (its densities and
// velocities are f32 grids sampled in f32); everything after the samples is in `fw`.

struct Params {
    nx: u32,
    ny: u32,
    nz: u32,
    nvox: u32,
    nsp: u32,
    n_lines: u32,
    has_bb: u32,
    has_vel: u32,
    model: u32,        // 0 classical, 1 relativistic
    invariant: u32,    // 1: k(s) = s^-5, 0: k(s) = 1 / s
    width: u32,
    height: u32,
    step: f32,         // path step (f32 on the CPU too)
    vel_factor: f32,   // velocity factor (applied to the f32 velocity sample, as on the CPU)
    off_pf: u32,       // offset in `tables` of the working-float parameters (`PFw`)
    cmf_n: u32,
    bb_k: u32,
    shift_mode: u32,   // banded: 0 nearest band, 1 energy-conserving
    off_lambda: u32,   // offset of the black-body grid in `tables`
    off_hat: u32,      // offset of the hat XYZs (3 per sample) in `tables`
    n_bands: u32,      // banded: bands over [range_lo, range_hi)
    off_band_w: u32,   // banded: offset of the per-band CMF integrals (3 per band)
    off_band_c: u32,   // banded: offset of the band centres
    n_abs: u32,        // banded with absorption: absorption entries after the n_lines emission ones
    absorbing: u32,    // banded: 1 when the bands are kept per ray (absorption on)
    pix_offset: u32,   // pwl with absorption: first pixel of the tile
    n_pix: u32,        // pwl with absorption: end of the tile (pixels)
    piece_cap: u32,    // pwl with absorption: min(piece_budget, device cap) pieces of tau_front
    region_l: u32,     // pwl with absorption: pieces of regions A and B
    stride: u32,       // pwl with absorption: working floats per ray
    pass_index: u32,   // pwl with absorption: 0 starts the rays, later passes resume them
    iter_budget: u32,  // pwl with absorption: loop iterations after which a pass yields
    iter_limit: u32,   // pwl with absorption: the adapter's loop limit per invocation
    broaden: u32,      // pwl without absorption: 1 when lines are broadened (thermal / sigma)
    off_kom: u32,      // broadening: offset of k / m per species ((m/s)^2 per K) in `tables`
    off_gauss: u32,    // broadening: offset of the unit Gaussian's knots (x, then g) in `tables`
    n_gauss: u32,      // broadening: knots of the unit Gaussian
    probe_n: u32,      // 2: the trip count of `limiter_exhausted`'s loop (a runtime value)
    g_origin_x: f32,   // the grid's world origin and spacing (world_to_index)
    g_origin_y: f32,
    g_origin_z: f32,
    g_spacing_x: f32,
    g_spacing_y: f32,
    g_spacing_z: f32,
    pad0: u32,
    pad1: u32,
}

// The parameters in working precision, read from `tables` at `P.off_pf` (same order).
struct PFw {
    range_lo: fw,
    range_hi: fw,
    min_width: fw,
    cmf_lo: fw,
    cmf_step: fw,
    bb_c1: fw,         // c1L for l in nm, per nm: B = c1 / l^5 / (exp(c2 / l T) - 1)
    bb_c2: fw,         // c2 in nm K
    temp_factor: fw,
    bb_factor: fw,     // black-body factor x BB_UNIT
    band_w: fw,        // banded: band width, nm
    merge_tol: fw,     // pwl with absorption: merge tolerance
    sigma2_user: fw,   // broadening: user velocity dispersion squared, (m/s)^2
}

var<private> PF: PFw;

fn load_pf() {
    let o = P.off_pf;
    PF.range_lo = tables[o];
    PF.range_hi = tables[o + 1u];
    PF.min_width = tables[o + 2u];
    PF.cmf_lo = tables[o + 3u];
    PF.cmf_step = tables[o + 4u];
    PF.bb_c1 = tables[o + 5u];
    PF.bb_c2 = tables[o + 6u];
    PF.temp_factor = tables[o + 7u];
    PF.bb_factor = tables[o + 8u];
    PF.band_w = tables[o + 9u];
    PF.merge_tol = tables[o + 10u];
    PF.sigma2_user = tables[o + 11u];
}

struct PixelRay {
    origin: vec3<f32>, // the camera ray's origin (world)
    t0: f32,           // its parameter where it enters the box
    dir: vec3<f32>,    // its direction (as the camera gives it)
    len: f32,          // path length inside the box
    los: vec3<f32>,    // unit world direction
    n_seg: u32,        // segments (0: the ray misses)
}

@group(0) @binding(0) var<storage, read> rays: array<PixelRay>;
// The device brick pool and its page table (pool.wgsl, gpu/src/pool.rs). Channels: the
// velocity's x, y, z, then the scalars: species densities 0..nsp, then black-body density,
// temperature, density x Planck factor (gas_temperature).
@group(0) @binding(1) var<storage, read> pool: array<f32>;
@group(0) @binding(2) var<storage, read> pages: array<vec2<u32>>;
// CMF samples (3 per wavelength, cmf_n of them), then the black-body grid and its hat XYZs,
// ..., and the working-float parameters.
@group(0) @binding(3) var<storage, read> tables: array<fw>;
// Per line: centre nm, strength x emission factor, species index, unused. Banded with the
// nearest shift: per rest-frame band entry, its centre nm, value per unit density, species.
@group(0) @binding(4) var<storage, read> lines: array<vec4<fw>>;
// Per pixel: X, Y, Z, flag (0 ok, 1: a Doppler shift was invalid), in working precision.
@group(0) @binding(5) var<storage, read_write> out_xyz: array<vec4<fw>>;
@group(0) @binding(6) var<uniform> P: Params;
// Banded with absorption: the band values of every pixel's ray (n_bands per pixel); the
// piecewise-linear kernels' per-ray state and pieces.
@group(0) @binding(7) var<storage, read_write> bands_buf: array<fw>;

// Banded: where deposits go (XYZ directly, or the ray's bands when absorbing).
var<private> acc_xyz: vec3<fw>;
var<private> band_base: u32;

const MAX_SPECIES: u32 = 8u;

const C_M_PER_S = 299792458.0;

alias Corner = PoolCorner;

fn grid_dims() -> vec3<u32> {
    return vec3<u32>(P.nx, P.ny, P.nz);
}

// The index-space position of path position t, as the CPU's `world_to_index(ray.at(t0 + t))`
// (the same f32 operations in the same order).
fn sample_pos(r: PixelRay, t: f32) -> vec3<f32> {
    let w = r.origin + r.dir * (r.t0 + t);
    return (w - vec3<f32>(P.g_origin_x, P.g_origin_y, P.g_origin_z))
        / vec3<f32>(P.g_spacing_x, P.g_spacing_y, P.g_spacing_z);
}

// The corners of blueshift-volume's `sample_trilinear_index` (clamped to the centres).
fn corners(p_in: vec3<f32>) -> Corner {
    return pool_corner(p_in, grid_dims());
}

fn lerp1(a: f32, b: f32, t: f32) -> f32 { return a * (1.0 - t) + b * t; }
fn lerp3(a: vec3<f32>, b: vec3<f32>, t: f32) -> vec3<f32> { return a * (1.0 - t) + b * t; }

// A scalar channel at the corners, in working precision: the CPU's nested lerps (x, then y,
// then z) in f32, as it samples.
fn sample_channel(c: Corner, ch: u32) -> fw {
    iters += 1u;
    let v = pool_fetch(ch + 3u, grid_dims(), c);
    let c00 = lerp1(v[0], v[1], c.t.x);
    let c10 = lerp1(v[2], v[3], c.t.x);
    let c01 = lerp1(v[4], v[5], c.t.x);
    let c11 = lerp1(v[6], v[7], c.t.x);
    return fw(lerp1(lerp1(c00, c10, c.t.y), lerp1(c01, c11, c.t.y), c.t.z));
}

// The velocity at the corners times the velocity factor (f32, as the CPU samples it).
fn sample_velocity(c: Corner) -> vec3<fw> {
    iters += 1u;
    let d = grid_dims();
    let x = pool_fetch(0u, d, c);
    let y = pool_fetch(1u, d, c);
    let z = pool_fetch(2u, d, c);
    let c00 = lerp3(vec3<f32>(x[0], y[0], z[0]), vec3<f32>(x[1], y[1], z[1]), c.t.x);
    let c10 = lerp3(vec3<f32>(x[2], y[2], z[2]), vec3<f32>(x[3], y[3], z[3]), c.t.x);
    let c01 = lerp3(vec3<f32>(x[4], y[4], z[4]), vec3<f32>(x[5], y[5], z[5]), c.t.x);
    let c11 = lerp3(vec3<f32>(x[6], y[6], z[6]), vec3<f32>(x[7], y[7], z[7]), c.t.x);
    let v = lerp3(lerp3(c00, c10, c.t.y), lerp3(c01, c11, c.t.y), c.t.z);
    return vec3<fw>(v * P.vel_factor);
}

// blueshift-spectrum's `WavelengthShift::from_velocity` for the velocity v (m/s) seen along
// `los`: (shift s, 1 when |v| >= c under the relativistic model, else 0).
fn shift_of(v: vec3<fw>, los_in: vec3<f32>) -> vec2<fw> {
    let los = vec3<fw>(los_in);
    let v_r = dot(v, los) / sqrt(dot(los, los));
    if (P.model == 1u) {
        let beta = sqrt(dot(v, v)) / C_M_PER_S;
        var bad: fw = 0.0;
        if (!(beta < 1.0)) { bad = 1.0; }
        return vec2<fw>((1.0 + v_r / C_M_PER_S) / sqrt(max(1.0 - beta * beta, 1e-30)), bad);
    }
    return vec2<fw>(1.0 + v_r / C_M_PER_S, 0.0);
}

fn cmf(k: u32) -> vec3<fw> {
    return vec3<fw>(tables[3u * k], tables[3u * k + 1u], tables[3u * k + 2u]);
}

fn lerp_at(a: fw, b: fw, va: fw, vb: fw, x: fw) -> fw {
    if (x <= a) { return va; }
    if (x >= b) { return vb; }
    return va + (vb - va) * ((x - a) / (b - a));
}

// Exact XYZ of the trapezoid (start, end, v0, v1) against the piecewise-linear CMFs, interval
// by interval of the CMF table (a line spans a few; no prefix differences, which cancel in f32).
fn trapezoid_xyz(start: fw, end: fw, v0: fw, v1: fw) -> vec3<fw> {
    // The same integration as the line-relative form, with wavelengths taken as they are.
    return trapezoid_xyz_local(0.0, start, end, v0, v1);
}

fn value_factor(s: fw) -> fw {
    if (P.invariant == 1u) {
        let s2 = s * s;
        return 1.0 / (s2 * s2 * s);
    }
    return 1.0 / s;
}

// Planck's law on the host's constants, in BB_UNIT x W sr^-1 m^-2 nm^-1 (l in nm).
// The black body's temperature at a sample: the brightness temperature at 700 nm of the
// interpolated emission (channel nsp + 2 holds rho / (exp(c2 / (700 T)) - 1) per voxel; the
// CPU's RawSamples do the same, see blueshift_doppler::DopplerScene::set_blackbody).
// Thermal broadening keeps the interpolated temperature (channel nsp + 1).
fn gas_temperature(c: Corner) -> fw {
    let rho = max(sample_channel(c, P.nsp), 0.0);
    let g = max(sample_channel(c, P.nsp + 2u), 0.0);
    if (rho > 0.0 && g > rho * 1e-30) {
        return 1.4387768775e7 / (700.0 * ln_fw(1.0 + rho / g));
    }
    return 0.0;
}

fn planck(l: fw, temp: fw) -> fw {
    let x = PF.bb_c2 / (l * temp);
    let den = expm1_fw(x);
    if (!(den < FW_MAX)) { return 0.0; }
    let l2 = l * l;
    return PF.bb_c1 / (l2 * l2 * l) / den;
}

// The XYZ of one sample's black-body row: sum_i hat_xyz[i] k(s) rho B(lambda_i / s, T).
fn bb_xyz(rho: fw, temp: fw, s: fw) -> vec3<fw> {
    var out = vec3<fw>(0.0);
    if (rho <= 0.0 || temp <= 0.0) { return out; }
    let k = value_factor(s) * rho;
    for (var i = 0u; i < P.bb_k; i++) { iters += 1u;
        let l = tables[P.off_lambda + i];
        let h = vec3<fw>(tables[P.off_hat + 3u * i], tables[P.off_hat + 3u * i + 1u],
                          tables[P.off_hat + 3u * i + 2u]);
        out += h * (k * planck(l / s, temp));
    }
    return out;
}

// ---- Line broadening (blueshift-tracking's profile.rs) ------------------------------------

// Velocity dispersion of species m at temperature t_k, m/s.
fn sigma_v(m: u32, t_k: fw) -> fw {
    return sqrt(tables[P.off_kom + m] * max(t_k, 0.0) + PF.sigma2_user);
}

// `trapezoid_xyz` of the trapezoid on [c + a, c + b] with all lengths taken relative to c:
// a Gaussian piece is sigma / 4 wide (5e-4 nm at 1 km/s), far below what absolute f32
// wavelengths resolve (6e-5 nm at 656 nm); only the CMF nodes' offsets from c round, which
// moves a kink of the continuous CMFs (a second-order error).
fn trapezoid_xyz_local(c: fw, a: fw, b: fw, v0: fw, v1: fw) -> vec3<fw> {
    var out = vec3<fw>(0.0);
    let lo_rel = PF.cmf_lo - c;
    let hi_rel = lo_rel + PF.cmf_step * fw(P.cmf_n - 1u);
    let ua = max(a, lo_rel);
    let ub = min(b, hi_rel);
    if (!(ub > ua)) { return out; }
    let last = P.cmf_n - 2u;
    let ia = min(u32(max(floor((ua - lo_rel) / PF.cmf_step), 0.0)), last);
    let ib = min(u32(max(floor((ub - lo_rel) / PF.cmf_step), 0.0)), last);
    for (var k = ia; k <= ib; k++) {
        iters += 1u;
        let x0 = lo_rel + fw(k) * PF.cmf_step;
        let x1 = x0 + PF.cmf_step;
        var u = x0;
        var w = x1;
        if (k == ia) { u = ua; }
        if (k == ib) { w = ub; }
        if (w <= u) { continue; }
        let fu = lerp_at(a, b, v0, v1, u);
        let fw = lerp_at(a, b, v0, v1, w);
        let g0 = cmf(k);
        let g1 = cmf(k + 1u);
        let gu = g0 + (g1 - g0) * ((u - x0) / PF.cmf_step);
        let gw = g0 + (g1 - g0) * ((w - x0) / PF.cmf_step);
        out += (w - u) * (2.0 * fu * gu + fu * gw + fw * gu + 2.0 * fw * gw) / 6.0;
    }
    return out;
}

// The XYZ of one emitted trapezoid on [c + a, c + b], kept as `segment_lines` keeps it
// (inside the range, not zero).
fn emitted_xyz(c: fw, a: fw, b: fw, h0: fw, h1: fw) -> vec3<fw> {
    if (c + b < PF.range_lo || c + a > PF.range_hi || (h0 <= 0.0 && h1 <= 0.0)) {
        return vec3<fw>(0.0);
    }
    return trapezoid_xyz_local(c, a, b, h0, h1);
}

// The unit PwlGaussian's tables (host, f64): knots z_i (uniform), values g_i, and the
// integrals of g and of z g from the first knot to z_i.
fn gz(i: u32) -> fw { return tables[P.off_gauss + i]; }
fn gg(i: u32) -> fw { return tables[P.off_gauss + P.n_gauss + i]; }
fn gc0(i: u32) -> fw { return tables[P.off_gauss + 2u * P.n_gauss + i]; }
fn gc1(i: u32) -> fw { return tables[P.off_gauss + 3u * P.n_gauss + i]; }

// (integral of g, integral of z g) from the first knot to z (clamped to the support).
fn gauss_cum(z_in: fw) -> vec2<fw> {
    let n = P.n_gauss;
    let z0 = gz(0u);
    let zn = gz(n - 1u);
    let z = clamp(z_in, z0, zn);
    let hz = (zn - z0) / fw(n - 1u);
    let i = min(u32(max(floor((z - z0) / hz), 0.0)), n - 2u);
    let zi = gz(i);
    let g0 = gg(i);
    let sl = (gg(i + 1u) - g0) / hz;
    let d = z - zi;
    let m0 = d * (g0 + 0.5 * sl * d);
    let m1 = zi * g0 * d + (zi * sl + g0) * d * d / 2.0 + sl * d * d * d / 3.0;
    return vec2<fw>(gc0(i) + m0, gc1(i) + m1);
}

// The XYZ of the PwlGaussian of `area` and `sigma` at `pos`, as the CPU's pieces give it (the
// pieces `segment_lines` keeps: those not wholly outside the wavelength range), in closed
// form per CMF interval: on an interval the CMFs are linear, so the integral needs only the
// profile's area and first moment there (no loop over the 32 pieces).
fn gauss_xyz(pos: fw, sigma: fw, area: fw) -> vec3<fw> {
    var out = vec3<fw>(0.0);
    let n = P.n_gauss;
    let z0 = gz(0u);
    let zn = gz(n - 1u);
    let hz = (zn - z0) / fw(n - 1u);
    // Kept pieces: end >= range_lo and start <= range_hi.
    let zl = (PF.range_lo - pos) / sigma;
    let zh = (PF.range_hi - pos) / sigma;
    var za = z0;
    if (zl > z0) { za = z0 + max(ceil((zl - z0) / hz) - 1.0, 0.0) * hz; }
    var zb = zn;
    if (zh < zn) { zb = z0 + min(floor((zh - z0) / hz) + 1.0, fw(n - 1u)) * hz; }
    // Local wavelengths (relative to pos), clipped to the CMF table.
    let lo_rel = PF.cmf_lo - pos;
    let hi_rel = lo_rel + PF.cmf_step * fw(P.cmf_n - 1u);
    let ua = max(za * sigma, lo_rel);
    let ub = min(zb * sigma, hi_rel);
    if (!(ub > ua)) { return out; }
    let last = P.cmf_n - 2u;
    let ia = min(u32(max(floor((ua - lo_rel) / PF.cmf_step), 0.0)), last);
    let ib = min(u32(max(floor((ub - lo_rel) / PF.cmf_step), 0.0)), last);
    for (var k = ia; k <= ib; k++) {
        iters += 1u;
        let x0 = lo_rel + fw(k) * PF.cmf_step;
        let u = max(ua, x0);
        let w = min(ub, x0 + PF.cmf_step);
        if (!(w > u)) { continue; }
        let m = gauss_cum(w / sigma) - gauss_cum(u / sigma);
        let g0 = cmf(k);
        let g1 = cmf(k + 1u);
        let slope = (g1 - g0) / PF.cmf_step;
        // integral of p (c(pos) + slope (lambda - pos)), c(pos) on this interval's line.
        let c_pos = g0 + slope * (0.0 - x0);
        out += area * (m.x * c_pos + sigma * m.y * slope);
    }
    return out;
}

// `emit_line`: one line over a segment (centre seen through shifts sa, sb; areas, velocity
// dispersions at the ends) as a trapezoid, or as up to 64 piecewise-linear Gaussians placed
// at the area centroids of equal sub-intervals of the sweep; returns their XYZ.
// (`emit_line_sources` below walks the same split for the absorbing kernel. They stay two
// functions: that one touches the absorbing kernel's piece buffers, and a call from here, even
// one never taken, would put those bindings into the emission-only pipeline's layout.)
fn emit_line_xyz(centre: fw, sa: fw, sb: fw, area_a: fw, area_b: fw, sig_a: fw,
                 sig_b: fw) -> vec3<fw> {
    var out = vec3<fw>(0.0);
    let la = sa * centre;
    let lb = sb * centre;
    let sna = la * sig_a / C_M_PER_S;
    let snb = lb * sig_b / C_M_PER_S;
    let sigma_mean = 0.5 * (sna + snb);
    let sweep = abs(lb - la);
    if (sigma_mean <= 0.0 || sweep >= 16.0 * sigma_mean) {
        var mw = PF.min_width;
        if (sigma_mean > 0.0) { mw = 0.0; }
        let wdt = max(sweep, mw);
        let mid = 0.5 * (la + lb);
        if (!(wdt > 0.0)) { return out; }
        let hh = trap_heights(la, lb, area_a, area_b, wdt);
        let h0 = hh.x;
        let h1 = hh.y;
        return emitted_xyz(mid, -0.5 * wdt, 0.5 * wdt, h0, h1);
    }
    let mm = u32(clamp(ceil(4.0 * sweep / sigma_mean), 1.0, 64.0));
    let inv = 1.0 / fw(mm);
    let da = area_b - area_a;
    for (var k = 0u; k < mm; k++) {
        iters += 1u;
        let u0 = fw(k) * inv;
        let u1 = fw(k + 1u) * inv;
        let a0 = area_a + da * u0;
        let a1 = area_a + da * u1;
        let area = 0.5 * (a0 + a1) * (u1 - u0);
        if (area <= 0.0) { continue; }
        let num = area_a * 0.5 * (u1 * u1 - u0 * u0) + da * (u1 * u1 * u1 - u0 * u0 * u0) / 3.0;
        let uc = clamp(num / area, u0, u1);
        let pos = la + (lb - la) * uc;
        let sigma = sna + (snb - sna) * uc;
        if (sigma > 0.0) {
            out += gauss_xyz(pos, sigma, area);
        } else {
            let w = max(PF.min_width, 1e-9);
            out += emitted_xyz(pos, -0.5 * w, 0.5 * w, area / w, area / w);
        }
    }
    return out;
}

// Resumable like `main_absorb` (lavapipe's loop limit): each pixel keeps 20 floats of state
// in `bands_buf` between passes (xyz, flag, s_a, t_a, bb_a, temp_a, rho_a, next sample,
// done); an unfinished pixel writes w = -1.
const MAIN_STATE: u32 = 20u;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= P.width || gid.y >= P.height) { return; }
    let pix = gid.y * P.width + gid.x;
    let r = rays[pix];
    let sb = pix * MAIN_STATE;
    iters = 0u;
    load_pf();
    var xyz = vec3<fw>(0.0);
    var flag: fw = 0.0;
    var rho_a: array<fw, 8>;
    var rho_b: array<fw, 8>;
    var s_a: fw = 1.0;
    var t_a: f32 = 0.0;
    var bb_a = vec3<fw>(0.0);
    var temp_a: fw = 0.0;
    var ii = 0u;
    let nsp = min(P.nsp, MAX_SPECIES);
    if (P.pass_index > 0u) {
        if (bands_buf[sb + 19u] != 0.0) { return; }
        xyz = vec3<fw>(bands_buf[sb], bands_buf[sb + 1u], bands_buf[sb + 2u]);
        flag = bands_buf[sb + 3u];
        s_a = bands_buf[sb + 4u];
        t_a = f32(bands_buf[sb + 5u]);
        bb_a = vec3<fw>(bands_buf[sb + 6u], bands_buf[sb + 7u], bands_buf[sb + 8u]);
        temp_a = bands_buf[sb + 9u];
        for (var m = 0u; m < MAX_SPECIES; m++) { iters += 1u; rho_a[m] = bands_buf[sb + 10u + m]; }
        ii = w2u(bands_buf[sb + 18u]);
    }
    if (r.n_seg == 0u) { ii = 1u; }
    while (ii <= r.n_seg && r.n_seg > 0u && iters < P.iter_budget) {
        iters += 1u;
        let i = r.n_seg - ii;
        let t = path_t(r, i);
        let c = corners(sample_pos(r, t));
        for (var m = 0u; m < nsp; m++) {
            iters += 1u;
            rho_b[m] = max(sample_channel(c, m), 0.0);
        }
        var bb_b = vec3<fw>(0.0);
        var temp_b: fw = 0.0;
        var s_b: fw = 1.0;
        var v = vec3<fw>(0.0);
        if (P.has_vel == 1u) { v = sample_velocity(c); }
        let sh = shift_of(v, r.los);
        if (sh.y != 0.0) { flag = 1.0; }
        s_b = sh.x;
        if (!(s_b > 0.0)) { flag = 1.0; s_b = 1.0; }
        if (P.has_bb == 1u) {
            let rho = max(sample_channel(c, P.nsp), 0.0) * PF.bb_factor;
            let temp = max(sample_channel(c, P.nsp + 1u), 0.0) * PF.temp_factor;
            bb_b = bb_xyz(rho, gas_temperature(c) * PF.temp_factor, s_b);
            temp_b = temp;
        }
        if (ii > 0u) {
            let dt = fw(abs(t_a - t));
            let ga = value_factor(s_a) * s_a;
            let gb = value_factor(s_b) * s_b;
            for (var li = 0u; li < P.n_lines; li++) {
                iters += 1u;
                let line = lines[li];
                let m = u32(line.z);
                let ra = rho_a[m];
                let rb = rho_b[m];
                if (ra <= 0.0 && rb <= 0.0) { continue; }
                let base = dt * line.y;
                let area_a = base * ra * ga;
                let area_b = base * rb * gb;
                if (P.broaden == 1u) {
                    xyz += emit_line_xyz(line.x, s_a, s_b, area_a, area_b,
                                         sigma_v(m, temp_a), sigma_v(m, temp_b));
                    continue;
                }
                let la = s_a * line.x;
                let lb = s_b * line.x;
                let wdt = max(abs(lb - la), PF.min_width);
                let mid = 0.5 * (la + lb);
                let lo = mid - 0.5 * wdt;
                let hi = mid + 0.5 * wdt;
                let hh = trap_heights(la, lb, area_a, area_b, wdt);
                let h0 = hh.x;
                let h1 = hh.y;
                if (hi < PF.range_lo || lo > PF.range_hi || (h0 <= 0.0 && h1 <= 0.0)) { continue; }
                xyz += trapezoid_xyz(lo, hi, h0, h1);
            }
            xyz += 0.5 * dt * (bb_a + bb_b);
        }
        for (var m = 0u; m < nsp; m++) { iters += 1u; rho_a[m] = rho_b[m]; }
        s_a = s_b;
        t_a = t;
        bb_a = bb_b;
        temp_a = temp_b;
        ii++;
        if (limiter_exhausted(P.probe_n)) { flag = 2.0; ii = r.n_seg + 1u; break; }
    }
    // One sample that alone passed the adapter's loop limit may have been cut short.
    if (iters >= P.iter_limit) { flag = 2.0; ii = r.n_seg + 1u; }
    let done = ii > r.n_seg;
    bands_buf[sb] = xyz.x;
    bands_buf[sb + 1u] = xyz.y;
    bands_buf[sb + 2u] = xyz.z;
    bands_buf[sb + 3u] = flag;
    bands_buf[sb + 4u] = s_a;
    bands_buf[sb + 5u] = fw(t_a);
    bands_buf[sb + 6u] = bb_a.x;
    bands_buf[sb + 7u] = bb_a.y;
    bands_buf[sb + 8u] = bb_a.z;
    bands_buf[sb + 9u] = temp_a;
    for (var m = 0u; m < MAX_SPECIES; m++) { bands_buf[sb + 10u + m] = rho_a[m]; }
    bands_buf[sb + 18u] = u2w(ii);
    bands_buf[sb + 19u] = select(fw(0.0), fw(1.0), done);
    if (done) {
        out_xyz[pix] = vec4<fw>(xyz, flag);
    } else {
        out_xyz[pix] = vec4<fw>(0.0, 0.0, 0.0, -1.0);
    }
}

// ---- Banded integrator (Algorithm 1), emission only -------------------------------------
// Without absorption the XYZ of the band values is linear in them, so each deposit into band
// d adds W[d] x value to XYZ directly (W[d]: the CMF integrals over band d, from the host):
// no per-ray band array.

fn band_weight(d: u32) -> vec3<fw> {
    let o = P.off_band_w + 3u * d;
    return vec3<fw>(tables[o], tables[o + 1u], tables[o + 2u]);
}

// blueshift-spectrum's BandLayout::band_of: the band holding x, or n_bands for none.
fn band_of(x: fw) -> u32 {
    if (!(x >= PF.range_lo && x < PF.range_hi)) { return P.n_bands; }
    return min(u32(floor((x - PF.range_lo) / PF.band_w)), P.n_bands - 1u);
}

// The banded `deposit`: a box of `area` over [lo, hi) spread over the bands it overlaps, as
// band means, each weighted by its CMF integrals.
fn add_band(d: u32, value: fw) {
    if (P.absorbing == 1u) {
        bands_buf[band_base + d] += value;
    } else {
        acc_xyz += band_weight(d) * value;
    }
}

fn deposit_add(lo: fw, hi: fw, area: fw) {
    let l = max(lo, PF.range_lo);
    let h = min(hi, PF.range_hi);
    if (h <= l || hi <= lo) { return; }
    let height = area / (hi - lo);
    let first = min(u32(floor((l - PF.range_lo) / PF.band_w)), P.n_bands - 1u);
    for (var i = first; i < P.n_bands; i++) { iters += 1u;
        let s = PF.range_lo + fw(i) * PF.band_w;
        if (s >= h) { break; }
        let ov = min(h, s + PF.band_w) - max(l, s);
        if (ov > 0.0) { add_band(i, height * ov / PF.band_w); }
    }
}

// Multiplies the bands a shifted absorption box overlaps by exp(-len rho k_band).
fn deposit_absorb(lo: fw, hi: fw, area: fw, len_rho: fw) {
    let l = max(lo, PF.range_lo);
    let h = min(hi, PF.range_hi);
    if (h <= l || hi <= lo) { return; }
    let height = area / (hi - lo);
    let first = min(u32(floor((l - PF.range_lo) / PF.band_w)), P.n_bands - 1u);
    for (var i = first; i < P.n_bands; i++) { iters += 1u;
        let s = PF.range_lo + fw(i) * PF.band_w;
        if (s >= h) { break; }
        let ov = min(h, s + PF.band_w) - max(l, s);
        if (ov > 0.0) {
            bands_buf[band_base + i] *= exp_fw(-len_rho * (height * ov / PF.band_w));
        }
    }
}

// blueshift-tracking's `absorb_half`: the sample's optical depth over path length `len`.
fn absorb(rho: ptr<function, array<fw, 8>>, sh: fw, len: fw) {
    for (var li = P.n_lines; li < P.n_lines + P.n_abs; li++) { iters += 1u;
        let line = lines[li];
        let m = u32(line.z);
        let rm = (*rho)[m];
        if (rm <= 0.0) { continue; }
        if (P.shift_mode == 0u) {
            let d = band_of(line.x * sh);
            if (d < P.n_bands) {
                bands_buf[band_base + d] *= exp_fw(-len * rm * line.y);
            }
        } else {
            deposit_absorb(sh * (line.x - 0.5 * PF.min_width), sh * (line.x + 0.5 * PF.min_width),
                           line.y, len * rm);
        }
    }
}

// Path position of sample i (f32, as the CPU's `RaySamples::t`).
fn path_t(r: PixelRay, i: u32) -> f32 {
    if (i == r.n_seg) { return r.len; }
    return min(f32(i) * P.step, r.len);
}

@compute @workgroup_size(8, 8, 1)
fn main_banded(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= P.width || gid.y >= P.height) { return; }
    let pix = gid.y * P.width + gid.x;
    let r = rays[pix];
    acc_xyz = vec3<fw>(0.0);
    band_base = pix * P.n_bands;
    iters = 0u;
    load_pf();
    var flag: fw = 0.0;
    var rho: array<fw, 8>;
    let nsp = min(P.nsp, MAX_SPECIES);
    if (P.absorbing == 1u) {
        for (var b = 0u; b < P.n_bands; b++) { iters += 1u; bands_buf[band_base + b] = 0.0; }
    }
    if (r.n_seg > 0u) {
        for (var ii = 0u; ii <= r.n_seg; ii++) { iters += 1u;
            let i = r.n_seg - ii;
            let t = path_t(r, i);
            var wt: fw = 0.0;
            if (i < r.n_seg) { wt += fw(abs(path_t(r, i + 1u) - t)); }
            if (i > 0u) { wt += fw(abs(t - path_t(r, i - 1u))); }
            wt *= 0.5;
            let c = corners(sample_pos(r, t));
            for (var m = 0u; m < nsp; m++) { iters += 1u;
                rho[m] = max(sample_channel(c, m), 0.0);
            }
            var v = vec3<fw>(0.0);
            if (P.has_vel == 1u) { v = sample_velocity(c); }
            let shv = shift_of(v, r.los);
            if (shv.y != 0.0) { flag = 1.0; }
            var sh = shv.x;
            if (!(sh > 0.0)) { flag = 1.0; sh = 1.0; }
            let g = value_factor(sh) * sh;
            if (P.absorbing == 1u) { absorb(&rho, sh, 0.5 * wt); }
            for (var li = 0u; li < P.n_lines; li++) { iters += 1u;
                let line = lines[li];
                let m = u32(line.z);
                let rm = rho[m];
                if (rm <= 0.0) { continue; }
                if (P.shift_mode == 0u) {
                    let d = band_of(line.x * sh);
                    if (d < P.n_bands) { add_band(d, wt * rm * g * line.y); }
                } else {
                    deposit_add(sh * (line.x - 0.5 * PF.min_width),
                                sh * (line.x + 0.5 * PF.min_width),
                                wt * rm * g * line.y);
                }
            }
            if (P.has_bb == 1u) {
                let brho = max(sample_channel(c, P.nsp), 0.0) * PF.bb_factor;
                let temp = gas_temperature(c) * PF.temp_factor;
                if (brho > 0.0 && temp > 0.0) {
                    let k = wt * brho * value_factor(sh);
                    for (var b = 0u; b < P.n_bands; b++) { iters += 1u;
                        let cb = tables[P.off_band_c + b];
                        add_band(b, k * planck(cb / sh, temp));
                    }
                }
            }
            if (P.absorbing == 1u) { absorb(&rho, sh, 0.5 * wt); }
        }
    }
    if (P.absorbing == 1u) {
        for (var b = 0u; b < P.n_bands; b++) { iters += 1u;
            acc_xyz += band_weight(b) * bands_buf[band_base + b];
        }
    }
    // lavapipe stops every loop of an invocation after 65535 iterations: report, not a
    // silently short ray.
    if (iters >= P.iter_limit || limiter_exhausted(P.probe_n)) { flag = 2.0; }
    out_xyz[pix] = vec4<fw>(acc_xyz, flag);
}

// ---- Piecewise-linear integrator with absorption, front to back ---------------------------
// blueshift-tracking's `front_to_back` (pwl.rs): marching from the eye, the ray keeps only
// the optical depth in front, tau_front(lambda), as a sorted array of linear pieces
// (start, end, value at start, value at end) in its own region of `bands_buf` (the host
// sizes it: `stride` floats per ray of the tile). Region layout, in pieces of 4 floats:
//   A  [0, L)            tau_front
//   B  [L, 2L)           tau_front + half the segment's depth (tau_mid)
//   TR [2L, 2L + M)      the segment's absorption trapezoids (half heights), M = n_abs
//   EP [2L + M, 2L + 2M) their sorted end points (4 per piece)
//   TT [2L + 2M, 2L + 4M) their sum as sorted pieces
// A segment's emission E adds its closed-form XYZ to `xyz`, and what tau_mid takes from it,
// integral E (1 - exp(-tau_mid)) cmf over tau_mid's support, to `taken` (exact per
// sub-interval cut at tau's, E's and the CMF table's breakpoints, exponential moments from the
// end where tau is smaller). The pixel is max(xyz - taken, 0).

const BAD: u32 = 0xffffffffu;
const BIG = 3.0e38;

var<private> rbase: u32;        // first float of this ray's region in bands_buf
var<private> rho_f: array<fw, 8>;
var<private> rho_n: array<fw, 8>;
var<private> fell_back: bool;   // the piece budget (or the device cap) forced coarser merges
var<private> budget_scale: fw;
// Loop iterations of this invocation (lavapipe stops every loop of an invocation after 65535
// iterations in all: the kernel counts its own and yields before, see `iter_budget`).
var<private> iters: u32;

struct Samp {
    t: f32,         // path position (f32, as the CPU's samples)
    s: fw,
    bbr: fw,       // black-body density x factor x BB_UNIT (0: none)
    temp: fw,      // temperature x factor (thermal broadening)
    btemp: fw,     // the black body's temperature x factor (see gas_temperature)
    bbx: vec3<fw>, // XYZ of the sample's black-body row (hat weights)
    bad: bool,      // the shift was invalid
}

fn pget(k: u32) -> vec4<fw> {
    let o = rbase + 4u * k;
    return vec4<fw>(bands_buf[o], bands_buf[o + 1u], bands_buf[o + 2u], bands_buf[o + 3u]);
}

fn pset(k: u32, v: vec4<fw>) {
    let o = rbase + 4u * k;
    bands_buf[o] = v.x;
    bands_buf[o + 1u] = v.y;
    bands_buf[o + 2u] = v.z;
    bands_buf[o + 3u] = v.w;
}

fn fget(k: u32) -> fw { return bands_buf[rbase + k]; }
fn fset(k: u32, v: fw) { bands_buf[rbase + k] = v; }

fn pat(p: vec4<fw>, x: fw) -> fw { return lerp_at(p.x, p.y, p.z, p.w, x); }

// Samples the ray at path position t: densities into `rho` (far or near), shift, black body.
fn sample_at(r: PixelRay, t: f32, far: bool) -> Samp {
    var o: Samp;
    o.t = t;
    o.bad = false;
    let c = corners(sample_pos(r, t));
    let nsp = min(P.nsp, MAX_SPECIES);
    for (var m = 0u; m < nsp; m++) { iters += 1u;
        let v = max(sample_channel(c, m), 0.0);
        if (far) { rho_f[m] = v; } else { rho_n[m] = v; }
    }
    var v = vec3<fw>(0.0);
    if (P.has_vel == 1u) { v = sample_velocity(c); }
    let shv = shift_of(v, r.los);
    if (shv.y != 0.0) { o.bad = true; }
    var s = shv.x;
    if (!(s > 0.0)) { o.bad = true; s = 1.0; }
    o.s = s;
    o.bbr = 0.0;
    o.temp = 0.0;
    o.btemp = 0.0;
    o.bbx = vec3<fw>(0.0);
    if (P.has_bb == 1u) {
        o.bbr = max(sample_channel(c, P.nsp), 0.0) * PF.bb_factor;
        o.temp = max(sample_channel(c, P.nsp + 1u), 0.0) * PF.temp_factor;
        o.btemp = gas_temperature(c) * PF.temp_factor;
        o.bbx = bb_xyz(o.bbr, o.btemp, s);
    }
    return o;
}

fn has_bb_row(a: Samp) -> bool { return a.bbr > 0.0 && a.btemp > 0.0; }

// One sample's black-body value on grid point i (the CPU's `bb_row`).
fn bb_value(a: Samp, i: u32) -> fw {
    if (!has_bb_row(a)) { return 0.0; }
    return value_factor(a.s) * a.bbr * planck(tables[P.off_lambda + i] / a.s, a.btemp);
}

struct Trap {
    t: vec4<fw>,   // lo, hi, value at lo, value at hi
    ok: bool,
}

// Line entry `li` over the segment (a = far end, b = near end), as `segment_lines` gives it:
// emission (values include the shift factor k(s) s) or optical depth, times `scale`.
fn seg_trap(li: u32, far: Samp, near: Samp, dt: fw, emission: bool, scale: fw) -> Trap {
    var o: Trap;
    o.ok = false;
    let line = lines[li];
    let m = u32(line.z);
    let ra = rho_f[m];
    let rb = rho_n[m];
    if (ra <= 0.0 && rb <= 0.0) { return o; }
    var ga: fw = 1.0;
    var gb: fw = 1.0;
    if (emission) {
        ga = value_factor(far.s) * far.s;
        gb = value_factor(near.s) * near.s;
    }
    let base = scale * dt * line.y;
    let area_a = base * ra * ga;
    let area_b = base * rb * gb;
    let la = far.s * line.x;
    let lb = near.s * line.x;
    let wdt = max(abs(lb - la), PF.min_width);
    let mid = 0.5 * (la + lb);
    let lo = mid - 0.5 * wdt;
    let hi = mid + 0.5 * wdt;
    let hh = trap_heights(la, lb, area_a, area_b, wdt);
    let h0 = hh.x;
    let h1 = hh.y;
    if (hi < PF.range_lo || lo > PF.range_hi || (h0 <= 0.0 && h1 <= 0.0)) { return o; }
    o.t = vec4<fw>(lo, hi, h0, h1);
    o.ok = hi > lo;
    return o;
}

// Inserts x into the sorted, duplicate-free floats [e0, e0 + n); returns the new count.
fn insert_sorted(e0: u32, n: u32, x: fw) -> u32 {
    var i = 0u;
    while (i < n && fget(e0 + i) < x) { iters += 1u; i++; }
    if (i < n && fget(e0 + i) == x) { return n; }
    for (var j = n; j > i; j--) { iters += 1u; fset(e0 + j, fget(e0 + j - 1u)); }
    fset(e0 + i, x);
    return n + 1u;
}

// The sum of the mt trapezoids at TR as sorted pieces at TT (cut at every end point, gaps
// left out, as repeated `add_trapezoid` gives it). Returns the piece count.
fn build_sum(tr: u32, ep: u32, tt: u32, mt: u32) -> u32 {
    let e0 = 4u * ep;
    var ne = 0u;
    for (var i = 0u; i < mt; i++) { iters += 1u;
        let q = pget(tr + i);
        ne = insert_sorted(e0, ne, q.x);
        ne = insert_sorted(e0, ne, q.y);
    }
    var nt = 0u;
    for (var k = 0u; k + 1u < ne; k++) { iters += 1u;
        let x0 = fget(e0 + k);
        let x1 = fget(e0 + k + 1u);
        var v0: fw = 0.0;
        var v1: fw = 0.0;
        var covered = false;
        for (var i = 0u; i < mt; i++) { iters += 1u;
            let q = pget(tr + i);
            if (q.x <= x0 && x1 <= q.y) {
                covered = true;
                v0 += pat(q, x0);
                v1 += pat(q, x1);
            }
        }
        if (covered) {
            pset(tt + nt, vec4<fw>(x0, x1, v0, v1));
            nt++;
        }
    }
    return nt;
}

// dst = src (na pieces) + tt (nt pieces), both sorted and disjoint: cut at the breakpoints
// of both where either is non-zero, as `PiecewiseLinear::add_trapezoid`. BAD when more than
// `cap` pieces would be needed (src is left untouched).
fn sum_into(src: u32, na: u32, tt: u32, nt: u32, dst: u32, cap: u32) -> u32 {
    var i = 0u;
    var j = 0u;
    var n = 0u;
    var x: fw = -BIG;
    loop { iters += 1u;
        let has_p = i < na;
        let has_q = j < nt;
        if (!has_p && !has_q) { break; }
        var p = vec4<fw>(0.0);
        var q = vec4<fw>(0.0);
        var ps: fw = BIG;
        var qs: fw = BIG;
        if (has_p) { p = pget(src + i); ps = max(p.x, x); }
        if (has_q) { q = pget(tt + j); qs = max(q.x, x); }
        let s = min(ps, qs);
        var e: fw = BIG;
        if (has_p) { if (ps > s) { e = min(e, ps); } else { e = min(e, p.y); } }
        if (has_q) { if (qs > s) { e = min(e, qs); } else { e = min(e, q.y); } }
        var v0: fw = 0.0;
        var v1: fw = 0.0;
        if (has_p && ps <= s) { v0 += pat(p, s); v1 += pat(p, e); }
        if (has_q && qs <= s) { v0 += pat(q, s); v1 += pat(q, e); }
        if (n >= cap) { return BAD; }
        pset(dst + n, vec4<fw>(s, e, v0, v1));
        n++;
        x = e;
        if (has_p && p.y <= x) { i++; }
        if (has_q && q.y <= x) { j++; }
    }
    return n;
}

// `PiecewiseLinear::merged(tol)` in place on [off, off + n): runs of contiguous pieces become
// one line while it stays within tol of every breakpoint (a cone of slopes from the run's
// start); zero pieces, and runs merged into zero, are dropped (as the CPU's
// `from_sorted_unchecked`). With `bridge` (the device's last resort, counted as a
// fallback) runs also cross gaps, the line kept within tol of zero over the gap.
fn merge(off: u32, n: u32, tol: fw, bridge: bool) -> u32 {
    var out = 0u;
    var have = false;
    var x0: fw = 0.0;
    var y0: fw = 0.0;
    var xe: fw = 0.0;
    var ye: fw = 0.0;
    var lo: fw = -BIG;
    var hi: fw = BIG;
    for (var k = 0u; k < n; k++) { iters += 1u;
        let p = pget(off + k);
        if (p.z == 0.0 && p.w == 0.0) {
            if (have) {
                if (y0 != 0.0 || ye != 0.0) {
                    pset(off + out, vec4<fw>(x0, xe, y0, ye));
                    out++;
                }
                have = false;
            }
            continue;
        }
        if (have && (xe == p.x || bridge)) {
            var l2 = lo;
            var h2 = hi;
            let dx = xe - x0;
            l2 = max(l2, (ye - tol - y0) / dx);
            h2 = min(h2, (ye + tol - y0) / dx);
            if (xe == p.x) {
                l2 = max(l2, (p.z - tol - y0) / dx);
                h2 = min(h2, (p.z + tol - y0) / dx);
            } else {
                let dg = p.x - x0;
                l2 = max(l2, max((-tol - y0) / dx, (-tol - y0) / dg));
                h2 = min(h2, min((tol - y0) / dx, (tol - y0) / dg));
                l2 = max(l2, (p.z - tol - y0) / dg);
                h2 = min(h2, (p.z + tol - y0) / dg);
            }
            let slope = (p.w - y0) / (p.y - x0);
            if (l2 <= slope && slope <= h2) {
                lo = l2;
                hi = h2;
                xe = p.y;
                ye = p.w;
                continue;
            }
        }
        if (have && (y0 != 0.0 || ye != 0.0)) {
            pset(off + out, vec4<fw>(x0, xe, y0, ye));
            out++;
        }
        have = true;
        x0 = p.x;
        y0 = p.z;
        xe = p.y;
        ye = p.w;
        lo = -BIG;
        hi = BIG;
    }
    if (have && (y0 != 0.0 || ye != 0.0)) {
        pset(off + out, vec4<fw>(x0, xe, y0, ye));
        out++;
    }
    return out;
}

fn max_value(off: u32, n: u32) -> fw {
    var m: fw = 0.0;
    for (var k = 0u; k < n; k++) { iters += 1u;
        let p = pget(off + k);
        m = max(m, max(p.z, p.w));
    }
    return m;
}

// dst = src + tt; when that needs more than L pieces, src is merged across gaps with growing
// tolerances until it fits (the device cap's fallback, counted). Returns dst's count or BAD.
fn add_sum(src: u32, n_src: ptr<function, u32>, tt: u32, nt: u32, dst: u32) -> u32 {
    var n = sum_into(src, *n_src, tt, nt, dst, P.region_l);
    var tol = max(PF.merge_tol * budget_scale, 1e-6 * max_value(src, *n_src));
    var guard = 0u;
    while (n == BAD && guard < 64u) { iters += 1u;
        fell_back = true;
        tol = min(tol * 4.0, 1e30);
        *n_src = merge(src, *n_src, tol, true);
        n = sum_into(src, *n_src, tt, nt, dst, P.region_l);
        guard++;
    }
    return n;
}

// `[int_0^h x^n exp(-s x) dx, n = 0, 1, 2]` for s >= 0: the series below |s h| = SERIES_Z
// (the recurrence cancels there; in f32 the switch is at 1, where 12 terms leave < 2e-10 and
// the recurrence above loses < 20 ulp; in f64 at 0.05 as on the CPU, 12 terms leave < 1e-24
// and the recurrence loses < 400 ulp).
fn exp_moments(s: fw, h: fw) -> vec3<fw> {
    let z = s * h;
    if (z < SERIES_Z) {
        // sum_k (-z)^k / k! / (n + k + 1), k = 0..11, as straight-line code (a loop here
        // would spend the software adapter's loop budget once per sub-interval).
        let y = -z;
        var m = vec3<fw>(1.0, 0.5, 1.0 / 3.0);
        var t = y;
        m += t * vec3<fw>(1.0 / 2.0, 1.0 / 3.0, 1.0 / 4.0);
        t *= y / 2.0;
        m += t * vec3<fw>(1.0 / 3.0, 1.0 / 4.0, 1.0 / 5.0);
        t *= y / 3.0;
        m += t * vec3<fw>(1.0 / 4.0, 1.0 / 5.0, 1.0 / 6.0);
        t *= y / 4.0;
        m += t * vec3<fw>(1.0 / 5.0, 1.0 / 6.0, 1.0 / 7.0);
        t *= y / 5.0;
        m += t * vec3<fw>(1.0 / 6.0, 1.0 / 7.0, 1.0 / 8.0);
        t *= y / 6.0;
        m += t * vec3<fw>(1.0 / 7.0, 1.0 / 8.0, 1.0 / 9.0);
        t *= y / 7.0;
        m += t * vec3<fw>(1.0 / 8.0, 1.0 / 9.0, 1.0 / 10.0);
        t *= y / 8.0;
        m += t * vec3<fw>(1.0 / 9.0, 1.0 / 10.0, 1.0 / 11.0);
        t *= y / 9.0;
        m += t * vec3<fw>(1.0 / 10.0, 1.0 / 11.0, 1.0 / 12.0);
        t *= y / 10.0;
        m += t * vec3<fw>(1.0 / 11.0, 1.0 / 12.0, 1.0 / 13.0);
        t *= y / 11.0;
        m += t * vec3<fw>(1.0 / 12.0, 1.0 / 13.0, 1.0 / 14.0);
        return vec3<fw>(m.x * h, m.y * h * h, m.z * h * h * h);
    }
    let e = exp_fw(-z);
    let i0 = (1.0 - e) / s;
    let i1 = (i0 - h * e) / s;
    let i2 = (2.0 * i1 - h * h * e) / s;
    return vec3<fw>(i0, i1, i2);
}

// integral over [u, w] of E C (1 - exp(-tau)), E and C linear (values at the ends), tau
// linear with the piece's slope; the exponential taken from the end where tau is smaller.
fn absorbed_on(u: fw, w: fw, e_u: fw, e_w: fw, c_u: vec3<fw>, c_w: vec3<fw>,
               tau_u: fw, tau_w: fw, slope: fw) -> vec3<fw> {
    let h = w - u;
    var base: fw = 0.0;
    var m = vec3<fw>(0.0);
    let flip = slope < 0.0;
    if (flip) {
        base = exp_fw(-max(tau_w, 0.0));
        m = exp_moments(-slope, h);
    } else {
        base = exp_fw(-max(tau_u, 0.0));
        m = exp_moments(slope, h);
    }
    let de = (e_w - e_u) / h;
    let dc = (c_w - c_u) / h;
    let q0 = e_u * c_u;
    let q1 = e_u * dc + de * c_u;
    let q2 = de * dc;
    let full = q0 * h + q1 * (h * h / 2.0) + q2 * (h * h * h / 3.0);
    var r0 = q0;
    var r1 = q1;
    if (flip) {
        r0 = q0 + q1 * h + q2 * (h * h);
        r1 = -q1 - 2.0 * q2 * h;
    }
    return full - base * (r0 * m.x + r1 * m.y + q2 * m.z);
}

// The heights at the low and high ends of a line's trapezoid of width `wdt` swept from `la`
// to `lb` (the CPU's `pwl::line_trapezoid`): the mean height tilted by the swept fraction of
// the width, so a still line emits a flat box and the result is continuous in the velocity.
fn trap_heights(la: fw, lb: fw, area_a: fw, area_b: fw, wdt: fw) -> vec2<fw> {
    let sweep = abs(lb - la);
    let mean = 0.5 * (area_a + area_b) / wdt;
    let tilt = 0.5 * (area_b - area_a) / wdt * (sweep / wdt);
    let ha = max(mean - tilt, 0.0);
    let hb = max(mean + tilt, 0.0);
    if (la <= lb) { return vec2<fw>(ha, hb); }
    return vec2<fw>(hb, ha);
}

// The next node of the grid base + k step strictly after u.
fn next_node(u: fw, base: fw, step: fw) -> fw {
    let k = floor((u - base) / step) + 1.0;
    var x = base + k * step;
    if (x <= u) { x = base + (k + 1.0) * step; }
    return x;
}

fn cmf_hi() -> fw { return PF.cmf_lo + PF.cmf_step * fw(P.cmf_n - 1u); }

// The CMFs at x, on the table interval holding `mid`.
fn cmf_on(mid: fw, x: fw) -> vec3<fw> {
    let k = min(u32(max(floor((mid - PF.cmf_lo) / PF.cmf_step), 0.0)), P.cmf_n - 2u);
    let x0 = PF.cmf_lo + fw(k) * PF.cmf_step;
    let g0 = cmf(k);
    let g1 = cmf(k + 1u);
    return g0 + (g1 - g0) * ((x - x0) / PF.cmf_step);
}

// What tau (region off, n pieces) takes from the segment's black body (the trapezoid rule
// along the ray on the black-body grid: row_i = dt (f_far,i + f_near,i) / 2).
fn absorbed_bb(off: u32, n: u32, far: Samp, near: Samp, dt: fw) -> vec3<fw> {
    var out = vec3<fw>(0.0);
    let kk = P.bb_k;
    let g0 = tables[P.off_lambda];
    let g1 = tables[P.off_lambda + kk - 1u];
    let gstep = (g1 - g0) / fw(kk - 1u);
    var cached = BAD;
    var r0: fw = 0.0;
    var r1: fw = 0.0;
    for (var k = 0u; k < n; k++) { iters += 1u;
        let p = pget(off + k);
        if (p.z <= 0.0 && p.w <= 0.0) { continue; }
        let lo = max(p.x, max(PF.cmf_lo, g0));
        let hi = min(p.y, min(cmf_hi(), g1));
        if (!(hi > lo)) { continue; }
        let slope = (p.w - p.z) / (p.y - p.x);
        var u = lo;
        var guard = 0u;
        while (u < hi && guard < 100000u) { iters += 1u;
            guard++;
            let w = min(hi, min(next_node(u, PF.cmf_lo, PF.cmf_step), next_node(u, g0, gstep)));
            let mid = 0.5 * (u + w);
            let gi = min(u32(max(floor((mid - g0) / gstep), 0.0)), kk - 2u);
            if (gi != cached) {
                cached = gi;
                r0 = 0.5 * dt * (bb_value(far, gi) + bb_value(near, gi));
                r1 = 0.5 * dt * (bb_value(far, gi + 1u) + bb_value(near, gi + 1u));
            }
            let xi = tables[P.off_lambda + gi];
            let xj = tables[P.off_lambda + gi + 1u];
            let e_u = lerp_at(xi, xj, r0, r1, u);
            let e_w = lerp_at(xi, xj, r0, r1, w);
            if (e_u > 0.0 || e_w > 0.0) {
                out += absorbed_on(u, w, e_u, e_w, cmf_on(mid, u), cmf_on(mid, w),
                                   pat(p, u), pat(p, w), slope);
            }
            u = w;
        }
    }
    return out;
}

// What tau (region off, n pieces) takes from one emission trapezoid.
fn absorbed_line(off: u32, n: u32, tr: vec4<fw>) -> vec3<fw> {
    var out = vec3<fw>(0.0);
    let a = max(tr.x, PF.cmf_lo);
    let b = min(tr.y, cmf_hi());
    if (!(b > a)) { return out; }
    // First piece ending after a.
    var lo_i = 0u;
    var hi_i = n;
    while (lo_i < hi_i) { iters += 1u;
        let mid = (lo_i + hi_i) / 2u;
        if (pget(off + mid).y <= a) { lo_i = mid + 1u; } else { hi_i = mid; }
    }
    for (var k = lo_i; k < n; k++) { iters += 1u;
        let p = pget(off + k);
        if (p.x >= b) { break; }
        if (p.z <= 0.0 && p.w <= 0.0) { continue; }
        let slope = (p.w - p.z) / (p.y - p.x);
        var u = max(a, p.x);
        let end = min(b, p.y);
        var guard = 0u;
        while (u < end && guard < 100000u) { iters += 1u;
            guard++;
            let w = min(end, next_node(u, PF.cmf_lo, PF.cmf_step));
            let mid = 0.5 * (u + w);
            let e_u = lerp_at(tr.x, tr.y, tr.z, tr.w, u);
            let e_w = lerp_at(tr.x, tr.y, tr.z, tr.w, w);
            if (e_u > 0.0 || e_w > 0.0) {
                out += absorbed_on(u, w, e_u, e_w, cmf_on(mid, u), cmf_on(mid, w),
                                   pat(p, u), pat(p, w), slope);
            }
            u = w;
        }
    }
    return out;
}

// ---- Broadened lines with absorption -------------------------------------------------------
// With broadening each line's sweep is the CPU's `emit_line`: a trapezoid or up to 64
// Gaussians of 32 pieces. Its sources are handled one at a time: mode 1 returns what tau
// (region off, n pieces) takes from them (emission lines); mode 2 adds them at half height
// to tau_front (absorption lines), one merge pass per source between the two regions
// (`t_cur` holds the current tau, `t_n` its pieces).
var<private> t_cur: u32;
var<private> t_oth: u32;
var<private> t_n: u32;
var<private> t_bad: bool;
var<private> t_tt: u32;     // scratch pieces for one source

fn add_run(nt: u32) {
    var n = t_n;
    let r = add_sum(t_cur, &n, t_tt, nt, t_oth);
    if (r == BAD) { t_bad = true; return; }
    t_n = r;
    let c = t_cur;
    t_cur = t_oth;
    t_oth = c;
}

fn source_trap(lo: fw, hi: fw, h0: fw, h1: fw, mode: u32, off: u32, n: u32) -> vec3<fw> {
    if (hi < PF.range_lo || lo > PF.range_hi || (h0 <= 0.0 && h1 <= 0.0) || !(hi > lo)) {
        return vec3<fw>(0.0);
    }
    if (mode == 1u) { return absorbed_line(off, n, vec4<fw>(lo, hi, h0, h1)); }
    pset(t_tt, vec4<fw>(lo, hi, 0.5 * h0, 0.5 * h1));
    add_run(1u);
    return vec3<fw>(0.0);
}

fn source_gauss(pos: fw, sigma: fw, area: fw, mode: u32, off: u32, n: u32) -> vec3<fw> {
    var out = vec3<fw>(0.0);
    let ng = P.n_gauss;
    let z0 = gz(0u);
    let zn = gz(ng - 1u);
    let hz = (zn - z0) / fw(ng - 1u);
    let kk = area / sigma;
    var cnt = 0u;
    for (var i = 0u; i + 1u < ng; i++) {
        iters += 1u;
        let lo = pos + gz(i) * sigma;
        let hi = pos + gz(i + 1u) * sigma;
        let h0 = kk * gg(i);
        let h1 = kk * gg(i + 1u);
        if (hi < PF.range_lo || lo > PF.range_hi || (h0 <= 0.0 && h1 <= 0.0) || !(hi > lo)) {
            continue;
        }
        if (mode == 1u) {
            out += absorbed_line(off, n, vec4<fw>(lo, hi, h0, h1));
        } else {
            pset(t_tt + cnt, vec4<fw>(lo, hi, 0.5 * h0, 0.5 * h1));
            cnt++;
        }
    }
    if (mode == 2u && cnt > 0u) { add_run(cnt); }
    return out;
}

// `emit_line` with its sources handled by `mode` (see above).
fn emit_line_sources(centre: fw, sa: fw, sb: fw, area_a: fw, area_b: fw, sig_a: fw,
                     sig_b: fw, mode: u32, off: u32, n: u32) -> vec3<fw> {
    var out = vec3<fw>(0.0);
    let la = sa * centre;
    let lb = sb * centre;
    let sna = la * sig_a / C_M_PER_S;
    let snb = lb * sig_b / C_M_PER_S;
    let sigma_mean = 0.5 * (sna + snb);
    let sweep = abs(lb - la);
    if (sigma_mean <= 0.0 || sweep >= 16.0 * sigma_mean) {
        var mw = PF.min_width;
        if (sigma_mean > 0.0) { mw = 0.0; }
        let wdt = max(sweep, mw);
        let mid = 0.5 * (la + lb);
        if (!(wdt > 0.0)) { return out; }
        let hh = trap_heights(la, lb, area_a, area_b, wdt);
        let h0 = hh.x;
        let h1 = hh.y;
        return source_trap(mid - 0.5 * wdt, mid + 0.5 * wdt, h0, h1, mode, off, n);
    }
    let mm = u32(clamp(ceil(4.0 * sweep / sigma_mean), 1.0, 64.0));
    let inv = 1.0 / fw(mm);
    let da = area_b - area_a;
    for (var k = 0u; k < mm; k++) {
        iters += 1u;
        let u0 = fw(k) * inv;
        let u1 = fw(k + 1u) * inv;
        let a0 = area_a + da * u0;
        let a1 = area_a + da * u1;
        let area = 0.5 * (a0 + a1) * (u1 - u0);
        if (area <= 0.0) { continue; }
        let num = area_a * 0.5 * (u1 * u1 - u0 * u0) + da * (u1 * u1 * u1 - u0 * u0 * u0) / 3.0;
        let uc = clamp(num / area, u0, u1);
        let pos = la + (lb - la) * uc;
        let sigma = sna + (snb - sna) * uc;
        if (sigma > 0.0) {
            out += source_gauss(pos, sigma, area, mode, off, n);
        } else {
            let w = max(PF.min_width, 1e-9);
            out += source_trap(pos - 0.5 * w, pos + 0.5 * w, area / w, area / w, mode, off, n);
        }
    }
    return out;
}

// Line entry li's areas over the segment (a = far end, b = near end), and its species.
struct LineAreas {
    ok: bool,
    m: u32,
    area_a: fw,
    area_b: fw,
}

fn line_areas(li: u32, far: Samp, near: Samp, dt: fw, emission: bool) -> LineAreas {
    var o: LineAreas;
    let line = lines[li];
    o.m = u32(line.z);
    let ra = rho_f[o.m];
    let rb = rho_n[o.m];
    o.ok = !(ra <= 0.0 && rb <= 0.0);
    var ga: fw = 1.0;
    var gb: fw = 1.0;
    if (emission) {
        ga = value_factor(far.s) * far.s;
        gb = value_factor(near.s) * near.s;
    }
    let base = dt * line.y;
    o.area_a = base * ra * ga;
    o.area_b = base * rb * gb;
    return o;
}

// Adds half of the segment's broadened absorption lines to tau (t_cur, t_n).
fn add_broadened_half(far: Samp, near: Samp, dt: fw) {
    for (var li = P.n_lines; li < P.n_lines + P.n_abs; li++) {
        iters += 1u;
        let a = line_areas(li, far, near, dt, false);
        if (!a.ok) { continue; }
        let line = lines[li];
        emit_line_sources(line.x, far.s, near.s, a.area_a, a.area_b, sigma_v(a.m, far.temp),
                          sigma_v(a.m, near.temp), 2u, 0u, 0u);
    }
}

// Per-ray state between passes (floats at the start of the ray's region, 8 pieces): the
// kernel yields after `iter_budget` loop iterations and the host dispatches it again.
const ST_PIECES: u32 = 8u;

fn save_state(xyz: vec3<fw>, taken: vec3<fw>, na: u32, merges: u32, merge_at: u32,
              max_pieces: u32, flags: u32, seg: u32, near: Samp) {
    fset(0u, xyz.x); fset(1u, xyz.y); fset(2u, xyz.z);
    fset(3u, taken.x); fset(4u, taken.y); fset(5u, taken.z);
    fset(6u, u2w(na));
    fset(7u, u2w(merges));
    fset(8u, u2w(merge_at));
    fset(9u, u2w(max_pieces));
    fset(10u, budget_scale);
    fset(11u, u2w(flags));
    fset(12u, u2w(seg));
    fset(13u, fw(near.t)); fset(14u, near.s); fset(15u, near.bbr); fset(16u, near.temp);
    fset(17u, near.bbx.x); fset(18u, near.bbx.y); fset(19u, near.bbx.z);
    // Slot 28: after the species (20 + MAX_SPECIES), before the pieces (4 ST_PIECES).
    fset(28u, near.btemp);
    for (var m = 0u; m < MAX_SPECIES; m++) { iters += 1u; fset(20u + m, rho_n[m]); }
}

// The front-to-back pass of one ray (see the section comment), resumable: pass 0 starts the
// ray, later passes continue from the saved state; a finished ray writes its pixel (w: the
// flags, max pieces x 16 + 8 loop limiter spent + 4 region overflow + 2 fallback + 1 invalid
// shift), an unfinished one writes w = -1.
@compute @workgroup_size(64, 1, 1)
fn main_absorb(@builtin(global_invocation_id) gid: vec3<u32>) {
    let pix = P.pix_offset + gid.x;
    if (pix >= P.n_pix) { return; }
    let r = rays[pix];
    rbase = gid.x * P.stride;
    iters = 0u;
    load_pf();
    let L = P.region_l;
    let M = max(P.n_abs, 1u);
    let A = ST_PIECES;
    let B = ST_PIECES + L;
    let TR = ST_PIECES + 2u * L;
    let EP = ST_PIECES + 2u * L + M;
    let TT = ST_PIECES + 2u * L + 2u * M;
    var xyz = vec3<fw>(0.0);
    var taken = vec3<fw>(0.0);
    var na = 0u;
    var merges = 0u;
    var merge_at = 64u;
    var max_pieces = 0u;
    var flags = 0u;
    var seg = 0u;
    var near: Samp;
    if (P.pass_index == 0u) {
        fell_back = false;
        budget_scale = 1.0;
        if (r.n_seg > 0u) {
            near = sample_at(r, path_t(r, 0u), false);
            if (near.bad) { flags |= 1u; }
        }
    } else {
        flags = w2u(fget(11u));
        seg = w2u(fget(12u));
        if ((flags & 16u) != 0u) { return; }
        xyz = vec3<fw>(fget(0u), fget(1u), fget(2u));
        taken = vec3<fw>(fget(3u), fget(4u), fget(5u));
        na = w2u(fget(6u));
        merges = w2u(fget(7u));
        merge_at = w2u(fget(8u));
        max_pieces = w2u(fget(9u));
        budget_scale = fget(10u);
        fell_back = (flags & 2u) != 0u;
        near.t = f32(fget(13u));
        near.s = fget(14u);
        near.bbr = fget(15u);
        near.temp = fget(16u);
        near.bbx = vec3<fw>(fget(17u), fget(18u), fget(19u));
        near.btemp = fget(28u);
        near.bad = false;
        for (var m = 0u; m < MAX_SPECIES; m++) { iters += 1u; rho_n[m] = fget(20u + m); }
    }
    while (seg < r.n_seg && iters < P.iter_budget) {
        iters += 1u;
        let far = sample_at(r, path_t(r, seg + 1u), true);
        if (far.bad) { flags |= 1u; }
        let dt = fw(abs(far.t - near.t));
        // Emission: closed-form XYZ of the lines and of the black body.
        var any_emit = false;
        for (var li = 0u; li < P.n_lines; li++) {
            iters += 1u;
            if (P.broaden == 1u) {
                let a = line_areas(li, far, near, dt, true);
                if (a.ok) {
                    any_emit = true;
                    xyz += emit_line_xyz(lines[li].x, far.s, near.s, a.area_a, a.area_b,
                                         sigma_v(a.m, far.temp), sigma_v(a.m, near.temp));
                }
                continue;
            }
            let e = seg_trap(li, far, near, dt, true, 1.0);
            if (e.ok) {
                any_emit = true;
                xyz += trapezoid_xyz(e.t.x, e.t.y, e.t.z, e.t.w);
            }
        }
        let has_bb = has_bb_row(far) || has_bb_row(near);
        if (has_bb) { xyz += 0.5 * dt * (far.bbx + near.bbx); }
        if (P.broaden == 1u) {
            // Broadened: sources one by one into tau, absorbed light per emitted source.
            t_cur = A;
            t_oth = B;
            t_n = na;
            t_tt = TT;
            t_bad = false;
            add_broadened_half(far, near, dt);
            if (t_bad) { flags |= 4u; break; }
            let mid_off = t_cur;
            let nmid = t_n;
            if (nmid > 0u && (has_bb || any_emit)) {
                if (has_bb) { taken += absorbed_bb(mid_off, nmid, far, near, dt); }
                for (var li = 0u; li < P.n_lines; li++) {
                    iters += 1u;
                    let a = line_areas(li, far, near, dt, true);
                    if (!a.ok) { continue; }
                    taken += emit_line_sources(lines[li].x, far.s, near.s, a.area_a, a.area_b,
                                               sigma_v(a.m, far.temp),
                                               sigma_v(a.m, near.temp), 1u, mid_off, nmid);
                }
            }
            add_broadened_half(far, near, dt);
            if (t_bad) { flags |= 4u; break; }
            na = t_n;
            if (t_cur != A) {
                for (var k = 0u; k < na; k++) { iters += 1u; pset(A + k, pget(B + k)); }
            }
        } else {
        // The segment's absorption trapezoids at half height, and their sum.
        var mt = 0u;
        for (var li = P.n_lines; li < P.n_lines + P.n_abs; li++) {
            iters += 1u;
            let e = seg_trap(li, far, near, dt, false, 1.0);
            if (e.ok) {
                pset(TR + mt, vec4<fw>(e.t.x, e.t.y, 0.5 * e.t.z, 0.5 * e.t.w));
                mt++;
            }
        }
        var nt = 0u;
        if (mt > 0u) { nt = build_sum(TR, EP, TT, mt); }
        // tau_mid = tau_front + half the segment's depth (in B; A itself when none).
        var mid_off = A;
        var nmid = na;
        if (nt > 0u) {
            nmid = add_sum(A, &na, TT, nt, B);
            mid_off = B;
            if (nmid == BAD) { flags |= 4u; break; }
        }
        if (nmid > 0u && (has_bb || any_emit)) {
            if (has_bb) { taken += absorbed_bb(mid_off, nmid, far, near, dt); }
            for (var li = 0u; li < P.n_lines; li++) {
                iters += 1u;
                let e = seg_trap(li, far, near, dt, true, 1.0);
                if (e.ok) { taken += absorbed_line(mid_off, nmid, e.t); }
            }
        }
        // tau_front = tau_mid + the other half.
        if (nt > 0u) {
            na = add_sum(B, &nmid, TT, nt, A);
            if (na == BAD) { flags |= 4u; break; }
        }
        }
        // The CPU's merge schedule: the k-th merge with tol 6 / (pi k)^2, then the budget.
        if (na > merge_at) {
            merges++;
            let kf = fw(merges);
            let share = 6.0 / (9.869604401089358 * kf * kf);
            na = merge(A, na, PF.merge_tol * share, false);
            merge_at = max(2u * na, 64u);
        }
        var guard = 0u;
        while (na > P.piece_cap && guard < 40u) {
            iters += 1u;
            budget_scale = min(budget_scale * 4.0, 1e30);
            na = merge(A, na, PF.merge_tol * budget_scale, false);
            fell_back = true;
            guard++;
        }
        max_pieces = max(max_pieces, na);
        near = far;
        for (var m = 0u; m < MAX_SPECIES; m++) { iters += 1u; rho_n[m] = rho_f[m]; }
        seg++;
        if (limiter_exhausted(P.probe_n)) { flags |= 8u; break; }
    }
    if (fell_back) { flags |= 2u; }
    // A segment that alone passed the adapter's loop limit may have been cut short.
    if (iters >= P.iter_limit) { flags |= 8u; }
    let done = seg >= r.n_seg || (flags & 12u) != 0u;
    if (done) { flags |= 16u; }
    save_state(xyz, taken, na, merges, merge_at, max_pieces, flags, seg, near);
    if (done) {
        let f = (flags & 15u) + 16u * max_pieces;
        out_xyz[pix] = vec4<fw>(max(xyz - taken, vec3<fw>(0.0)), fw(f));
    } else {
        out_xyz[pix] = vec4<fw>(0.0, 0.0, 0.0, -1.0);
    }
}
