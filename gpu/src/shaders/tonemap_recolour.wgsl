// C_out = (C_in / L_in)^s * L_out (blueshift_tonemap::plane::recolour), one invocation per
// pixel; pixels with L_in <= 0 or L_out not > 0 come out black.

struct Params {
    n: u32,
    saturation: f32,
    _p0: u32,
    _p1: u32,
}

@group(0) @binding(0) var<storage, read> rgb: array<f32>;
@group(0) @binding(1) var<storage, read> lum: array<f32>;
@group(0) @binding(2) var<storage, read> lum_out: array<f32>;
@group(0) @binding(3) var<storage, read_write> out_rgb: array<f32>;
@group(0) @binding(4) var<uniform> p: Params;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= p.n {
        return;
    }
    let lin = lum[i];
    let lout = lum_out[i];
    for (var c = 0u; c < 3u; c++) {
        var v = 0.0;
        if lin > 0.0 && lout > 0.0 {
            let ratio = rgb[3u * i + c] / lin;
            if p.saturation == 1.0 {
                v = ratio * lout;
            } else {
                v = pow(ratio, p.saturation) * lout;
            }
        }
        out_rgb[3u * i + c] = v;
    }
}
