// The relativistic environment renderer (blueshift_relativity::render) per pixel: pinhole
// camera in the observer's frame, inverse aberration, environment lookup (equirect, cube
// map or the procedural checker), Doppler colour shift from the CPU's table of 3x3
// matrices over ln D, searchlight D^4. f32 arithmetic (the CPU uses f64).

struct Params {
    forward: vec4<f32>,
    right: vec4<f32>,
    up: vec4<f32>,
    beta: vec4<f32>,      // xyz = beta, w = speed
    width: u32,
    height: u32,
    half_w: f32,
    half_h: f32,
    gamma: f32,
    aberration: u32,
    doppler: u32,
    searchlight: u32,
    env_kind: u32,        // 0 equirect, 1 cube, 2 checker
    env_w: u32,           // equirect width or cube face size
    env_h: u32,           // equirect height
    table_len: u32,
    ln_min: f32,
    ln_max: f32,
    ln_step: f32,
    cell_deg: f32,
    grid_deg: f32,
    line_deg: f32,
    one_minus_speed: f32, // 1 - |beta|, computed in f64 on the host
    _p1: f32,
    light: vec4<f32>,
    dark: vec4<f32>,
    line: vec4<f32>,
}

@group(0) @binding(0) var<storage, read> env: array<f32>;
@group(0) @binding(1) var<storage, read> table: array<f32>;
@group(0) @binding(2) var<storage, read_write> out_rgb: array<f32>;
@group(0) @binding(3) var<uniform> p: Params;

const PI: f32 = 3.14159265358979;
const TAU: f32 = 6.28318530717959;

fn texel(base: u32, w: u32, x: u32, y: u32) -> vec3<f32> {
    let i = 3u * (base + y * w + x);
    return vec3<f32>(env[i], env[i + 1u], env[i + 2u]);
}

fn imod(a: i32, n: i32) -> i32 {
    return ((a % n) + n) % n;
}

fn fmod_euclid(a: f32, b: f32) -> f32 {
    var r = a % b;
    if r < 0.0 {
        r += b;
    }
    return r;
}

// (longitude, polar angle) as blueshift_relativity::lon_polar. The polar angle is
// atan2(|xz|, y), not the CPU's acos(y): equal for unit vectors, but acos in f32 loses up to
// 3e-4 rad near the poles (and is approximated on some drivers), which moved lookups by a
// sizeable fraction of a texel on real 1k-2k maps.
fn lon_polar(d: vec3<f32>) -> vec2<f32> {
    return vec2<f32>(atan2(d.x, -d.z), atan2(length(d.xz), d.y));
}

fn sample_equirect(d: vec3<f32>) -> vec3<f32> {
    let w = p.env_w;
    let h = p.env_h;
    let lp = lon_polar(d);
    let u = 0.5 + lp.x / TAU;
    let v = lp.y / PI;
    let x = u * f32(w) - 0.5;
    let y = clamp(v * f32(h) - 0.5, 0.0, f32(h - 1u));
    let x0 = floor(x);
    let y0 = floor(y);
    let fx = x - x0;
    let fy = y - y0;
    let xa = u32(imod(i32(x0), i32(w)));
    let xb = u32(imod(i32(x0) + 1, i32(w)));
    let ya = u32(y0);
    let yb = min(ya + 1u, h - 1u);
    let top = mix(texel(0u, w, xa, ya), texel(0u, w, xb, ya), fx);
    let bot = mix(texel(0u, w, xa, yb), texel(0u, w, xb, yb), fx);
    return mix(top, bot, fy);
}

// (face, s, t) as blueshift_relativity::cube_face_st.
fn cube_face_st(d: vec3<f32>) -> vec3<f32> {
    let a = abs(d);
    var face = 0.0;
    var sc = 0.0;
    var tc = 0.0;
    var ma = 1.0;
    if a.x >= a.y && a.x >= a.z {
        ma = a.x;
        tc = -d.y;
        if d.x > 0.0 { face = 0.0; sc = -d.z; } else { face = 1.0; sc = d.z; }
    } else if a.y >= a.z {
        ma = a.y;
        sc = d.x;
        if d.y > 0.0 { face = 2.0; tc = d.z; } else { face = 3.0; tc = -d.z; }
    } else {
        ma = a.z;
        tc = -d.y;
        if d.z > 0.0 { face = 4.0; sc = d.x; } else { face = 5.0; sc = -d.x; }
    }
    return vec3<f32>(face, 0.5 * (sc / ma + 1.0), 0.5 * (tc / ma + 1.0));
}

fn cube_dir(face: u32, s: f32, t: f32) -> vec3<f32> {
    let sc = 2.0 * s - 1.0;
    let tc = 2.0 * t - 1.0;
    switch face {
        case 0u: { return vec3<f32>(1.0, -tc, -sc); }
        case 1u: { return vec3<f32>(-1.0, -tc, sc); }
        case 2u: { return vec3<f32>(sc, 1.0, tc); }
        case 3u: { return vec3<f32>(sc, -1.0, -tc); }
        case 4u: { return vec3<f32>(sc, -tc, 1.0); }
        default: { return vec3<f32>(-sc, -tc, -1.0); }
    }
}

fn cube_tap(face: u32, i: i32, j: i32) -> vec3<f32> {
    let n = i32(p.env_w);
    let nn = p.env_w * p.env_w;
    if i >= 0 && i < n && j >= 0 && j < n {
        return texel(face * nn, p.env_w, u32(i), u32(j));
    }
    let nf = f32(n);
    let d = cube_dir(face, (f32(i) + 0.5) / nf, (f32(j) + 0.5) / nf);
    let fst = cube_face_st(d);
    let x = u32(clamp(i32(fst.y * nf), 0, n - 1));
    let y = u32(clamp(i32(fst.z * nf), 0, n - 1));
    return texel(u32(fst.x) * nn, p.env_w, x, y);
}

fn sample_cube(d: vec3<f32>) -> vec3<f32> {
    let fst = cube_face_st(d);
    let face = u32(fst.x);
    let n = f32(p.env_w);
    let x = fst.y * n - 0.5;
    let y = fst.z * n - 0.5;
    let x0 = floor(x);
    let y0 = floor(y);
    let fx = x - x0;
    let fy = y - y0;
    let i = i32(x0);
    let j = i32(y0);
    let top = mix(cube_tap(face, i, j), cube_tap(face, i + 1, j), fx);
    let bot = mix(cube_tap(face, i, j + 1), cube_tap(face, i + 1, j + 1), fx);
    return mix(top, bot, fy);
}

fn near_grid(a: f32) -> bool {
    let r = fmod_euclid(a, p.grid_deg);
    return min(r, p.grid_deg - r) < 0.5 * p.line_deg;
}

fn sample_checker(d: vec3<f32>) -> vec3<f32> {
    let lp = lon_polar(d);
    let lon_deg = degrees(lp.x) + 180.0;
    let lat_deg = degrees(lp.y);
    if p.grid_deg > 0.0 && (near_grid(lon_deg) || near_grid(lat_deg)) {
        return p.line.xyz;
    }
    let i = i32(floor(lon_deg / p.cell_deg));
    let j = i32(floor(lat_deg / p.cell_deg));
    if imod(i + j, 2) == 0 {
        return p.light.xyz;
    }
    return p.dark.xyz;
}

fn sample_env(d: vec3<f32>) -> vec3<f32> {
    switch p.env_kind {
        case 0u: { return sample_equirect(d); }
        case 1u: { return sample_cube(d); }
        default: { return sample_checker(d); }
    }
}

// 1 - cos of the angle between the unit vector d and the unit axis, given c = cos and
// perp = d - c axis: |perp|^2 / (1 + c) for c > 0, where 1 - c itself would cancel.
fn one_minus_cos(c: f32, perp: vec3<f32>) -> f32 {
    if c > 0.0 {
        return dot(perp, perp) / (1.0 + c);
    }
    return 1.0 - c;
}

// Velocity::observer_to_scene: aberration with the boost reversed, b = -speed. The CPU's
// (c + b) / (1 + b c) u + perp / (gamma (1 + b c)) is, up to the positive factor 1 + b c
// that the normalisation removes, (c - speed) u + perp / gamma; and c - speed =
// (1 - speed) - (1 - c) with 1 - speed from the host, so nothing cancels in f32 for rays
// near the direction of motion at speeds near 1 (f32 holds 1 - 0.999999 to 6 % only).
fn observer_to_scene(d: vec3<f32>) -> vec3<f32> {
    let speed = p.beta.w;
    if speed == 0.0 {
        return d;
    }
    let u = p.beta.xyz / speed;
    let c = dot(d, u);
    let perp = d - c * u;
    let c_minus_speed = p.one_minus_speed - one_minus_cos(c, perp);
    return normalize(c_minus_speed * u + perp / p.gamma);
}

// Velocity::doppler_factor_observer, 1 / (gamma (1 - beta . d)), with 1 - beta . d =
// (1 - speed) + speed (1 - c) so that it keeps its precision as above.
fn doppler_factor(d: vec3<f32>) -> f32 {
    let speed = p.beta.w;
    if speed == 0.0 {
        return 1.0;
    }
    let u = p.beta.xyz / speed;
    let c = dot(d, u);
    let perp = d - c * u;
    return 1.0 / (p.gamma * (p.one_minus_speed + speed * one_minus_cos(c, perp)));
}

fn table_entry(k: u32, i: u32) -> f32 {
    return table[9u * k + i];
}

fn doppler_shift(dop: f32, rgb: vec3<f32>) -> vec3<f32> {
    let l = log(dop);
    if !(l >= p.ln_min && l <= p.ln_max) {
        return vec3<f32>(0.0);
    }
    let x = (l - p.ln_min) / p.ln_step;
    let k = min(u32(floor(x)), p.table_len - 2u);
    let t = x - f32(k);
    var out = vec3<f32>(0.0);
    for (var i = 0u; i < 3u; i++) {
        var acc = 0.0;
        for (var j = 0u; j < 3u; j++) {
            let a = table_entry(k, 3u * i + j);
            let b = table_entry(k + 1u, 3u * i + j);
            acc += (a + (b - a) * t) * rgb[j];
        }
        out[i] = acc;
    }
    return out;
}

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let x = id.x;
    let y = id.y;
    if x >= p.width || y >= p.height {
        return;
    }
    let sx = (2.0 * (f32(x) + 0.5) / f32(p.width) - 1.0) * p.half_w;
    let sy = (1.0 - 2.0 * (f32(y) + 0.5) / f32(p.height)) * p.half_h;
    let d_obs = normalize(p.forward.xyz + sx * p.right.xyz + sy * p.up.xyz);
    var d_scene = d_obs;
    if p.aberration == 1u {
        d_scene = observer_to_scene(d_obs);
    }
    var rgb = sample_env(d_scene);
    if p.doppler == 1u || p.searchlight == 1u {
        let dop = doppler_factor(d_obs);
        if p.doppler == 1u {
            rgb = doppler_shift(dop, rgb);
        }
        if p.searchlight == 1u {
            let d2 = dop * dop;
            rgb = rgb * (d2 * d2);
        }
    }
    let o = 3u * (y * p.width + x);
    out_rgb[o] = rgb.x;
    out_rgb[o + 1u] = rgb.y;
    out_rgb[o + 2u] = rgb.z;
}
