//! Readers against independently decoded values of real files, writers round-tripping, and
//! malformed input giving errors, never panics.

use std::path::{Path, PathBuf};

use blueshift_volume::io::{self, Endian, nrrd};
use blueshift_volume::{AnyGrid, DiskType, Error, ReadOptions, Volume, read, read_with};
use glam::Vec3;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// The shared real datasets, or `None` with a printed reason (the tests then skip).
fn shared(rel: &str) -> Option<PathBuf> {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut candidates: Vec<PathBuf> = std::env::var_os("BLUESHIFT_SHARED_DATA")
        .map(PathBuf::from)
        .into_iter()
        .collect();
    candidates.push(manifest.join("../../shared/data"));
    candidates.push(manifest.join("../../../shared/data"));
    for c in candidates {
        let p = c.join(rel);
        if p.exists() {
            return Some(p);
        }
    }
    eprintln!(
        "SKIP: shared data file {rel} not found (set BLUESHIFT_SHARED_DATA to ../shared/data)"
    );
    None
}

fn i16_le(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(2)
        .map(|c| f32::from(i16::from_le_bytes([c[0], c[1]])))
        .collect()
}
fn f32_le(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}
fn f32_be(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_be_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn scalars(v: &Volume, ch: usize) -> Vec<f32> {
    v.channels()[ch].grid.to_f32_vec()
}

fn vectors(v: &Volume, name: &str) -> Vec<f32> {
    match v.grid(name).unwrap() {
        AnyGrid::Vec3(g) => g.data().iter().flat_map(|v| v.to_array()).collect(),
        other => panic!("{name} is {:?}, not a vector grid", other.scalar_type()),
    }
}

fn assert_close(a: Vec3, b: Vec3, what: &str) {
    assert!(
        (a - b).abs().max_element() < 1e-4,
        "{what}: expected {b}, got {a}, diff {}",
        (a - b).abs()
    );
}

#[test]
fn headsq_crop_reads_identically_in_every_format() {
    let reference = i16_le(&std::fs::read(data("valid/headsq_crop_16x16x8_int16.raw")).unwrap());
    let org = Vec3::new(20.0 * 3.2, 20.0 * 3.2, 40.0 * 1.5);
    let cases: [(&str, Vec3, Vec3); 8] = [
        (
            "valid/headsq_crop_ascii.nrrd",
            Vec3::new(3.2, 3.2, 1.5),
            Vec3::ZERO,
        ),
        ("valid/headsq_crop_16x16x8_int16.raw", Vec3::ONE, Vec3::ZERO),
        (
            "valid/headsq_crop_be.nrrd",
            Vec3::new(3.2, 3.2, 1.5),
            Vec3::ZERO,
        ),
        ("valid/headsq_crop_gzip.nrrd", Vec3::new(3.2, 3.2, 1.5), org),
        (
            "valid/headsq_crop.nhdr",
            Vec3::new(3.2, 3.2, 1.5),
            Vec3::ZERO,
        ),
        ("valid/headsq_crop.mha", Vec3::new(3.2, 3.2, 1.5), org),
        (
            "valid/headsq_crop.mhd",
            Vec3::new(3.2, 3.2, 1.5),
            Vec3::ZERO,
        ),
        ("valid/headsq_crop_ascii.vtk", Vec3::new(3.2, 3.2, 1.5), org),
    ];
    for (file, spacing, origin) in cases {
        let v = read(data(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert_eq!(v.geometry().dims, [16, 16, 8], "{file}");
        assert_close(v.geometry().spacing, spacing, file);
        assert_close(v.geometry().origin, origin, file);
        assert_eq!(v.channels()[0].stored_as, Some(DiskType::I16), "{file}");
        assert_eq!(scalars(&v, 0), reference, "{file}: voxel values differ");
    }
}

#[test]
fn carotid_crop_vtk_loads_scalars_and_interleaved_vectors() {
    let s_ref =
        f32_le(&std::fs::read(data("valid/carotid_crop_scalars_8x8x6_float32.raw")).unwrap());
    let v_ref =
        f32_le(&std::fs::read(data("valid/carotid_crop_vectors_8x8x6x3_float32.raw")).unwrap());
    let v = read(data("valid/carotid_crop_binary.vtk")).unwrap();
    assert_eq!(v.geometry().dims, [8, 8, 6]);
    assert_close(v.geometry().origin, Vec3::new(130.0, 100.0, 21.0), "origin");
    let names: Vec<&str> = v.channels().iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["scalars", "vectors"]);
    assert_eq!(scalars(&v, 0), s_ref);
    assert_eq!(vectors(&v, "vectors"), v_ref);
    // The same vectors as a 4D NRRD (big-endian, 3-vector axis first).
    let n = read(data("valid/carotid_crop_vectors.nrrd")).unwrap();
    assert_eq!(vectors(&n, "vectors"), v_ref);
    // And as an Open SciVis raw with an x3 component count.
    let r = read(data("valid/carotid_crop_vectors_8x8x6x3_float32.raw")).unwrap();
    assert_eq!(vectors(&r, "vectors"), v_ref);
}

#[test]
fn headsq_matches_independent_decode_and_published_statistics() {
    let Some(nhdr) = shared("headsq/headsq_64x64x93_int16le.nhdr") else {
        return;
    };
    let raw = i16_le(&std::fs::read(nhdr.with_file_name("headsq_64x64x93_int16le.raw")).unwrap());
    let v = read(&nhdr).unwrap();
    assert_eq!(v.geometry().dims, [64, 64, 93]);
    assert_close(v.geometry().spacing, Vec3::new(3.2, 3.2, 1.5), "spacing");
    let got = scalars(&v, 0);
    assert_eq!(got, raw);
    // SOURCE.md: values 0..3926, mean 507.7.
    assert_eq!(v.channels()[0].grid.finite_range(), Some((0.0, 3926.0)));
    let mean = got.iter().map(|&x| f64::from(x)).sum::<f64>() / got.len() as f64;
    assert!(
        (mean - 507.7).abs() < 0.05,
        "mean {mean}, SOURCE.md says 507.7"
    );
}

#[test]
fn lidc2_gzip_nrrd_matches_flate2_and_published_mean() {
    let Some(nhdr) = shared("lidc2-ct/lidc2_256x256x133_uint8.nhdr") else {
        return;
    };
    use std::io::Read;
    let mut raw = Vec::new();
    flate2::read::GzDecoder::new(
        std::fs::File::open(nhdr.with_file_name("lidc2_256x256x133_uint8.raw.gz")).unwrap(),
    )
    .read_to_end(&mut raw)
    .unwrap();
    let v = read(&nhdr).unwrap();
    assert_eq!(v.geometry().dims, [256, 256, 133]);
    assert_close(
        v.geometry().spacing,
        Vec3::new(1.40625, 1.40625, 2.5),
        "spacing",
    );
    let AnyGrid::U8(g) = &v.channels()[0].grid else {
        panic!("uint8 should stay u8")
    };
    assert_eq!(g.data(), &raw[..]);
    let mean = raw.iter().map(|&b| f64::from(b)).sum::<f64>() / raw.len() as f64;
    assert!(
        (mean - 7.05).abs() < 0.01,
        "mean {mean}, SOURCE.md says 7.05"
    );
}

#[test]
fn ironprot_vtk_equals_its_extracted_raw() {
    let Some(vtk) = shared("ironprot/ironProt.vtk") else {
        return;
    };
    let raw = std::fs::read(vtk.with_file_name("ironProt_68x68x68_uint8.raw")).unwrap();
    let v = read(&vtk).unwrap();
    assert_eq!(v.geometry().dims, [68, 68, 68]);
    let AnyGrid::U8(g) = &v.channels()[0].grid else {
        panic!("unsigned_char should load as u8")
    };
    assert_eq!(g.data(), &raw[..]);
    let mean = raw.iter().map(|&b| f64::from(b)).sum::<f64>() / raw.len() as f64;
    assert!(
        (mean - 13.1).abs() < 0.05,
        "mean {mean}, SOURCE.md says 13.1"
    );
    // The NRRD header over the same bytes gives the same grid.
    let n = read(vtk.with_file_name("ironProt_68x68x68_uint8.nhdr")).unwrap();
    assert_eq!(n.channels()[0].grid, v.channels()[0].grid);
}

#[test]
fn carotid_vtk_matches_byte_offsets_of_source_md() {
    let Some(vtk) = shared("carotid-flow/carotid.vtk") else {
        return;
    };
    let bytes = std::fs::read(&vtk).unwrap();
    let n = 76 * 49 * 45;
    // SOURCE.md: scalars at byte 182, vectors at byte 670525, both big-endian f32.
    let s_ref = f32_be(&bytes[182..182 + 4 * n]);
    let v_ref = f32_be(&bytes[670_525..670_525 + 12 * n]);
    let v = read(&vtk).unwrap();
    assert_eq!(v.geometry().dims, [76, 49, 45]);
    assert_close(v.geometry().origin, Vec3::new(100.0, 80.0, 1.0), "origin");
    assert_eq!(scalars(&v, 0), s_ref);
    assert_eq!(vectors(&v, "vectors"), v_ref);
    assert_eq!(v.channels()[0].grid.finite_range(), Some((0.0, 580.0)));
}

#[test]
fn enzo_channels_match_source_md_ranges() {
    let Some(d) = shared("enzo-moving7/density_gcm3_64x64x64_f32le.nhdr") else {
        return;
    };
    let dens = read(&d).unwrap();
    assert_close(dens.geometry().spacing, Vec3::splat(0.015625), "spacing");
    let (_, hi) = dens.channels()[0].grid.finite_range().unwrap();
    assert!((hi / 2.75e-24 - 1.0).abs() < 0.01, "max density {hi}");
    let t = read(d.with_file_name("temperature_K_64x64x64_f32le.nhdr")).unwrap();
    let (lo, hi) = t.channels()[0].grid.finite_range().unwrap();
    assert!(
        (lo - 1.0).abs() < 0.01 && (hi - 16_697.0).abs() < 1.0,
        "temperature {lo}..{hi}"
    );
    let vel = read(d.with_file_name("velocity_kms_64x64x64x3_f32le.nhdr")).unwrap();
    assert_eq!(vel.geometry().dims, [64, 64, 64]);
    let comps = vectors(&vel, "vectors");
    let (lo, hi) = comps
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &c| (a.min(c), b.max(c)));
    assert!(
        (lo - 155.6).abs() < 0.1 && (hi - 331.9).abs() < 0.1,
        "velocity {lo}..{hi} km/s"
    );
    // The raw file by its Open SciVis-style name gives the same vectors.
    let raw = read(d.with_file_name("velocity_kms_64x64x64x3_f32le.raw")).unwrap();
    assert_eq!(vectors(&raw, "vectors"), comps);
}

#[test]
fn nrrd_writer_round_trips_and_keeps_i16_and_spacing() {
    let v = read(data("valid/headsq_crop_gzip.nrrd")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for gzip in [false, true] {
        let out = dir.path().join(format!("rt{gzip}.nrrd"));
        let written = nrrd::write_file(
            &out,
            &v.channels()[0],
            &nrrd::WriteOptions { gzip, disk: None },
        )
        .unwrap();
        assert_eq!(written, DiskType::I16);
        let text = std::fs::read(&out).unwrap();
        assert!(text.starts_with(b"NRRD0004\n") && text.windows(12).any(|w| w == b"type: int16\n"));
        let back = read(&out).unwrap();
        assert_eq!(back.geometry(), v.geometry());
        assert_eq!(scalars(&back, 0), scalars(&v, 0));
    }
    // Vectors round-trip as a 4D float NRRD.
    let c = read(data("valid/carotid_crop_binary.vtk")).unwrap();
    let out = dir.path().join("vec.nrrd");
    nrrd::write_file(
        &out,
        c.channel("vectors").unwrap(),
        &nrrd::WriteOptions::default(),
    )
    .unwrap();
    assert_eq!(
        vectors(&read(&out).unwrap(), "vectors"),
        vectors(&c, "vectors")
    );
}

#[test]
fn raw_writer_round_trips_through_the_scivis_name() {
    let v = read(data("valid/headsq_crop.mha")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = Vec::new();
    let disk = io::raw::write_raw(&mut bytes, &v.channels()[0]).unwrap();
    let name = io::raw::scivis_file_name("crop", v.geometry().dims, disk);
    assert_eq!(name, "crop_16x16x8_int16.raw");
    let p = dir.path().join(name);
    std::fs::write(&p, &bytes).unwrap();
    assert_eq!(scalars(&read(&p).unwrap(), 0), scalars(&v, 0));
}

#[test]
fn non_finite_values_are_refused_on_request() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("nan.nrrd");
    let mut b =
        b"NRRD0004\ntype: float\ndimension: 3\nsizes: 2 1 1\nendian: little\nencoding: raw\n\n"
            .to_vec();
    b.extend_from_slice(&1.0f32.to_le_bytes());
    b.extend_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&p, &b).unwrap();
    assert!(read(&p).is_ok(), "NaN is allowed by default");
    let err = read_with(
        &p,
        &ReadOptions {
            reject_non_finite: true,
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(
        matches!(
            err,
            Error::NonFinite {
                x: 1,
                y: 0,
                z: 0,
                ..
            }
        ),
        "{err}"
    );
}

#[test]
fn limits_refuse_before_allocating() {
    let opts = ReadOptions {
        limits: blueshift_volume::Limits {
            max_voxels: 1000,
            max_alloc_bytes: 1 << 20,
        },
        ..Default::default()
    };
    let err = read_with(data("valid/headsq_crop.mha"), &opts).unwrap_err();
    assert!(matches!(err, Error::Limits(_)), "{err}");
}

#[test]
fn invalid_files_error_without_panic() {
    let dir = data("invalid");
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        let r = read(&p);
        assert!(r.is_err(), "{} should be refused", p.display());
        let msg = r.unwrap_err().to_string();
        assert!(
            !msg.is_empty() && !msg.contains('\n'),
            "one-line message for {}: {msg}",
            p.display()
        );
        n += 1;
    }
    assert!(n >= 25, "only {n} invalid files tested");
}

/// A MetaImage header without its `ElementDataFile` line runs into the binary data: the
/// error says what the header lacks.
#[test]
fn a_metaimage_header_without_its_data_line_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("noedf.mha");
    let mut bytes =
        b"ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_FLOAT\n".to_vec();
    bytes.extend([0xff, 0xfe, 0x80, 0x81, 0x00, 0x12, 0x9f, 0xc3]);
    std::fs::write(&p, &bytes).unwrap();
    let msg = read(&p).unwrap_err().to_string();
    assert!(
        msg.contains("ElementDataFile") && !msg.contains('\n'),
        "{msg}"
    );
}

/// A compressed MetaImage's `CompressedDataSize`: the exact size reads; a size past the
/// file's end is refused by name; a size that cuts the stream short is refused as truncated
/// (the size used to go unread, and a wrong one passed).
#[test]
fn metaimage_compressed_data_size_is_checked() {
    use std::io::Write;
    let values: Vec<f32> = (0..8).map(|i| i as f32 * 0.5).collect();
    let raw: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    let mut enc = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    enc.write_all(&raw).unwrap();
    let z = enc.finish().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let file = |size: usize| {
        let p = dir.path().join(format!("z{size}.mha"));
        let mut bytes = format!(
            "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_FLOAT\n\
             CompressedData = True\nCompressedDataSize = {size}\nElementDataFile = LOCAL\n"
        )
        .into_bytes();
        bytes.extend(&z);
        // Trailing bytes after the stream (its declared size ends before them).
        bytes.extend([0u8; 7]);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    let v = read(file(z.len())).unwrap();
    assert_eq!(v.channels()[0].grid.to_f32_vec(), values);
    let past = read(file(z.len() + 100)).unwrap_err().to_string();
    assert!(past.contains("CompressedDataSize"), "{past}");
    let short = read(file(z.len() - 4)).unwrap_err().to_string();
    assert!(!short.contains('\n'), "{short}");
}

/// A zero spacing in an NRRD, MetaImage or VTK header: one line that names the format and
/// the spacing, and says "invalid data" once (it said it twice, the geometry's own error
/// wrapped in the reader's).
#[test]
fn a_zero_spacing_is_refused_in_one_plain_line() {
    let dir = tempfile::tempdir().unwrap();
    let files: [(&str, &str); 3] = [
        (
            "z.nrrd",
            "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\nspacings: 0 1 1\n\
             encoding: raw\nendian: little\n\n",
        ),
        (
            "z.mha",
            "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_FLOAT\n\
             ElementSpacing = 0 1 1\nElementDataFile = LOCAL\n",
        ),
        (
            "z.vtk",
            "# vtk DataFile Version 3.0\nz\nBINARY\nDATASET STRUCTURED_POINTS\n\
             DIMENSIONS 2 2 2\nSPACING 0 1 1\nORIGIN 0 0 0\nPOINT_DATA 8\n\
             SCALARS s float 1\nLOOKUP_TABLE default\n",
        ),
    ];
    for (name, header) in files {
        let p = dir.path().join(name);
        let mut bytes = header.as_bytes().to_vec();
        bytes.extend([0u8; 32]);
        std::fs::write(&p, bytes).unwrap();
        let msg = read(&p).unwrap_err().to_string();
        assert!(
            msg.matches("invalid data").count() == 1 && msg.contains("spacing"),
            "{name}: {msg}"
        );
    }
}

mod mutated_headers {
    //! Property tests: any truncation or byte change in a valid file's header gives Ok or Err,
    //! never a panic, and never a huge allocation (the default limits stay in force).
    use super::*;
    use proptest::prelude::*;

    const FILES: [&str; 8] = [
        "valid/headsq_crop_ascii.nrrd",
        "valid/headsq_crop_be.nrrd",
        "valid/headsq_crop_gzip.nrrd",
        "valid/headsq_crop.mha",
        "valid/headsq_crop_ascii.vtk",
        "valid/carotid_crop_binary.vtk",
        "valid/carotid_crop_vectors.nrrd",
        "valid/headsq_crop.nhdr",
    ];

    fn try_read(file: &str, bytes: &[u8]) {
        let dir = tempfile::tempdir().unwrap();
        // Keep the name (the format is chosen by extension) and the detached data file.
        let p = dir.path().join(Path::new(file).file_name().unwrap());
        std::fs::write(&p, bytes).unwrap();
        let raw = "headsq_crop_16x16x8_int16.raw";
        std::fs::copy(data(&format!("valid/{raw}")), dir.path().join(raw)).unwrap();
        let opts = ReadOptions {
            limits: blueshift_volume::Limits {
                max_voxels: 1 << 22,
                max_alloc_bytes: 1 << 26,
            },
            ..Default::default()
        };
        let _ = read_with(&p, &opts);
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

        #[test]
        fn truncation_never_panics(f in 0..FILES.len(), cut in 0.0f64..1.0) {
            let b = std::fs::read(data(FILES[f])).unwrap();
            let n = (b.len() as f64 * cut) as usize;
            try_read(FILES[f], &b[..n]);
        }

        #[test]
        fn header_byte_changes_never_panic(f in 0..FILES.len(), edits in prop::collection::vec((0usize..400, any::<u8>()), 1..6)) {
            let mut b = std::fs::read(data(FILES[f])).unwrap();
            for (pos, val) in edits {
                let i = pos % b.len().min(400);
                b[i] = val;
            }
            try_read(FILES[f], &b);
        }

        #[test]
        fn header_number_changes_never_panic(f in 0..FILES.len(), which in 0usize..40, num in prop_oneof![
            Just("0".to_string()), Just("-1".to_string()), Just("nan".to_string()), Just("1e39".to_string()),
            Just("18446744073709551616".to_string()), Just("4294967296".to_string()), (0u64..100_000).prop_map(|v| v.to_string())
        ]) {
            let b = std::fs::read(data(FILES[f])).unwrap();
            // Replace the `which`-th run of ASCII digits in the header region with `num`.
            let head_len = b.len().min(400);
            let mut runs = Vec::new();
            let mut i = 0;
            while i < head_len {
                if b[i].is_ascii_digit() {
                    let s = i;
                    while i < head_len && b[i].is_ascii_digit() { i += 1; }
                    runs.push((s, i));
                } else { i += 1; }
            }
            prop_assume!(!runs.is_empty());
            let (s, e) = runs[which % runs.len()];
            let mut out = b[..s].to_vec();
            out.extend_from_slice(num.as_bytes());
            out.extend_from_slice(&b[e..]);
            try_read(FILES[f], &out);
        }
    }
}

#[test]
fn scivis_names_parse_as_documented() {
    use blueshift_volume::io::raw::parse_scivis_name;
    let n = parse_scivis_name(Path::new("skull_256x256x256_uint8.raw")).unwrap();
    assert_eq!(
        (n.dims, n.disk, n.components),
        ([256, 256, 256], DiskType::U8, 1)
    );
    let n = parse_scivis_name(Path::new("/x/velocity_kms_64x64x64x3_f32le.raw")).unwrap();
    assert_eq!(
        (n.dims, n.disk, n.components),
        ([64, 64, 64], DiskType::F32, 3)
    );
    let n = parse_scivis_name(Path::new("ct_512x512x100_int16.raw")).unwrap();
    assert_eq!((n.disk, n.endian), (DiskType::I16, Endian::Little));
    let n = parse_scivis_name(Path::new("ct_512x512x100_int16be.raw")).unwrap();
    assert_eq!((n.disk, n.endian), (DiskType::I16, Endian::Big));
    // `double` ends in "le" but is a type, not `doub` little-endian.
    for (name, endian) in [
        ("d_2x2x2_double.raw", Endian::Little),
        ("d_2x2x2_doublele.raw", Endian::Little),
        ("d_2x2x2_doublebe.raw", Endian::Big),
    ] {
        let n = parse_scivis_name(Path::new(name)).unwrap();
        assert_eq!((n.disk, n.endian), (DiskType::F64, endian), "{name}");
    }
    for bad in [
        "skull.raw",
        "a_256x256_uint8.raw",
        "a_0x2x2_uint8.raw",
        "a_2x2x2_complex.raw",
        "a_2x2x2_uint8.nrrd",
    ] {
        assert!(parse_scivis_name(Path::new(bad)).is_none(), "{bad}");
    }
}

proptest::proptest! {
    #[test]
    fn scivis_name_parsing_never_panics(name in "[a-z0-9_x.]{0,40}") {
        let _ = blueshift_volume::io::raw::parse_scivis_name(Path::new(&name));
    }
}

#[test]
fn staged_reader_selects_channels_in_order() {
    let v = io::reader(data("valid/carotid_crop_binary.vtk"))
        .channels(["vectors", "scalars"])
        .load()
        .unwrap();
    let names: Vec<&str> = v.channels().iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["vectors", "scalars"]);
    let err = io::reader(data("valid/carotid_crop_binary.vtk"))
        .channels(["density"])
        .load()
        .unwrap_err();
    assert!(
        err.to_string().contains("channels: scalars, vectors"),
        "{err}"
    );
}

/// A detached header records its data file's size and checksum (`blueshift data:=`), so a
/// header beside another write's data file of the same size (a writer killed between its
/// two renames) is refused; a header without the line (any other writer's) reads as before.
#[test]
fn detached_header_refuses_a_data_file_it_was_not_written_with() {
    let dir = tempfile::tempdir().unwrap();
    let write = |seed: u64, stem: &str| {
        let v = blueshift_volume::synth::by_name("turbulence", 8, seed).unwrap();
        let (mut h, mut d) = (Vec::new(), Vec::new());
        let data_name = format!("{stem}.raw");
        nrrd::write_detached(
            &mut h,
            &mut d,
            &data_name,
            &v.channels()[0],
            &Default::default(),
        )
        .unwrap();
        std::fs::write(dir.path().join(format!("{stem}.nhdr")), &h).unwrap();
        std::fs::write(dir.path().join(&data_name), &d).unwrap();
        String::from_utf8(h).unwrap()
    };
    let a = write(1, "a");
    write(2, "b");
    let path = dir.path().join("a.nhdr");
    assert!(read(&path).is_ok());
    std::fs::copy(dir.path().join("b.raw"), dir.path().join("a.raw")).unwrap();
    let err = read(&path).unwrap_err().to_string();
    assert!(err.contains("does not match its header"), "{err}");
    let plain: String = a
        .lines()
        .filter(|l| !l.starts_with("blueshift data:="))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(&path, plain).unwrap();
    assert!(read(&path).is_ok());
}

/// A gzip NRRD whose CRC-32 does not match its data, or whose stream holds more than its
/// sizes declare, is refused by the in-core reader and by the streaming converter's source
/// (gzip verifies its CRC only at the end of the stream, after the last voxel is read).
#[test]
fn gzip_nrrd_with_a_wrong_crc_or_extra_data_is_refused() {
    use std::io::Write;
    let good = std::fs::read(data("valid/headsq_crop_gzip.nrrd")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let check = |name: &str, bytes: &[u8], needle: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        let e = read(&p).unwrap_err().to_string();
        assert!(e.contains(needle), "{name}: {e}");
        let mut src = blueshift_volume::ooc::GzipFileSource::probe(&p)
            .unwrap()
            .unwrap();
        let [nx, ny, nz] = blueshift_volume::ooc::SlabSource::geometry(&src).dims;
        let mut slice = vec![0f32; nx * ny];
        let got: Result<Vec<()>, _> = (0..nz)
            .map(|z| blueshift_volume::ooc::SlabSource::read_slice(&mut src, z, &mut slice))
            .collect();
        let e = got.unwrap_err().to_string();
        assert!(e.contains(needle), "{name} streamed: {e}");
    };
    // The gzip trailer is the CRC-32 of the data, then its length: change the CRC.
    let mut bad_crc = good.clone();
    let at = bad_crc.len() - 8;
    bad_crc[at] ^= 0x5a;
    check("crc.nrrd", &bad_crc, "corrupt");
    // A second gzip member after the first: more data than 16 x 16 x 8 int16 values.
    let mut more = good.clone();
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    enc.write_all(&[7u8; 64]).unwrap();
    more.extend(enc.finish().unwrap());
    check("more.nrrd", &more, "more bytes than the header");
    // The file unchanged reads, and so does it with bytes after its gzip stream that are
    // not another member (padding, a newline), which gzip ignores: the same voxels.
    let p = dir.path().join("good.nrrd");
    std::fs::write(&p, &good).unwrap();
    let want = read(&p).unwrap();
    for tail in [&b"\n"[..], &[0u8; 4][..]] {
        let mut padded = good.clone();
        padded.extend_from_slice(tail);
        std::fs::write(&p, &padded).unwrap();
        assert_eq!(
            scalars(&read(&p).unwrap(), 0),
            scalars(&want, 0),
            "{tail:?}"
        );
    }
}

/// A `.raw` file whose name does not give its volume (a size of 0, no type) says what the
/// name must hold, not that the format is unknown.
#[test]
fn a_raw_file_misnamed_says_what_its_name_must_hold() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["a_0x32x32_float32.raw", "b_4x4x4.raw", "c.RAW"] {
        let p = dir.path().join(name);
        std::fs::write(&p, [0u8; 64]).unwrap();
        let e = read(&p).unwrap_err().to_string();
        assert!(
            e.contains("name_XxYxZ_type.raw") && e.contains("--raw-dims"),
            "{name}: {e}"
        );
    }
}

/// A float64 voxel beyond f32's range is refused in one line by the in-core reader and the
/// streaming converter's source, instead of becoming an infinity the file does not hold.
#[test]
fn float64_values_beyond_f32_are_refused_not_made_infinite() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("big_5x1x1_double.raw");
    let vals = [1.0f64, 0.1, 1e300, -1e-300, 3.0];
    std::fs::write(
        &p,
        vals.iter()
            .flat_map(|v| v.to_le_bytes())
            .collect::<Vec<_>>(),
    )
    .unwrap();
    let e = read(&p).unwrap_err().to_string();
    assert!(e.contains("1e300") && e.contains("beyond the range"), "{e}");
    let mut src = blueshift_volume::ooc::RawFileSource::probe(&p)
        .unwrap()
        .unwrap();
    let mut slice = vec![0f32; 5];
    let e = blueshift_volume::ooc::SlabSource::read_slice(&mut src, 0, &mut slice)
        .unwrap_err()
        .to_string();
    assert!(e.contains("beyond the range"), "{e}");
    // In range, the values are read (rounded to f32; -1e-300 underflows to -0).
    let q = dir.path().join("ok_5x1x1_double.raw");
    let ok = [1.0f64, 0.1, 1e30, -1e-300, 3.0];
    std::fs::write(
        &q,
        ok.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<_>>(),
    )
    .unwrap();
    let want: Vec<f32> = ok.iter().map(|&v| v as f32).collect();
    assert_eq!(scalars(&read(&q).unwrap(), 0), want);
}

/// ASCII values their declared type cannot hold are refused in one line (they were rounded
/// or clamped: `300` in a `uchar` NRRD read as 255); values it holds read as written.
#[test]
fn ascii_values_outside_their_type_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let nrrd = |ty: &str, vals: &str| {
        let p = dir.path().join("a.nrrd");
        std::fs::write(
            &p,
            format!(
                "NRRD0004\ntype: {ty}\ndimension: 3\nsizes: 2 1 1\nencoding: ascii\n\n{vals}\n"
            ),
        )
        .unwrap();
        read(&p)
    };
    let vtk = |ty: &str, vals: &str| {
        let p = dir.path().join("a.vtk");
        std::fs::write(
            &p,
            format!(
                "# vtk DataFile Version 3.0\nt\nASCII\nDATASET STRUCTURED_POINTS\nDIMENSIONS 2 1 1\n\
                 SPACING 1 1 1\nORIGIN 0 0 0\nPOINT_DATA 2\nSCALARS s {ty} 1\nLOOKUP_TABLE default\n{vals}\n"
            ),
        )
        .unwrap();
        read(&p)
    };
    for (ty, vals) in [
        ("uchar", "3 300"),
        ("signed char", "-200 3"),
        ("short", "1 2.5"),
    ] {
        let e = nrrd(ty, vals).unwrap_err().to_string();
        assert!(e.contains("is not a"), "{ty} {vals}: {e}");
    }
    let e = nrrd("float", "1 1e39").unwrap_err().to_string();
    assert!(e.contains("'1e39'"), "{e}");
    assert_eq!(
        scalars(&nrrd("uchar", "3 255").unwrap(), 0),
        vec![3.0, 255.0]
    );
    assert_eq!(
        scalars(&nrrd("short", "-7 2.0").unwrap(), 0),
        vec![-7.0, 2.0]
    );
    let e = vtk("unsigned_char", "1 999").unwrap_err().to_string();
    assert!(e.contains("VTK") && e.contains("'999'"), "{e}");
    assert_eq!(
        scalars(&vtk("unsigned_char", "1 200").unwrap(), 0),
        vec![1.0, 200.0]
    );
}

/// Data arrays of one name get suffixes `_2`, `_3`, ... in order (in time linear in their
/// number), and a file with more arrays than the reader takes is refused.
#[test]
fn vtk_repeated_array_names_get_numbered_and_their_count_is_capped() {
    let dir = tempfile::tempdir().unwrap();
    let file = |n: usize| {
        let mut s = String::from(
            "# vtk DataFile Version 3.0\nx\nASCII\nDATASET STRUCTURED_POINTS\nDIMENSIONS 1 1 1\n\
             ORIGIN 0 0 0\nSPACING 1 1 1\nPOINT_DATA 1\n",
        );
        for k in 0..n {
            s.push_str(&format!("SCALARS a float\nLOOKUP_TABLE default\n{k}\n"));
        }
        let p = dir.path().join(format!("m{n}.vtk"));
        std::fs::write(&p, s).unwrap();
        p
    };
    let v = blueshift_volume::read(file(4)).unwrap();
    let names: Vec<&str> = v.channels().iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["a", "a_2", "a_3", "a_4"]);
    let e = blueshift_volume::read(file(4097)).unwrap_err();
    assert!(matches!(e, blueshift_volume::Error::Limits(_)), "{e}");
}

/// A header whose spacing or direction along an axis is negative stores that axis from high
/// to low coordinate. Every reader, in core and streamed for the converter, must give each
/// voxel the value the file holds for its world position (here an analytic function of the
/// position the header assigns to each stored voxel), so the volume is not mirrored.
#[test]
fn negative_axis_directions_keep_every_voxel_at_its_world_position() {
    use blueshift_volume::ooc::{GzipFileSource, RawFileSource, SlabSource};
    use std::io::Write;
    let dims = [5usize, 4, 3];
    let f = |p: Vec3| 100.0 * p.x + 10.0 * p.y + p.z;
    // The stored values, file order, for voxel 0 at `origin` and `signed` spacing per axis.
    let stored = |origin: Vec3, signed: Vec3| -> Vec<f32> {
        let mut v = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    v.push(f(origin + Vec3::new(i as f32, j as f32, k as f32) * signed));
                }
            }
        }
        v
    };
    let le = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
    let gz = |b: &[u8]| {
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        e.write_all(b).unwrap();
        e.finish().unwrap()
    };
    // Checks a loaded grid's values (x fastest, as loaded) against f at each voxel's world
    // position, and that its spacing is positive with the volume where the file put it.
    let check = |g: &Geometry, values: &[f32], what: &str| {
        assert!(g.spacing.min_element() > 0.0, "{what}: {g:?}");
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let p = g.origin + Vec3::new(i as f32, j as f32, k as f32) * g.spacing;
                    let got = values[i + dims[0] * (j + dims[1] * k)];
                    assert!(
                        (got - f(p)).abs() < 1e-3,
                        "{what}: voxel {i},{j},{k} at {p} holds {got}, the file says {}",
                        f(p)
                    );
                }
            }
        }
    };
    use blueshift_volume::Geometry;
    let dir = tempfile::tempdir().unwrap();
    let o = Vec3::new(1.0, -2.0, 0.5);
    // (name, header, voxel bytes, origin, signed spacing)
    let nrrd = |dirs: &str, origin: &str, enc: &str| {
        format!(
            "NRRD0004\ntype: float\ndimension: 3\nsizes: 5 4 3\nendian: little\n\
             encoding: {enc}\n{dirs}\n{origin}\n"
        )
        .replace("\n\n", "\n")
            + "\n"
    };
    let cases: Vec<(&str, String, bool, Vec3, Vec3)> = vec![
        (
            "dirs.nrrd",
            nrrd(
                "space directions: (-0.5,0,0) (0,2,0) (0,0,-1)",
                "space origin: (1,-2,0.5)",
                "raw",
            ),
            false,
            o,
            Vec3::new(-0.5, 2.0, -1.0),
        ),
        (
            "spacings.nrrd",
            nrrd("spacings: 0.5 -2 1", "", "raw"),
            false,
            Vec3::ZERO,
            Vec3::new(0.5, -2.0, 1.0),
        ),
        (
            "xy.nrrd",
            nrrd(
                "space directions: (-0.5,0,0) (0,-2,0) (0,0,1)",
                "space origin: (1,-2,0.5)",
                "gzip",
            ),
            true,
            o,
            Vec3::new(-0.5, -2.0, 1.0),
        ),
        (
            "z.nrrd",
            nrrd(
                "space directions: (0.5,0,0) (0,2,0) (0,0,-1)",
                "space origin: (1,-2,0.5)",
                "gzip",
            ),
            true,
            o,
            Vec3::new(0.5, 2.0, -1.0),
        ),
        (
            "flip.mha",
            "ObjectType = Image\nNDims = 3\nDimSize = 5 4 3\nElementType = MET_FLOAT\n\
             ElementSpacing = 0.5 2 1\nOffset = 1 -2 0.5\n\
             TransformMatrix = -1 0 0 0 1 0 0 0 -1\nElementDataFile = LOCAL\n"
                .to_string(),
            false,
            o,
            Vec3::new(-0.5, 2.0, -1.0),
        ),
    ];
    for (name, header, gzip, origin, signed) in &cases {
        let values = stored(*origin, *signed);
        let payload = if *gzip { gz(&le(&values)) } else { le(&values) };
        let p = dir.path().join(name);
        std::fs::write(&p, [header.as_bytes(), &payload].concat()).unwrap();
        let v = read(&p).unwrap();
        let g = *v.geometry();
        check(&g, &scalars(&v, 0), name);
        // The converter's streamed sources give the same slices.
        let raw = RawFileSource::probe(&p).unwrap();
        let streamed: Option<Box<dyn SlabSource>> = match raw {
            Some(s) => Some(Box::new(s)),
            None => GzipFileSource::probe(&p)
                .unwrap()
                .map(|s| Box::new(s) as Box<dyn SlabSource>),
        };
        match streamed {
            Some(mut s) => {
                assert_eq!(s.geometry(), g, "{name}");
                let mut all = vec![0f32; dims[0] * dims[1] * dims[2]];
                for (z, out) in all.chunks_exact_mut(dims[0] * dims[1]).enumerate() {
                    s.read_slice(z, out).unwrap();
                }
                check(&g, &all, &format!("{name} streamed"));
            }
            // A reversed z axis in a gzip stream is read in core.
            None => assert!(*name == "z.nrrd", "{name} did not stream"),
        }
    }
    // Directions in centimetres (1e21) and at 1e-25: their squares over- and underflow f32.
    for v in ["1e21", "-1e21", "1e-25"] {
        let p = dir.path().join("cm.nrrd");
        let header = nrrd(
            &format!("space directions: ({v},0,0) (0,{v},0) (0,0,{v})"),
            "space origin: (0,0,0)",
            "raw",
        );
        std::fs::write(
            &p,
            [header.as_bytes(), &le(&stored(Vec3::ZERO, Vec3::ONE))].concat(),
        )
        .unwrap();
        let g = *read(&p).unwrap().geometry();
        let want: f32 = v.trim_start_matches('-').parse().unwrap();
        assert!(
            (g.spacing - Vec3::splat(want)).abs().max_element() <= want * 1e-6,
            "{v}: {g:?}"
        );
    }
    // VTK (big-endian binary) with a negative SPACING, scalars and vectors.
    let signed = Vec3::new(-0.5, 2.0, -1.0);
    let values = stored(o, signed);
    let mut vtk = b"# vtk DataFile Version 3.0\nflip\nBINARY\nDATASET STRUCTURED_POINTS\n\
        DIMENSIONS 5 4 3\nSPACING -0.5 2 -1\nORIGIN 1 -2 0.5\nPOINT_DATA 60\n\
        SCALARS s float 1\nLOOKUP_TABLE default\n"
        .to_vec();
    vtk.extend(values.iter().flat_map(|x| x.to_be_bytes()));
    vtk.extend(b"\nVECTORS v float\n");
    vtk.extend(
        values
            .iter()
            .flat_map(|x| [*x, 2.0 * x, -x])
            .flat_map(|x| x.to_be_bytes()),
    );
    vtk.push(b'\n');
    let p = dir.path().join("flip.vtk");
    std::fs::write(&p, vtk).unwrap();
    let v = read(&p).unwrap();
    let g = *v.geometry();
    check(&g, &scalars(&v, 0), "vtk scalars");
    // A vector's components are world components: reordering voxels leaves them as they are.
    let vecs = vectors(&v, "v");
    for c in 0..3 {
        let comp: Vec<f32> = vecs.iter().skip(c).step_by(3).copied().collect();
        let scale = [1.0, 2.0, -1.0][c];
        let unscaled: Vec<f32> = comp.iter().map(|x| x / scale).collect();
        check(&g, &unscaled, &format!("vtk vector component {c}"));
    }
}

/// A header field given twice leaves which value was meant unknown (NRRD's format calls it
/// an error), and an NRRD colour axis is not a vector: all are refused with one line.
#[test]
fn repeated_header_fields_and_colour_axes_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let voxels = vec![0u8; 2 * 2 * 2 * 3];
    let cases: [(&str, &str, &str); 8] = [
        (
            "both.nrrd",
            "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nspacings: 1 1 1\n\
             space directions: (2,0,0) (0,2,0) (0,0,2)\nencoding: raw\n\n",
            "both 'spacings' and 'space directions'",
        ),
        (
            "rgb3.nrrd",
            "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\n\
             kinds: domain domain RGB-color\nencoding: raw\n\n",
            "colour",
        ),
        (
            "kinds.nrrd",
            "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nkinds: domain domain\n\
             encoding: raw\n\n",
            "kinds has 2 entries",
        ),
        (
            "twice.nrrd",
            "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nsizes: 4 1 2\nencoding: raw\n\n",
            "given twice",
        ),
        (
            "alias.nrrd",
            "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nbyte skip: 0\nbyteskip: 0\n\
             encoding: raw\n\n",
            "given twice",
        ),
        (
            "rgb.nrrd",
            "NRRD0004\ntype: uchar\ndimension: 4\nsizes: 3 2 2 2\n\
             kinds: RGB-color domain domain domain\nencoding: raw\n\n",
            "colour",
        ),
        (
            "twice.mha",
            "NDims = 3\nDimSize = 2 2 2\nDimSize = 4 1 2\nElementType = MET_UCHAR\n\
             ElementDataFile = LOCAL\n",
            "given twice",
        ),
        (
            "alias.mha",
            "NDims = 3\nDimSize = 2 2 2\nOffset = 0 0 0\nOrigin = 1 0 0\n\
             ElementType = MET_UCHAR\nElementDataFile = LOCAL\n",
            "given twice",
        ),
    ];
    for (name, header, want) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, [header.as_bytes(), &voxels].concat()).unwrap();
        let e = read(&p).unwrap_err().to_string();
        assert!(e.contains(want), "{name}: {e}");
    }
    // The same headers without the repeat read.
    let p = dir.path().join("once.nrrd");
    std::fs::write(
        &p,
        [
            b"NRRD0004\ntype: uchar\ndimension: 4\nsizes: 3 2 2 2\n\
              kinds: 3-vector domain domain domain\nencoding: raw\n\n"
                .as_slice(),
            &voxels,
        ]
        .concat(),
    )
    .unwrap();
    read(&p).unwrap();
}
