// C_out = (C_in / L_in)^s * L_out (blueshift_tonemap::plane::recolour), one invocation per
// pixel; pixels with L_in <= 0 or L_out not > 0 come out black. With `fit` != 0 the result
// is then brought into the display cube by constant-luminance desaturation towards grey
// (blueshift_tonemap::plane::fit_to_display, as recolour_in_gamut does for the local
// operators), with the Rec. 709 weights of blueshift_tonemap::LUMINANCE_WEIGHTS.

struct Params {
    n: u32,
    saturation: f32,
    fit: u32,
    _p1: u32,
}

@group(0) @binding(0) var<storage, read> rgb: array<f32>;
@group(0) @binding(1) var<storage, read> lum: array<f32>;
@group(0) @binding(2) var<storage, read> lum_out: array<f32>;
@group(0) @binding(3) var<storage, read_write> out_rgb: array<f32>;
@group(0) @binding(4) var<uniform> p: Params;

fn in_cube(c: f32) -> bool {
    return c >= 0.0 && c <= 1.0;
}

fn fit_to_display(c: vec3<f32>) -> vec3<f32> {
    if in_cube(c.x) && in_cube(c.y) && in_cube(c.z) {
        return c;
    }
    let y = 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z;
    // `y > 0` is false for NaN too.
    if !(y > 0.0) {
        return vec3<f32>(0.0);
    }
    if y >= 1.0 {
        return vec3<f32>(1.0);
    }
    var t = 1.0;
    for (var k = 0u; k < 3u; k++) {
        let v = c[k];
        if v > 1.0 {
            t = min(t, (1.0 - y) / (v - y));
        } else if v < 0.0 {
            t = min(t, y / (y - v));
        }
    }
    return clamp(vec3<f32>(y) + t * (c - vec3<f32>(y)), vec3<f32>(0.0), vec3<f32>(1.0));
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= p.n {
        return;
    }
    let lin = lum[i];
    let lout = lum_out[i];
    var o = vec3<f32>(0.0);
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
        o[c] = v;
    }
    if p.fit != 0u {
        o = fit_to_display(o);
    }
    out_rgb[3u * i] = o.x;
    out_rgb[3u * i + 1u] = o.y;
    out_rgb[3u * i + 2u] = o.z;
}
