//! The viewer's hot path: the first frame after an edit, from the edit to the PNG bytes the
//! page receives (edit, render, display mapping, PNG encoding), against a fresh session
//! built for every frame (what a viewer without session reuse would pay), in the same run.
//!
//! - `lidc2_tf_edit`: the lidc2 chest CT (256 x 256 x 133, 8 bit; `../shared/data/lidc2-ct`,
//!   or the synthetic `three-cubes` at 128^3 when the data folder is absent), MDWT 1-DDA,
//!   a 256 x 256 frame at 1 spp after changing the transfer function (only its majorant
//!   grid is rebuilt); `lidc2_camera_move`: the same after moving the camera (nothing is
//!   rebuilt); `lidc2_fresh`: scene (macrocells, majorants) and session built, then the frame;
//!   `lidc2_quarter_preview`: the viewer's 64 x 64 first preview after a TF edit.
//! - `galaxy_camera_move`: the Doppler galaxy (64^3, emission only: black body and H lines,
//!   absorption factor 0), piecewise linear, a 256 x 256 frame after a camera move;
//!   `galaxy_quarter_preview`: its 64 x 64 preview; `galaxy_fresh`: a new session per frame.
//!
//! Run: `cargo bench -p blueshift-view --bench preview`.

use std::hint::black_box;
use std::path::PathBuf;

use blueshift_camera::{Camera, Silent};
use blueshift_doppler::{DopplerScene, DopplerSession, DopplerSettings};
use blueshift_tfedit::TransferFunction;
use blueshift_tracking::{
    Blend, DdaMode, Integrator, Progressive, RenderSettings, Scene, TrackingSession,
};
use blueshift_volume::AnyGrid;
use criterion::Criterion;
use image::Rgb32FImage;

const SIZE: u32 = 256;

fn lidc2() -> AnyGrid {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/lidc2-ct/lidc2_256x256x133_uint8.nhdr");
    match blueshift_volume::read(&p) {
        Ok(v) => v.channels()[0].grid.clone(),
        Err(e) => {
            eprintln!("lidc2 not found ({e}); using three-cubes 128^3");
            let v = blueshift_volume::synth::by_name("three-cubes", 128, 1).expect("synth");
            v.channels()[0].grid.clone()
        }
    }
}

/// A CT-like transfer function over the data range with the opacity ramp at `at`.
fn tf(grid: &AnyGrid, at: f64) -> TransferFunction {
    let (lo, hi) = grid.finite_range().expect("range");
    let (lo, hi) = (f64::from(lo), f64::from(hi));
    let b = blueshift_tfedit::builtin_over("grey", [lo, hi]).expect("tf");
    let knots = vec![
        blueshift_tfedit::OpacityKnot::new(lo, 0.0),
        blueshift_tfedit::OpacityKnot::new(lo + at * (hi - lo), 0.0),
        blueshift_tfedit::OpacityKnot::new(hi, 0.6),
    ];
    TransferFunction::new([lo, hi], b.color_knots().to_vec(), knots).expect("tf")
}

fn integrator() -> Integrator {
    Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    }
}

fn settings(scene: &Scene, w: u32) -> RenderSettings {
    let mut s = RenderSettings::default_for(scene, w, w, false);
    s.spp = 1;
    s
}

/// The page's bytes for an accumulation: display mapping (exposure), sRGB, PNG.
fn frame_bytes(acc: &Progressive) -> Vec<u8> {
    let img = acc.mean_image();
    let rgb = Rgb32FImage::from_fn(img.width(), img.height(), |x, y| {
        let p = img.get_pixel(x, y).0;
        image::Rgb([p[0], p[1], p[2]])
    });
    let d = blueshift_view::display::to_rgb8(&rgb, None, 0.0).expect("display");
    blueshift_view::display::png_bytes(&d).expect("png")
}

fn orbit(c: Camera, k: usize) -> Camera {
    let a = if k.is_multiple_of(2) { 0.05f32 } else { -0.05 };
    let back = c.eye - c.target;
    let rot = glam::Quat::from_axis_angle(c.up.normalize(), a);
    Camera {
        eye: c.target + rot * back,
        ..c
    }
}

fn galaxy() -> DopplerScene {
    let vol = blueshift_volume::synth::galaxy(64, 1).expect("galaxy");
    let mut s = DopplerScene::from_volume(&vol, &["bb", "H"]).expect("scene");
    s.factors.absorption = 0.0;
    s
}

fn doppler_png(img: &blueshift_doppler::DopplerImage) -> Vec<u8> {
    let rgb = blueshift_doppler::DisplayOptions::default().to_rgb8(img);
    let d = image::RgbImage::from_raw(img.width, img.height, rgb).expect("size");
    blueshift_view::display::png_bytes(&d).expect("png")
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    let grid = lidc2();
    let tfs = [tf(&grid, 0.3), tf(&grid, 0.35)];
    let build = |t: &TransferFunction| {
        Scene::new(vec![("ct".to_owned(), grid.clone(), t.clone())], 40.0, 4).expect("scene")
    };
    let scene = build(&tfs[0]);
    let st = settings(&scene, SIZE);
    let mut g = c.benchmark_group("view_preview");
    g.sample_size(10);
    let mut f = 0;
    g.bench_function("lidc2_fresh", |b| {
        b.iter(|| {
            // The same alternation of transfer functions as the edit below.
            f += 1;
            let s = build(&tfs[f % 2]);
            let session = TrackingSession::new(s, integrator(), st.clone()).expect("session");
            black_box(frame_bytes(&session.render(&Silent).expect("render").image))
        });
    });
    let mut session =
        TrackingSession::new(scene.clone(), integrator(), st.clone()).expect("session");
    let mut k = 0;
    g.bench_function("lidc2_tf_edit", |b| {
        b.iter(|| {
            k += 1;
            session
                .set_transfer_function(0, tfs[k % 2].clone())
                .expect("tf");
            black_box(frame_bytes(&session.render(&Silent).expect("render").image))
        });
    });
    g.bench_function("lidc2_camera_move", |b| {
        b.iter(|| {
            k += 1;
            let cam = orbit(session.settings().camera, k);
            session.set_camera(cam).expect("camera");
            black_box(frame_bytes(&session.render(&Silent).expect("render").image))
        });
    });
    session
        .set_settings(settings(&scene, SIZE / 4))
        .expect("settings");
    g.bench_function("lidc2_quarter_preview", |b| {
        b.iter(|| {
            k += 1;
            session
                .set_transfer_function(0, tfs[k % 2].clone())
                .expect("tf");
            black_box(frame_bytes(&session.render(&Silent).expect("render").image))
        });
    });
    let gscene = galaxy();
    let dst = DopplerSettings::default_for(&gscene, SIZE, SIZE);
    g.bench_function("galaxy_fresh", |b| {
        b.iter(|| {
            let s = DopplerSession::new(gscene.clone(), dst.clone()).expect("session");
            black_box(doppler_png(&s.render(&Silent).expect("render")))
        });
    });
    let mut ds = DopplerSession::new(gscene.clone(), dst.clone()).expect("session");
    g.bench_function("galaxy_camera_move", |b| {
        b.iter(|| {
            k += 1;
            let cam = orbit(ds.settings().camera, k);
            ds.set_camera(cam).expect("camera");
            black_box(doppler_png(&ds.render(&Silent).expect("render")))
        });
    });
    let mut small = dst.clone();
    small.width = SIZE / 4;
    small.height = SIZE / 4;
    ds.set_settings(small).expect("settings");
    g.bench_function("galaxy_quarter_preview", |b| {
        b.iter(|| {
            k += 1;
            let cam = orbit(ds.settings().camera, k);
            ds.set_camera(cam).expect("camera");
            black_box(doppler_png(&ds.render(&Silent).expect("render")))
        });
    });
    g.finish();
    c.final_summary();
}
