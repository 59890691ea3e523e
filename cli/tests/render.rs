//! `blueshift render`: an analytic homogeneous slab through the CLI, thread-count
//! determinism, scene files, ParaView presets, and one-line errors naming the field.

use std::path::Path;
use std::process::{Command, Output};

fn blueshift(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .arg("render")
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

/// A 9^3 NRRD of constant 0.5 with unit spacing: the box is [0, 8]^3.
fn write_slab(dir: &Path) {
    let mut bytes = b"NRRD0004\ntype: float\ndimension: 3\nsizes: 9 9 9\nspacings: 1 1 1\nendian: little\nencoding: raw\n\n".to_vec();
    for _ in 0..729 {
        bytes.extend_from_slice(&0.5f32.to_le_bytes());
    }
    std::fs::write(dir.join("slab.nrrd"), bytes).unwrap();
    std::fs::write(
        dir.join("tf.json"),
        r#"{ "format": "blueshift-transfer-function", "version": 1, "domain": [0, 1],
            "color": [ { "x": 0, "rgb": [1, 1, 1] } ],
            "opacity": [ { "x": 0, "alpha": 0.5 } ] }"#,
    )
    .unwrap();
}

fn read_exr(p: &Path) -> image::Rgba32FImage {
    image::open(p).unwrap().to_rgba32f()
}

fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn homogeneous_slab_matches_beer_lambert_for_every_method() {
    // sigma = 0.5 x density scale 0.2 = 0.1 per unit, L = 8: alpha = 1 - exp(-0.8).
    let dir = tempfile::tempdir().unwrap();
    write_slab(dir.path());
    let expected = 1.0 - (-0.8f64).exp();
    for method in ["woodcock", "mdwt-ndda", "mdwt-1dda", "marcher"] {
        let out = blueshift(
            &[
                "--volume",
                "slab.nrrd",
                "--tf",
                "tf.json",
                "--method",
                method,
                "--camera",
                "ortho",
                "--spp",
                "64",
                "--width",
                "16",
                "--height",
                "16",
                "--density-scale",
                "0.2",
                "--background",
                "0,0,0",
                "--out",
                "o.exr",
                "--png",
                "o.png",
            ],
            dir.path(),
        );
        ok(&out);
        let img = read_exr(&dir.path().join("o.exr"));
        let n = f64::from(img.width() * img.height());
        let mean: f64 = img.pixels().map(|p| f64::from(p.0[0])).sum::<f64>() / n;
        // 16 x 16 x 64 Bernoulli samples: standard error about 0.002.
        assert!(
            (mean - expected).abs() < 0.01,
            "{method}: {mean} vs {expected}"
        );
        assert!(dir.path().join("o.png").exists());
    }
}

#[test]
fn same_seed_same_image_on_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let common = [
        "--synth",
        "three-cubes",
        "--res",
        "16",
        "--tf",
        "builtin:viridis",
        "--spp",
        "4",
        "--width",
        "20",
        "--height",
        "12",
        "--density-scale",
        "5",
        "--seed",
        "3",
    ];
    let mut a = common.to_vec();
    a.extend(["--threads", "1", "--out", "a.exr"]);
    let mut b = common.to_vec();
    b.extend(["--threads", "2", "--out", "b.exr"]);
    ok(&blueshift(&a, dir.path()));
    ok(&blueshift(&b, dir.path()));
    let ia = read_exr(&dir.path().join("a.exr"));
    let ib = read_exr(&dir.path().join("b.exr"));
    assert_eq!(ia.as_raw(), ib.as_raw());
    assert!(ia.pixels().any(|p| p.0[3] > 0.1));
}

#[test]
fn scene_file_and_paraview_preset_render() {
    let dir = tempfile::tempdir().unwrap();
    write_slab(dir.path());
    std::fs::write(
        dir.path().join("pv.json"),
        r#"[{ "Name": "flat", "ColorSpace": "RGB", "RGBPoints": [0, 1, 0, 0, 1, 1, 0, 0],
             "Points": [0, 0.5, 0.5, 0, 1, 0.5, 0.5, 0] }]"#,
    )
    .unwrap();
    std::fs::create_dir(dir.path().join("s")).unwrap();
    std::fs::write(
        dir.path().join("s/scene.json"),
        r#"{ "channels": [ { "volume": "../slab.nrrd", "tf": "../pv.json" },
                           { "synth": "three-cubes", "res": 9, "channel": "red", "tf": "builtin:grey" } ],
             "method": "mdwt-ndda", "blend": "max", "spp": 2, "width": 8, "height": 8,
             "camera": "perspective", "density_scale": 0.1,
             "light": { "direction": [1, 0, 0] } }"#,
    )
    .unwrap();
    // The two channels have different geometry: a one-line error naming channels[1].
    let out = blueshift(&["s/scene.json", "--out", "x.exr"], dir.path());
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("channels[1]") && err.trim().lines().count() == 1,
        "{err}"
    );
    assert!(!dir.path().join("x.exr").exists());
    // With the slab alone it renders; flags override the file.
    std::fs::write(
        dir.path().join("s/one.json"),
        r#"{ "channels": [ { "volume": "../slab.nrrd", "tf": "../pv.json" } ],
             "method": "mdwt-ndda", "spp": 2, "width": 8, "height": 8, "density_scale": 0.1 }"#,
    )
    .unwrap();
    ok(&blueshift(
        &["s/one.json", "--spp", "3", "--json", "--out", "x.exr"],
        dir.path(),
    ));
    let img = read_exr(&dir.path().join("x.exr"));
    assert_eq!(img.dimensions(), (8, 8));
    // Red only: the preset's colour.
    assert!(img.pixels().all(|p| p.0[1] == 0.0 && p.0[2] == 0.0));
}

#[test]
fn bad_input_gets_one_line_errors_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    write_slab(dir.path());
    let cases: &[(&str, &[&str], &str)] = &[
        (
            r#"{ "channels": [], "colour": 1 }"#,
            &[],
            "unknown field `colour`",
        ),
        (
            r#"{ "channels": [ { "volume": "nope.nrrd", "tf": "tf.json" } ] }"#,
            &[],
            "channels[0].volume",
        ),
        (
            r#"{ "channels": [ { "volume": "slab.nrrd", "tf": "tf.json" } ], "spp": 0 }"#,
            &[],
            "spp",
        ),
        (
            r#"{ "channels": [ { "volume": "slab.nrrd", "tf": "missing.json" } ] }"#,
            &[],
            "channels[0].tf",
        ),
        (
            r#"{ "channels": [ { "volume": "slab.nrrd", "tf": "tf.json" } ], "method": "x" }"#,
            &[],
            "method",
        ),
        (
            r#"{ "channels": [ { "volume": "slab.nrrd", "tf": "tf.json" } ] }"#,
            &["--width", "0"],
            "image size",
        ),
        (
            r#"{ "channels": [ { "volume": "slab.nrrd", "tf": "tf.json" } ], "blend": "mix", "weights": [1, 2] }"#,
            &[],
            "weights",
        ),
        (
            // A level of detail for a volume in memory (which has its finest level only).
            r#"{ "channels": [ { "volume": "slab.nrrd", "tf": "tf.json" } ] }"#,
            &["--lod", "2"],
            "levels of detail need every channel",
        ),
    ];
    for (i, (json, extra, needle)) in cases.iter().enumerate() {
        let f = format!("bad{i}.json");
        std::fs::write(dir.path().join(&f), json).unwrap();
        let mut args = vec![f.as_str(), "--out", "bad.exr"];
        args.extend_from_slice(extra);
        let out = blueshift(&args, dir.path());
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "case {i}: {err}");
        assert!(err.contains(needle), "case {i}: '{err}' lacks '{needle}'");
        assert_eq!(err.trim().lines().count(), 1, "case {i}: {err}");
        assert!(!dir.path().join("bad.exr").exists());
    }
    // An image format's name for the EXR that --out writes.
    let out = blueshift(
        &[
            "--volume",
            "slab.nrrd",
            "--tf",
            "tf.json",
            "--out",
            "bad.png",
        ],
        dir.path(),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("--out writes OpenEXR"), "{err}");
    assert!(!dir.path().join("bad.png").exists());
}

#[test]
fn summed_method_heat_maps_and_timing_protocol() {
    // Slab: sigma = 0.1 per unit over L = 8 with a tight majorant: no rejections, and the
    // mean tentative collisions per ray is 1 - exp(-0.8) (the ray stops at its first).
    let dir = tempfile::tempdir().unwrap();
    write_slab(dir.path());
    let out = blueshift(
        &[
            "--volume",
            "slab.nrrd",
            "--tf",
            "tf.json",
            "--method",
            "mdwt-summed",
            "--camera",
            "ortho",
            "--density-scale",
            "0.2",
            "--width",
            "16",
            "--height",
            "16",
            "--heatmap",
            "collisions",
            "--heatmap",
            "rejections",
            "--heatmap",
            "steps",
            "--warmup",
            "2",
            "--frames",
            "30",
            "--macrocell",
            "4",
            "--json",
            "--out",
            "s.exr",
        ],
        dir.path(),
    );
    ok(&out);
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["spp"], 30);
    assert_eq!(j["timings"]["frames"], 30);
    assert_eq!(j["timings"]["warmup"], 2);
    assert!(j["timings"]["median_s"].as_f64().unwrap() > 0.0);
    let expected = 1.0 - (-0.8f64).exp();
    let mean = j["heatmaps"]["collisions"]["mean"].as_f64().unwrap();
    let se = (expected * (1.0 - expected) / (256.0 * 30.0)).sqrt();
    assert!((mean - expected).abs() < 4.0 * se, "{mean} vs {expected}");
    assert_eq!(j["heatmaps"]["rejections"]["max"].as_f64().unwrap(), 0.0);
    // The image: alpha = 1 - exp(-0.8) within the noise.
    let img = read_exr(&dir.path().join("s.exr"));
    let a: f64 = img.pixels().map(|p| f64::from(p.0[3])).sum::<f64>() / 256.0;
    assert!((a - expected).abs() < 4.0 * se, "{a}");
    // The heat EXR has named channels; the PNGs exist with a colour bar beside the map.
    let heat = std::fs::read(dir.path().join("s.heat.exr")).unwrap();
    for name in ["collisions", "rejections", "steps"] {
        assert!(
            heat.windows(name.len()).any(|w| w == name.as_bytes()),
            "{name}"
        );
        let png = image::open(dir.path().join(format!("s.heat-{name}.png"))).unwrap();
        assert!(png.width() > 16);
    }
}

#[test]
fn shading_blends_and_bad_settings() {
    let dir = tempfile::tempdir().unwrap();
    write_slab(dir.path());
    let run = |extra: &[&str]| {
        let mut a = vec![
            "--volume",
            "slab.nrrd",
            "--tf",
            "tf.json",
            "--camera",
            "ortho",
            "--width",
            "8",
            "--height",
            "8",
            "--spp",
            "4",
            "--out",
            "o.exr",
        ];
        a.extend_from_slice(extra);
        blueshift(&a, dir.path())
    };
    ok(&run(&[
        "--shading",
        "--light",
        "1,1,-1",
        "--light-intensity",
        "2",
    ]));
    ok(&run(&["--method", "marcher", "--blend", "max"]));
    ok(&run(&["--method", "marcher", "--blend", "weighted"]));
    for (extra, needle) in [
        (vec!["--light", "0,0,0"], "light.direction"),
        (vec!["--light", "nan,0,1"], "light"),
        (vec!["--heatmap", "heat"], "unknown 'heat'"),
        (
            vec!["--light-intensity", "-1", "--light", "0,0,1"],
            "light-intensity",
        ),
        (vec!["--method", "marcher", "--shading"], "shading"),
        (vec!["--warmup", "2"], "--frames"),
    ] {
        let out = run(&extra);
        assert!(!out.status.success(), "{extra:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(needle), "{extra:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
    }
    // Shininess < 0 in a scene file's material.
    std::fs::write(
        dir.path().join("scene.json"),
        r#"{ "channels": [ { "volume": "slab.nrrd", "tf": "tf.json",
             "material": { "shininess": -2 } } ], "shading": true, "width": 4, "height": 4 }"#,
    )
    .unwrap();
    let out = blueshift(&["scene.json", "--out", "o.exr"], dir.path());
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("shininess"));
}

#[test]
fn png_preview_through_tone_mapping_operators() {
    let dir = tempfile::tempdir().unwrap();
    write_slab(dir.path());
    let base = [
        "--volume",
        "slab.nrrd",
        "--tf",
        "tf.json",
        "--density-scale",
        "0.2",
        "--spp",
        "4",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        "x.exr",
    ];
    for op in [
        "exposure",
        "linear",
        "drago",
        "reinhard",
        "reinhard-local",
        "durand",
        "fattal",
    ] {
        let mut args = base.to_vec();
        args.extend(["--png", "x.png", "--tonemap", op]);
        ok(&blueshift(&args, dir.path()));
        let png = image::open(dir.path().join("x.png")).unwrap().to_rgb8();
        assert_eq!(png.dimensions(), (8, 8));
        // The slab glows white in the middle: the preview is not black.
        assert!(png.pixels().any(|p| p.0[0] > 50), "{op}");
        std::fs::remove_file(dir.path().join("x.png")).unwrap();
    }
    let mut args = base.to_vec();
    let last = args.len() - 1;
    args[last] = "y.exr";
    args.extend(["--png", "y.png", "--tonemap", "gamma"]);
    let out = blueshift(&args, dir.path());
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--tonemap"));
    assert!(!dir.path().join("y.png").exists());
    assert!(
        !dir.path().join("y.exr").exists(),
        "refused before rendering"
    );
}

/// `render --help` shows every default a user relies on (image size, samples, method, blend,
/// camera and the view convention).
#[test]
fn help_shows_the_defaults() {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(["render", "--help"])
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&o.stdout);
    for want in [
        "[default: 512]",
        "[default: 16; 1 for the marcher",
        "[default: mdwt-1dda]",
        "[default: density]",
        "[default: perspective]",
        "[default: 30]",
        "[default: z]",
        "[default: 0]",
        "[default: 1]",
        "[default: f32]",
        "observer on the +z side",
    ] {
        assert!(help.contains(want), "render --help lacks {want:?}");
    }
}

/// The process's peak resident MiB from the out-of-core report line.
fn peak_resident(stderr: &str) -> f64 {
    let at = stderr
        .find("process peak resident ")
        .unwrap_or_else(|| panic!("no resident report in {stderr}"));
    stderr[at + 22..]
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

#[test]
fn a_volume_many_times_the_cache_renders_in_the_budget_plus_a_stated_overhead() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let synth = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_blueshift"))
            .arg("synth")
            .args(args)
            .current_dir(d)
            .output()
            .unwrap();
        ok(&o);
    };
    // 224^3 f32: 45 MiB at level 0 (52 MiB with its levels), 11x the 4 MiB budget.
    synth(&["marschner-lobb", "big.bsv", "--res", "224"]);
    synth(&["marschner-lobb", "small.bsv", "--res", "24"]);
    let run = |vol: &str| {
        let o = blueshift(
            &[
                "--volume",
                vol,
                "--tf",
                "builtin:viridis",
                "--cache-mb",
                "4",
                "--method",
                "mdwt-1dda",
                "--width",
                "96",
                "--height",
                "96",
                "--spp",
                "2",
                "--threads",
                "2",
                "--out",
                "o.exr",
            ],
            d,
        );
        ok(&o);
        peak_resident(&String::from_utf8_lossy(&o.stderr))
    };
    let small = run("small.bsv");
    let big = run("big.bsv");
    // The stated overhead over the budget: one brick ((64 + 2)^3 f32 = 1.1 MiB) per thread
    // and field in the per-thread slots (3 threads here, with the caller's), one brick being
    // read per thread, and the one-off macrocells of every level (0.9 MiB); 4 MiB of slack
    // for the allocator. The baseline (a 24^3 file that fits in one brick) holds the program,
    // the image buffers and the threads.
    let overhead = 3.0 * 1.1 + 3.0 * 1.1 + 0.9 + 4.0;
    assert!(
        big <= small + 4.0 + overhead,
        "peak resident {big:.1} MiB for a 52 MiB file in a 4 MiB cache (baseline {small:.1} MiB)"
    );
}

#[test]
fn progressive_render_previews_each_coarser_level_then_renders_the_exact_image() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args([
            "synth",
            "marschner-lobb",
            "m.bsv",
            "--res",
            "32",
            "--brick",
            "8",
        ])
        .current_dir(d)
        .output()
        .unwrap();
    ok(&o);
    let run = |out: &str, extra: &[&str]| {
        let mut args = vec![
            "--volume",
            "m.bsv",
            "--tf",
            "builtin:viridis",
            "--width",
            "24",
            "--height",
            "24",
            "--spp",
            "3",
            "--out",
            out,
        ];
        args.extend_from_slice(extra);
        let o = blueshift(&args, d);
        ok(&o);
        let log = String::from_utf8_lossy(&o.stderr).to_string();
        (std::fs::read(d.join(out)).unwrap(), log)
    };
    let (exact, _) = run("a.exr", &[]);
    let (prog, log) = run("b.exr", &["--progressive"]);
    let steps: Vec<&str> = log
        .lines()
        .filter(|l| l.starts_with("progressive:"))
        .collect();
    assert_eq!(steps.len(), 3, "{log}");
    assert!(steps[0].contains("pass 1, level 2 (8x8x8), 1 spp"), "{log}");
    assert!(
        steps[1].contains("pass 2, level 1 (16x16x16), 1 spp"),
        "{log}"
    );
    assert!(steps[2].contains("pass 3, level 0 (32x32x32):"), "{log}");
    assert_eq!(prog, exact, "the last step is the exact render");
    // Brick by brick: the coarsest level first, quick steps over what has loaded (each says
    // how many bricks are at the final level), the exact render last.
    let (bricks, log) = run("c.exr", &["--progressive", "bricks"]);
    let steps: Vec<&str> = log
        .lines()
        .filter(|l| l.starts_with("progressive:"))
        .collect();
    assert!(steps.len() >= 2, "{log}");
    assert!(steps[0].contains("pass 1, level 2 (8x8x8), 1 spp"), "{log}");
    for s in &steps[1..steps.len() - 1] {
        assert!(
            s.contains("and finer where loaded") && s.contains(" of 64 bricks"),
            "{log}"
        );
    }
    assert!(
        steps[steps.len() - 1].contains("level 0 (32x32x32):"),
        "{log}"
    );
    assert_eq!(bricks, exact, "the last step is the exact render");
    // From --lod 1: levels are absolute, the last step is level 1's render.
    let (b1, log1) = run("e.exr", &["--progressive", "bricks", "--lod", "1"]);
    let steps: Vec<&str> = log1
        .lines()
        .filter(|l| l.starts_with("progressive:"))
        .collect();
    assert!(
        steps[0].contains("pass 1, level 2 (8x8x8), 1 spp"),
        "{log1}"
    );
    assert!(
        steps[steps.len() - 1].contains("level 1 (16x16x16):"),
        "{log1}"
    );
    let (l1, _) = run("f.exr", &["--lod", "1"]);
    assert_eq!(b1, l1);
    let o = blueshift(
        &[
            "--volume",
            "m.bsv",
            "--tf",
            "builtin:viridis",
            "--lod",
            "brick",
            "--progressive",
            "bricks",
            "--out",
            "g.exr",
        ],
        d,
    );
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--progressive renders whole levels"));
    let o = blueshift(
        &["--synth", "three-cubes", "--progressive", "--out", "c.exr"],
        d,
    );
    assert!(!o.status.success());
    let o = blueshift(
        &[
            "--volume",
            "m.bsv",
            "--tf",
            "builtin:viridis",
            "--progressive",
            "rows",
            "--out",
            "d.exr",
        ],
        d,
    );
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("levels or bricks"), "{err}");
    assert!(!d.join("d.exr").exists());
}

/// `--lod brick` on a zoomed-out view where every brick's footprint picks level 1: the
/// prefetcher queues the level-1 bricks the render samples, so no finest-level brick is
/// read at all (it used to queue each region's level-0 brick too).
#[test]
fn lod_brick_prefetches_the_level_each_region_samples() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args([
            "synth",
            "marschner-lobb",
            "m.bsv",
            "--res",
            "64",
            "--brick",
            "8",
        ])
        .current_dir(d)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let reads = |lod: &str| {
        let o = blueshift(
            &[
                "--volume",
                "m.bsv",
                "--tf",
                "builtin:viridis",
                "--method",
                "marcher",
                "--camera",
                "ortho",
                "--zoom",
                "0.5",
                "--width",
                "32",
                "--height",
                "32",
                "--cache-mb",
                "1000",
                "--lod",
                lod,
                "--out",
                &format!("{lod}.exr"),
            ],
            d,
        );
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(o.status.success(), "{err}");
        err.lines()
            .find_map(|l| l.split_once("bricks read: ").map(|(_, r)| r.to_owned()))
            .unwrap_or_else(|| panic!("{err}"))
    };
    let brick = reads("brick");
    assert!(brick.starts_with("64 at level 1 ("), "{brick}");
    assert!(!brick.contains("level 0"), "{brick}");
    assert!(reads("exact").starts_with("512 at level 0 ("));
}
