// Doppler volume rendering, emission-only piecewise-linear integrator (the Doppler paper's
// Algorithm 2 as blueshift-tracking's `pwl.rs` does it for rays without absorption): one
// thread per pixel marches its ray back to front; per segment each line of each species
// emits the trapezoid between its two shifted positions (area = emitted energy), whose XYZ is
// integrated exactly against the piecewise-linear CIE 1931 CMFs; black bodies are sampled on
// a fixed wavelength grid at both ends of the segment (trapezoid rule along the ray), each
// grid sample weighted by the XYZ of its hat function (precomputed on the host in f64).

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
    step: f32,
    range_lo: f32,
    range_hi: f32,
    min_width: f32,
    cmf_lo: f32,
    cmf_step: f32,
    cmf_n: u32,
    bb_k: u32,
    bb_c1: f32,        // c1L for l in nm, per nm: B = c1 / l^5 / (exp(c2 / l T) - 1)
    bb_c2: f32,        // c2 in nm K
    shift_mode: u32,   // banded: 0 nearest band, 1 energy-conserving
    temp_factor: f32,
    vel_factor: f32,
    off_lambda: u32,   // offset of the black-body grid in `tables`
    off_hat: u32,      // offset of the hat XYZs (3 per sample) in `tables`
    bb_factor: f32,    // black-body factor x BB_UNIT
    n_bands: u32,      // banded: bands over [range_lo, range_hi)
    band_w: f32,       // banded: band width, nm
    off_band_w: u32,   // banded: offset of the per-band CMF integrals (3 per band)
    off_band_c: u32,   // banded: offset of the band centres
    n_abs: u32,        // banded with absorption: absorption entries after the n_lines emission ones
    absorbing: u32,    // banded: 1 when the bands are kept per ray (absorption on)
    abs_factor: f32,   // absorption factor
    pad1: u32,
}

struct PixelRay {
    p0: vec3<f32>,     // index-space entry point
    n_seg: u32,        // segments (0: the ray misses)
    dir_idx: vec3<f32>,// index-space step per world unit of path
    len: f32,          // path length inside the box
    los: vec3<f32>,    // unit world direction
    pad: f32,
}

@group(0) @binding(0) var<storage, read> rays: array<PixelRay>;
// Scalar channels, nvox each: species densities 0..nsp, then black-body density, temperature.
@group(0) @binding(1) var<storage, read> channels: array<f32>;
@group(0) @binding(2) var<storage, read> velocity: array<f32>;
// CMF samples (3 per wavelength, cmf_n of them), then the black-body grid and its hat XYZs.
@group(0) @binding(3) var<storage, read> tables: array<f32>;
// Per line: centre nm, strength x emission factor, species index, unused. Banded with the
// nearest shift: per rest-frame band entry, its centre nm, value per unit density, species.
@group(0) @binding(4) var<storage, read> lines: array<vec4<f32>>;
// Per pixel: X, Y, Z, flag (0 ok, 1: a Doppler shift was invalid).
@group(0) @binding(5) var<storage, read_write> out_xyz: array<vec4<f32>>;
@group(0) @binding(6) var<uniform> P: Params;
// Banded with absorption: the band values of every pixel's ray (n_bands per pixel).
@group(0) @binding(7) var<storage, read_write> bands_buf: array<f32>;

// Banded: where deposits go (XYZ directly, or the ray's bands when absorbing).
var<private> acc_xyz: vec3<f32>;
var<private> band_base: u32;

const MAX_SPECIES: u32 = 8u;
const C_M_PER_S: f32 = 299792458.0;

fn vidx(x: u32, y: u32, z: u32) -> u32 {
    return x + P.nx * (y + P.ny * z);
}

struct Corner {
    i: array<u32, 8>,
    w: array<f32, 8>,
}

// Trilinear weights as blueshift-volume's `sample_trilinear_index` (clamped to the centres).
fn corners(p_in: vec3<f32>) -> Corner {
    let mx = vec3<f32>(f32(P.nx - 1u), f32(P.ny - 1u), f32(P.nz - 1u));
    let p = min(max(p_in, vec3<f32>(0.0)), mx);
    let f = floor(p);
    let t = p - f;
    let x0 = u32(f.x);
    let y0 = u32(f.y);
    let z0 = u32(f.z);
    let x1 = min(x0 + 1u, P.nx - 1u);
    let y1 = min(y0 + 1u, P.ny - 1u);
    let z1 = min(z0 + 1u, P.nz - 1u);
    var c: Corner;
    c.i = array<u32, 8>(vidx(x0, y0, z0), vidx(x1, y0, z0), vidx(x0, y1, z0), vidx(x1, y1, z0),
                        vidx(x0, y0, z1), vidx(x1, y0, z1), vidx(x0, y1, z1), vidx(x1, y1, z1));
    let ux = 1.0 - t.x;
    let uy = 1.0 - t.y;
    let uz = 1.0 - t.z;
    c.w = array<f32, 8>(ux * uy * uz, t.x * uy * uz, ux * t.y * uz, t.x * t.y * uz,
                        ux * uy * t.z, t.x * uy * t.z, ux * t.y * t.z, t.x * t.y * t.z);
    return c;
}

fn sample_channel(c: Corner, ch: u32) -> f32 {
    let base = ch * P.nvox;
    var v = 0.0;
    for (var k = 0u; k < 8u; k++) {
        v += c.w[k] * channels[base + c.i[k]];
    }
    return v;
}

fn sample_velocity(c: Corner) -> vec3<f32> {
    var v = vec3<f32>(0.0);
    for (var k = 0u; k < 8u; k++) {
        let j = 3u * c.i[k];
        v += c.w[k] * vec3<f32>(velocity[j], velocity[j + 1u], velocity[j + 2u]);
    }
    return v;
}

fn cmf(k: u32) -> vec3<f32> {
    return vec3<f32>(tables[3u * k], tables[3u * k + 1u], tables[3u * k + 2u]);
}

fn lerp_at(a: f32, b: f32, va: f32, vb: f32, x: f32) -> f32 {
    if (x <= a) { return va; }
    if (x >= b) { return vb; }
    return va + (vb - va) * ((x - a) / (b - a));
}

// Exact XYZ of the trapezoid (start, end, v0, v1) against the piecewise-linear CMFs, interval
// by interval of the CMF table (a line spans a few; no prefix differences, which cancel in f32).
fn trapezoid_xyz(start: f32, end: f32, v0: f32, v1: f32) -> vec3<f32> {
    let lo = P.cmf_lo;
    let hi = P.cmf_lo + P.cmf_step * f32(P.cmf_n - 1u);
    let a = max(start, lo);
    let b = min(end, hi);
    var out = vec3<f32>(0.0);
    if (!(b > a)) { return out; }
    let last = P.cmf_n - 2u;
    let ia = min(u32(floor((a - lo) / P.cmf_step)), last);
    let ib = min(u32(floor((b - lo) / P.cmf_step)), last);
    for (var k = ia; k <= ib; k++) {
        let x0 = lo + f32(k) * P.cmf_step;
        let x1 = x0 + P.cmf_step;
        var u = x0;
        var w = x1;
        if (k == ia) { u = a; }
        if (k == ib) { w = b; }
        if (w <= u) { continue; }
        let fu = lerp_at(start, end, v0, v1, u);
        let fw = lerp_at(start, end, v0, v1, w);
        let g0 = cmf(k);
        let g1 = cmf(k + 1u);
        let gu = g0 + (g1 - g0) * ((u - x0) / P.cmf_step);
        let gw = g0 + (g1 - g0) * ((w - x0) / P.cmf_step);
        out += (w - u) * (2.0 * fu * gu + fu * gw + fw * gu + 2.0 * fw * gw) / 6.0;
    }
    return out;
}

fn value_factor(s: f32) -> f32 {
    if (P.invariant == 1u) {
        let s2 = s * s;
        return 1.0 / (s2 * s2 * s);
    }
    return 1.0 / s;
}

// Planck's law on the host's constants, in BB_UNIT x W sr^-1 m^-2 nm^-1 (l in nm).
fn planck(l: f32, temp: f32) -> f32 {
    let x = P.bb_c2 / (l * temp);
    var den = exp(x) - 1.0;
    if (x < 1e-3) {
        den = x * (1.0 + 0.5 * x);
    }
    if (!(den < 3.0e38)) { return 0.0; }
    let l2 = l * l;
    return P.bb_c1 / (l2 * l2 * l) / den;
}

// The XYZ of one sample's black-body row: sum_i hat_xyz[i] k(s) rho B(lambda_i / s, T).
fn bb_xyz(rho: f32, temp: f32, s: f32) -> vec3<f32> {
    var out = vec3<f32>(0.0);
    if (rho <= 0.0 || temp <= 0.0) { return out; }
    let k = value_factor(s) * rho;
    for (var i = 0u; i < P.bb_k; i++) {
        let l = tables[P.off_lambda + i];
        let h = vec3<f32>(tables[P.off_hat + 3u * i], tables[P.off_hat + 3u * i + 1u],
                          tables[P.off_hat + 3u * i + 2u]);
        out += h * (k * planck(l / s, temp));
    }
    return out;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= P.width || gid.y >= P.height) { return; }
    let pix = gid.y * P.width + gid.x;
    let r = rays[pix];
    var xyz = vec3<f32>(0.0);
    var flag = 0.0;
    var rho_a: array<f32, 8>;
    var rho_b: array<f32, 8>;
    var s_a = 1.0;
    var t_a = 0.0;
    var bb_a = vec3<f32>(0.0);
    let nsp = min(P.nsp, MAX_SPECIES);
    if (r.n_seg > 0u) {
        for (var ii = 0u; ii <= r.n_seg; ii++) {
            let i = r.n_seg - ii;
            var t = r.len;
            if (i != r.n_seg) { t = min(f32(i) * P.step, r.len); }
            let c = corners(r.p0 + r.dir_idx * t);
            for (var m = 0u; m < nsp; m++) {
                rho_b[m] = max(sample_channel(c, m), 0.0);
            }
            var bb_b = vec3<f32>(0.0);
            var s_b = 1.0;
            var v = vec3<f32>(0.0);
            if (P.has_vel == 1u) { v = sample_velocity(c) * P.vel_factor; }
            let v_r = dot(v, r.los);
            if (P.model == 1u) {
                let beta = length(v) / C_M_PER_S;
                if (!(beta < 1.0)) { flag = 1.0; }
                s_b = (1.0 + v_r / C_M_PER_S) / sqrt(max(1.0 - beta * beta, 1e-30));
            } else {
                s_b = 1.0 + v_r / C_M_PER_S;
            }
            if (!(s_b > 0.0)) { flag = 1.0; s_b = 1.0; }
            if (P.has_bb == 1u) {
                let rho = max(sample_channel(c, P.nsp), 0.0) * P.bb_factor;
                let temp = max(sample_channel(c, P.nsp + 1u), 0.0) * P.temp_factor;
                bb_b = bb_xyz(rho, temp, s_b);
            }
            if (ii > 0u) {
                let dt = abs(t_a - t);
                let ga = value_factor(s_a) * s_a;
                let gb = value_factor(s_b) * s_b;
                for (var li = 0u; li < P.n_lines; li++) {
                    let line = lines[li];
                    let m = u32(line.z);
                    let ra = rho_a[m];
                    let rb = rho_b[m];
                    if (ra <= 0.0 && rb <= 0.0) { continue; }
                    let base = dt * line.y;
                    let area_a = base * ra * ga;
                    let area_b = base * rb * gb;
                    let la = s_a * line.x;
                    let lb = s_b * line.x;
                    let wdt = max(abs(lb - la), P.min_width);
                    let mid = 0.5 * (la + lb);
                    let lo = mid - 0.5 * wdt;
                    let hi = mid + 0.5 * wdt;
                    var h0 = area_a / wdt;
                    var h1 = area_b / wdt;
                    if (la > lb) { h0 = area_b / wdt; h1 = area_a / wdt; }
                    if (hi < P.range_lo || lo > P.range_hi || (h0 <= 0.0 && h1 <= 0.0)) { continue; }
                    xyz += trapezoid_xyz(lo, hi, h0, h1);
                }
                xyz += 0.5 * dt * (bb_a + bb_b);
            }
            for (var m = 0u; m < nsp; m++) { rho_a[m] = rho_b[m]; }
            s_a = s_b;
            t_a = t;
            bb_a = bb_b;
        }
    }
    out_xyz[pix] = vec4<f32>(xyz, flag);
}

// ---- Banded integrator (Algorithm 1), emission only -------------------------------------
// Without absorption the XYZ of the band values is linear in them, so each deposit into band
// d adds W[d] x value to XYZ directly (W[d]: the CMF integrals over band d, from the host):
// no per-ray band array.

fn band_weight(d: u32) -> vec3<f32> {
    let o = P.off_band_w + 3u * d;
    return vec3<f32>(tables[o], tables[o + 1u], tables[o + 2u]);
}

// blueshift-spectrum's BandLayout::band_of: the band holding x, or n_bands for none.
fn band_of(x: f32) -> u32 {
    if (!(x >= P.range_lo && x < P.range_hi)) { return P.n_bands; }
    return min(u32(floor((x - P.range_lo) / P.band_w)), P.n_bands - 1u);
}

// The banded `deposit`: a box of `area` over [lo, hi) spread over the bands it overlaps, as
// band means, each weighted by its CMF integrals.
fn add_band(d: u32, value: f32) {
    if (P.absorbing == 1u) {
        bands_buf[band_base + d] += value;
    } else {
        acc_xyz += band_weight(d) * value;
    }
}

fn deposit_add(lo: f32, hi: f32, area: f32) {
    let l = max(lo, P.range_lo);
    let h = min(hi, P.range_hi);
    if (h <= l || hi <= lo) { return; }
    let height = area / (hi - lo);
    let first = min(u32(floor((l - P.range_lo) / P.band_w)), P.n_bands - 1u);
    for (var i = first; i < P.n_bands; i++) {
        let s = P.range_lo + f32(i) * P.band_w;
        if (s >= h) { break; }
        let ov = min(h, s + P.band_w) - max(l, s);
        if (ov > 0.0) { add_band(i, height * ov / P.band_w); }
    }
}

// Multiplies the bands a shifted absorption box overlaps by exp(-len rho k_band).
fn deposit_absorb(lo: f32, hi: f32, area: f32, len_rho: f32) {
    let l = max(lo, P.range_lo);
    let h = min(hi, P.range_hi);
    if (h <= l || hi <= lo) { return; }
    let height = area / (hi - lo);
    let first = min(u32(floor((l - P.range_lo) / P.band_w)), P.n_bands - 1u);
    for (var i = first; i < P.n_bands; i++) {
        let s = P.range_lo + f32(i) * P.band_w;
        if (s >= h) { break; }
        let ov = min(h, s + P.band_w) - max(l, s);
        if (ov > 0.0) {
            bands_buf[band_base + i] *= exp(-len_rho * (height * ov / P.band_w));
        }
    }
}

// blueshift-tracking's `absorb_half`: the sample's optical depth over path length `len`.
fn absorb(rho: ptr<function, array<f32, 8>>, sh: f32, len: f32) {
    for (var li = P.n_lines; li < P.n_lines + P.n_abs; li++) {
        let line = lines[li];
        let m = u32(line.z);
        let rm = (*rho)[m];
        if (rm <= 0.0) { continue; }
        if (P.shift_mode == 0u) {
            let d = band_of(line.x * sh);
            if (d < P.n_bands) {
                bands_buf[band_base + d] *= exp(-len * rm * line.y);
            }
        } else {
            deposit_absorb(sh * (line.x - 0.5 * P.min_width), sh * (line.x + 0.5 * P.min_width),
                           line.y, len * rm);
        }
    }
}

fn path_t(r: PixelRay, i: u32) -> f32 {
    if (i == r.n_seg) { return r.len; }
    return min(f32(i) * P.step, r.len);
}

@compute @workgroup_size(8, 8, 1)
fn main_banded(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= P.width || gid.y >= P.height) { return; }
    let pix = gid.y * P.width + gid.x;
    let r = rays[pix];
    acc_xyz = vec3<f32>(0.0);
    band_base = pix * P.n_bands;
    var flag = 0.0;
    var rho: array<f32, 8>;
    let nsp = min(P.nsp, MAX_SPECIES);
    if (P.absorbing == 1u) {
        for (var b = 0u; b < P.n_bands; b++) { bands_buf[band_base + b] = 0.0; }
    }
    if (r.n_seg > 0u) {
        for (var ii = 0u; ii <= r.n_seg; ii++) {
            let i = r.n_seg - ii;
            let t = path_t(r, i);
            var wt = 0.0;
            if (i < r.n_seg) { wt += abs(path_t(r, i + 1u) - t); }
            if (i > 0u) { wt += abs(t - path_t(r, i - 1u)); }
            wt *= 0.5;
            let c = corners(r.p0 + r.dir_idx * t);
            for (var m = 0u; m < nsp; m++) {
                rho[m] = max(sample_channel(c, m), 0.0);
            }
            var v = vec3<f32>(0.0);
            if (P.has_vel == 1u) { v = sample_velocity(c) * P.vel_factor; }
            let v_r = dot(v, r.los);
            var sh = 1.0;
            if (P.model == 1u) {
                let beta = length(v) / C_M_PER_S;
                if (!(beta < 1.0)) { flag = 1.0; }
                sh = (1.0 + v_r / C_M_PER_S) / sqrt(max(1.0 - beta * beta, 1e-30));
            } else {
                sh = 1.0 + v_r / C_M_PER_S;
            }
            if (!(sh > 0.0)) { flag = 1.0; sh = 1.0; }
            let g = value_factor(sh) * sh;
            if (P.absorbing == 1u) { absorb(&rho, sh, 0.5 * wt); }
            for (var li = 0u; li < P.n_lines; li++) {
                let line = lines[li];
                let m = u32(line.z);
                let rm = rho[m];
                if (rm <= 0.0) { continue; }
                if (P.shift_mode == 0u) {
                    let d = band_of(line.x * sh);
                    if (d < P.n_bands) { add_band(d, wt * rm * g * line.y); }
                } else {
                    deposit_add(sh * (line.x - 0.5 * P.min_width),
                                sh * (line.x + 0.5 * P.min_width),
                                wt * rm * g * line.y);
                }
            }
            if (P.has_bb == 1u) {
                let brho = max(sample_channel(c, P.nsp), 0.0) * P.bb_factor;
                let temp = max(sample_channel(c, P.nsp + 1u), 0.0) * P.temp_factor;
                if (brho > 0.0 && temp > 0.0) {
                    let k = wt * brho * value_factor(sh);
                    for (var b = 0u; b < P.n_bands; b++) {
                        let cb = tables[P.off_band_c + b];
                        add_band(b, k * planck(cb / sh, temp));
                    }
                }
            }
            if (P.absorbing == 1u) { absorb(&rho, sh, 0.5 * wt); }
        }
    }
    if (P.absorbing == 1u) {
        for (var b = 0u; b < P.n_bands; b++) {
            acc_xyz += band_weight(b) * bands_buf[band_base + b];
        }
    }
    out_xyz[pix] = vec4<f32>(acc_xyz, flag);
}
