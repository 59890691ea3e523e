//! libFuzzer target `tf_json`: [`blueshift_fuzz::tf_json`].
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    blueshift_fuzz::tf_json(data);
});
