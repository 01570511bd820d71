#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| mouthpiece_fuzz_targets::take_play(data));
