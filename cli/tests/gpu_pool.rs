//! The device brick pool through the CLI: a `.bsv` scene renders on the GPU (`doppler` and
//! `render`) as on the CPU; a level whose non-constant bricks exceed `--gpu-pool-mb` is
//! refused on `gpu` with one line and no output, runs on the CPU under `auto`, and under
//! `--lod auto` renders the finest coarser level that fits (the same bytes as asking for
//! that level); per-brick levels of detail (`--lod brick`) and `--progressive levels|bricks`
//! render on the GPU as on the CPU.

use std::path::Path;
use std::process::{Command, Output};

mod common;
use common::{gpu_ok, read_exr};

fn blueshift(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .current_dir(dir)
        // auto takes the software adapter too (it prefers the CPU to lavapipe otherwise).
        .env("BLUESHIFT_GPU", "software")
        .output()
        .unwrap()
}

/// The hydrogen shell at 40^3 in `.bsv` files (bricks of 8): levels 40, 20, 10, 5. In pool
/// bricks of 32: 8 per channel at level 0, 1 at level 1; with the velocity's three
/// components and the density, 32 and 4 bricks (at most that many slots; 20 of the 32 are
/// not constant). One MiB holds 7 slots of 33^3 f32.
fn shell(dir: &Path) {
    let o = blueshift(
        &[
            "synth",
            "hydrogen-shell",
            "s.bsv",
            "--res",
            "40",
            "--brick",
            "8",
        ],
        dir,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let scene = r#"{"velocity": {"files": ["s_velocity_m_per_s_x.bsv",
            "s_velocity_m_per_s_y.bsv", "s_velocity_m_per_s_z.bsv"]},
        "species": [{"name": "hydrogen", "lines": "H", "density": {"file": "s.bsv"}}],
        "factors": {"velocity": 10}}"#;
    std::fs::write(dir.join("scene.json"), scene).unwrap();
}

fn doppler(dir: &Path, out: &str, extra: &[&str]) -> Output {
    let mut a = vec!["doppler", "--scene", "scene.json", "--out", out];
    if !extra.contains(&"--width") {
        a.extend(["--width", "16", "--height", "16"]);
    }
    a.extend_from_slice(extra);
    blueshift(&a, dir)
}

/// The stderr of a run that succeeded.
fn ok(o: &Output) -> String {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The largest difference of two EXR images' samples.
fn max_diff(a: &Path, b: &Path) -> f32 {
    let (a, b) = (read_exr(a), read_exr(b));
    a.as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn doppler_bricked_scene_on_the_gpu_pool_cap_and_lod_auto() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    shell(d);
    let c = doppler(d, "cpu.exr", &[]);
    assert!(c.status.success(), "{}", String::from_utf8_lossy(&c.stderr));
    let g = doppler(d, "gpu.exr", &["--device", "gpu"]);
    if !gpu_ok("doppler", &g) {
        return;
    }
    common::close_doppler(&d.join("cpu.exr"), &d.join("gpu.exr"));
    let log = String::from_utf8_lossy(&g.stderr);
    // Of the 32 bricks the shell's corners are constant (outside the shell: no slot).
    assert!(log.contains(" of 32 bricks resident"), "{log}");

    // Level 0 needs 32 slots: refused on gpu, one line, no output.
    let r = doppler(d, "never.exr", &["--device", "gpu", "--gpu-pool-mb", "1"]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("--gpu-pool-mb"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(!d.join("never.exr").exists() && !d.join("never.png").exists());
    // auto renders it on the CPU: the CPU's bytes.
    let a = doppler(d, "auto.exr", &["--device", "auto", "--gpu-pool-mb", "1"]);
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    assert!(String::from_utf8_lossy(&a.stderr).contains("rendering on the CPU"));
    assert!(
        std::fs::read(d.join("auto.exr")).unwrap() == std::fs::read(d.join("cpu.exr")).unwrap()
    );

    // --lod auto at 64x64 picks level 0 (no level's voxels are as small as a pixel); the
    // pool takes level 1: the image of asking for level 1 on the GPU.
    let wide = ["--width", "64", "--height", "64", "--device", "gpu"];
    let mut x = wide.to_vec();
    x.extend(["--lod", "auto", "--gpu-pool-mb", "1"]);
    let l = doppler(d, "auto1.exr", &x);
    assert!(l.status.success(), "{}", String::from_utf8_lossy(&l.stderr));
    let log = String::from_utf8_lossy(&l.stderr);
    assert!(
        log.contains("at level 1 (level 0 does not fit the pool)"),
        "{log}"
    );
    let mut y = wide.to_vec();
    y.extend(["--lod", "1"]);
    let one = doppler(d, "one.exr", &y);
    assert!(
        one.status.success(),
        "{}",
        String::from_utf8_lossy(&one.stderr)
    );
    assert!(
        std::fs::read(d.join("auto1.exr")).unwrap() == std::fs::read(d.join("one.exr")).unwrap(),
        "the coarser level's image"
    );
    // Per-brick levels (every field bricked alike): the GPU pool holds each level's
    // sampled bricks and renders the CPU's image.
    ok(&doppler(d, "brick.exr", &["--lod", "brick"]));
    let log = ok(&doppler(
        d,
        "gbrick.exr",
        &["--lod", "brick", "--device", "gpu"],
    ));
    assert!(log.contains("2 levels per brick"), "{log}");
    common::close_doppler(&d.join("brick.exr"), &d.join("gbrick.exr"));
    // At 24x24 every region takes level 0 (20 non-constant bricks): a 1 MiB pool (7 slots)
    // takes every region one level coarser, and stderr says so.
    let log = ok(&doppler(
        d,
        "fit.exr",
        &[
            "--lod",
            "brick",
            "--width",
            "24",
            "--height",
            "24",
            "--device",
            "gpu",
            "--gpu-pool-mb",
            "1",
        ],
    ));
    assert!(log.contains("every brick 1 level(s) coarser"), "{log}");
    // Progressive on the GPU, by levels and brick by brick, through one device pool: the
    // coarsest level first, the exact image last (the CPU's).
    for how in ["levels", "bricks"] {
        let out = format!("prog-{how}.exr");
        let log = ok(&doppler(
            d,
            &out,
            &["--device", "gpu", "--progressive", how],
        ));
        assert!(
            log.contains("progressive: pass 1, level 3 (5x5x5)"),
            "{log}"
        );
        assert!(log.contains("on the gpu"), "{log}");
        common::close_doppler(&d.join("cpu.exr"), &d.join(&out));
    }
    // A zero cap is the user's error.
    let z = doppler(d, "z.exr", &["--device", "gpu", "--gpu-pool-mb", "0"]);
    assert!(!z.status.success());
    assert!(String::from_utf8_lossy(&z.stderr).contains("at least 1"));
}

#[test]
fn render_bricked_volume_on_the_gpu_pool_cap_and_lod_auto() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Turbulence: no constant brick, so level 0 needs 8 slots and level 1 one.
    let o = blueshift(
        &[
            "synth",
            "turbulence",
            "t.bsv",
            "--res",
            "40",
            "--brick",
            "8",
        ],
        d,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // `size` x `size` pixels.
    let render_at = |out: &str, size: &str, extra: &[&str]| {
        let mut a = vec![
            "render",
            "--volume",
            "t.bsv",
            "--tf",
            "builtin:viridis",
            "--method",
            "marcher",
            "--width",
            size,
            "--height",
            size,
            "--out",
            out,
        ];
        a.extend_from_slice(extra);
        blueshift(&a, d)
    };
    let render = |out: &str, extra: &[&str]| render_at(out, "64", extra);
    ok(&render("cpu.exr", &[]));
    let g = render("gpu.exr", &["--device", "gpu"]);
    if !gpu_ok("render", &g) {
        return;
    }
    // The marcher's f32 tolerance over some 100 steps (gpu/tests/pool.rs).
    let diff = max_diff(&d.join("cpu.exr"), &d.join("gpu.exr"));
    assert!(diff <= 1e-4, "max |gpu - cpu| = {diff}");
    let log = String::from_utf8_lossy(&g.stderr);
    assert!(
        log.contains("GPU brick pool: 8 of 8 bricks resident"),
        "{log}"
    );
    // 8 slots at level 0, more than a 1 MiB pool's 7.
    let r = render("never.exr", &["--device", "gpu", "--gpu-pool-mb", "1"]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("brick pool"), "{err}");
    assert!(!d.join("never.exr").exists());
    let log = ok(&render(
        "auto1.exr",
        &["--device", "gpu", "--gpu-pool-mb", "1", "--lod", "auto"],
    ));
    assert!(
        log.contains("at level 1 (level 0 does not fit the pool)"),
        "{log}"
    );
    // Per-brick levels at 16x16 (bricks near the eye at level 0, far ones at level 1): the
    // pool holds each level's sampled bricks and the GPU renders the CPU's image.
    ok(&render_at("brick.exr", "16", &["--lod", "brick"]));
    let log = ok(&render_at(
        "gbrick.exr",
        "16",
        &["--lod", "brick", "--device", "gpu"],
    ));
    assert!(log.contains("2 levels per brick"), "{log}");
    let diff = max_diff(&d.join("brick.exr"), &d.join("gbrick.exr"));
    assert!(diff <= 1e-4, "per-brick: max |gpu - cpu| = {diff}");
    // At 24x24 the per-brick view holds 8 level-0 bricks and one of level 1: a 1 MiB pool
    // (7 slots) takes every brick one level coarser, and stderr says so.
    let log = ok(&render_at(
        "fit.exr",
        "24",
        &["--lod", "brick", "--device", "gpu", "--gpu-pool-mb", "1"],
    ));
    assert!(log.contains("every brick 1 level(s) coarser"), "{log}");
    // Progressive on the GPU, by levels and brick by brick: every pass a view of one device
    // pool, the coarsest level first, and the final image the CPU's.
    for how in ["levels", "bricks"] {
        let out = format!("prog-{how}.exr");
        let log = ok(&render(&out, &["--device", "gpu", "--progressive", how]));
        assert!(
            log.contains("progressive: pass 1, level 3 (5x5x5)"),
            "{log}"
        );
        assert!(log.contains("GPU brick pool"), "{log}");
        let diff = max_diff(&d.join("cpu.exr"), &d.join(&out));
        assert!(diff <= 1e-4, "progressive {how}: max |gpu - cpu| = {diff}");
    }
    let one = render("one.exr", &["--device", "gpu", "--lod", "1"]);
    assert!(
        one.status.success(),
        "{}",
        String::from_utf8_lossy(&one.stderr)
    );
    assert!(
        std::fs::read(d.join("auto1.exr")).unwrap() == std::fs::read(d.join("one.exr")).unwrap(),
        "the coarser level's image"
    );
}
