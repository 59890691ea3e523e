// A dense linear transform along one image axis: along x (axis 0)
// out[y, i] = sum_j m[i, j] in[y, j] with an (w x w) matrix, along y (axis 1)
// out[i, x] = sum_j m[i, j] in[j, x] with an (h x h) matrix. With DCT-II / DCT-III
// matrices this is the separable 2-D DCT of the Poisson solver (exact, O(N (w + h))).

struct Params {
    w: u32,
    h: u32,
    axis: u32,
    _p0: u32,
}

@group(0) @binding(0) var<storage, read> src: array<f32>;
@group(0) @binding(1) var<storage, read> m: array<f32>;
@group(0) @binding(2) var<storage, read_write> dst: array<f32>;
@group(0) @binding(3) var<uniform> p: Params;

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let x = id.x;
    let y = id.y;
    if x >= p.w || y >= p.h {
        return;
    }
    var acc = 0.0;
    if p.axis == 0u {
        for (var j = 0u; j < p.w; j++) {
            acc += m[x * p.w + j] * src[y * p.w + j];
        }
    } else {
        for (var j = 0u; j < p.h; j++) {
            acc += m[y * p.h + j] * src[j * p.w + x];
        }
    }
    dst[y * p.w + x] = acc;
}
