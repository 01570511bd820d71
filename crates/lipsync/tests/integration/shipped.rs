//! The shipped class table and the generated segments.

use mouthpiece_lipsync::phones::{self, PhoneFormat};
use mouthpiece_lipsync::{weights_for_phones, ClassTable, SegmentTable};

const CLASSES: &str = include_str!("../../../../config/lipsync/classes.toml");

const TIMIT: &[&str] = &[
    "b", "d", "g", "p", "t", "k", "dx", "q", "bcl", "dcl", "gcl", "pcl", "tcl", "kcl", "jh", "ch",
    "s", "sh", "z", "zh", "f", "th", "v", "dh", "m", "n", "ng", "em", "en", "eng", "nx", "l", "r",
    "w", "y", "hh", "hv", "el", "iy", "ih", "eh", "ey", "ae", "aa", "aw", "ay", "ah", "ao", "oy",
    "ow", "uh", "uw", "ux", "er", "ax", "ix", "axr", "ax-h", "pau", "epi", "h#",
];

const ARPABET: &[&str] = &[
    "AA", "AE", "AH", "AO", "AW", "AY", "B", "CH", "D", "DH", "EH", "ER", "EY", "F", "G", "HH",
    "IH", "IY", "JH", "K", "L", "M", "N", "NG", "OW", "OY", "P", "R", "S", "SH", "T", "TH", "UH",
    "UW", "V", "W", "Y", "Z", "ZH", "SIL",
];

fn table() -> ClassTable {
    ClassTable::from_toml_str(CLASSES, "classes.toml").unwrap()
}

#[test]
fn sixteen_classes_cover_timit_and_arpabet_with_silence_alone() {
    let t = table();
    assert_eq!(TIMIT.len(), 61);
    assert_eq!(t.len(), 16);
    for p in TIMIT.iter().chain(ARPABET) {
        let n = phones::normalise(p);
        assert!(t.class_of(&n).is_some(), "{p} has no class");
    }
    // Stress digits are ignored.
    assert_eq!(t.class_of(&phones::normalise("AH1")), t.class_of("ah"));
    let sil = t.silence();
    for p in ["h#", "pau", "sil"] {
        assert_eq!(t.class_of(p), Some(sil));
    }
    assert!(t.classes[sil].target.iter().all(|&w| w == 0.0));
    // Every other class has a target of its own: no two classes look the same.
    for (i, a) in t.classes.iter().enumerate() {
        for b in &t.classes[..i] {
            assert_ne!(a.target, b.target, "{} and {}", a.name, b.name);
        }
    }
}

#[test]
fn all_256_segments_exist_and_are_continuous() {
    let t = table();
    let s = SegmentTable::generate(&t);
    let mut count = 0;
    for a in 0..16 {
        for b in 0..16 {
            let seg = s.get(a, b);
            count += 1;
            for p in 0..t.poses.len() {
                // Continuous within the segment (stable end = change start) and across
                // segments (starts at a's target, ends at b's), checked on dense samples.
                let (st, ch) = (&seg.stable[p], &seg.change[p]);
                assert_eq!(st.at(0.0), t.classes[a].target[p]);
                assert_eq!(st.at(1.0), ch.at(0.0));
                assert_eq!(ch.at(1.0), t.classes[b].target[p]);
                let n = 1000;
                for stage in [st, ch] {
                    let mut prev = stage.at(0.0);
                    for i in 1..=n {
                        let v = stage.at(i as f64 / n as f64);
                        // |w'| ≤ 1.5 for a smoothstep between weights in [0, 1].
                        assert!((v - prev).abs() <= 1.5 / n as f64 + 1e-12);
                        prev = v;
                    }
                }
            }
        }
    }
    assert_eq!(count, 256);
}

#[test]
fn silence_gives_exactly_zero_weights() {
    let t = table();
    let s = SegmentTable::generate(&t);
    let phones = phones::read("0 8000 h#\n8000 16000 pau\n", PhoneFormat::Timit, "s.phn").unwrap();
    let w = weights_for_phones(&phones, "s.phn", &t, &s, 0.04, 60.0).unwrap();
    assert_eq!(w.len(), 61);
    assert!(w.values.iter().all(|&v| v == 0.0));
}

#[test]
fn identical_phone_files_give_identical_weights() {
    let t = table();
    let s = SegmentTable::generate(&t);
    let text = "0 3050 h#\n3050 4559 sh\n4559 5723 ix\n5723 6400 hv\n6400 8160 eh\n8160 9140 dcl\n9140 10700 jh\n10700 12000 h#\n";
    let a = phones::read(text, PhoneFormat::Timit, "a.phn").unwrap();
    let b = phones::read(text, PhoneFormat::Timit, "b.phn").unwrap();
    let wa = weights_for_phones(&a, "a.phn", &t, &s, 0.04, 60.0).unwrap();
    let wb = weights_for_phones(&b, "b.phn", &t, &s, 0.04, 60.0).unwrap();
    assert_eq!(wa, wb);
    assert!(wa.values.iter().any(|&v| v > 0.5));
}

#[test]
fn a_timeline_of_too_many_samples_is_refused_before_sampling() {
    let t = table();
    let segments = SegmentTable::generate(&t);
    // Ten minutes of phones (the longest accepted) at 10 000 samples per second would be
    // 6e6 samples: an error naming the sample count, no allocation.
    let spans = phones::read(
        "0 1000 sh\n1000 9600000 iy\n",
        PhoneFormat::Timit,
        "long.phn",
    )
    .unwrap();
    let err = weights_for_phones(&spans, "long.phn", &t, &segments, 0.04, 10_000.0).unwrap_err();
    assert!(
        err.to_string().contains("long.phn: the phones last 600 s")
            && err.to_string().contains("4000000 samples"),
        "{err}"
    );
    // The same phones at 40 per second are 24 000 samples: fine.
    let w = weights_for_phones(&spans, "long.phn", &t, &segments, 0.04, 40.0).unwrap();
    assert_eq!(w.len(), 600 * 40 + 1);
}

/// A phone that lasts a day (or 18 hours) is refused where it is read, with its line, as the
/// speech reader refuses audio longer than ten minutes: not minutes of weights written.
#[test]
fn a_phone_longer_than_the_limit_is_refused_at_its_line() {
    for (text, format) in [
        ("0 1000 sh\n1000 1382400000 iy\n", PhoneFormat::Timit),
        (
            "{\"start\": 0, \"end\": 0.1, \"phone\": \"sh\"}\n{\"start\": 0.1, \"end\": 64800, \"phone\": \"iy\"}\n",
            PhoneFormat::Jsonl,
        ),
    ] {
        let err = phones::read(text, format, "day.phn").unwrap_err().to_string();
        assert!(
            err.starts_with("day.phn:2:") && err.contains("past the limit of 600 s"),
            "{err}"
        );
    }
    assert_eq!(phones::MAX_PHONE_SECONDS, 600.0);
}

#[test]
fn montreal_forced_aligner_labels_read_with_the_shipped_table() {
    // MFA writes `spn` (spoken noise: a word not in its dictionary), `sil` and `sp`, with
    // ARPAbet stress digits; `spn` is the neutral mouth, as the recogniser's `+spn+`.
    let t = table();
    let text = "{\"start\": 0.0, \"end\": 0.1, \"phone\": \"sil\"}\n\
                {\"start\": 0.1, \"end\": 0.4, \"phone\": \"spn\"}\n\
                {\"start\": 0.4, \"end\": 0.5, \"phone\": \"sp\"}\n\
                {\"start\": 0.5, \"end\": 0.6, \"phone\": \"AH0\"}\n";
    let spans = phones::read(text, PhoneFormat::Jsonl, "mfa.jsonl").unwrap();
    let classes = t.classify(&spans, "mfa.jsonl").unwrap();
    assert_eq!(classes[..3], [t.silence(); 3]);
    let segments = SegmentTable::generate(&t);
    assert!(weights_for_phones(&spans, "mfa.jsonl", &t, &segments, 0.04, 60.0).is_ok());
}
