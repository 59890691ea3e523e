// The Poisson solve in the DCT domain: divide coefficient (k, l) by the eigenvalue of the
// Neumann 5-point Laplacian (2 cos(pi k / W) - 2) + (2 cos(pi l / H) - 2); the (0, 0)
// coefficient (the free constant) is set to 0.

struct Params {
    w: u32,
    h: u32,
    _p0: u32,
    _p1: u32,
}

@group(0) @binding(0) var<storage, read_write> coef: array<f32>;
@group(0) @binding(1) var<storage, read> cx: array<f32>;
@group(0) @binding(2) var<storage, read> cy: array<f32>;
@group(0) @binding(3) var<uniform> p: Params;

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let k = id.x;
    let l = id.y;
    if k >= p.w || l >= p.h {
        return;
    }
    let i = l * p.w + k;
    if k == 0u && l == 0u {
        coef[i] = 0.0;
    } else {
        coef[i] = coef[i] / (cx[k] + cy[l]);
    }
}
