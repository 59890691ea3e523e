// Durand & Dorsey fast bilateral filter, step 3: slice the blurred grid at each pixel's
// value (bilinear in space, linear between the two bracketing levels), as
// blueshift_tonemap::ops::durand::fast_bilateral does.

struct Params {
    w: u32,
    h: u32,
    gw: u32,
    gh: u32,
    nl: u32,
    nseg: u32,
    lo: f32,
    step: f32,
    scale: f32,
    _p0: u32,
    _p1: u32,
    _p2: u32,
}

@group(0) @binding(0) var<storage, read> input: array<f32>;
@group(0) @binding(1) var<storage, read> grid: array<f32>;
@group(0) @binding(2) var<storage, read_write> base_out: array<f32>;
@group(0) @binding(3) var<uniform> p: Params;

fn bilinear(off: u32, xin: f32, yin: f32) -> f32 {
    let x = clamp(xin, 0.0, f32(p.gw - 1u));
    let y = clamp(yin, 0.0, f32(p.gh - 1u));
    let x0 = u32(floor(x));
    let y0 = u32(floor(y));
    let x1 = min(x0 + 1u, p.gw - 1u);
    let y1 = min(y0 + 1u, p.gh - 1u);
    let fx = x - f32(x0);
    let fy = y - f32(y0);
    let a = grid[off + y0 * p.gw + x0];
    let b = grid[off + y0 * p.gw + x1];
    let c = grid[off + y1 * p.gw + x0];
    let d = grid[off + y1 * p.gw + x1];
    return (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy;
}

fn value(k: u32, v: f32, gx: f32, gy: f32) -> f32 {
    let plane = p.gw * p.gh;
    let ww = bilinear(k * plane, gx, gy);
    if ww > 1e-20 {
        return bilinear((p.nl + k) * plane, gx, gy) / ww;
    }
    return v;
}

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let x = id.x;
    let y = id.y;
    if x >= p.w || y >= p.h {
        return;
    }
    let v = input[y * p.w + x];
    let t = clamp((v - p.lo) / p.step, 0.0, f32(p.nseg));
    let j = min(u32(floor(t)), p.nseg - 1u);
    let f = t - f32(j);
    let gx = (f32(x) + 0.5) * p.scale - 0.5;
    let gy = (f32(y) + 0.5) * p.scale - 0.5;
    base_out[y * p.w + x] = value(j, v, gx, gy) * (1.0 - f) + value(j + 1u, v, gx, gy) * f;
}
