//! `benches/scripts/gpu_bench.sh report`: criterion's JSON to the CSV and table that the
//! device runs bring back, on a made-up criterion folder (no adapter, no bench build). The
//! script's whole run on lavapipe (`gpu_bench.sh check`) is a step of `.ci/run`.
#![cfg(unix)]

use std::path::Path;
use std::process::Command;

/// Writes one benchmark the way criterion 0.8 does: `<dir>/new/{benchmark,estimates,sample}.json`.
fn bench(root: &Path, dir: &str, group: &str, function: &str, mean_ns: f64, sample: &str) {
    let new = root.join(dir).join("new");
    std::fs::create_dir_all(&new).unwrap();
    std::fs::write(
        new.join("benchmark.json"),
        format!(
            r#"{{"group_id":"{group}","function_id":"{function}","value_str":null,"throughput":null,"full_id":"{group}/{function}","directory_name":"{dir}","title":"{group}/{function}"}}"#
        ),
    )
    .unwrap();
    let est = |p: f64| {
        format!(
            r#"{{"confidence_interval":{{"confidence_level":0.95,"lower_bound":{},"upper_bound":{}}},"point_estimate":{p},"standard_error":1.5e-3}}"#,
            0.9 * p,
            1.1 * p
        )
    };
    std::fs::write(
        new.join("estimates.json"),
        format!(
            r#"{{"mean":{},"median":{},"median_abs_dev":{},"slope":null,"std_dev":{}}}"#,
            est(mean_ns),
            est(mean_ns * 0.98),
            est(1.0),
            est(2.0)
        ),
    )
    .unwrap();
    std::fs::write(new.join("sample.json"), sample).unwrap();
}

const TEN: &str = r#"{"sampling_mode":"Linear","iters":[1.0,2.0,3.0,4.0,5.0,6.0,7.0,8.0,9.0,10.0],"times":[1,2,3,4,5,6,7,8,9,10]}"#;
/// criterion's `--quick` on a call slower than its measurement time: one call, reported twice.
const ONE: &str =
    r#"{"sampling_mode":"Flat","iters":[1.0,1.0],"times":[78933000000.0,78933000000.00002]}"#;

fn report(criterion: &Path, out: &Path) -> std::process::Output {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../benches/scripts/gpu_bench.sh");
    Command::new("bash")
        .arg(script)
        .arg("report")
        .arg(criterion)
        .arg(out)
        .output()
        .expect("bash runs")
}

#[test]
fn report_turns_criterion_json_into_one_csv_and_a_table() {
    let tmp = tempfile::tempdir().unwrap();
    let (crit, out) = (tmp.path().join("criterion"), tmp.path().join("out"));
    let paper = "tracking_paper";
    bench(
        &crit,
        "tracking_paper/mdwt-1dda-512x4-2560x1440_no-shadows",
        paper,
        "mdwt-1dda-512x4-2560x1440/no-shadows",
        4.0e6,
        TEN,
    );
    bench(
        &crit,
        "tracking_paper/mdwt-1dda-256-channels_10",
        paper,
        "mdwt-1dda-256-channels/10",
        8.0e6,
        TEN,
    );
    bench(
        &crit,
        "tracking_paper/mdwt-1dda-256-channels_2",
        paper,
        "mdwt-1dda-256-channels/2",
        5.0e6,
        TEN,
    );
    // The group's name carries the adapter's, and so its folder: a path with spaces.
    let table1 = "doppler_table1 (NVIDIA H200)";
    bench(
        &crit,
        "doppler_table1 (NVIDIA H200)/gpu_f64_galaxy_H_C_He_doppler_on",
        table1,
        "gpu_f64/galaxy_H_C_He_doppler_on",
        78_933e6,
        ONE,
    );
    bench(
        &crit,
        "tonemap_small/drago_cpu",
        "tonemap_small",
        "drago_cpu",
        5.0e6,
        TEN,
    );
    bench(
        &crit,
        "tonemap_small/drago_gpu",
        "tonemap_small",
        "drago_gpu",
        7.5e6,
        TEN,
    );
    bench(
        &crit,
        "pool/upload_dense",
        "pool",
        "upload/dense",
        2.0e7,
        TEN,
    );

    let o = report(&crit, &out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(out.join("gpu_bench.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
    assert_eq!(
        rows[0].join(","),
        "group,bench,mean_ms,ci_low_ms,ci_high_ms,median_ms,calls,fps,gpu_over_cpu,sampling,adapter"
    );
    assert_eq!(rows.len(), 8, "{csv}");
    let row = |bench: &str| {
        rows.iter()
            .find(|r| r[1] == bench)
            .unwrap_or_else(|| panic!("{csv}"))
    };
    let r = row("mdwt-1dda-512x4-2560x1440/no-shadows");
    assert_eq!(
        r[..8],
        [paper, r[1], "4", "3.6", "4.4", "3.92", "55", "250"]
    );
    let r = row("gpu_f64/galaxy_H_C_He_doppler_on");
    assert_eq!(r[0], "doppler_table1");
    assert_eq!((r[2], r[6]), ("78933", "1"));
    assert_eq!(row("drago_gpu")[8], "1.5");
    assert_eq!(row("drago_cpu")[8], "");
    assert_eq!(row("upload/dense")[7], "", "an upload is no frame");
    // Channel counts in numeric order.
    let order: Vec<&str> = rows.iter().map(|r| r[1]).collect();
    let pos = |b: &str| order.iter().position(|x| *x == b).unwrap();
    assert!(pos("mdwt-1dda-256-channels/2") < pos("mdwt-1dda-256-channels/10"));
    let md = std::fs::read_to_string(out.join("gpu_bench.md")).unwrap();
    assert!(md.contains("| 250 |  | 291 FPS (RTX 4090, NYX) |"), "{md}");
    assert!(md.contains("78933 ms (Titan RTX)"), "{md}");
}

#[test]
fn report_fails_without_results_or_on_a_time_that_is_no_positive_number() {
    let tmp = tempfile::tempdir().unwrap();
    let (crit, out) = (tmp.path().join("criterion"), tmp.path().join("out"));
    std::fs::create_dir_all(&crit).unwrap();
    assert!(!report(&crit, &out).status.success(), "an empty folder");
    bench(
        &crit,
        "tonemap_small/linear_gpu",
        "tonemap_small",
        "linear_gpu",
        0.0,
        TEN,
    );
    let o = report(&crit, &out);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("tonemap_small/linear_gpu"));
}
