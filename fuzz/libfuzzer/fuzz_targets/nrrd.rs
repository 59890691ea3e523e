//! libFuzzer target `nrrd`: [`blueshift_fuzz::nrrd`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::nrrd(data);
});
