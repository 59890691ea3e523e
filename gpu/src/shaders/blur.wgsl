// Separable Gaussian blur of a stack of planes (blueshift_tonemap::plane::Plane::
// gaussian_blur): a symmetric odd kernel, edges clamped, summed in kernel order.
// `horizontal` = 1 convolves rows, 0 columns. invocation (x, y, plane); the result of
// plane k goes to plane `dst_plane + k` of `dst`.

struct Params {
    w: u32,
    h: u32,
    planes: u32,
    radius: u32,
    horizontal: u32,
    dst_plane: u32,
    _p1: u32,
    _p2: u32,
}

@group(0) @binding(0) var<storage, read> src: array<f32>;
@group(0) @binding(1) var<storage, read> kernel: array<f32>;
@group(0) @binding(2) var<storage, read_write> dst: array<f32>;
@group(0) @binding(3) var<uniform> p: Params;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let x = id.x;
    let y = id.y;
    let k = id.z;
    if x >= p.w || y >= p.h || k >= p.planes {
        return;
    }
    let base = k * p.w * p.h;
    let r = i32(p.radius);
    var acc = 0.0;
    for (var i = 0; i <= 2 * r; i++) {
        var v: f32;
        if p.horizontal == 1u {
            let xs = u32(clamp(i32(x) + i - r, 0, i32(p.w) - 1));
            v = src[base + y * p.w + xs];
        } else {
            let ys = u32(clamp(i32(y) + i - r, 0, i32(p.h) - 1));
            v = src[base + ys * p.w + x];
        }
        acc += kernel[i] * v;
    }
    dst[(p.dst_plane + k) * p.w * p.h + y * p.w + x] = acc;
}
