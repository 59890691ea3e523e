//! ParaView presets (real files from ParaView's source and a ParaView export, see
//! tests/data/paraview/PROVENANCE.md), built-in maps and blueshift's JSON format.

mod common;
use common::assert_close;

use blueshift_tfedit::paraview::{from_paraview_str, paraview_preset_names, to_paraview_string};
use blueshift_tfedit::{
    ColorSpace, DataAxis, Error, Format, TransferFunction, builtin, load, parse_any,
};

const EXCERPT: &str = include_str!("data/paraview/ColorMaps-excerpt.json");
const OKUBO_WEISS: &str = include_str!("data/paraview/OkuboWeiss.json");

fn preset_names() -> Vec<String> {
    paraview_preset_names(&serde_json::from_str(EXCERPT).unwrap())
}

#[test]
fn every_preset_in_the_paraview_excerpt_round_trips() {
    let names = preset_names();
    assert_eq!(names.len(), 9, "not enough presets were tested");
    for name in &names {
        let tf = from_paraview_str(EXCERPT, Some(name)).unwrap();
        let text = to_paraview_string(&tf);
        let back = from_paraview_str(&text, None).unwrap();
        assert_eq!(back, tf, "{name}: knots, space, domain or name changed");
        let [lo, hi] = tf.domain();
        for i in 0..=1000 {
            let v = lo + (hi - lo) * f64::from(i) / 1000.0;
            assert_eq!(back.eval(v), tf.eval(v), "{name} at {v}");
        }
    }
}

#[test]
fn imported_presets_reproduce_their_control_points() {
    let doc: serde_json::Value = serde_json::from_str(EXCERPT).unwrap();
    for preset in doc.as_array().unwrap() {
        let name = preset["Name"].as_str().unwrap();
        let tf = from_paraview_str(EXCERPT, Some(name)).unwrap();
        let pts: Vec<f64> = preset["RGBPoints"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let quads: Vec<&[f64]> = pts.chunks_exact(4).collect();
        for (i, q) in quads.iter().enumerate() {
            // Two points at the same x make a jump; the function takes the later colour
            // from x on (right-continuous), so check only the last point at each x.
            if quads.get(i + 1).is_some_and(|n| n[0] == q[0]) {
                continue;
            }
            let c = tf.color(q[0]);
            for k in 0..3 {
                assert_close(
                    f64::from(c[k]),
                    q[k + 1],
                    1e-6,
                    &format!("{name} at x = {}", q[0]),
                );
            }
        }
        // Without "Points" the opacity is ParaView's default ramp from 0 to 1.
        let [lo, hi] = tf.domain();
        assert_eq!(tf.opacity(lo), 0.0);
        assert_eq!(tf.opacity(hi), 1.0);
    }
    let cw = from_paraview_str(EXCERPT, Some("Cool to Warm")).unwrap();
    assert_eq!(cw.color_space(), ColorSpace::Diverging);
    assert_eq!(
        from_paraview_str(EXCERPT, Some("Blue to Red Rainbow"))
            .unwrap()
            .color_space(),
        ColorSpace::Hsv
    );
}

#[test]
fn moreland_cool_warm_midpoint_is_221_grey() {
    // Moreland 2009 ("Diverging Color Maps for Scientific Visualization"): diverging
    // interpolation between his cool (59, 76, 192) and warm (180, 4, 38) end points passes
    // through white-ish (221, 221, 221) half way.
    let c = ColorSpace::Diverging.interpolate(
        [59.0 / 255.0, 76.0 / 255.0, 192.0 / 255.0],
        [180.0 / 255.0, 4.0 / 255.0, 38.0 / 255.0],
        0.5,
    );
    for v in c {
        assert_close(v * 255.0, 221.0, 1.0, "cool-warm midpoint");
    }
}

#[test]
fn vtk_colour_space_reference_values() {
    // VTK's TestColorTransferFunction: red at 0, blue at 1, MapValue(0.5) gives
    // (128, 0, 128) in RGB and (0, 0, 255) in Step.
    let (red, blue) = ([1.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
    let to8 = |c: [f64; 3]| c.map(|v| (255.0 * v + 0.5) as u8);
    assert_eq!(
        to8(ColorSpace::Rgb.interpolate(red, blue, 0.5)),
        [128, 0, 128]
    );
    assert_eq!(
        to8(ColorSpace::Step.interpolate(red, blue, 0.5)),
        [0, 0, 255]
    );
}

#[test]
fn paraview_export_with_opacity_points_gives_that_opacity_curve() {
    // OkuboWeiss.json: Points (0, 1), (1, 0), (2, 1), midpoint 0.5, sharpness 0.
    let tf = from_paraview_str(OKUBO_WEISS, None).unwrap();
    assert_eq!(tf.name(), "OkuboWeiss");
    assert_eq!(tf.domain(), [0.0, 2.0]);
    assert_close(f64::from(tf.opacity(0.0)), 1.0, 0.0, "x = 0");
    assert_close(f64::from(tf.opacity(0.5)), 0.5, 1e-7, "x = 0.5");
    assert_close(f64::from(tf.opacity(1.0)), 0.0, 0.0, "x = 1");
    assert_close(f64::from(tf.opacity(1.75)), 0.75, 1e-7, "x = 1.75");
    assert_close(
        f64::from(tf.max_opacity(0.6..=1.2)),
        0.4,
        1e-6,
        "majorant of [0.6, 1.2]",
    );
    assert_close(f64::from(tf.color(1.0)[1]), 0.913725, 1e-6, "green knot");
    // And through load(), told apart from blueshift's JSON by content.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("okubo.json");
    std::fs::write(&p, OKUBO_WEISS).unwrap();
    assert_eq!(load(&p).unwrap(), tf);
    let back = from_paraview_str(&to_paraview_string(&tf), None).unwrap();
    assert_eq!(back, tf);
}

#[test]
fn builtin_viridis_and_inferno_follow_matplotlibs_256_entry_tables() {
    for (builtin_name, preset) in [("viridis", "Viridis"), ("inferno", "Inferno")] {
        let full = from_paraview_str(EXCERPT, Some(preset)).unwrap();
        let ours = builtin(builtin_name).unwrap();
        let mut worst = 0f32;
        for k in full.color_knots() {
            let c = ours.color(k.x);
            for (ours_c, table_c) in c.iter().zip(k.rgb) {
                worst = worst.max((ours_c - table_c).abs());
            }
        }
        // 65 of 256 knots, interpolated linearly: within 1/255 of every table entry.
        assert!(
            worst < 1.0 / 255.0,
            "{builtin_name}: worst deviation {worst}"
        );
    }
    for name in blueshift_tfedit::BUILTIN_NAMES {
        let tf = builtin(name).unwrap();
        assert_eq!(tf.name(), name);
        assert_eq!(tf.domain(), [0.0, 1.0]);
    }
    assert!(matches!(builtin("jet"), Err(Error::Parameter(_))));
    // cool-warm and black-body are ParaView's own presets.
    for (b, p) in [
        ("cool-warm", "Cool to Warm"),
        ("black-body", "Black-Body Radiation"),
    ] {
        let (ours, theirs) = (
            builtin(b).unwrap(),
            from_paraview_str(EXCERPT, Some(p)).unwrap(),
        );
        for i in 0..=100 {
            let v = f64::from(i) / 100.0;
            assert_eq!(ours.color(v), theirs.color(v), "{b} at {v}");
        }
    }
}

#[test]
fn blueshift_json_round_trips_and_is_told_apart_from_paraview() {
    let tf = blueshift_tfedit::builtin_over("inferno", [0.5, 5000.0])
        .unwrap()
        .with_data_axis(DataAxis::Log)
        .unwrap()
        .with_alpha_g(0.05)
        .unwrap()
        .with_color_space(ColorSpace::Hsv);
    let text = tf.to_json_string();
    assert_eq!(TransferFunction::from_json_str(&text).unwrap(), tf);
    let (parsed, format) = parse_any(&text).unwrap();
    assert_eq!((parsed, format), (tf.clone(), Format::Blueshift));
    assert_eq!(parse_any(EXCERPT).unwrap().1, Format::ParaView);
    // serde: the transfer function is (de)serialisable directly.
    let v = serde_json::to_value(&tf).unwrap();
    let back: TransferFunction = serde_json::from_value(v).unwrap();
    assert_eq!(back, tf);
    // ParaView keeps the log axis and alpha_g.
    let pv = from_paraview_str(&to_paraview_string(&tf), None).unwrap();
    assert_eq!(pv.data_axis(), DataAxis::Log);
    assert_eq!(pv.alpha_g(), 0.05);
}

#[test]
fn malformed_files_give_errors_naming_the_entry_and_never_panic() {
    let cases: &[(&str, &str)] = &[
        ("", "not valid JSON"),
        (
            "[{\"Name\": \"x\", \"RGBPoints\": [0, 0, 0",
            "not valid JSON",
        ),
        ("42", "neither"),
        ("{\"hello\": 1}", "neither"),
        ("[]", "neither"),
        (
            "[{\"Name\": \"e\", \"RGBPoints\": []}]",
            "RGBPoints is empty",
        ),
        (
            "[{\"Name\": \"m\", \"RGBPoints\": [0, 0, 0]}]",
            "not a multiple of 4",
        ),
        (
            "[{\"Name\": \"s\", \"RGBPoints\": [0, 0, 0, \"red\"]}]",
            "entry 3",
        ),
        (
            "[{\"Name\": \"c\", \"RGBPoints\": [0, 0, 0, 0, 1, 2, 0, 0]}]",
            "RGBPoints point 1",
        ),
        (
            "[{\"Name\": \"o\", \"RGBPoints\": [0, 0, 0, 0, 1, 1, 1, 1], \"Points\": [0, 0, 0.5, 0, 1, 1.5, 0.5, 0]}]",
            "Points point 1",
        ),
        ("[{\"Name\": \"z\", \"RGBPoints\": [3, 0, 0, 0]}]", "range"),
        (
            "[{\"Name\": \"k\", \"ColorSpace\": \"Wavelet\", \"RGBPoints\": [0, 0, 0, 0, 1, 1, 1, 1]}]",
            "unknown ColorSpace",
        ),
        (
            "[{\"Name\": \"i\", \"IndexedColors\": [1, 0, 0]}]",
            "categorical",
        ),
        (
            "[{\"Name\": \"n\", \"NanColor\": [1, 0, 0, 0, 1, 0], \"RGBPoints\": [0, 0, 0, 0, 1, 1, 1, 1]}]",
            "NanColor has 6 numbers",
        ),
        (
            "[{\"Name\": \"g\", \"BlueshiftGlobalOpacity\": \"half\", \"RGBPoints\": [0, 0, 0, 0, 1, 1, 1, 1]}]",
            "BlueshiftGlobalOpacity \"half\" is not a number",
        ),
        (
            "[{\"Name\": \"l\", \"UseLogScale\": true, \"RGBPoints\": [-1, 0, 0, 0, 1, 1, 1, 1]}]",
            "positive",
        ),
        (
            "{\"format\": \"blueshift-transfer-function\", \"version\": 1, \"domain\": [0, 1], \"color\": [], \"opacity\": [{\"x\": 0, \"alpha\": 0}]}",
            "no colour knots",
        ),
        (
            "{\"format\": \"blueshift-transfer-function\", \"version\": 1, \"domain\": [0, 1], \"color\": [{\"x\": 0, \"rgb\": [0, 0, 0]}], \"opacity\": [{\"x\": 0.5, \"alpha\": 0}, {\"x\": 0.2, \"alpha\": 0}]}",
            "opacity knot 1",
        ),
        (
            "{\"format\": \"blueshift-transfer-function\", \"version\": 1, \"domain\": [0, 1], \"color\": [{\"x\": 0, \"rgb\": [0, 0, 0]}], \"opacity\": [{\"x\": 0, \"alpha\": -0.1}]}",
            "opacity knot 0",
        ),
        (
            "{\"format\": \"blueshift-transfer-function\", \"version\": 9, \"domain\": [0, 1], \"color\": [{\"x\": 0, \"rgb\": [0, 0, 0]}], \"opacity\": [{\"x\": 0, \"alpha\": 0}]}",
            "version 9",
        ),
        (
            "{\"format\": \"blueshift-transfer-function\", \"version\": 1, \"domain\": [0, 1], \"color\": [{\"x\": 0, \"rgb\": [0, 0]}], \"opacity\": []}",
            "blueshift transfer function",
        ),
        (
            "{\"format\": \"blueshift-transfer-function\", \"version\": 1, \"domain\": [0, 1], \"colour\": []}",
            "unknown field",
        ),
    ];
    for (text, needle) in cases {
        let err = parse_any(text).unwrap_err().to_string();
        assert!(
            err.contains(needle),
            "{text:?}: error {err:?} does not mention {needle:?}"
        );
    }
    // Every truncation of a real preset is an error, not a panic.
    for cut in (0..OKUBO_WEISS.len()).step_by(7) {
        let _ = parse_any(&OKUBO_WEISS[..cut]);
    }
    let missing = load("/nonexistent/tf.json").unwrap_err();
    assert!(
        matches!(missing, Error::Io { .. }) && missing.to_string().contains("/nonexistent/tf.json")
    );
}

mod never_panics {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Fuzz-style: the real presets with bytes overwritten by JSON-significant
        /// characters parse to a value or an error, never a panic.
        #[test]
        fn mutated_presets_never_panic(
            edits in prop::collection::vec((0usize..400, prop::sample::select(b"[]{},:\"-0123456789.eE tn".to_vec())), 1..6),
            which in any::<bool>(),
        ) {
            let mut bytes = if which { OKUBO_WEISS.as_bytes().to_vec() } else { EXCERPT.as_bytes()[..2000].to_vec() };
            for (pos, b) in edits {
                let i = pos % bytes.len();
                bytes[i] = b;
            }
            let text = String::from_utf8_lossy(&bytes);
            if let Ok((tf, _)) = parse_any(&text) {
                // Whatever parses is a valid transfer function.
                let [lo, hi] = tf.domain();
                prop_assert!(lo < hi);
                let _ = tf.eval(0.5 * (lo + hi));
            }
        }
    }
}
