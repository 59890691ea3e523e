// Global tone-mapping curves and recolouring, one invocation per pixel; mirrors
// blueshift_tonemap::GlobalCurve::apply_clean (f32 per-pixel arithmetic, constants
// resolved on the host in f64).
// mode 0: linear (every channel times c0), 1: Drago, 2: Reinhard global.

struct Params {
    mode: u32,
    n: u32,
    saturation: f32,
    c0: f32, // linear: scale; Drago: 1/adaptation; Reinhard: scale
    c1: f32, // Drago: 1/scaled_max; Reinhard: 1/white^2 (0 for none)
    c2: f32, // Drago: exponent ln(bias)/ln(0.5)
    c3: f32, // Drago: coef Ld_max*0.01/log10(scaled_max+1)
    _pad: f32,
}

@group(0) @binding(0) var<storage, read> rgb: array<f32>;
@group(0) @binding(1) var<storage, read> lum: array<f32>;
@group(0) @binding(2) var<storage, read_write> out_rgb: array<f32>;
@group(0) @binding(3) var<uniform> p: Params;

fn curve(l: f32) -> f32 {
    if p.mode == 1u {
        let x = l * p.c0;
        // ln_1p(x): for the tiny x where log(1+x) loses digits use the series.
        var l1p: f32;
        if x < 1e-4 {
            l1p = x * (1.0 - 0.5 * x);
        } else {
            l1p = log(1.0 + x);
        }
        return p.c3 * l1p / log(2.0 + 8.0 * pow(x * p.c1, p.c2));
    }
    let x = l * p.c0;
    return x * (1.0 + x * p.c1) / (1.0 + x);
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= p.n {
        return;
    }
    if p.mode == 0u {
        for (var c = 0u; c < 3u; c++) {
            out_rgb[3u * i + c] = rgb[3u * i + c] * p.c0;
        }
        return;
    }
    let lin = lum[i];
    var lout = 0.0;
    if lin > 0.0 {
        lout = curve(lin);
    }
    for (var c = 0u; c < 3u; c++) {
        var v = 0.0;
        // `lout > 0` is false for NaN too: such a pixel comes out black.
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
