#![no_main]

// The session reader turns a panic inside the mcap crate (arithmetic on lengths from the
// file) into an error, as the daemon and the CLI see it; libfuzzer-sys's hook would abort
// before that. Panics nothing catches still abort (libfuzzer-sys checks the call's result).
libfuzzer_sys::fuzz_target!(
    init: {
        let _ = std::panic::take_hook();
    },
    |data: &[u8]| mouthpiece_fuzz_targets::mcap(data)
);
