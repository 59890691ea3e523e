//! libFuzzer target `spectrum_csv`: [`blueshift_fuzz::spectrum_csv`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::spectrum_csv(data);
});
