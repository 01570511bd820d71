//! Phones → 60 fps weight curves (read, classify, map, stitch) for 60 s of speech.
//! `cargo bench -p mouthpiece-lipsync --bench lipsync`; real-time factor = 60 s / time.

use criterion::{criterion_group, criterion_main, Criterion};
use mouthpiece_lipsync::phones::{self, PhoneFormat};
use mouthpiece_lipsync::{weights_for_phones, ClassTable, SegmentTable};

const CLASSES: &str = include_str!("../../../config/lipsync/classes.toml");

/// 60 s of phones cycling through every class, 30–150 ms long (some shorter than T).
fn phone_file() -> String {
    let names = [
        "sh", "iy", "hh", "ae", "d", "y", "er", "d", "aa", "r", "k", "s", "uw", "t", "ih", "n",
        "g", "r", "iy", "z", "w", "ao", "m", "f", "th", "pau", "ow", "ch", "l", "v",
    ];
    let mut s = String::new();
    let (mut t, mut i) = (0u64, 0usize);
    while t < 60 * 16_000 {
        let len = 480 + (i * 7919 % 1920) as u64; // 30–150 ms at 16 kHz
        s.push_str(&format!("{t} {} {}\n", t + len, names[i % names.len()]));
        t += len;
        i += 1;
    }
    s
}

fn bench(c: &mut Criterion) {
    let table = ClassTable::from_toml_str(CLASSES, "classes.toml").unwrap();
    let segments = SegmentTable::generate(&table);
    let text = phone_file();
    c.bench_function("phones_to_weights_60s_60fps", |b| {
        b.iter(|| {
            let p = phones::read(&text, PhoneFormat::Timit, "bench.phn").unwrap();
            weights_for_phones(&p, "bench.phn", &table, &segments, 0.04, 60.0).unwrap()
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
