//! libFuzzer target `nhdr`: [`blueshift_fuzz::nhdr`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::nhdr(data);
});
