// Durand & Dorsey: compress the base, keep the detail, back to linear luminance:
// L_out = 10^((b - b_max) * gamma + (log_l - b)).

struct Params {
    n: u32,
    bmax: f32,
    gamma: f32,
    _p0: u32,
}

@group(0) @binding(0) var<storage, read> log_l: array<f32>;
@group(0) @binding(1) var<storage, read> base: array<f32>;
@group(0) @binding(2) var<storage, read_write> lum_out: array<f32>;
@group(0) @binding(3) var<uniform> p: Params;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= p.n {
        return;
    }
    let b = base[i];
    lum_out[i] = pow(10.0, (b - p.bmax) * p.gamma + (log_l[i] - b));
}
