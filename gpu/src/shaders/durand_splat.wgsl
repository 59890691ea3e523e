// Durand & Dorsey fast bilateral filter, step 1 (blueshift_tonemap::ops::durand::
// fast_bilateral): splat the log luminance into a (level, gy, gx) grid of weights and
// weighted values. One invocation per grid cell (gx, gy) walks its z x z pixels in the CPU's
// order (rows, then columns), so no two invocations write the same cell.
// Layout: weights of level j at [j * gw * gh + gy * gw + gx], values at [(nl + j) * gw * gh + ...].

struct Params {
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
    probe_n: u32, // 2: the trip count of `limiter_exhausted`'s loop (a runtime value)
    _p1: u32,
}

@group(0) @binding(0) var<storage, read> input: array<f32>;
@group(0) @binding(1) var<storage, read> levels: array<f32>;
@group(0) @binding(2) var<storage, read_write> grid: array<f32>;
@group(0) @binding(3) var<uniform> p: Params;
// Set to 1 when an invocation batch ran out of the adapter's loop limit (a cell walks
// z x z pixels, z = sigma_s / 4).
@group(0) @binding(4) var<storage, read_write> limited: array<atomic<u32>>;


@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let gx = id.x;
    let gy = id.y;
    if gx >= p.gw || gy >= p.gh {
        return;
    }
    let plane = p.gw * p.gh;
    let cell = gy * p.gw + gx;
    for (var j = 0u; j < p.nl; j++) {
        grid[j * plane + cell] = 0.0;
        grid[(p.nl + j) * plane + cell] = 0.0;
    }
    let y1 = min((gy + 1u) * p.z, p.h);
    let x1 = min((gx + 1u) * p.z, p.w);
    for (var y = gy * p.z; y < y1; y++) {
        for (var x = gx * p.z; x < x1; x++) {
            let v = input[y * p.w + x];
            let jlo = u32(max(ceil((v - p.cut - p.lo) / p.step), 0.0));
            // As the CPU's `as usize`: negative saturates to 0.
            let jhi = min(u32(max(floor((v + p.cut - p.lo) / p.step), 0.0)), p.nl - 1u);
            for (var j = jlo; j <= jhi; j++) {
                let d = v - levels[j];
                let g = exp(-d * d * p.inv2r2);
                grid[j * plane + cell] += g;
                grid[(p.nl + j) * plane + cell] += g * v;
            }
        }
    }
    if limiter_exhausted(p.probe_n) {
        atomicOr(&limited[0], 1u);
    }
}
