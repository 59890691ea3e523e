//! A Doppler scene's memory is checked against the budget before any grid is made: each
//! species naming the same file still gets a grid of its own after unit conversion.

use blueshift_doppler::SceneFile;
use blueshift_volume::MemoryBudget;

fn scene_with_species(dir: &std::path::Path, n: usize) -> SceneFile {
    let raw = dir.join("d_16x16x16_float32.raw");
    let bytes: Vec<u8> = (0..16 * 16 * 16)
        .flat_map(|i| (1.0 + (i % 7) as f32).to_le_bytes())
        .collect();
    std::fs::write(&raw, bytes).unwrap();
    let species: Vec<String> = (0..n)
        .map(|i| {
            format!(
                r#"{{ "name": "H{i}", "lines": "H", "density": {{ "file": "d_16x16x16_float32.raw", "unit": "cm-3" }} }}"#
            )
        })
        .collect();
    let text = format!(r#"{{ "species": [{}] }}"#, species.join(","));
    SceneFile::parse(&text, dir).unwrap()
}

#[test]
fn many_species_of_one_file_are_checked_against_the_budget() {
    let dir = tempfile::tempdir().unwrap();
    let file = scene_with_species(dir.path(), 20);
    // 20 grids of 16^3 f32: 327,680 bytes.
    let need = 20 * 16 * 16 * 16 * 4;
    let small = MemoryBudget::new(need - 1, "--max-memory");
    let err = file
        .load_within(None, &Default::default(), None, &small)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("--max-memory") && err.contains("20 grids"),
        "{err}"
    );
    let enough = MemoryBudget::new(need, "--max-memory");
    let scene = file
        .load_within(None, &Default::default(), None, &enough)
        .unwrap();
    assert_eq!(scene.species().len(), 20);
}
