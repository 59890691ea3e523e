//! One orientation everywhere (yt's): a probe volume whose only bright voxels sit at
//! (+x, +y) must land top-right in `render` (CPU and GPU, and its heat maps), in `doppler`
//! (CPU and GPU) and in the moment maps of a `--cube`; `--view` and the camera flags move
//! it where the view says.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn blueshift(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .output()
        .expect("run blueshift")
}

fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A 16^3 float NRRD: 1 in a 3^3 block at high x, high y and low z, a faint 0.02 elsewhere
/// (so the box is not empty for any renderer). Returns the header's path.
fn probe(dir: &Path) -> PathBuf {
    let n = 16usize;
    let mut bytes = Vec::with_capacity(n * n * n * 4);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let hot = (11..14).contains(&x) && (11..14).contains(&y) && (2..5).contains(&z);
                let v: f32 = if hot { 1.0 } else { 0.02 };
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    std::fs::write(dir.join("probe.raw"), bytes).unwrap();
    let hdr = dir.join("probe.nhdr");
    std::fs::write(
        &hdr,
        "NRRD0004\ntype: float\ndimension: 3\nsizes: 16 16 16\nencoding: raw\nendian: little\ndata file: probe.raw\n",
    )
    .unwrap();
    hdr
}

/// The luminance-weighted centroid of the brightest pixels (above half the maximum), as
/// fractions of the width and height (y from the top).
fn bright_centroid(lum: &[f32], w: usize, h: usize) -> (f32, f32) {
    let max = lum.iter().copied().fold(0.0f32, f32::max);
    assert!(max > 0.0, "blank image");
    let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
    for (i, &v) in lum.iter().enumerate() {
        if v > 0.5 * max {
            sx += (i % w) as f32 + 0.5;
            sy += (i / w) as f32 + 0.5;
            s += 1.0;
        }
    }
    (sx / s / w as f32, sy / s / h as f32)
}

fn exr_lum(p: &Path, channel: usize) -> (Vec<f32>, usize, usize) {
    let img = common::read_exr(p);
    let (w, h) = (img.width() as usize, img.height() as usize);
    (img.pixels().map(|p| p.0[channel]).collect(), w, h)
}

fn png_lum(p: &Path) -> (Vec<f32>, usize, usize) {
    let img = image::open(p).unwrap().to_luma32f();
    let (w, h) = (img.width() as usize, img.height() as usize);
    (img.into_raw(), w, h)
}

fn top_right(what: &str, (x, y): (f32, f32)) {
    assert!(
        x > 0.55 && y < 0.45,
        "{what}: the (+x, +y) voxel is at ({x:.2}, {y:.2}), not top-right"
    );
}

fn render_probe(dir: &Path, extra: &[&str], name: &str) -> Option<PathBuf> {
    let vol = probe(dir);
    let out = dir.join(format!("{name}.exr"));
    let mut args = vec![
        "render",
        "--volume",
        vol.to_str().unwrap(),
        "--tf",
        "builtin:grey",
        "--width",
        "32",
        "--height",
        "32",
        "--spp",
        "4",
        "--density-scale",
        "4",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = blueshift(&args);
    if extra.contains(&"gpu") && !common::gpu_ok("render", &o) {
        return None;
    }
    ok(&o);
    Some(out)
}

#[test]
fn render_puts_plus_x_plus_y_top_right_on_cpu_and_gpu_and_in_heat_maps() {
    let dir = tempfile::tempdir().unwrap();
    for (extra, name) in [
        (&["--camera", "ortho"][..], "cpu-ortho"),
        (&[][..], "cpu-persp"),
        (&["--method", "marcher"][..], "marcher"),
        (&["--device", "gpu", "--camera", "ortho"][..], "gpu"),
    ] {
        if let Some(out) = render_probe(dir.path(), extra, name) {
            let (l, w, h) = exr_lum(&out, 0);
            top_right(name, bright_centroid(&l, w, h));
        }
    }
    // Collisions happen where the extinction is: in the probe.
    let out = render_probe(
        dir.path(),
        &["--method", "woodcock", "--heatmap", "collisions"],
        "heat",
    )
    .unwrap();
    let heat = out.with_extension("heat.exr");
    let img = exr::prelude::read_all_flat_layers_from_file(&heat).unwrap();
    let layer = &img.layer_data[0];
    let (w, h) = (layer.size.width(), layer.size.height());
    let ch = layer
        .channel_data
        .list
        .iter()
        .find(|c| c.name.to_string().contains("collisions"))
        .expect("a collisions channel");
    let l: Vec<f32> = (0..w * h)
        .map(|i| ch.sample_data.value_by_flat_index(i).to_f32())
        .collect();
    top_right("collision heat map", bright_centroid(&l, w, h));
}

#[test]
fn views_and_camera_flags_move_the_probe_as_they_say() {
    let dir = tempfile::tempdir().unwrap();
    // From behind (-z) the image is mirrored: the probe is top-left.
    let out = render_probe(dir.path(), &["--camera", "ortho", "--view", "-z"], "back").unwrap();
    let (l, w, h) = exr_lum(&out, 0);
    let (x, y) = bright_centroid(&l, w, h);
    assert!(x < 0.45 && y < 0.45, "--view -z: ({x:.2}, {y:.2})");
    // From +x: y right, z up; the probe has high y and low z: bottom-right.
    let out = render_probe(dir.path(), &["--camera", "ortho", "--view", "x"], "x").unwrap();
    let (l, w, h) = exr_lum(&out, 0);
    let (x, y) = bright_centroid(&l, w, h);
    assert!(x > 0.55 && y > 0.55, "--view x: ({x:.2}, {y:.2})");
    // An explicit eye on the +z axis with the default up is the default view.
    let out = render_probe(
        dir.path(),
        &[
            "--camera",
            "ortho",
            "--eye",
            "7.5,7.5,60",
            "--target",
            "7.5,7.5,7.5",
        ],
        "eye",
    )
    .unwrap();
    let (l, w, h) = exr_lum(&out, 0);
    top_right("--eye on +z", bright_centroid(&l, w, h));
    // Zoom 2 about the centre pushes the probe outwards, towards the top-right corner.
    let base = render_probe(dir.path(), &["--camera", "ortho"], "base").unwrap();
    let zoom = render_probe(dir.path(), &["--camera", "ortho", "--zoom", "2"], "zoom").unwrap();
    let (l0, w, h) = exr_lum(&base, 0);
    let (l1, _, _) = exr_lum(&zoom, 0);
    let (x0, y0) = bright_centroid(&l0, w, h);
    let (x1, y1) = bright_centroid(&l1, w, h);
    assert!(
        (x1 - 0.5) > 1.5 * (x0 - 0.5) && (0.5 - y1) > 1.5 * (0.5 - y0),
        "zoom: ({x0:.2},{y0:.2}) -> ({x1:.2},{y1:.2})"
    );
    // With --out, so the error is the view's (not clap's missing --out, whose usage line
    // happened to mention --view when usage errors were several lines).
    let tmp = tempfile::tempdir().unwrap();
    let bad_out = tmp.path().join("bad.exr");
    let bad = blueshift(&[
        "render",
        "--synth",
        "three-cubes",
        "--tf",
        "builtin:grey",
        "--view",
        "w",
        "--out",
        bad_out.to_str().unwrap(),
    ]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("view"));
}

fn doppler_scene(dir: &Path) -> PathBuf {
    probe(dir);
    let scene = dir.join("probe.json");
    std::fs::write(
        &scene,
        r#"{ "data_dir": ".",
  "temperature": { "value": 8000, "unit": "K" },
  "species": [ { "name": "H I", "lines": "H", "density": { "file": "probe.nhdr", "unit": "cm-3" } } ],
  "factors": { "velocity": 1, "temperature": 1, "emission": 1, "absorption": 0, "blackbody": 0 } }"#,
    )
    .unwrap();
    scene
}

#[test]
fn doppler_images_and_cube_moment_maps_agree_with_render() {
    let dir = tempfile::tempdir().unwrap();
    let scene = doppler_scene(dir.path());
    for device in ["cpu", "gpu"] {
        let out = dir.path().join(format!("d-{device}.exr"));
        let o = blueshift(&[
            "doppler",
            "--scene",
            scene.to_str().unwrap(),
            "--width",
            "32",
            "--height",
            "32",
            "--device",
            device,
            "--out",
            out.to_str().unwrap(),
        ]);
        if device == "gpu" && !common::gpu_ok("doppler", &o) {
            continue;
        }
        ok(&o);
        // Channel 1 of the XYZ EXR is Y, the luminance.
        let (l, w, h) = exr_lum(&out, 1);
        top_right(
            &format!("doppler --device {device}"),
            bright_centroid(&l, w, h),
        );
        let (l, w, h) = png_lum(&out.with_extension("png"));
        top_right(
            &format!("doppler --device {device} PNG"),
            bright_centroid(&l, w, h),
        );
    }
    let cube = dir.path().join("c.fits");
    ok(&blueshift(&[
        "doppler",
        "--scene",
        scene.to_str().unwrap(),
        "--width",
        "32",
        "--height",
        "32",
        "--cube",
        cube.to_str().unwrap(),
        "--line",
        "H-alpha",
        "--velocity-bins",
        "-300:300:12",
        "--moments",
    ]));
    let mut seen = 0;
    for entry in std::fs::read_dir(dir.path()).unwrap() {
        let p = entry.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if name.starts_with('c') && name.contains("mom0") && name.ends_with(".exr") {
            let (l, w, h) = exr_lum(&p, 0);
            top_right("moment 0 map", bright_centroid(&l, w, h));
            seen += 1;
        }
    }
    assert_eq!(seen, 1, "no moment-0 EXR among the cube's outputs");
}

/// The triad on a PNG: from the default view world x points right (red pixels right of the
/// triad's origin) and y up (green above it); from +x, y points right instead.
#[test]
fn the_triad_shows_the_axes_as_the_camera_sees_them() {
    let dir = tempfile::tempdir().unwrap();
    let count = |png: &Path, red: bool, x: std::ops::Range<u32>, y: std::ops::Range<u32>| {
        let img = image::open(png).unwrap().to_rgb8();
        let mut n = 0;
        for yy in y.clone() {
            for xx in x.clone() {
                let p = img.get_pixel(xx, yy).0;
                let hit = if red {
                    p[0] > 200 && p[1] < 120 && p[2] < 120
                } else {
                    p[1] > 200 && p[0] < 120 && p[2] < 120
                };
                n += usize::from(hit);
            }
        }
        n
    };
    for (view, x_right) in [("z", true), ("x", false)] {
        let png = dir.path().join(format!("t-{view}.png"));
        let out = dir.path().join(format!("t-{view}.exr"));
        ok(&blueshift(&[
            "render",
            "--synth",
            "three-cubes",
            "--res",
            "8",
            "--tf",
            "builtin:grey",
            "--density-scale",
            "0",
            "--width",
            "160",
            "--height",
            "160",
            "--spp",
            "1",
            "--camera",
            "ortho",
            "--view",
            view,
            "--triad",
            "--out",
            out.to_str().unwrap(),
            "--png",
            png.to_str().unwrap(),
        ]));
        // The triad's origin: 20 + 14 pixels in from the bottom-right corner.
        let (ox, oy) = (160 - 20 - 14, 160 - 20 - 14);
        let red_right = count(&png, true, ox + 4..ox + 20, oy - 2..oy + 3);
        let green_up = count(&png, false, ox - 2..ox + 3, oy - 20..oy - 4);
        let green_right = count(&png, false, ox + 4..ox + 20, oy - 2..oy + 3);
        if x_right {
            assert!(
                red_right > 10 && green_up > 10,
                "{view}: {red_right} {green_up}"
            );
        } else {
            assert!(
                red_right == 0 && green_right > 10,
                "{view}: {red_right} {green_right}"
            );
        }
    }
}
