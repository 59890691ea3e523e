//! The context on a real adapter (lavapipe in CI): a dispatch computes what the CPU does,
//! and every failure is a typed error.

use blueshift_gpu::Error;
use blueshift_gpu::context::test_context;

#[test]
fn scale_matches_the_cpu() {
    let Some(ctx) = test_context() else { return };
    let x: Vec<f32> = (0..1000).map(|i| i as f32 * 0.25 - 7.0).collect();
    let y = blueshift_gpu::scale(ctx, &x, 1.5, -2.0).unwrap();
    assert_eq!(y.len(), x.len());
    for (xi, yi) in x.iter().zip(&y) {
        // a*x+b with exactly representable inputs: FMA or not, the result is exact.
        assert_eq!(*yi, 1.5 * xi - 2.0);
    }
}

#[test]
fn report_names_the_adapter() {
    let Some(ctx) = test_context() else { return };
    let r = ctx.report();
    assert!(!r.name.is_empty());
    assert!(
        r.limits
            .iter()
            .any(|(n, v)| n == "max_storage_buffer_binding_size" && *v > 0)
    );
    assert_eq!(r.hardware, ctx.is_hardware());
}

#[test]
fn an_absurd_buffer_is_refused_naming_the_limit() {
    let Some(ctx) = test_context() else { return };
    let err = ctx.storage_buffer_zeroed("huge", u64::MAX / 2).unwrap_err();
    match err {
        Error::LimitExceeded { limit, .. } => assert!(limit.starts_with("max_")),
        other => panic!("expected LimitExceeded, got {other}"),
    }
}

#[test]
fn a_broken_shader_is_a_validation_error_not_a_panic() {
    let Some(ctx) = test_context() else { return };
    let err = ctx
        .compute_pipeline(
            "broken",
            "@compute @workgroup_size(1) fn main() { let x: f32 = 1u; }",
            "main",
        )
        .unwrap_err();
    assert!(matches!(err, Error::Validation(_)), "{err}");
    // The device is still usable afterwards.
    let y = blueshift_gpu::scale(ctx, &[1.0, 2.0], 2.0, 0.0).unwrap();
    assert_eq!(y, vec![2.0, 4.0]);
}

#[test]
fn too_many_workgroups_is_a_limit_error() {
    let Some(ctx) = test_context() else { return };
    let err = ctx.groups("test", u32::MAX, 1).unwrap_err();
    assert!(
        matches!(
            err,
            Error::LimitExceeded {
                limit: "max_compute_workgroups_per_dimension",
                ..
            }
        ),
        "{err}"
    );
}

#[test]
fn forcing_a_missing_adapter_name_is_no_adapter() {
    let opts = blueshift_gpu::GpuOptions::with_adapter(blueshift_gpu::AdapterChoice::Name(
        "no-such-adapter-xyz".into(),
    ));
    let err = blueshift_gpu::GpuContext::new(opts).unwrap_err();
    assert!(matches!(err, Error::NoAdapter(_)), "{err}");
}

#[test]
fn a_destroyed_device_is_a_typed_error_not_a_panic_or_a_hang() {
    if test_context().is_none() {
        return;
    }
    // A private context (the shared one stays usable for the other tests).
    let ctx = blueshift_gpu::GpuContext::new(blueshift_gpu::GpuOptions::default()).unwrap();
    assert_eq!(
        blueshift_gpu::scale(&ctx, &[1.0, 2.0], 2.0, 0.0).unwrap(),
        vec![2.0, 4.0]
    );
    ctx.device().destroy();
    let err = blueshift_gpu::scale(&ctx, &[1.0, 2.0], 2.0, 0.0).unwrap_err();
    assert!(matches!(err, Error::DeviceLost(_)), "{err}");
    // Once lost, every later call says so.
    let again = blueshift_gpu::scale(&ctx, &[3.0], 1.0, 0.0).unwrap_err();
    assert!(matches!(again, Error::DeviceLost(_)), "{again}");
}

#[test]
fn a_pipeline_is_compiled_once_per_context() {
    if test_context().is_none() {
        return;
    }
    // A private context: its cache holds only what this test compiles.
    let ctx = blueshift_gpu::GpuContext::new(blueshift_gpu::GpuOptions::default()).unwrap();
    assert_eq!(ctx.cached_pipelines(), 0);
    assert_eq!(
        blueshift_gpu::scale(&ctx, &[1.0], 2.0, 1.0).unwrap(),
        vec![3.0]
    );
    assert_eq!(ctx.cached_pipelines(), 1);
    // The same source and entry again: the cached pipeline, which still computes.
    assert_eq!(
        blueshift_gpu::scale(&ctx, &[2.0], 2.0, 1.0).unwrap(),
        vec![5.0]
    );
    assert_eq!(ctx.cached_pipelines(), 1);
    // Another source is another pipeline; a broken one is an error and is not kept.
    let other = blueshift_gpu::SCALE_WGSL.replace("params.a * x[i]", "params.a * x[i] * 2.0");
    ctx.compute_pipeline("scale x2", &other, "main").unwrap();
    assert_eq!(ctx.cached_pipelines(), 2);
    assert!(ctx.compute_pipeline("broken", "fn main(", "main").is_err());
    assert_eq!(ctx.cached_pipelines(), 2);
}
