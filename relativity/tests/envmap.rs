//! Environment maps: the OpenGL cube convention, seamless sampling, conversion, bad input.

use blueshift_relativity::{
    CubeMap, Environment, EquirectMap, Error, cube_dir, cube_face_st, from_lon_polar, lon_polar,
};
use glam::DVec3;
use image::Rgb32FImage;

/// A smooth test field: linear in the direction, so bilinear sampling of texel-centre
/// values is accurate to O(1/N^2) on a face and to O(1/N) across edges if seamless.
fn field(d: DVec3) -> [f32; 3] {
    let d = d.normalize();
    [(1.0 + d.x) as f32, (1.0 + d.y) as f32, (1.0 + d.z) as f32]
}

fn cube_of(n: u32) -> CubeMap {
    let faces = std::array::from_fn(|f| {
        Rgb32FImage::from_fn(n, n, |x, y| {
            let nf = f64::from(n);
            image::Rgb(field(cube_dir(
                f,
                (f64::from(x) + 0.5) / nf,
                (f64::from(y) + 0.5) / nf,
            )))
        })
    });
    CubeMap::new(faces).unwrap()
}

fn dirs() -> Vec<DVec3> {
    // A deterministic spiral of directions over the sphere (Fibonacci lattice).
    let n = 2000;
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (f64::from(i) + 0.5) / f64::from(n);
            let phi = f64::from(i) * 2.399_963_229_728_653;
            let r = (1.0 - z * z).sqrt();
            DVec3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// OpenGL 4.6 table 8.19: spot checks of face selection and (s, t) orientation.
#[test]
fn cube_faces_follow_the_opengl_convention() {
    let cases = [
        (DVec3::new(1.0, 0.0, -0.5), 0, 0.75, 0.5),
        (DVec3::new(1.0, 0.5, 0.0), 0, 0.5, 0.25),
        (DVec3::new(-1.0, 0.0, 0.5), 1, 0.75, 0.5),
        (DVec3::new(0.5, 1.0, 0.0), 2, 0.75, 0.5),
        (DVec3::new(0.0, 1.0, 0.5), 2, 0.5, 0.75),
        (DVec3::new(0.0, -1.0, 0.5), 3, 0.5, 0.25),
        (DVec3::new(0.5, 0.0, 1.0), 4, 0.75, 0.5),
        (DVec3::new(0.5, 0.0, -1.0), 5, 0.25, 0.5),
    ];
    for (d, face, s, t) in cases {
        let (f, s2, t2) = cube_face_st(d);
        assert_eq!(f, face, "{d}");
        assert!(
            (s - s2).abs() < 1e-12 && (t - t2).abs() < 1e-12,
            "{d}: {s2} {t2}"
        );
    }
    for d in dirs() {
        let (f, s, t) = cube_face_st(d);
        assert!((cube_dir(f, s, t).normalize() - d).length() < 1e-12);
    }
}

#[test]
fn lon_polar_round_trip() {
    for d in dirs() {
        let (lon, polar) = lon_polar(d);
        assert!((from_lon_polar(lon, polar) - d).length() < 1e-12);
    }
    // -Z is the centre of the equirectangular image, +Y its top.
    assert!(lon_polar(DVec3::NEG_Z).0.abs() < 1e-15);
    assert!(lon_polar(DVec3::Y).1.abs() < 1e-15);
}

/// Seamless: the bilinear cube sample of a linear field is within a texel's variation of
/// the field everywhere, edges and corners included (a non-seamless sampler that clamps at
/// face edges errs by half a texel's gradient there too, so we also check continuity across
/// each edge directly).
#[test]
fn cube_sampling_is_seamless() {
    let n = 32;
    let cube = cube_of(n);
    let texel = 2.0 / f64::from(n); // field change per texel is at most this
    let mut worst = 0.0_f64;
    for d in dirs() {
        let s = cube.sample(d);
        let f = field(d);
        for c in 0..3 {
            worst = worst.max(f64::from((s[c] - f[c]).abs()));
        }
    }
    assert!(worst < 0.5 * texel, "worst {worst} vs texel {texel}");
    // Continuity across the +X / +Z edge and the +X/+Y/+Z corner.
    for base in [DVec3::new(1.0, 0.3, 1.0), DVec3::new(1.0, 1.0, 1.0)] {
        let eps = 1e-7;
        let a = cube.sample(base + DVec3::new(eps, eps, -eps));
        let b = cube.sample(base + DVec3::new(-eps, -eps, eps));
        for c in 0..3 {
            assert!(
                (a[c] - b[c]).abs() < 0.1 * texel as f32,
                "{base}: {a:?} {b:?}"
            );
        }
    }
}

#[test]
fn equirect_and_cube_convert_into_each_other() {
    let cube = Environment::Cube(cube_of(64));
    let eq = Environment::Equirect(cube.to_equirect(256, 128).unwrap());
    let back = eq.to_cube(64).unwrap();
    let back = Environment::Cube(back);
    let mut worst = 0.0_f32;
    for d in dirs() {
        let (a, b) = (field(d), back.sample(d));
        for c in 0..3 {
            worst = worst.max((a[c] - b[c]).abs());
        }
    }
    // Two resamplings of a linear field: error bounded by a few texels' variation.
    assert!(worst < 0.05, "worst {worst}");
}

#[test]
fn malformed_maps_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    // Missing faces.
    for name in ["px", "nx", "py"] {
        image::RgbImage::new(4, 4)
            .save(dir.path().join(format!("{name}.png")))
            .unwrap();
    }
    let e = Environment::load(dir.path()).unwrap_err();
    assert!(e.to_string().contains("ny, pz, nz"), "{e}");
    // Unequal faces.
    for name in ["ny", "pz"] {
        image::RgbImage::new(4, 4)
            .save(dir.path().join(format!("{name}.png")))
            .unwrap();
    }
    image::RgbImage::new(4, 5)
        .save(dir.path().join("nz.png"))
        .unwrap();
    assert!(matches!(
        Environment::load(dir.path()),
        Err(Error::MalformedMap { .. })
    ));
    // Truncated file.
    let full = dir.path().join("full.png");
    image::RgbImage::new(16, 8).save(&full).unwrap();
    let bytes = std::fs::read(&full).unwrap();
    let cut = dir.path().join("cut.png");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    assert!(matches!(Environment::load(&cut), Err(Error::Image { .. })));
    // Not an image at all, and a missing path.
    let junk = dir.path().join("junk.exr");
    std::fs::write(&junk, b"not an exr").unwrap();
    assert!(Environment::load(&junk).is_err());
    assert!(Environment::load(&dir.path().join("nothing")).is_err());
    // NaN texels.
    let mut img = Rgb32FImage::new(4, 2);
    img.put_pixel(1, 1, image::Rgb([f32::NAN, 0.0, 0.0]));
    assert!(EquirectMap::new(img).is_err());
}

/// PNG is sRGB-encoded: 8-bit 128 decodes to ((128/255 + 0.055) / 1.055)^2.4 = 0.21586.
#[test]
fn png_is_srgb_decoded_and_prefix_cube_loads() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("env.png");
    image::RgbImage::from_pixel(8, 4, image::Rgb([128, 128, 128]))
        .save(&p)
        .unwrap();
    let env = Environment::load(&p).unwrap();
    let v = env.sample(DVec3::X)[0];
    assert!((v - 0.215_861).abs() < 1e-5, "{v}");
    // Cube by common prefix, float (.exr) faces kept linear.
    for (k, name) in ["px", "nx", "py", "ny", "pz", "nz"].iter().enumerate() {
        let img = Rgb32FImage::from_pixel(4, 4, image::Rgb([k as f32 + 0.5, 2.0, 3.0]));
        image::DynamicImage::ImageRgb32F(img)
            .save(dir.path().join(format!("sky_{name}.exr")))
            .unwrap();
    }
    let cube = Environment::load(&dir.path().join("sky_")).unwrap();
    assert!((cube.sample(DVec3::NEG_Y)[0] - 3.5).abs() < 1e-6);
    assert!((cube.sample(DVec3::Z)[0] - 4.5).abs() < 1e-6);
}

/// A PFM environment (little-endian, bottom row first, as the format stores it) reads with
/// its texels where an EXR of the same image has them, as `load` lists `.pfm` among the
/// single-file maps.
#[test]
fn a_pfm_map_reads_as_the_same_image_in_exr_does() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (16u32, 8u32);
    // Written by hand: PF header, scale -1 (little endian), rows from the bottom up.
    let texel = |x: u32, y: u32| [x as f32 + 0.25, y as f32 * 2.0, (x * y) as f32 + 0.5];
    let mut bytes = format!("PF\n{w} {h}\n-1.0\n").into_bytes();
    for y in (0..h).rev() {
        for x in 0..w {
            for c in texel(x, y) {
                bytes.extend(c.to_le_bytes());
            }
        }
    }
    let pfm = dir.path().join("env.pfm");
    std::fs::write(&pfm, bytes).unwrap();
    let exr = dir.path().join("env.exr");
    image::DynamicImage::ImageRgb32F(Rgb32FImage::from_fn(w, h, |x, y| image::Rgb(texel(x, y))))
        .save(&exr)
        .unwrap();
    let (a, b) = (
        Environment::load(&pfm).unwrap(),
        Environment::load(&exr).unwrap(),
    );
    for d in dirs() {
        assert_eq!(a.sample(d), b.sample(d), "{d}");
    }
}

/// OpenEXR maps read as `tonemap` reads them, so luminance/chroma files (which the image
/// crate refuses) load, in colour: the 8x4 file OpenEXR wrote for tonemap's tests, whose
/// reconstruction by OpenEXR's RgbaInputFile is dumped beside it.
#[test]
fn a_luminance_chroma_exr_map_loads_in_colour() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tonemap/tests/data/yc");
    let env = Environment::load(&dir.join("yc_8x4_bottom_zip.exr")).unwrap();
    let want: Vec<f32> = std::fs::read(dir.join("yc_8x4_bottom_zip.rgba.f32"))
        .unwrap()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let Environment::Equirect(map) = env else {
        panic!("a 2:1 map is equirectangular");
    };
    for (p, q) in map.image().pixels().zip(want.chunks_exact(4)) {
        assert_eq!(p.0, [q[0], q[1], q[2]]);
    }
    assert!(
        map.image().pixels().any(|p| p.0[0] != p.0[1]),
        "read as grey"
    );
}

/// An image of `cells` (column, row) face cells of `n` pixels, cell `k` filled with colour
/// `[k + 1, 10 (k + 1), 0]`, other texels black.
fn layout_image(cols: u32, rows: u32, n: u32, cells: &[(u32, u32)]) -> Rgb32FImage {
    Rgb32FImage::from_fn(cols * n, rows * n, |x, y| {
        let c = (x / n, y / n);
        match cells.iter().position(|&p| p == c) {
            Some(k) => image::Rgb([(k + 1) as f32, 10.0 * (k + 1) as f32, 0.0]),
            None => image::Rgb([0.0; 3]),
        }
    })
}

const AXES: [DVec3; 6] = [
    DVec3::X,
    DVec3::NEG_X,
    DVec3::Y,
    DVec3::NEG_Y,
    DVec3::Z,
    DVec3::NEG_Z,
];

/// Which cell (index into the layout's list) the environment shows along each axis.
fn cell_seen(env: &Environment, axis: DVec3) -> usize {
    let c = env.sample(axis);
    assert!((c[1] - 10.0 * c[0]).abs() < 1e-4 && c[0] >= 1.0, "{c:?}");
    c[0].round() as usize - 1
}

/// Single files with cube layouts are cube maps: the axis directions land on the faces the
/// layouts define (independent truths: the face order +X, -X, +Y, -Y, +Z, -Z of a strip;
/// the unfolded cross with +Y above +Z and -X, +Z, +X, -Z across; OpenEXR's frame turned
/// 180 degrees about +Y for its 1:6 strip).
#[test]
fn single_file_cube_layouts_are_read_as_cube_maps() {
    let n = 8;
    // 6:1 strip, faces left to right.
    let cells: Vec<(u32, u32)> = (0..6).map(|k| (k, 0)).collect();
    let env = Environment::from_single_image(layout_image(6, 1, n, &cells)).unwrap();
    assert!(matches!(env, Environment::Cube(_)));
    for (k, a) in AXES.iter().enumerate() {
        assert_eq!(cell_seen(&env, *a), k, "6:1 strip, axis {a}");
    }
    // 4:3 cross: +Y (1,0); -X (0,1), +Z (1,1), +X (2,1), -Z (3,1); -Y (1,2).
    let cells = [(2, 1), (0, 1), (1, 0), (1, 2), (1, 1), (3, 1)];
    let env = Environment::from_single_image(layout_image(4, 3, n, &cells)).unwrap();
    for (k, a) in AXES.iter().enumerate() {
        assert_eq!(cell_seen(&env, *a), k, "4:3 cross, axis {a}");
    }
    // 3:4 cross: +Y (1,0); -X (0,1), +Z (1,1), +X (2,1); -Y (1,2); -Z (1,3).
    let cells = [(2, 1), (0, 1), (1, 0), (1, 2), (1, 1), (1, 3)];
    let env = Environment::from_single_image(layout_image(3, 4, n, &cells)).unwrap();
    for (k, a) in AXES.iter().enumerate() {
        assert_eq!(cell_seen(&env, *a), k, "3:4 cross, axis {a}");
    }
    // 1:6 OpenEXR strip: faces top to bottom in OpenEXR's frame, (x, y, z) -> (-x, y, -z).
    let cells: Vec<(u32, u32)> = (0..6).map(|k| (0, k)).collect();
    let env = Environment::from_single_image(layout_image(1, 6, n, &cells)).unwrap();
    for (a, want) in AXES.iter().zip([1, 0, 2, 3, 5, 4]) {
        assert_eq!(cell_seen(&env, *a), want, "1:6 strip, axis {a}");
    }
}

/// Orientation within a face: in a 6:1 strip the top-left texel of the +X face looks along
/// (1, 1, 1) (OpenGL table 8.19: +X has sc = -z, tc = -y), its bottom-right along (1, -1, -1).
#[test]
fn strip_faces_keep_the_opengl_orientation() {
    let n = 16;
    let mut img = Rgb32FImage::new(6 * n, n);
    img.put_pixel(0, 0, image::Rgb([5.0, 0.0, 0.0]));
    img.put_pixel(n - 1, n - 1, image::Rgb([0.0, 7.0, 0.0]));
    let env = Environment::from_single_image(img).unwrap();
    let Environment::Cube(cube) = &env else {
        panic!("not a cube map")
    };
    assert_eq!(cube.faces()[0].get_pixel(0, 0).0, [5.0, 0.0, 0.0]);
    let corner = |d: DVec3| {
        let (f, s, t) = cube_face_st(d);
        (f, (s * f64::from(n)) as u32, (t * f64::from(n)) as u32)
    };
    assert_eq!(corner(DVec3::new(1.0, 0.99, 0.99)), (0, 0, 0));
    assert_eq!(corner(DVec3::new(1.0, -0.99, -0.99)), (0, n - 1, n - 1));
    assert_eq!(cube.faces()[0].get_pixel(n - 1, n - 1).0, [0.0, 7.0, 0.0]);
}

/// The real OpenEXR pair: the Kerner parking lot as a 1:6 cube strip and as a lat-long map
/// show the same sky in every direction (log-luminance correlation over 2,000 directions).
#[test]
fn kerner_cube_strip_matches_its_lat_long_map() {
    let data =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/envmap-kerner");
    let (cube, ll) = (
        data.join("KernerEnvCube.exr"),
        data.join("KernerEnvLatLong.exr"),
    );
    if !cube.exists() || !ll.exists() {
        eprintln!("SKIP: {} not present", data.display());
        return;
    }
    let cube = Environment::load(&cube).unwrap();
    assert!(matches!(cube, Environment::Cube(_)));
    let ll = Environment::load(&ll).unwrap();
    assert!(matches!(ll, Environment::Equirect(_)));
    let lum = |c: [f32; 3]| {
        (0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2])
            .max(1e-6)
            .ln()
    };
    let (a, b): (Vec<f64>, Vec<f64>) = dirs()
        .iter()
        .map(|&d| (f64::from(lum(cube.sample(d))), f64::from(lum(ll.sample(d)))))
        .unzip();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (ma, mb) = (mean(&a), mean(&b));
    let cov: f64 = a.iter().zip(&b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
    let r = cov / (va * vb).sqrt();
    eprintln!("log-luminance correlation {r}");
    assert!(r > 0.95, "log-luminance correlation {r}");
}

/// Aspect ratios that are no layout are refused with a message naming the layouts.
#[test]
fn other_aspect_ratios_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("odd.png");
    image::RgbImage::new(30, 10).save(&p).unwrap();
    let e = Environment::load(&p).unwrap_err().to_string();
    assert!(
        e.contains("30x10") && e.contains("2:1") && e.contains("6:1"),
        "{e}"
    );
}

/// A Radiance file whose signature follows a `VIEW=` line (as Debevec's `memorial.hdr`
/// has it) reads as the same file without that line: Radiance's tools and `blueshift
/// tonemap` accept it. The pixels are flat RGBE, (128, 64, 32, 129) = (1, 0.5, 0.25).
#[test]
fn a_radiance_header_with_lines_before_its_signature_reads() {
    let dir = tempfile::tempdir().unwrap();
    let body = |preamble: &str| {
        let mut b =
            format!("{preamble}#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 8\n").into_bytes();
        for _ in 0..32 {
            b.extend_from_slice(&[128, 64, 32, 129]);
        }
        b
    };
    let plain = dir.path().join("plain.hdr");
    let view = dir.path().join("view.hdr");
    std::fs::write(&plain, body("")).unwrap();
    std::fs::write(&view, body("VIEW= -vtv -vh 90 -vv 150\n")).unwrap();
    let a = blueshift_relativity::read_linear(&plain).unwrap();
    let b = blueshift_relativity::read_linear(&view).unwrap();
    assert_eq!(a, b);
    assert_eq!((b.width(), b.height()), (8, 4));
    assert_eq!(b.get_pixel(3, 2).0, [1.0, 0.5, 0.25]);
    assert!(matches!(
        Environment::load(&view).unwrap(),
        Environment::Equirect(_)
    ));
    // A missing file is named as missing, not as a cube map without faces.
    let e = Environment::load(&dir.path().join("none.exr")).unwrap_err();
    assert!(e.to_string().contains("no such file"), "{e}");
}
