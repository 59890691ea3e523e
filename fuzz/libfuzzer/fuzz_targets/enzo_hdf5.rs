//! libFuzzer target `enzo_hdf5`: [`blueshift_fuzz::enzo_hdf5`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::enzo_hdf5(data);
});
