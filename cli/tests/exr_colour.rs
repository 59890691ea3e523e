//! OpenEXR outputs say what their colour channels hold: XYZ renders carry the XYZ
//! `chromaticities` attribute; `--exr-space linear-srgb` converts them.

use std::path::Path;
use std::process::Command;

fn blueshift(args: &[&str]) -> std::process::Output {
    let out = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn chromaticities(p: &Path) -> Option<exr::meta::attribute::Chromaticities> {
    let meta = exr::meta::MetaData::read_from_file(p, false).unwrap();
    meta.headers[0].shared_attributes.chromaticities
}

fn pixels(p: &Path) -> Vec<[f32; 4]> {
    let img = image::open(p).unwrap().to_rgba32f();
    img.pixels().map(|p| p.0).collect()
}

#[test]
fn doppler_exr_is_xyz_with_its_chromaticities_or_linear_srgb_on_request() {
    let dir = tempfile::tempdir().unwrap();
    let xyz = dir.path().join("xyz.exr");
    let srgb = dir.path().join("srgb.exr");
    let common = [
        "doppler", "--synth", "shell", "--res", "16", "--width", "24", "--height", "24",
    ];
    let mut a = common.to_vec();
    a.extend(["--out", xyz.to_str().unwrap()]);
    blueshift(&a);
    let mut b = common.to_vec();
    b.extend([
        "--exr-space",
        "linear-srgb",
        "--out",
        srgb.to_str().unwrap(),
    ]);
    blueshift(&b);

    // The XYZ "primaries" of OpenEXR's ImfChromaticities: R = X, G = Y, B = Z.
    let c = chromaticities(&xyz).expect("an XYZ EXR must carry chromaticities");
    assert_eq!((c.red.0, c.red.1), (1.0, 0.0));
    assert_eq!((c.green.0, c.green.1), (0.0, 1.0));
    assert_eq!((c.blue.0, c.blue.1), (0.0, 0.0));
    assert!((c.white.0 - 1.0 / 3.0).abs() < 1e-7 && (c.white.1 - 1.0 / 3.0).abs() < 1e-7);
    // Linear sRGB is the OpenEXR default (Rec. 709): no attribute.
    assert!(chromaticities(&srgb).is_none());

    // The linear-sRGB file is the XYZ file through the IEC 61966-2-1 matrix.
    const M: [[f32; 3]; 3] = [
        [3.2406, -1.5372, -0.4986],
        [-0.9689, 1.8758, 0.0415],
        [0.0557, -0.2040, 1.0570],
    ];
    let (px, ps) = (pixels(&xyz), pixels(&srgb));
    assert_eq!(px.len(), ps.len());
    let peak = px.iter().map(|p| p[1]).fold(0.0f32, f32::max);
    assert!(peak > 0.0, "the shell renders something");
    for (x, s) in px.iter().zip(&ps) {
        for i in 0..3 {
            let want = M[i][0] * x[0] + M[i][1] * x[1] + M[i][2] * x[2];
            assert!(
                (s[i] - want).abs() <= 2e-3 * peak,
                "channel {i}: {} vs {want}",
                s[i]
            );
        }
        assert_eq!(s[3], 1.0);
    }
}
