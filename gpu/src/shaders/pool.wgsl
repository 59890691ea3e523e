
// ---------------------------------------------------------------- the device brick pool
// (gpu/src/pool.rs). Every channel is cut into bricks of POOL_B^3 voxels, each stored with
// one more voxel per axis (the clamped neighbour trilinear sampling reads), so the eight
// corners of a sample always lie in one brick. `pages[ch * pages_per_channel + brick]` is
// (slot, 0) for a brick held in `pool` at `slot * POOL_S^3`, or (POOL_CONSTANT, value bits)
// for a brick whose voxels all equal `value` (held nowhere). The including shader declares
// `pool: array<f32>` and `pages: array<vec2<u32>>`.

const POOL_B: u32 = 32u;
const POOL_S: u32 = 33u;
const POOL_CONSTANT: u32 = 0xffffffffu;

struct PoolCorner {
    page: u32,      // the brick's index in a channel's page table
    off: u32,       // corner (x0, y0, z0)'s index inside the brick
    t: vec3<f32>,   // fractions along x, y, z
}

// The corner of blueshift-volume's `sample_trilinear_index` at continuous index coordinates
// `q` of a grid of `dims` voxels (clamped to the centres; NaN -> 0).
fn pool_corner(q: vec3<f32>, dims: vec3<u32>) -> PoolCorner {
    let mx = vec3<f32>(dims - vec3<u32>(1u));
    var p = min(max(q, vec3<f32>(0.0)), mx);
    if q.x != q.x { p.x = 0.0; }
    if q.y != q.y { p.y = 0.0; }
    if q.z != q.z { p.z = 0.0; }
    let f = floor(p);
    let c0 = vec3<u32>(f);
    let b = c0 / POOL_B;
    let l = c0 - b * POOL_B;
    let nb = (dims + vec3<u32>(POOL_B - 1u)) / POOL_B;
    var c: PoolCorner;
    c.page = b.x + nb.x * (b.y + nb.y * b.z);
    c.off = l.x + POOL_S * (l.y + POOL_S * l.z);
    c.t = p - f;
    return c;
}

// The eight corner values of channel `ch`: x0y0z0, x1y0z0, x0y1z0, x1y1z0, x0y0z1, x1y0z1,
// x0y1z1, x1y1z1.
fn pool_fetch(ch: u32, dims: vec3<u32>, c: PoolCorner) -> array<f32, 8> {
    let nb = (dims + vec3<u32>(POOL_B - 1u)) / POOL_B;
    let e = pages[ch * (nb.x * nb.y * nb.z) + c.page];
    if e.x == POOL_CONSTANT {
        let v = bitcast<f32>(e.y);
        return array<f32, 8>(v, v, v, v, v, v, v, v);
    }
    let o = e.x * (POOL_S * POOL_S * POOL_S) + c.off;
    let sy = POOL_S;
    let sz = POOL_S * POOL_S;
    return array<f32, 8>(pool[o], pool[o + 1u], pool[o + sy], pool[o + sy + 1u],
                         pool[o + sz], pool[o + sz + 1u], pool[o + sz + sy],
                         pool[o + sz + sy + 1u]);
}
