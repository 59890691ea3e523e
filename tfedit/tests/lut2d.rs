//! The 2D encoding of long tables (HDR VolVis section 6.2, Fig. 8).

mod common;
use common::assert_close;

use blueshift_tfedit::{Lut2d, builtin_over};

#[test]
fn linear_filtering_across_every_row_break_equals_the_1d_table() {
    // 65,536 entries (16-bit data) in rows of n = 4,094: 17 rows of 4,096 texels.
    let tf = builtin_over("inferno", [0.0, 65_535.0]).unwrap().with_alpha_g(0.01).unwrap();
    let lut = tf.lut(65_536).unwrap();
    let tex = Lut2d::encode_for_max_texture(&lut, 4096).unwrap();
    assert_eq!((tex.rows(), tex.width(), tex.row_len()), (17, 4096, 4094));
    let n = tex.row_len();
    for k in 1..tex.rows() {
        let brk = (k * n) as f64; // entries kn - 1 and kn sit in different rows
        for off in [-1.0, -0.75, -0.5, -0.25, -1e-3, 0.0, 1e-3, 0.5] {
            let p = brk + off;
            let a = lut.sample_position(p);
            let b = tex.sample_position(p);
            for c in 0..4 {
                assert_close(f64::from(b[c]), f64::from(a[c]), 1e-6, &format!("row break {k}, p = {p}, channel {c}"));
            }
            // Independently: linear interpolation between the two neighbouring entries.
            let i = p.floor() as usize;
            let f = (p - i as f64) as f32;
            let (e0, e1) = (lut.get(i).unwrap(), lut.get(i + 1).unwrap());
            let expected = e0[0] + (e1[0] - e0[0]) * f;
            assert_close(f64::from(b[0]), f64::from(expected), 1e-6, "lerp of neighbours");
        }
    }
}

#[test]
fn border_texels_duplicate_the_neighbouring_rows_entries() {
    let tf = builtin_over("viridis", [0.0, 1.0]).unwrap();
    let lut = tf.lut(1000).unwrap();
    let tex = Lut2d::encode(&lut, 64).unwrap();
    assert_eq!(tex.rows(), 16); // 15 full rows and one of 40 entries
    for k in 0..tex.rows() {
        // Texel 0 of row k is entry kn - 1; texel n + 1 is entry (k + 1) n (clamped).
        let left = (k * 64).saturating_sub(1);
        let right = ((k + 1) * 64).min(999);
        assert_eq!(tex.texel(k, 0), lut.get(left));
        assert_eq!(tex.texel(k, 65), lut.get(right));
        assert_eq!(tex.entry_of_texel(k, 0), Some(left));
        assert_eq!(tex.entry_of_texel(k, 65), Some(right));
    }
    // The index mapping both ways.
    for i in [0usize, 1, 63, 64, 65, 500, 998, 999] {
        let (row, col) = tex.texel_of_entry(i).unwrap();
        assert!((1..=64).contains(&col));
        assert_eq!(tex.entry_of_texel(row, col), Some(i));
        assert_eq!(tex.texel(row, col), lut.get(i));
        let (x, r) = tex.coords_of_position(i as f64);
        assert_close(tex.position_of_coords(x, r), i as f64, 1e-12, "position round trip");
    }
    assert_eq!(tex.texel_of_entry(1000), None);
    assert_eq!(tex.entry_of_texel(16, 0), None);
    assert!(Lut2d::encode(&lut, 0).is_err());
    assert!(Lut2d::encode_for_max_texture(&lut, 16).is_err(), "1000 entries do not fit 16 x 16");
}

#[test]
fn capacity_of_a_square_texture_is_m_times_m_minus_2() {
    // HDR VolVis section 6.2: a 4,096 x 4,096 texture holds 4,096 x 4,094 (16,769,024)
    // entries. The same rule checked on a 64 x 64 texture: 64 x 62 = 3,968 entries fit,
    // one more does not.
    let tf = builtin_over("grey", [0.0, 1.0]).unwrap();
    let lut = tf.lut(64 * 62).unwrap();
    let tex = Lut2d::encode_for_max_texture(&lut, 64).unwrap();
    assert_eq!((tex.rows(), tex.width()), (64, 64));
    let too_long = tf.lut(64 * 62 + 1).unwrap();
    assert!(Lut2d::encode_for_max_texture(&too_long, 64).is_err());
}
