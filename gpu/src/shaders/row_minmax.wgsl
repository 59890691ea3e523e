// Per-row minimum and maximum of a plane (one invocation per row); the host folds the rows
// in order, so the result is exact and independent of scheduling.

struct Params {
    w: u32,
    h: u32,
    _p0: u32,
    _p1: u32,
}

@group(0) @binding(0) var<storage, read> src: array<f32>;
@group(0) @binding(1) var<storage, read_write> out_minmax: array<f32>;
@group(0) @binding(2) var<uniform> p: Params;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let y = id.x;
    if y >= p.h {
        return;
    }
    var lo = src[y * p.w];
    var hi = lo;
    for (var x = 1u; x < p.w; x++) {
        let v = src[y * p.w + x];
        lo = min(lo, v);
        hi = max(hi, v);
    }
    out_minmax[2u * y] = lo;
    out_minmax[2u * y + 1u] = hi;
}
