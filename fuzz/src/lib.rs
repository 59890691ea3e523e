//! Fuzz targets for every reader blueshift has: volume files (NRRD attached and detached,
//! MetaImage, VTK, Open SciVis raw names, the bricked `.bsv`), HDR images through the
//! tonemap reader (EXR, Radiance, PFM), transfer functions (blueshift and ParaView JSON),
//! Doppler and render scene JSON (parsed and loaded), emission-line lists, spectrum CSV and
//! FITS headers, and AMR output (Athena++ `.athdf`, Enzo HDF5 grids).
//!
//! Each target takes arbitrary bytes and must return, whatever they are, without a panic,
//! an abort, unbounded memory or unbounded time: an error is the right answer to a bad
//! input. The targets are plain functions so that two drivers share them:
//! - `tests/smoke.rs` runs each over its seed corpus and a fixed number of deterministic
//!   mutations in `cargo test`, with a per-input memory ceiling (a counting allocator);
//! - `libfuzzer/` is a cargo-fuzz project with one libFuzzer binary per target for the long
//!   runs (see `README.md`).
//!
//! Readers that take paths get the bytes as a file in a fixture folder that also holds the
//! data files the seeds name (the committed test volumes and two small `.bsv` files), so
//! detached headers and scene files reach their data.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// One fuzz target: a name (the libFuzzer binary's and the corpus folder's), the function,
/// and where its seeds are, relative to the workspace root (files or folders; folders are
/// read whole, not recursively).
#[derive(Clone, Copy, Debug)]
pub struct Target {
    /// The target's name.
    pub name: &'static str,
    /// Runs the reader on the bytes: whether it accepted them.
    pub run: fn(&[u8]) -> bool,
    /// Seed files and folders, relative to the workspace root.
    pub seeds: &'static [&'static str],
}

/// Every target, in the order the smoke test runs them.
pub const TARGETS: &[Target] = &[
    Target {
        name: "nrrd",
        run: nrrd,
        seeds: &[
            "volume/tests/data/valid/headsq_crop_ascii.nrrd",
            "volume/tests/data/valid/headsq_crop_be.nrrd",
            "volume/tests/data/valid/headsq_crop_gzip.nrrd",
            "volume/tests/data/valid/carotid_crop_vectors.nrrd",
            "volume/tests/data/invalid",
        ],
    },
    Target {
        name: "nhdr",
        run: nhdr,
        seeds: &["volume/tests/data/valid/headsq_crop.nhdr"],
    },
    Target {
        name: "mhd",
        run: mhd,
        seeds: &[
            "volume/tests/data/valid/headsq_crop.mhd",
            "volume/tests/data/valid/headsq_crop.mha",
        ],
    },
    Target {
        name: "vtk",
        run: vtk,
        seeds: &[
            "volume/tests/data/valid/headsq_crop_ascii.vtk",
            "volume/tests/data/valid/carotid_crop_binary.vtk",
        ],
    },
    Target {
        name: "raw_name",
        run: raw_name,
        seeds: &["fuzz/corpus/raw_name"],
    },
    Target {
        name: "bsv",
        run: bsv,
        seeds: &["fuzz/corpus/bsv"],
    },
    Target {
        name: "exr",
        run: exr,
        seeds: &["tonemap/tests/data/desk_crop_64x64.exr", "fuzz/corpus/exr"],
    },
    Target {
        name: "radiance",
        run: radiance,
        seeds: &["tonemap/tests/data/memorial_crop_64x96.hdr"],
    },
    Target {
        name: "pfm",
        run: pfm,
        seeds: &["fuzz/corpus/pfm"],
    },
    Target {
        name: "tf_json",
        run: tf_json,
        seeds: &[
            "tfedit/tests/data/paraview",
            "examples/enzo/gas_density_tf.json",
            "examples/enzo/temperature_tf.json",
        ],
    },
    Target {
        name: "doppler_scene",
        run: doppler_scene,
        seeds: &["fuzz/corpus/doppler_scene"],
    },
    Target {
        name: "render_scene",
        run: render_scene,
        seeds: &["fuzz/corpus/render_scene"],
    },
    Target {
        name: "line_list",
        run: line_list,
        seeds: &[
            "spectrum/data/lines_h1_balmer.csv",
            "spectrum/data/lines_he1.csv",
            "spectrum/data/lines_c1.csv",
        ],
    },
    Target {
        name: "spectrum_csv",
        run: spectrum_csv,
        seeds: &["fuzz/corpus/spectrum_csv"],
    },
    Target {
        name: "fits",
        run: fits,
        seeds: &["fuzz/corpus/fits"],
    },
    Target {
        name: "athdf",
        run: athdf,
        seeds: &["volume/tests/data/amr/athena2.athdf"],
    },
    Target {
        name: "enzo_hdf5",
        run: enzo_hdf5,
        seeds: &["volume/tests/data/amr/enzo2/amr2_0000.cpu0000"],
    },
];

/// The target named `name`.
#[must_use]
pub fn target(name: &str) -> Option<&'static Target> {
    TARGETS.iter().find(|t| t.name == name)
}

/// The workspace root (where the seed paths start).
#[must_use]
pub fn workspace_root() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// The fixture folder: a private temporary folder holding the committed valid test volumes
/// (so detached headers and scene files find their data) and the `.bsv` seeds, made once
/// per process and removed at exit only by the OS's temporary-file cleaning (a fuzzing
/// process ends by being killed).
#[must_use]
pub fn fixture() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = tempfile::Builder::new()
            .prefix("blueshift-fuzz-")
            .tempdir()
            .map(tempfile::TempDir::keep)
            .unwrap_or_else(|_| std::env::temp_dir());
        for src in ["volume/tests/data/valid", "fuzz/corpus/bsv"] {
            let Ok(entries) = std::fs::read_dir(workspace_root().join(src)) else {
                continue;
            };
            for e in entries.flatten() {
                let _ = std::fs::copy(e.path(), dir.join(e.file_name()));
            }
        }
        dir
    })
}

/// Writes `data` to a file of this thread's in the fixture folder, named `input.<ext>`
/// (unique per thread), and runs `f` on its path.
fn with_file(data: &[u8], ext: &str, f: impl FnOnce(&Path) -> bool) -> bool {
    let id = format!("{:?}", std::thread::current().id());
    let id: String = id.chars().filter(char::is_ascii_digit).collect();
    let path = fixture().join(format!("input-{id}.{ext}"));
    std::fs::write(&path, data).is_ok() && f(&path)
}

fn text(data: &[u8]) -> Option<&str> {
    std::str::from_utf8(data).ok()
}

/// A volume file read with the default limits; any channel read is touched.
fn volume_file(data: &[u8], ext: &str) -> bool {
    with_file(data, ext, |p| {
        std::hint::black_box(blueshift_volume::read(p)).is_ok()
    })
}

/// Attached NRRD (`.nrrd`).
pub fn nrrd(data: &[u8]) -> bool {
    volume_file(data, "nrrd")
}

/// Detached NRRD header (`.nhdr`), whose data file may be one of the fixture's.
pub fn nhdr(data: &[u8]) -> bool {
    volume_file(data, "nhdr")
}

/// MetaImage header (`.mhd`, data in a fixture file or local).
pub fn mhd(data: &[u8]) -> bool {
    volume_file(data, "mhd")
}

/// Legacy VTK structured points (`.vtk`).
pub fn vtk(data: &[u8]) -> bool {
    volume_file(data, "vtk")
}

/// An Open SciVis raw file name (`name_XxYxZ_type.raw`): the bytes are the name, parsed
/// and, when it parses, read as a raw file of that name holding the same bytes.
pub fn raw_name(data: &[u8]) -> bool {
    let Some(name) = text(data) else {
        return false;
    };
    if name.is_empty() || name.contains(['/', '\0']) || name.len() > 200 {
        return false;
    }
    let parsed = blueshift_volume::io::raw::parse_scivis_name(Path::new(name));
    if parsed.is_some() {
        let path = fixture().join(format!("fuzz-{name}"));
        if std::fs::write(&path, data).is_ok() {
            let _ = std::hint::black_box(blueshift_volume::read(&path));
            let _ = std::fs::remove_file(&path);
        }
    }
    parsed.is_some()
}

/// A bricked `.bsv` file: opened (header, checksums, macrocells), its coarsest level loaded
/// whole and a few samples taken of its finest through the brick cache.
pub fn bsv(data: &[u8]) -> bool {
    use blueshift_volume::ooc::{BrickedFile, Sampler};
    with_file(data, "bsv", |p| {
        let Ok(f) = BrickedFile::open(p, 4) else {
            return false;
        };
        let levels = f.levels();
        let mut ok = levels > 0
            && std::hint::black_box(f.load_level(levels - 1, &blueshift_volume::Limits::default()))
                .is_ok();
        match f.level(0) {
            Ok(s) => {
                let d = s.geometry().dims;
                for t in [0.0f32, 0.37, 0.5, 0.99] {
                    let p = glam::Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32) * t;
                    ok &= std::hint::black_box(s.sample_index(p)).is_ok();
                }
            }
            Err(_) => ok = false,
        }
        ok
    })
}

/// OpenEXR through the tonemap reader, and through the CLI's rows path (the compact
/// source, Drago's two passes over its rows), which must give the image's codes.
pub fn exr(data: &[u8]) -> bool {
    with_file(data, "exr", |p| {
        let img = blueshift_tonemap::io::read_exr(p, &blueshift_tonemap::io::Limits::default());
        rows_match_image(p);
        img.is_ok()
    })
}

/// Radiance `.hdr` through the tonemap reader, and through the rows path as [`exr`].
pub fn radiance(data: &[u8]) -> bool {
    with_file(data, "hdr", |p| {
        let img =
            blueshift_tonemap::io::read_radiance(p, &blueshift_tonemap::io::Limits::default());
        rows_match_image(p);
        img.is_ok()
    })
}

/// Reads `p` as the CLI's 8-bit PNG path does (a compact `HdrSource`, the format found from
/// the content) and tone-maps it with Drago over its rows. Where the file also reads as an
/// image (the same detection), the codes must be those of the whole image (a difference
/// panics: a finding). The format-specific readers above may read another format's file
/// differently (a Radiance header inside an OpenEXR file's bytes).
fn rows_match_image(p: &Path) {
    use blueshift_tonemap::{CleanImage, DragoParams, Operator};
    let limits = blueshift_tonemap::io::Limits::default();
    let Ok(src) = blueshift_tonemap::io::read_hdr_source_with(p, &limits) else {
        return;
    };
    let drago = Operator::Drago(DragoParams::default());
    let Ok(Some((codes, _))) = std::hint::black_box(drago.apply_rows_srgb8(&src)) else {
        return;
    };
    if let Ok(img) = blueshift_tonemap::io::read_hdr_image_with(p, &limits) {
        let whole = drago.apply_clean_srgb8(&CleanImage::new(&img));
        assert!(
            whole.is_ok_and(|w| w == codes),
            "the rows path's codes differ from the whole image's"
        );
    }
}

/// Portable float map through the tonemap reader.
pub fn pfm(data: &[u8]) -> bool {
    with_file(data, "pfm", |p| {
        std::hint::black_box(blueshift_tonemap::io::read_pfm(
            p,
            &blueshift_tonemap::io::Limits::default(),
        ))
        .is_ok()
    })
}

/// A transfer function in blueshift's or ParaView's JSON, detected as the CLI does.
pub fn tf_json(data: &[u8]) -> bool {
    text(data).is_some_and(|t| std::hint::black_box(blueshift_tfedit::parse_any(t)).is_ok())
}

/// A Doppler scene file: parsed with the fixture folder as its base, then loaded (every
/// field read, the spectra built).
pub fn doppler_scene(data: &[u8]) -> bool {
    text(data)
        .and_then(|t| blueshift_doppler::scene_file::SceneFile::parse(t, fixture()).ok())
        .is_some_and(|s| std::hint::black_box(s.load()).is_ok())
}

/// A render scene file: parsed as if it were in the fixture folder, then built (channels
/// read or synthesised, transfer functions, integrator, settings).
pub fn render_scene(data: &[u8]) -> bool {
    let path = fixture().join("scene.json");
    text(data)
        .and_then(|t| blueshift_tracking::scene_file::RenderSceneFile::from_json(t, &path).ok())
        .is_some_and(|s| {
            let memory = blueshift_tracking::scene_file::Preloaded {
                budget: Some(blueshift_volume::MemoryBudget::new(
                    FUZZ_BUDGET,
                    "fuzz budget",
                )),
                ..Default::default()
            };
            std::hint::black_box(s.build_with(&memory)).is_ok()
        })
}

/// The memory budget the targets give the readers that take one (what `--max-memory`
/// sets in the CLI): a scene asking for more must be refused before it allocates.
pub const FUZZ_BUDGET: u64 = 128 << 20;

/// An emission-line list (CSV).
pub fn line_list(data: &[u8]) -> bool {
    text(data).is_some_and(|t| {
        std::hint::black_box(blueshift_spectrum::parse_line_list(t, "fuzz")).is_ok()
    })
}

/// A piecewise-linear spectrum as `blueshift spectrum --csv` writes it.
pub fn spectrum_csv(data: &[u8]) -> bool {
    text(data).is_some_and(|t| {
        std::hint::black_box(blueshift_spectrum::PiecewiseLinear::parse_csv(t, "fuzz")).is_ok()
    })
}

/// A FITS file's primary header (as the cube tests read what the CLI writes).
pub fn fits(data: &[u8]) -> bool {
    std::hint::black_box(blueshift_doppler::read_fits(data)).is_ok()
}

/// An AMR hierarchy read whole: the field's blocks, a few reconstructed samples and one
/// brick of its finest level.
fn amr(p: &Path, field: &str) -> bool {
    use blueshift_volume::amr::Hierarchy;
    let Ok(h) = Hierarchy::open(p) else {
        return false;
    };
    let Ok(f) = h.field(field, &blueshift_volume::Limits::default()) else {
        return false;
    };
    for t in [0.0, 0.31, 0.5, 0.97] {
        let q = h.domain_lo + (h.domain_hi - h.domain_lo) * t;
        std::hint::black_box(f.sample(q));
    }
    let f = std::sync::Arc::new(f);
    std::hint::black_box(f.source().read_brick(0, 0)).is_ok()
}

/// An Athena++ `.athdf` file (HDF5 attributes, block layout, the `prim` dataset).
pub fn athdf(data: &[u8]) -> bool {
    with_file(data, "athdf", |p| amr(p, "rho"))
}

/// The HDF5 grid file of a two-level Enzo hierarchy (its parameter and hierarchy files are
/// the committed fixture's).
pub fn enzo_hdf5(data: &[u8]) -> bool {
    let Ok(dir) = tempfile::tempdir() else {
        return false;
    };
    let src = workspace_root().join("volume/tests/data/amr/enzo2");
    for name in ["amr2_0000", "amr2_0000.hierarchy"] {
        if std::fs::copy(src.join(name), dir.path().join(name)).is_err() {
            return false;
        }
    }
    if std::fs::write(dir.path().join("amr2_0000.cpu0000"), data).is_err() {
        return false;
    }
    amr(&dir.path().join("amr2_0000"), "Density")
}
