// Woodcock tracking, multi-density Woodcock tracking (N-DDA, 1-DDA, summed majorant) and
// the emission-absorption ray marcher: a port of blueshift-tracking's integrator.rs, dda.rs,
// camera.rs and rng.rs, one thread per pixel, progressive accumulation (Welford) per pixel.
//
// 64-bit integers are emulated with vec2<u32> (x = low word, y = high word) so that the
// counter-based random numbers equal the CPU's bit for bit.

// ---------------------------------------------------------------- parameters and buffers

struct Params {
    width: u32,
    height: u32,
    sample_begin: u32,
    sample_count: u32,
    seed_lo: u32,
    seed_hi: u32,
    n_channels: u32,
    lut_len: u32,
    dims: vec3<u32>,
    k: u32,
    cdims: vec3<u32>,
    n_cells: u32,
    origin: vec3<f32>,
    density_scale: f32,
    spacing: vec3<f32>,
    projection: u32, // 0 perspective, 1 orthographic
    eye: vec3<f32>,
    cam_h: f32, // tan(fov / 2) or half the orthographic height
    fwd: vec3<f32>,
    jitter: u32,
    right: vec3<f32>,
    kind: u32, // 0 Woodcock, 1 MDWT, 2 marcher
    up: vec3<f32>,
    dda: u32, // 0 N-DDA, 1 1-DDA, 2 summed
    background: vec3<f32>,
    blend: u32, // 0 density, 1 max, 2 mix, 3 weighted, 4 composite
    light_dir: vec3<f32>,
    has_light: u32,
    light_radiance: vec3<f32>,
    ambient: f32,
    bounds_lo: vec3<f32>,
    step: f32,
    bounds_hi: vec3<f32>,
    early_termination: f32,
    prec_mode: u32, // 0 f32, 1 f16, 2 u8
    channel: u32, // Woodcock's channel
    probe_n: u32, // 2: the trip count of `limiter_exhausted`'s loop (a runtime value)
    _pad1: u32,
    // A coarser level of a bricked file: the finest level's box in this level's voxel
    // index coordinates, which rays are clipped to (framed 1), and the sides where it
    // reaches past the voxel box (bits 0-2 below on x, y, z; bits 3-5 above), whose edge
    // cells extend to it (CellLayout::frame in the tracking crate).
    frame_lo: vec3<f32>,
    framed: u32,
    frame_hi: vec3<f32>,
    open_sides: u32,
}

@group(0) @binding(0) var<uniform> P: Params;
// The channels' device brick pool and page table (pool.wgsl, gpu/src/pool.rs).
@group(0) @binding(1) var<storage, read> pool: array<f32>;
@group(0) @binding(8) var<storage, read> pages: array<vec2<u32>>;
// Channels' lookup tables, lut_len RGBA entries each.
@group(0) @binding(2) var<storage, read> luts: array<vec4<f32>>;
// Majorants, n_cells per channel, then the cell-wise total.
@group(0) @binding(3) var<storage, read> majorants: array<f32>;
// Per pixel running mean and sum of squared deviations.
@group(0) @binding(4) var<storage, read_write> acc_mean: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> acc_m2: array<vec4<f32>>;
// Two vec4 per channel: (domain min, domain max, blend weight, 0), (NaN colour, 0).
@group(0) @binding(6) var<storage, read> chan: array<vec4<f32>>;
// Set to 1 when an invocation batch ran out of the adapter's loop limit (see below).
@group(0) @binding(7) var<storage, read_write> limited: array<atomic<u32>>;

const BIG: f32 = 3.0e38;


// ---------------------------------------------------------------- 64-bit arithmetic

fn add64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.x + b.x;
    let carry = select(0u, 1u, lo < a.x);
    return vec2<u32>(lo, a.y + b.y + carry);
}

fn xor64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    return a ^ b;
}

// Logical right shift by 0 < n < 64.
fn shr64(a: vec2<u32>, n: u32) -> vec2<u32> {
    if n >= 32u {
        return vec2<u32>(a.y >> (n - 32u), 0u);
    }
    return vec2<u32>((a.x >> n) | (a.y << (32u - n)), a.y >> n);
}

// Full 32 x 32 -> 64-bit product.
fn mulwide(a: u32, b: u32) -> vec2<u32> {
    let a0 = a & 0xffffu;
    let a1 = a >> 16u;
    let b0 = b & 0xffffu;
    let b1 = b >> 16u;
    let p00 = a0 * b0;
    let p01 = a0 * b1;
    let p10 = a1 * b0;
    let p11 = a1 * b1;
    let mid = (p00 >> 16u) + (p01 & 0xffffu) + (p10 & 0xffffu);
    let lo = (p00 & 0xffffu) | (mid << 16u);
    let hi = p11 + (p01 >> 16u) + (p10 >> 16u) + (mid >> 16u);
    return vec2<u32>(lo, hi);
}

// Wrapping 64-bit product.
fn mul64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let w = mulwide(a.x, b.x);
    return vec2<u32>(w.x, w.y + a.x * b.y + a.y * b.x);
}

const GOLDEN: vec2<u32> = vec2<u32>(0x7f4a7c15u, 0x9e3779b9u);
const MIX1: vec2<u32> = vec2<u32>(0x1ce4e5b9u, 0xbf58476du);
const MIX2: vec2<u32> = vec2<u32>(0x133111ebu, 0x94d049bbu);
const PIXEL_MUL: vec2<u32> = vec2<u32>(0x6659fd93u, 0xd6e8feb8u);
const SAMPLE_MUL: vec2<u32> = vec2<u32>(0x78bd642fu, 0xa0761d64u);

// SplitMix64's finaliser (tracking::rng::mix64).
fn mix64(z0: vec2<u32>) -> vec2<u32> {
    var z = mul64(xor64(z0, shr64(z0, 30u)), MIX1);
    z = mul64(xor64(z, shr64(z, 27u)), MIX2);
    return xor64(z, shr64(z, 31u));
}

// ---------------------------------------------------------------- counter-based RNG

var<private> rng_key: vec2<u32>;
var<private> rng_dim: u32;

fn rng_key_of(seed: vec2<u32>, pixel: u32, sample: u32) -> vec2<u32> {
    var k = mix64(add64(seed, GOLDEN));
    k = mix64(xor64(k, mul64(vec2<u32>(pixel, 0u), PIXEL_MUL)));
    k = mix64(xor64(k, mul64(vec2<u32>(sample, 0u), SAMPLE_MUL)));
    return k;
}

fn rng_at(key: vec2<u32>, dim: u32) -> vec2<u32> {
    return mix64(add64(key, mul64(vec2<u32>(dim + 1u, 0u), GOLDEN)));
}

fn rng_start(pixel: u32, sample: u32) {
    rng_key = rng_key_of(vec2<u32>(P.seed_lo, P.seed_hi), pixel, sample);
    rng_dim = 0u;
}

// Uniform in [0, 1): the top 24 bits.
fn rand_u() -> f32 {
    let v = rng_at(rng_key, rng_dim);
    rng_dim = rng_dim + 1u;
    return f32(v.y >> 8u) * (1.0 / 16777216.0);
}

fn exponential(sigma: f32) -> f32 {
    return -log(1.0 - rand_u()) / sigma;
}

// ---------------------------------------------------------------- precision

// f32 -> binary16 (round to nearest, ties to even) -> f32, in f32 arithmetic.
fn f16_emulated(v: f32) -> f32 {
    let x = bitcast<u32>(v);
    let sign = x & 0x80000000u;
    let a = x & 0x7fffffffu;
    if a >= 0x7f800000u {
        return v;
    }
    if a >= 0x477ff000u {
        return bitcast<f32>(sign | 0x7f800000u);
    }
    if a < 0x38800000u {
        // Subnormal half: multiples of 2^-24, round() ties to even.
        let q = round(abs(v) * 16777216.0) * (1.0 / 16777216.0);
        return bitcast<f32>(sign | bitcast<u32>(q));
    }
    let lsb = (a >> 13u) & 1u;
    let r = (a + 0xfffu + lsb) & 0xffffe000u;
    return bitcast<f32>(sign | r);
}

fn to_f16(v: f32) -> f32 {
    return f16_emulated(v); // F16_IMPL
}

// 8-bit unorm: clamp to [0, 1], round half away from zero to multiples of 1/255.
fn to_u8(v: f32) -> f32 {
    let x = clamp(v, 0.0, 1.0) * 255.0;
    let f = floor(x);
    let r = select(f, f + 1.0, x - f >= 0.5);
    return r / 255.0;
}

fn quantise(v: f32) -> f32 {
    if P.prec_mode == 1u {
        return to_f16(v);
    }
    if P.prec_mode == 2u {
        return to_u8(v);
    }
    return v;
}

// ---------------------------------------------------------------- scene sampling

fn is_nan(v: f32) -> bool {
    return v != v;
}

// Trilinear sample of channel n at continuous index coordinates (clamped; NaN -> 0), read
// from the brick pool.
fn sample_index(n: u32, q: vec3<f32>) -> f32 {
    let c = pool_corner(q, P.dims);
    let v = pool_fetch(n, P.dims, c);
    let t = c.t;
    let v000 = v[0];
    let v100 = v[1];
    let v010 = v[2];
    let v110 = v[3];
    let v001 = v[4];
    let v101 = v[5];
    let v011 = v[6];
    let v111 = v[7];
    let c00 = v000 * (1.0 - t.x) + v100 * t.x;
    let c10 = v010 * (1.0 - t.x) + v110 * t.x;
    let c01 = v001 * (1.0 - t.x) + v101 * t.x;
    let c11 = v011 * (1.0 - t.x) + v111 * t.x;
    let e0 = c00 * (1.0 - t.y) + c10 * t.y;
    let e1 = c01 * (1.0 - t.y) + c11 * t.y;
    return e0 * (1.0 - t.z) + e1 * t.z;
}

// A data value's coordinate on its transfer function's axis: the value, or its log10 on
// a log axis (`info.w` = 1), whose domain is positive: values at or below 0 clamp to the
// domain's minimum as on the CPU.
fn axis_coord(v: f32, info: vec4<f32>) -> f32 {
    if info.w != 0.0 {
        return log2(max(v, 1.17549435e-38)) * 0.30102999566;
    }
    return v;
}

// Extinction (xyz unused) and colour of channel n at world point p: (r, g, b, sigma).
fn scene_sample(n: u32, p: vec3<f32>) -> vec4<f32> {
    let v = sample_index(n, (p - P.origin) / P.spacing);
    let info = chan[2u * n];
    if is_nan(v) {
        return vec4<f32>(chan[2u * n + 1u].xyz, 0.0);
    }
    let last = f32(P.lut_len - 1u);
    let pos = clamp((axis_coord(v, info) - info.x) / (info.y - info.x) * last, 0.0, last);
    let i = min(u32(floor(pos)), P.lut_len - 2u);
    let fr = pos - f32(i);
    let a = luts[n * P.lut_len + i];
    let b = luts[n * P.lut_len + i + 1u];
    let rgba = a + (b - a) * fr;
    return vec4<f32>(rgba.xyz, rgba.w * P.density_scale);
}

fn weight(n: u32) -> f32 {
    return chan[2u * n].z;
}

struct Winner {
    n: u32,
    s: f32,
    c: vec3<f32>,
}

// The channel with the largest extinction (first on ties) and its max / mix colour.
fn winner(use_mix: bool, p: vec3<f32>) -> Winner {
    var best = 0u;
    var best_s = -BIG;
    var best_c = vec3<f32>(0.0);
    var mixc = vec3<f32>(0.0);
    for (var m = 0u; m < P.n_channels; m = m + 1u) {
        let sc = scene_sample(m, p);
        if sc.w > best_s {
            best_s = sc.w;
            best = m;
            best_c = sc.xyz;
        }
        if use_mix {
            mixc = mixc + sc.xyz * sc.w * weight(m);
        }
    }
    if is_nan(best_s) || best_s <= 0.0 {
        return Winner(best, 0.0, best_c);
    }
    if use_mix {
        return Winner(best, best_s, mixc / best_s);
    }
    return Winner(best, best_s, best_c);
}

// Effective (colour, extinction) of channel n at p under the blend.
fn blended(blend: u32, n: u32, p: vec3<f32>) -> vec4<f32> {
    if blend == 0u || blend == 4u {
        return scene_sample(n, p);
    }
    if blend == 3u {
        let sc = scene_sample(n, p);
        return vec4<f32>(sc.xyz, sc.w * weight(n));
    }
    let w = winner(blend == 2u, p);
    if w.n != n || w.s <= 0.0 {
        return vec4<f32>(scene_sample(n, p).xyz, 0.0);
    }
    return vec4<f32>(w.c, w.s);
}

fn total_sigma(blend: u32, p: vec3<f32>) -> f32 {
    var acc = 0.0;
    if blend == 1u || blend == 2u {
        for (var m = 0u; m < P.n_channels; m = m + 1u) {
            acc = max(acc, scene_sample(m, p).w);
        }
        return acc;
    }
    for (var m = 0u; m < P.n_channels; m = m + 1u) {
        acc = acc + blended(blend, m, p).w;
    }
    return acc;
}

// ---------------------------------------------------------------- rays and the DDA

struct Ray {
    o: vec3<f32>,
    d: vec3<f32>,
}

fn camera_ray(px: f32, py: f32) -> Ray {
    let w = f32(max(P.width, 1u));
    let h = f32(max(P.height, 1u));
    let aspect = f32(P.width) / h;
    let sx = (2.0 * px / w - 1.0) * aspect;
    let sy = 1.0 - 2.0 * py / h;
    if P.projection == 0u {
        let d = P.fwd + P.right * (sx * P.cam_h) + P.up * (sy * P.cam_h);
        return Ray(P.eye, normalize(d));
    }
    return Ray(P.eye + P.right * (sx * P.cam_h) + P.up * (sy * P.cam_h), P.fwd);
}

// Slab clip of o + t d against [lo, hi] for t >= 0; x = t0, y = t1, z = 1 if it hits.
fn clip(o: vec3<f32>, d: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>, reciprocal: bool) -> vec3<f32> {
    var t0 = 0.0;
    var t1 = BIG;
    for (var a = 0; a < 3; a = a + 1) {
        let oa = o[a];
        let da = d[a];
        if da == 0.0 {
            if oa < lo[a] || oa > hi[a] {
                return vec3<f32>(0.0, 0.0, 0.0);
            }
            continue;
        }
        var ta: f32;
        var tb: f32;
        if reciprocal {
            let inv = 1.0 / da;
            ta = (lo[a] - oa) * inv;
            tb = (hi[a] - oa) * inv;
        } else {
            ta = (lo[a] - oa) / da;
            tb = (hi[a] - oa) / da;
        }
        if ta > tb {
            let s = ta;
            ta = tb;
            tb = s;
        }
        t0 = max(t0, ta);
        t1 = min(t1, tb);
    }
    if t0 <= t1 && t1 < BIG {
        return vec3<f32>(t0, t1, 1.0);
    }
    return vec3<f32>(0.0, 0.0, 0.0);
}

struct Dda {
    cell: vec3<i32>,
    step: vec3<i32>,
    o: vec3<f32>,
    inv_d: vec3<f32>,
    t: f32,
    t_end: f32,
    budget: u32,
    done: bool,
}

struct DdaCell {
    cell: u32,
    t_min: f32,
    t_max: f32,
}

fn dda_new(ray: Ray, t_max: f32) -> Dda {
    var dda: Dda;
    dda.done = true;
    dda.budget = P.cdims.x + P.cdims.y + P.cdims.z + 4u;
    let kf = f32(P.k);
    let o = (ray.o - P.origin) / P.spacing / kf;
    let d = ray.d / P.spacing / kf;
    let n = vec3<f32>(P.dims - vec3<u32>(1u)) / kf;
    dda.o = o;
    if all(d == vec3<f32>(0.0)) {
        return dda;
    }
    var lo = vec3<f32>(0.0);
    var hi = n;
    if P.framed != 0u {
        lo = P.frame_lo / kf;
        hi = P.frame_hi / kf;
    }
    let c = clip(o, d, lo, hi, false);
    if c.z == 0.0 {
        return dda;
    }
    let t0 = c.x;
    let t1 = min(c.y, t_max);
    if t0 > t1 {
        return dda;
    }
    let p = clamp(o + d * t0, vec3<f32>(0.0), n);
    for (var a = 0; a < 3; a = a + 1) {
        var fl = floor(p[a]);
        if is_nan(fl) {
            fl = 0.0;
        }
        dda.cell[a] = clamp(i32(fl), 0, i32(P.cdims[a]) - 1);
        if d[a] > 0.0 {
            dda.step[a] = 1;
        } else if d[a] < 0.0 {
            dda.step[a] = -1;
        } else {
            dda.step[a] = 0;
        }
        if d[a] != 0.0 {
            dda.inv_d[a] = 1.0 / d[a];
        } else {
            dda.inv_d[a] = 0.0;
        }
    }
    dda.t = t0;
    dda.t_end = t1;
    dda.done = false;
    return dda;
}

fn next_crossing(dda: ptr<function, Dda>, a: i32) -> f32 {
    let s = (*dda).step[a];
    if s == 0 {
        return BIG;
    }
    // An edge cell whose side the frame reaches past is never left through that side.
    let cell = (*dda).cell[a];
    let below = s < 0 && cell == 0 && (P.open_sides & (1u << u32(a))) != 0u;
    let above = s > 0 && cell == i32(P.cdims[a]) - 1 && (P.open_sides & (8u << u32(a))) != 0u;
    if below || above {
        return BIG;
    }
    let boundary = f32((*dda).cell[a] + select(0, 1, s > 0));
    return (boundary - (*dda).o[a]) * (*dda).inv_d[a];
}

// The next cell, or false when the walk is over.
fn dda_next(dda: ptr<function, Dda>, out: ptr<function, DdaCell>) -> bool {
    if (*dda).done || (*dda).budget == 0u {
        return false;
    }
    (*dda).budget = (*dda).budget - 1u;
    let tx = next_crossing(dda, 0);
    let ty = next_crossing(dda, 1);
    let tz = next_crossing(dda, 2);
    var axis = 2;
    var t_cross = tz;
    if tx <= ty && tx <= tz {
        axis = 0;
        t_cross = tx;
    } else if ty <= tz {
        axis = 1;
        t_cross = ty;
    }
    let t_exit = min(max(t_cross, (*dda).t), (*dda).t_end);
    let c = (*dda).cell;
    (*out).cell = u32(c.x) + P.cdims.x * (u32(c.y) + P.cdims.y * u32(c.z));
    (*out).t_min = (*dda).t;
    (*out).t_max = t_exit;
    if t_exit >= (*dda).t_end {
        (*dda).done = true;
    } else {
        (*dda).cell[axis] = (*dda).cell[axis] + (*dda).step[axis];
        let ca = (*dda).cell[axis];
        if ca < 0 || ca >= i32(P.cdims[axis]) {
            (*dda).done = true;
        }
        (*dda).t = t_exit;
    }
    return true;
}

// t + step, but at least the next float after t.
fn advance(t: f32, step: f32) -> f32 {
    let next = t + step;
    if next > t {
        return next;
    }
    if t <= 0.0 {
        return 1.0e-30;
    }
    return bitcast<f32>(bitcast<u32>(t) + 1u);
}

fn ray_at(ray: Ray, t: f32) -> vec3<f32> {
    return ray.o + ray.d * t;
}

// ---------------------------------------------------------------- shadows and shading

// Ratio-tracked transmittance from p along dir through the majorant grid `grid` (a channel
// index, or n_channels for the total); the extinction is channel `grid`'s, or the blend's
// total for the total grid.
fn shadow_transmittance(grid: u32, blend: u32, p: vec3<f32>, dir: vec3<f32>) -> f32 {
    let ray = Ray(p, dir);
    var tr = 1.0;
    var dda = dda_new(ray, BIG);
    var cell: DdaCell;
    loop {
        if !dda_next(&dda, &cell) {
            break;
        }
        let maj = majorants[grid * P.n_cells + cell.cell];
        if maj <= 0.0 {
            continue;
        }
        var t = cell.t_min;
        loop {
            t = advance(t, exponential(maj));
            if t >= cell.t_max {
                break;
            }
            let q = ray_at(ray, t);
            var s: f32;
            if grid < P.n_channels {
                s = scene_sample(grid, q).w;
            } else {
                s = total_sigma(blend, q);
            }
            tr = tr * max(1.0 - s / maj, 0.0);
            if tr <= 0.0 {
                return tr;
            }
        }
    }
    return tr;
}

fn shade(colour: vec3<f32>, p: vec3<f32>, grid: u32, blend: u32) -> vec3<f32> {
    if P.has_light == 0u {
        return colour;
    }
    let t = shadow_transmittance(grid, blend, p, P.light_dir);
    return colour * (vec3<f32>(P.ambient) + P.light_radiance * t);
}

fn background() -> vec4<f32> {
    return vec4<f32>(P.background, 0.0);
}

// ---------------------------------------------------------------- integrators

fn woodcock(n: u32, ray: Ray) -> vec4<f32> {
    var dda = dda_new(ray, BIG);
    var cell: DdaCell;
    loop {
        if !dda_next(&dda, &cell) {
            break;
        }
        let maj = majorants[n * P.n_cells + cell.cell];
        if maj <= 0.0 {
            continue;
        }
        var t = cell.t_min;
        loop {
            t = advance(t, exponential(maj));
            if t >= cell.t_max {
                break;
            }
            let p = ray_at(ray, t);
            let sc = scene_sample(n, p);
            if rand_u() * maj < sc.w {
                return vec4<f32>(shade(sc.xyz, p, n, 0u), 1.0);
            }
        }
    }
    return background();
}

fn mdwt(mode: u32, blend: u32, ray: Ray) -> vec4<f32> {
    var hit_t = BIG;
    var hit_c = vec3<f32>(0.0);
    var cell: DdaCell;
    if mode == 0u {
        for (var n = 0u; n < P.n_channels; n = n + 1u) {
            var dda = dda_new(ray, hit_t);
            var stop = false;
            loop {
                if stop || !dda_next(&dda, &cell) {
                    break;
                }
                let maj = majorants[n * P.n_cells + cell.cell];
                if maj <= 0.0 {
                    continue;
                }
                var t = cell.t_min;
                loop {
                    t = advance(t, exponential(maj));
                    if t >= cell.t_max {
                        break;
                    }
                    let sc = blended(blend, n, ray_at(ray, t));
                    if rand_u() * maj < sc.w {
                        hit_t = t;
                        hit_c = sc.xyz;
                        stop = true;
                        break;
                    }
                }
            }
        }
    } else if mode == 1u {
        let total = P.n_channels * P.n_cells;
        var dda = dda_new(ray, BIG);
        loop {
            if !dda_next(&dda, &cell) {
                break;
            }
            if majorants[total + cell.cell] <= 0.0 {
                continue;
            }
            for (var n = 0u; n < P.n_channels; n = n + 1u) {
                let maj = majorants[n * P.n_cells + cell.cell];
                if maj <= 0.0 {
                    continue;
                }
                var t = cell.t_min;
                loop {
                    t = advance(t, exponential(maj));
                    if t > hit_t || t >= cell.t_max {
                        break;
                    }
                    let sc = blended(blend, n, ray_at(ray, t));
                    if rand_u() * maj < sc.w {
                        hit_t = t;
                        hit_c = sc.xyz;
                        break;
                    }
                }
            }
            if hit_t < BIG {
                break;
            }
        }
    } else {
        let total = P.n_channels * P.n_cells;
        var dda = dda_new(ray, BIG);
        var stop = false;
        loop {
            if stop || !dda_next(&dda, &cell) {
                break;
            }
            let maj = majorants[total + cell.cell];
            if maj <= 0.0 {
                continue;
            }
            var t = cell.t_min;
            loop {
                t = advance(t, exponential(maj));
                if t >= cell.t_max {
                    break;
                }
                let p = ray_at(ray, t);
                let u = rand_u() * maj;
                if blend == 1u || blend == 2u {
                    let w = winner(blend == 2u, p);
                    if u < w.s {
                        hit_t = t;
                        hit_c = w.c;
                        stop = true;
                        break;
                    }
                } else {
                    var acc = 0.0;
                    for (var n = 0u; n < P.n_channels; n = n + 1u) {
                        let sc = blended(blend, n, p);
                        acc = acc + sc.w;
                        if u < acc {
                            hit_t = t;
                            hit_c = sc.xyz;
                            stop = true;
                            break;
                        }
                    }
                    if stop {
                        break;
                    }
                }
            }
        }
    }
    if hit_t >= BIG {
        return background();
    }
    let p = ray_at(ray, hit_t);
    return vec4<f32>(shade(hit_c, p, P.n_channels, blend), 1.0);
}

// (sigma, emission) of the marcher at p; `only` < n_channels restricts to one channel.
fn point_emission(blend: u32, only: u32, p: vec3<f32>) -> vec4<f32> {
    let multi = only >= P.n_channels && P.n_channels > 1u;
    if multi && (blend == 1u || blend == 2u) {
        var best_s = 0.0;
        var best_c = vec3<f32>(0.0);
        var mixc = vec3<f32>(0.0);
        for (var m = 0u; m < P.n_channels; m = m + 1u) {
            let sc = scene_sample(m, p);
            if sc.w > best_s {
                best_s = sc.w;
                best_c = sc.xyz;
            }
            if blend == 2u {
                mixc = mixc + sc.xyz * sc.w * weight(m);
            }
        }
        if blend == 2u {
            return vec4<f32>(mixc, best_s);
        }
        return vec4<f32>(best_c * best_s, best_s);
    }
    var sigma = 0.0;
    var emit = vec3<f32>(0.0);
    var lo = 0u;
    var hi = P.n_channels;
    if only < P.n_channels {
        lo = only;
        hi = only + 1u;
    }
    for (var n = lo; n < hi; n = n + 1u) {
        let sc = blended(blend, n, p);
        sigma = sigma + sc.w;
        emit = emit + sc.w * sc.xyz;
    }
    return vec4<f32>(emit, sigma);
}

fn march(blend: u32, only: u32, ray: Ray) -> vec4<f32> {
    let step = P.step;
    let jitter = rand_u();
    var c = vec3<f32>(0.0);
    var a = 0.0;
    let cl = clip(ray.o, ray.d, P.bounds_lo, P.bounds_hi, true);
    if cl.z != 0.0 {
        let t0 = cl.x;
        let t1 = cl.y;
        let n_steps = u32(max(ceil((t1 - t0) / step), 1.0));
        for (var i = 0u; i < n_steps; i = i + 1u) {
            let ta = t0 + f32(i) * step;
            let tb = min(ta + step, t1);
            let len = tb - ta;
            if len <= 0.0 {
                break;
            }
            let p = ray_at(ray, ta + jitter * len);
            let se = point_emission(blend, only, p);
            let sigma = se.w;
            if sigma <= 0.0 {
                continue;
            }
            let alpha = 1.0 - exp(-sigma * len);
            let w = (1.0 - a) * alpha / sigma;
            c = vec3<f32>(
                quantise(c.x + w * se.x),
                quantise(c.y + w * se.y),
                quantise(c.z + w * se.z),
            );
            a = quantise(a + (1.0 - a) * alpha);
            if a >= P.early_termination {
                break;
            }
        }
    }
    return vec4<f32>(c + (1.0 - a) * P.background, a);
}

fn li(ray: Ray) -> vec4<f32> {
    if P.kind == 0u {
        return woodcock(P.channel, ray);
    }
    if P.blend == 4u {
        var acc = vec4<f32>(0.0);
        for (var n = 0u; n < P.n_channels; n = n + 1u) {
            var v: vec4<f32>;
            if P.kind == 1u {
                v = woodcock(n, ray);
            } else {
                v = march(0u, n, ray);
            }
            acc = acc + weight(n) * v;
        }
        return acc;
    }
    if P.kind == 1u {
        return mdwt(P.dda, P.blend, ray);
    }
    return march(P.blend, P.n_channels, ray);
}

@compute @workgroup_size(8, 8, 1)
fn render_pass(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= P.width || gid.y >= P.height {
        return;
    }
    let pixel = gid.y * P.width + gid.x;
    var mean = acc_mean[pixel];
    var m2 = acc_m2[pixel];
    for (var s = 0u; s < P.sample_count; s = s + 1u) {
        let sample = P.sample_begin + s;
        rng_start(pixel, sample);
        var jx = 0.5;
        var jy = 0.5;
        if P.jitter != 0u {
            jx = rand_u();
            jy = rand_u();
        }
        let ray = camera_ray(f32(gid.x) + jx, f32(gid.y) + jy);
        let v = li(ray);
        let count = f32(sample + 1u);
        let d = v - mean;
        mean = mean + d / count;
        m2 = m2 + d * (v - mean);
    }
    acc_mean[pixel] = mean;
    acc_m2[pixel] = m2;
    if limiter_exhausted(P.probe_n) {
        atomicOr(&limited[0], 1u);
    }
}

// ---------------------------------------------------------------- majorants on the device

struct MajorantParams {
    n_cells: u32,
    n_channels: u32,
    lut_len: u32,
    // Channel to rebuild, or n_channels for all of them.
    channel: u32,
    density_scale: f32,
    probe_n: u32, // 2, as Params::probe_n
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(10) var<uniform> MP: MajorantParams;
// Macrocell minima then maxima, n_cells each per channel: [ch0 mins, ch0 maxs, ch1 mins, ...].
@group(0) @binding(11) var<storage, read> cell_ranges: array<f32>;
@group(0) @binding(12) var<storage, read> maj_luts: array<vec4<f32>>;
@group(0) @binding(13) var<storage, read> maj_chan: array<vec4<f32>>;
@group(0) @binding(14) var<storage, read_write> maj_out: array<f32>;
// Set to 1 when the loop limiter ran out while scanning a table (see `limiter_exhausted`).
@group(0) @binding(15) var<storage, read_write> maj_limited: array<atomic<u32>>;

fn lut_pos(n: u32, v: f32) -> f32 {
    let info = maj_chan[2u * n];
    let last = f32(MP.lut_len - 1u);
    return clamp((axis_coord(v, info) - info.x) / (info.y - info.x) * last, 0.0, last);
}

// Majorant of one (cell, channel): the largest lookup-table opacity among the entries a
// linear lookup of any value in the cell's widened range blends, times the density scale.
@compute @workgroup_size(64, 1, 1)
fn build_majorants(@builtin(global_invocation_id) gid: vec3<u32>) {
    let cell = gid.x;
    var n = gid.y;
    if MP.channel < MP.n_channels {
        n = MP.channel;
    }
    if cell >= MP.n_cells || n >= MP.n_channels {
        return;
    }
    let lo = cell_ranges[2u * n * MP.n_cells + cell];
    let hi = cell_ranges[(2u * n + 1u) * MP.n_cells + cell];
    var i0 = 0u;
    var i1 = MP.lut_len - 1u;
    if lo <= hi {
        let m = max(abs(lo), abs(hi));
        let eps = m * 1.0e-6 + 1.0e-30;
        i0 = u32(floor(lut_pos(n, lo - eps)));
        i1 = min(u32(ceil(lut_pos(n, hi + eps))), MP.lut_len - 1u);
    }
    var best = 0.0;
    for (var i = i0; i <= i1; i = i + 1u) {
        best = max(best, maj_luts[n * MP.lut_len + i].w);
    }
    maj_out[n * MP.n_cells + cell] = best * MP.density_scale;
    if limiter_exhausted(MP.probe_n) {
        atomicOr(&maj_limited[0], 1u);
    }
}

// The total majorant: the cell-wise sum over channels, in channel order.
@compute @workgroup_size(64, 1, 1)
fn sum_majorants(@builtin(global_invocation_id) gid: vec3<u32>) {
    let cell = gid.x;
    if cell >= MP.n_cells {
        return;
    }
    var acc = 0.0;
    for (var n = 0u; n < MP.n_channels; n = n + 1u) {
        acc = acc + maj_out[n * MP.n_cells + cell];
    }
    maj_out[MP.n_channels * MP.n_cells + cell] = acc;
}

// ---------------------------------------------------------------- probes for the tests

// Keys: (seed lo, seed hi, pixel, sample); output: 8 dimensions of raw bits per key.
@group(0) @binding(20) var<storage, read> probe_keys: array<vec4<u32>>;
@group(0) @binding(21) var<storage, read_write> probe_bits: array<vec2<u32>>;

@compute @workgroup_size(64, 1, 1)
fn rng_probe(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= arrayLength(&probe_keys) {
        return;
    }
    let k = probe_keys[i];
    let key = rng_key_of(vec2<u32>(k.x, k.y), k.z, k.w);
    for (var d = 0u; d < 8u; d = d + 1u) {
        probe_bits[i * 8u + d] = rng_at(key, d);
    }
}

// Input values; output: (f16 rounding, 8-bit rounding) per value.
@group(0) @binding(22) var<storage, read> probe_in: array<f32>;
@group(0) @binding(23) var<storage, read_write> probe_out: array<vec2<f32>>;

@compute @workgroup_size(64, 1, 1)
fn quantise_probe(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= arrayLength(&probe_in) {
        return;
    }
    probe_out[i] = vec2<f32>(to_f16(probe_in[i]), to_u8(probe_in[i]));
}

// Sample points: index coordinates and the channel (as bits); output: the trilinear sample
// through the brick pool.
@group(0) @binding(24) var<storage, read> probe_points: array<vec4<f32>>;
@group(0) @binding(25) var<storage, read_write> probe_samples: array<f32>;

@compute @workgroup_size(64, 1, 1)
fn sample_probe(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= arrayLength(&probe_points) {
        return;
    }
    let q = probe_points[i];
    probe_samples[i] = sample_index(bitcast<u32>(q.w), q.xyz);
}
