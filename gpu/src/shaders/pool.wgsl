
// ---------------------------------------------------------------- the device brick pool
// (gpu/src/pool.rs). Every channel is cut into bricks of POOL_B^3 voxels, each stored with
// one more voxel per axis (the clamped neighbour trilinear sampling reads), so the eight
// corners of a sample always lie in one brick. The including shader declares
// `pool: array<f32>` and `pages: array<vec2<u32>>`, laid out as
//   pages[0] = (levels, pages per channel), pages[1] = (first page t0, 0);
//   with more than one level (per-brick levels of detail, `--lod brick`):
//     pages[2] = (regions x, regions y), pages[3] = (regions z, region edge in voxels),
//     pages[4 + 5 l ..] = level l: (nx, ny), (nz, its first page within a channel),
//       (origin x, origin y), (origin z, spacing x), (spacing y, spacing z) (f32 bits),
//     then each region's level, one byte each, x fastest, eight to an entry;
//   pages[t0 + ch * pages_per_channel + page] = (slot, 0) for a brick held in `pool` at
//     `slot * POOL_S^3`, or (POOL_CONSTANT, value bits) for a brick whose voxels all equal
//     `value` (held nowhere).
// A sample at base-level index coordinates q in a region of level l is level l's trilinear
// sample at the same world point, as blueshift-volume's `BrickedField::try_sample_index`.

const POOL_B: u32 = 32u;
const POOL_S: u32 = 33u;
const POOL_CONSTANT: u32 = 0xffffffffu;
const POOL_HEAD: u32 = 2u;

struct PoolCorner {
    page: u32,      // the brick's index in a channel's pages, t0 included
    off: u32,       // corner (x0, y0, z0)'s index inside the brick
    t: vec3<f32>,   // fractions along x, y, z
}

// Clamped to the voxel centres of a grid of `dims` (NaN -> 0), as `clamped_cell`.
fn pool_clamp(q: vec3<f32>, dims: vec3<u32>) -> vec3<f32> {
    let mx = vec3<f32>(dims - vec3<u32>(1u));
    var p = min(max(q, vec3<f32>(0.0)), mx);
    if q.x != q.x { p.x = 0.0; }
    if q.y != q.y { p.y = 0.0; }
    if q.z != q.z { p.z = 0.0; }
    return p;
}

// The corner of a level of `dims` voxels whose pages start at `first`.
fn pool_corner_at(q: vec3<f32>, dims: vec3<u32>, first: u32) -> PoolCorner {
    let p = pool_clamp(q, dims);
    let f = floor(p);
    let c0 = vec3<u32>(f);
    let b = c0 / POOL_B;
    let l = c0 - b * POOL_B;
    let nb = (dims + vec3<u32>(POOL_B - 1u)) / POOL_B;
    var c: PoolCorner;
    c.page = first + b.x + nb.x * (b.y + nb.y * b.z);
    c.off = l.x + POOL_S * (l.y + POOL_S * l.z);
    c.t = p - f;
    return c;
}

fn pool_f32(v: u32) -> f32 {
    return bitcast<f32>(v);
}

// The corner of a sample at base-level index coordinates `q` of a pool with per-region
// levels (`levels` > 1).
fn pool_corner_lod(q: vec3<f32>, dims: vec3<u32>, levels: u32) -> PoolCorner {
    let t0 = pages[1].x;
    let rxy = pages[2];
    let rze = pages[3];
    let v = vec3<u32>(floor(pool_clamp(q, dims))) / rze.y;
    let ri = v.x + rxy.x * (v.y + rxy.y * v.z);
    let w = pages[POOL_HEAD + 2u + 5u * levels + ri / 8u];
    let word = select(w.x, w.y, (ri % 8u) >= 4u);
    let l = (word >> (8u * (ri % 4u))) & 0xffu;
    let e = POOL_HEAD + 2u + 5u * l;
    let first = t0 + pages[e + 1u].y;
    if l == 0u {
        return pool_corner_at(q, dims, first);
    }
    let b = POOL_HEAD + 2u;
    let o0 = vec3<f32>(pool_f32(pages[b + 2u].x), pool_f32(pages[b + 2u].y),
                       pool_f32(pages[b + 3u].x));
    let s0 = vec3<f32>(pool_f32(pages[b + 3u].y), pool_f32(pages[b + 4u].x),
                       pool_f32(pages[b + 4u].y));
    let ol = vec3<f32>(pool_f32(pages[e + 2u].x), pool_f32(pages[e + 2u].y),
                       pool_f32(pages[e + 3u].x));
    let sl = vec3<f32>(pool_f32(pages[e + 3u].y), pool_f32(pages[e + 4u].x),
                       pool_f32(pages[e + 4u].y));
    let world = o0 + q * s0;
    let dl = vec3<u32>(pages[e].x, pages[e].y, pages[e + 1u].x);
    return pool_corner_at((world - ol) / sl, dl, first);
}

// The corner of blueshift-volume's `sample_trilinear_index` at continuous index coordinates
// `q` of a grid of `dims` voxels (clamped to the centres; NaN -> 0), at the level the
// sample's region takes.
fn pool_corner(q: vec3<f32>, dims: vec3<u32>) -> PoolCorner {
    let levels = pages[0].x;
    if levels > 1u {
        return pool_corner_lod(q, dims, levels);
    }
    return pool_corner_at(q, dims, POOL_HEAD);
}

// The eight corner values of channel `ch`: x0y0z0, x1y0z0, x0y1z0, x1y1z0, x0y0z1, x1y0z1,
// x0y1z1, x1y1z1. (`dims` is the base level's, kept for the callers' symmetry.)
fn pool_fetch(ch: u32, dims: vec3<u32>, c: PoolCorner) -> array<f32, 8> {
    let e = pages[ch * pages[0].y + c.page];
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
