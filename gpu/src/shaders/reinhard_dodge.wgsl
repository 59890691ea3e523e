// Reinhard et al. 2002 local operator, Eq. 7-9 (blueshift_tonemap::ops::reinhard::
// dodge_and_burn): per pixel, pick the largest scale whose centre-surround difference
// stays under epsilon, then L_d = L / (1 + V1(chosen scale)).
// `centres` holds the n + 1 blurred planes of the scaled luminance, scale k at plane k.

struct Params {
    n_pixels: u32,
    n_scales: u32,
    num: f32,
    epsilon: f32,
}

@group(0) @binding(0) var<storage, read> l: array<f32>;
@group(0) @binding(1) var<storage, read> centres: array<f32>;
@group(0) @binding(2) var<storage, read> scales: array<f32>;
@group(0) @binding(3) var<storage, read_write> lum_out: array<f32>;
@group(0) @binding(4) var<uniform> p: Params;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= p.n_pixels {
        return;
    }
    var chosen = centres[i];
    for (var k = 0u; k < p.n_scales; k++) {
        let v1 = centres[k * p.n_pixels + i];
        let v2 = centres[(k + 1u) * p.n_pixels + i];
        let s = scales[k];
        let v = (v1 - v2) / (p.num / (s * s) + v1);
        if abs(v) >= p.epsilon {
            break;
        }
        chosen = v1;
    }
    lum_out[i] = l[i] / (1.0 + chosen);
}
