// y[i] = a * x[i] + b: the context's smoke-test kernel (and a minimal example of the
// crate's buffer conventions: storage at bindings 0.., uniform last).

struct Params {
    a: f32,
    b: f32,
    n: u32,
    _pad: u32,
}

@group(0) @binding(0) var<storage, read> x: array<f32>;
@group(0) @binding(1) var<storage, read_write> y: array<f32>;
@group(0) @binding(2) var<uniform> params: Params;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= params.n {
        return;
    }
    y[i] = params.a * x[i] + params.b;
}
