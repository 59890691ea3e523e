// Per-row minimum and maximum of a plane (one invocation per row); the host folds the rows
// in order, so the result is exact and independent of scheduling.

struct Params {
    w: u32,
    h: u32,
    probe_n: u32, // 2: the trip count of `limiter_exhausted`'s loop (a runtime value)
    _p1: u32,
}

@group(0) @binding(0) var<storage, read> src: array<f32>;
@group(0) @binding(1) var<storage, read_write> out_minmax: array<f32>;
@group(0) @binding(2) var<uniform> p: Params;
// Set to 1 when an invocation batch ran out of the adapter's loop limit (a row wider than
// 65535 pixels).
@group(0) @binding(3) var<storage, read_write> limited: array<atomic<u32>>;


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
    if limiter_exhausted(p.probe_n) {
        atomicOr(&limited[0], 1u);
    }
}
