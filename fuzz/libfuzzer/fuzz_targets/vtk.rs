//! libFuzzer target `vtk`: [`blueshift_fuzz::vtk`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::vtk(data);
});
