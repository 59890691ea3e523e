// Fattal et al. 2002: attenuated gradients G = grad(H) * Phi (forward differences, each
// attenuated by Phi at the edge midpoint, (Phi(x) + Phi(x+1)) / 2 in x and likewise in y; zero
// at the far border) and their divergence div G (backward differences), as
// blueshift_tonemap::ops::fattal::compressed_log_luminance builds the Poisson right side.

struct Params {
    w: u32,
    h: u32,
    _p0: u32,
    _p1: u32,
}

@group(0) @binding(0) var<storage, read> hlog: array<f32>;
@group(0) @binding(1) var<storage, read> phi: array<f32>;
@group(0) @binding(2) var<storage, read_write> div: array<f32>;
@group(0) @binding(3) var<uniform> p: Params;

fn gx(x: u32, y: u32) -> f32 {
    if x + 1u < p.w {
        let i = y * p.w + x;
        return (hlog[i + 1u] - hlog[i]) * 0.5 * (phi[i] + phi[i + 1u]);
    }
    return 0.0;
}

fn gy(x: u32, y: u32) -> f32 {
    if y + 1u < p.h {
        let i = y * p.w + x;
        return (hlog[i + p.w] - hlog[i]) * 0.5 * (phi[i] + phi[i + p.w]);
    }
    return 0.0;
}

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let x = id.x;
    let y = id.y;
    if x >= p.w || y >= p.h {
        return;
    }
    var v = gx(x, y) + gy(x, y);
    if x > 0u {
        v -= gx(x - 1u, y);
    }
    if y > 0u {
        v -= gy(x, y - 1u);
    }
    div[y * p.w + x] = v;
}
