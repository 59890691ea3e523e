//! Every WGSL file in `gpu/src/shaders/` parses and validates with naga (the same naga
//! wgpu uses), so a shader error fails the tests and not a user's run. Files that call the
//! loop-limiter probe are validated with `limiter.wgsl` prepended, those that sample the
//! brick pool with `pool.wgsl` appended, and `doppler.wgsl` with
//! each of its precision preludes, as the crate compiles them. Every `Pod` struct the crate
//! uploads into a WGSL struct has the size and member offsets naga lays that struct out with.

use std::path::Path;

fn validate(path: &Path) -> Result<(), String> {
    let mut src = std::fs::read_to_string(path).map_err(|e| e.to_string())?;
    // Shaders that sample the brick pool get its lookup appended, as the crate compiles
    // them; the lookup alone gets the bindings its includers declare.
    if src.contains("pool_fetch(") && !src.contains("fn pool_fetch") {
        src.push_str(blueshift_gpu::pool::POOL_WGSL);
    }
    if path.ends_with("pool.wgsl") {
        src = format!(
            "@group(0) @binding(0) var<storage, read> pool: array<f32>;\n\
             @group(0) @binding(1) var<storage, read> pages: array<vec2<u32>>;\n{src}"
        );
    }
    // Shaders that call the loop-limiter probe get it prepended, as the crate compiles them.
    if src.contains("limiter_exhausted(") && !src.contains("fn limiter_exhausted") {
        return validate_source(&format!("{}{src}", blueshift_gpu::LIMITER_WGSL));
    }
    validate_source(&src)
}

fn validate_source(src: &str) -> Result<(), String> {
    let src = src.to_string();
    let module = naga::front::wgsl::parse_str(&src).map_err(|e| e.emit_to_string(&src))?;
    // All capabilities: f16 / f64 shaders are validated too (the context only loads them
    // where the adapter has the feature).
    let mut validator = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::all(),
    );
    validator
        .validate(&module)
        .map_err(|e| e.emit_to_string(&src))?;
    Ok(())
}

#[test]
fn every_wgsl_shader_validates() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/shaders");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .expect("shaders folder")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "wgsl"))
        // The Doppler body needs its prelude (the working float `fw`): checked below.
        .filter(|p| !p.ends_with("doppler.wgsl"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no .wgsl files in {}", dir.display());
    let failures: Vec<String> = files
        .iter()
        .filter_map(|p| validate(p).err().map(|e| format!("{}:\n{e}", p.display())))
        .collect();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn the_doppler_shader_validates_in_both_precisions() {
    for double in [false, true] {
        let src = blueshift_gpu::doppler::shader_source(double);
        if let Err(e) = validate_source(&src) {
            panic!(
                "doppler.wgsl with the {} prelude:\n{e}",
                if double { "f64" } else { "f32" }
            );
        }
    }
    // Without a prelude the body does not compile (`fw` is undefined): the check can fail.
    assert!(validate_source(blueshift_gpu::doppler::DOPPLER_WGSL).is_err());
}

/// What is wrong with `layout` against naga's layout of its WGSL struct (nothing: empty).
fn layout_mismatches(layout: &blueshift_gpu::layout::PodLayout) -> Vec<String> {
    let what = format!("{} -> {} in {}", layout.rust, layout.wgsl, layout.shader);
    let module = match naga::front::wgsl::parse_str(&layout.source) {
        Ok(m) => m,
        Err(e) => return vec![format!("{what}: {}", e.emit_to_string(&layout.source))],
    };
    let mut layouter = naga::proc::Layouter::default();
    if let Err(e) = layouter.update(module.to_ctx()) {
        return vec![format!("{what}: naga's layouter failed: {e}")];
    }
    let Some((handle, members)) = module.types.iter().find_map(|(h, ty)| match &ty.inner {
        naga::TypeInner::Struct { members, .. } if ty.name.as_deref() == Some(layout.wgsl) => {
            Some((h, members))
        }
        _ => None,
    }) else {
        return vec![format!("{what}: no struct {} in the shader", layout.wgsl)];
    };
    let mut bad = Vec::new();
    let span = layouter[handle].size as usize;
    if span != layout.size {
        bad.push(format!(
            "{what}: size {} in Rust, span {span} in WGSL",
            layout.size
        ));
    }
    for (name, offset) in &layout.fields {
        match members.iter().find(|m| m.name.as_deref() == Some(*name)) {
            None => bad.push(format!("{what}: no member `{name}` in the WGSL struct")),
            Some(m) if m.offset as usize != *offset => bad.push(format!(
                "{what}: `{name}` at offset {offset} in Rust, {} in WGSL",
                m.offset
            )),
            Some(_) => {}
        }
    }
    for m in members {
        let name = m.name.as_deref().unwrap_or("?");
        let n = layout.fields.iter().filter(|(f, _)| *f == name).count();
        if n != 1 {
            bad.push(format!(
                "{what}: WGSL member `{name}` (offset {}) is filled by {n} Rust fields",
                m.offset
            ));
        }
    }
    bad
}

#[test]
fn every_uploaded_pod_struct_has_the_wgsl_layout() {
    let layouts = blueshift_gpu::layout::pod_layouts();
    let failures: Vec<String> = layouts.iter().flat_map(layout_mismatches).collect();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // Every shader with a uniform is covered (a new one must be added to `pod_layouts`), and
    // the check can fail.
    let shaders: std::collections::BTreeSet<_> = layouts
        .iter()
        .map(|l| l.shader.split(' ').next().unwrap())
        .collect();
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/shaders");
    for entry in std::fs::read_dir(&dir).expect("shaders folder") {
        let path = entry.expect("shaders folder entry").path();
        let src = std::fs::read_to_string(&path).unwrap_or_default();
        let name = path.file_name().unwrap().to_string_lossy();
        if src.contains("var<uniform>") {
            assert!(
                shaders.contains(&*name),
                "{name} has a uniform but no Pod layout checked against it"
            );
        }
    }
    let mut wrong = layouts[0].clone();
    wrong.size += 4;
    let (first, second) = (wrong.fields[0].1, wrong.fields[1].1);
    (wrong.fields[0].1, wrong.fields[1].1) = (second, first);
    wrong.fields.push(("no_such_member", 0));
    let found = layout_mismatches(&wrong);
    assert_eq!(found.len(), 4, "{found:#?}");
}

#[test]
fn the_validator_rejects_a_broken_shader() {
    // The check above can fail: a type error is caught.
    let dir = tempfile_dir();
    let p = dir.join("broken.wgsl");
    std::fs::write(
        &p,
        "@compute @workgroup_size(1) fn main() { let x: f32 = 1u; }",
    )
    .unwrap();
    assert!(validate(&p).is_err());
    std::fs::remove_dir_all(&dir).ok();
}

fn tempfile_dir() -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("blueshift-gpu-naga-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}
