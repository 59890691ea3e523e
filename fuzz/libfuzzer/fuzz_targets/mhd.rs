//! libFuzzer target `mhd`: [`blueshift_fuzz::mhd`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::mhd(data);
});
