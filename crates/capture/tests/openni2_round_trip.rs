//! Through the real OpenNI2 library (Debian's libopenni2-0): the Dummy device live, recorded
//! to `.oni` by OpenNI2's recorder and to MCAP, and both replayed byte for byte.
//!
//! One test function on purpose: the steps build on each other's files, and OpenNI2 is
//! process-global (all calls go through the one OpenNI thread of mouthpiece-openni2).

use std::path::Path;
use std::time::{Duration, Instant};

use mouthpiece_capture::record::{record_mcap, record_oni, RecordLimits};
use mouthpiece_capture::{open_source, CaptureConfig, Frame, FrameSource, SourceError, SourceSpec};
use mouthpiece_recording::{ColorEncoding, WriterOptions};

type Pair = (Vec<u8>, Vec<u16>);

fn pair(f: &Frame) -> Pair {
    (f.color.data.clone(), f.depth.data.clone())
}

fn read_all(spec: &str) -> Vec<Frame> {
    let mut src =
        open_source(spec, &CaptureConfig::default()).unwrap_or_else(|e| panic!("{spec}: {e}"));
    let mut frames = Vec::new();
    while let Some(f) = src.next_frame().unwrap() {
        frames.push(f);
        assert!(frames.len() < 10_000, "{spec} does not end");
    }
    frames
}

fn assert_increasing(frames: &[Frame], what: &str) {
    for (i, w) in frames.windows(2).enumerate() {
        assert!(
            w[1].device_ts_us > w[0].device_ts_us,
            "{what}: timestamps not increasing at {i}"
        );
        assert_eq!(w[1].seq, w[0].seq + 1, "{what}: sequence gap at {i}");
    }
}

fn spec(s: String) -> SourceSpec {
    SourceSpec::parse(&s).unwrap()
}

/// What a failed match says about the file: for each replayed pair whose colour and depth
/// were both seen live, the live frames' time apart (device timestamps), counted. A file whose
/// colour is shifted against its depth (the recorder missed one stream's first frame: it
/// rewrites each stream's times from its own first frame) shows one non-zero shift.
fn stream_shift(live: &[Pair], live_ts: &[u64], replayed: &[Pair]) -> String {
    let mut shifts = std::collections::BTreeMap::<i64, usize>::new();
    for (c, d) in replayed {
        let at_colour = live.iter().position(|p| &p.0 == c);
        let at_depth = live.iter().position(|p| &p.1 == d);
        if let (Some(i), Some(j)) = (at_colour, at_depth) {
            *shifts
                .entry(live_ts[j] as i64 - live_ts[i] as i64)
                .or_default() += 1;
        }
    }
    format!(
        "replayed pairs by live depth time minus live colour time (µs): {shifts:?}; {} live, {} replayed",
        live.len(),
        replayed.len()
    )
}

#[test]
fn dummy_live_oni_and_mcap_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let oni = dir.path().join("dummy.oni");
    // The Dummy is software: on a loaded machine its thread can be starved for seconds. This
    // test is about round trips, not unplug detection, so a stall is not taken for a loss.
    let config = CaptureConfig {
        stall_timeout: Duration::from_secs(60),
        ..CaptureConfig::default()
    };

    // 1. Live: at least 60 pairs with increasing timestamps, what the device agreed to.
    let mut live = open_source("openni2:Dummy", &config).unwrap();
    assert!(live.info().live);
    assert_eq!(
        (live.info().color_width, live.info().color_height),
        (320, 240)
    );
    assert_eq!(live.info().fps, 30.0);
    let frames: Vec<Frame> = (0..60)
        .map(|_| live.next_frame().unwrap().unwrap())
        .collect();
    assert_increasing(&frames, "live Dummy");
    for f in &frames {
        assert_eq!(f.color.data.len(), 320 * 240 * 3);
        assert_eq!(f.depth.data.len(), 320 * 240);
        assert!(f.wall_clock.is_some());
        assert!(f.calibration.depth_registered);
    }
    drop(live);

    // 2. Record the live device to .oni with OpenNI2's recorder.
    let mut recorded_live: Vec<Pair> = Vec::new();
    let mut recorded_ts: Vec<u64> = Vec::new();
    let limits = RecordLimits {
        seconds: Some(3.0),
        ..Default::default()
    };
    let summary = record_oni(&spec("openni2:Dummy".into()), &config, &oni, &limits, |f| {
        recorded_live.push(pair(f));
        recorded_ts.push(f.device_ts_us);
    })
    .unwrap();
    assert!(summary.frames >= 60, "{summary:?}");
    assert_eq!(
        summary.oni_fixed_nodes, 2,
        "the Dummy's streams lack cropping: both nodes need the fix"
    );
    assert!(summary.lost.is_none());

    // 3. Replay it (unpaced, every frame): the live pairs come back, in order.
    let l1 = read_all(&format!("replay:{}?speed=0", oni.display()));
    assert!(l1.len() >= 60, "only {} frames replayed", l1.len());
    assert_increasing(&l1, ".oni replay");
    let replayed: Vec<Pair> = l1.iter().map(pair).collect();
    let first = recorded_live
        .iter()
        .position(|p| replayed.contains(p))
        .unwrap_or_else(|| {
            panic!(
                "no live pair in the .oni; {}",
                stream_shift(&recorded_live, &recorded_ts, &replayed)
            )
        });
    // The recorder is started (and has taken its start) before the streams.
    assert_eq!(first, 0, "the recorder missed {first} pairs at the start");
    let mut it = replayed.iter();
    for (i, p) in recorded_live[first..].iter().enumerate() {
        assert!(
            it.any(|r| r == p),
            "live pair {i} is missing from the .oni replay, or out of order"
        );
    }
    let distinct: std::collections::HashSet<&Pair> = replayed.iter().collect();
    assert!(
        distinct.len() > replayed.len() / 2,
        "the Dummy frames should differ"
    );

    // 4. .oni → MCAP (lossless colour) → replay: identical bytes, in order.
    let mcap = dir.path().join("dummy.mcap");
    let options = WriterOptions {
        color: ColorEncoding::Raw,
        ..Default::default()
    };
    let s = record_mcap(
        &spec(format!("replay:{}?speed=0", oni.display())),
        &config,
        &mcap,
        options,
        &RecordLimits::default(),
        |_| {},
    )
    .unwrap();
    assert_eq!(s.frames as usize, l1.len());
    let l2 = read_all(&format!("replay:{}?speed=0", mcap.display()));
    assert_eq!(l2.len(), l1.len());
    assert!(
        l2.iter().map(pair).eq(replayed.iter().cloned()),
        "MCAP replay differs from the .oni replay"
    );
    assert_increasing(&l2, "MCAP replay");
    assert_eq!(*l2[0].calibration, *l1[0].calibration);

    // 5. .oni replay → .oni again (OpenNI2's recorder on the file player): identical.
    let oni2 = dir.path().join("again.oni");
    record_oni(
        &spec(format!("replay:{}?speed=0", oni.display())),
        &config,
        &oni2,
        &RecordLimits::default(),
        |_| {},
    )
    .unwrap();
    let l3 = read_all(&format!("replay:{}?speed=0", oni2.display()));
    assert!(
        l3.iter().map(pair).eq(replayed.iter().cloned()),
        "re-recorded .oni differs"
    );

    // 6. Looping keeps going with increasing timestamps; seeking starts at the right frame.
    let mut looped =
        open_source(&format!("replay:{}?speed=0&loop=1", oni.display()), &config).unwrap();
    let n = l1.len();
    let frames: Vec<Frame> = (0..n + 5)
        .map(|_| looped.next_frame().unwrap().expect("looping never ends"))
        .collect();
    assert_increasing(&frames, "looping .oni");
    assert_eq!(pair(&frames[n + 3]), replayed[3]);
    drop(looped);
    for file in [&oni, &mcap] {
        let t0 = l1[0].device_ts_us;
        let target = l1
            .iter()
            .position(|f| f.device_ts_us - t0 >= 1_000_000)
            .unwrap();
        let mut sought = open_source(
            &format!("replay:{}?speed=0&start=1", file.display()),
            &config,
        )
        .unwrap();
        let f = sought.next_frame().unwrap().unwrap();
        assert_eq!(pair(&f), replayed[target], "start=1 on {}", file.display());
    }
    let mut src = mouthpiece_capture::open_openni2(
        &spec(format!("replay:{}?speed=0", oni.display())),
        &config,
    )
    .unwrap();
    for _ in 0..40 {
        src.next_frame().unwrap().unwrap();
    }
    src.seek(Duration::from_millis(500)).unwrap(); // backwards: reopens and reads forward
    let target = l1
        .iter()
        .position(|f| f.device_ts_us - l1[0].device_ts_us >= 500_000)
        .unwrap();
    assert_eq!(pair(&src.next_frame().unwrap().unwrap()), replayed[target]);
    drop(src);

    // 7. Paced replay takes recorded time (× speed).
    for (speed, min_s) in [(1.0, 0.4), (2.0, 0.2)] {
        let mut paced =
            open_source(&format!("replay:{}?speed={speed}", oni.display()), &config).unwrap();
        let start = Instant::now();
        for _ in 0..16 {
            paced.next_frame().unwrap().unwrap();
        }
        let took = start.elapsed().as_secs_f64();
        assert!(
            took >= min_s,
            "16 frames at speed {speed} took only {took:.3} s"
        );
    }

    // 8. A truncated .oni plays to its cut with a warning, and ends.
    let cut = dir.path().join("cut.oni");
    let bytes = std::fs::read(&oni).unwrap();
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    match open_source(&format!("replay:{}?speed=0", cut.display()), &config) {
        Ok(mut src) => {
            let mut n = 0;
            while let Some(f) = src.next_frame().unwrap() {
                assert_eq!(pair(&f), replayed[n], "truncated replay frame {n}");
                n += 1;
            }
            assert!(n < l1.len(), "{n} frames from half a file");
        }
        Err(err) => panic!("a truncated .oni should play up to its cut: {err}"),
    }
    bad_inputs(dir.path());
}

fn bad_inputs(dir: &Path) {
    let config = CaptureConfig::default();
    let err = |spec: &str| -> SourceError {
        match open_source(spec, &config) {
            Ok(_) => panic!("{spec} opened"),
            Err(e) => e,
        }
    };
    let missing = format!("replay:{}/nope.oni", dir.display());
    let e = err(&missing);
    assert!(
        matches!(e, SourceError::Open { .. }) && e.to_string().contains("no such file"),
        "{e}"
    );
    assert!(e.to_string().contains(&missing));

    let garbage = dir.join("garbage.oni");
    std::fs::write(&garbage, vec![0x42u8; 5000]).unwrap();
    let e = err(&format!("replay:{}", garbage.display()));
    assert!(matches!(e, SourceError::Format { .. }), "{e}");
    assert!(e.to_string().contains("garbage.oni"), "{e}");

    let mcap = dir.join("garbage.mcap");
    std::fs::write(&mcap, b"not an mcap file").unwrap();
    let e = err(&format!("replay:{}", mcap.display()));
    assert!(e.to_string().contains("garbage.mcap"), "{e}");

    let e = err("openni2:no-such-device-uri");
    assert!(matches!(e, SourceError::Open { .. }), "{e}");
    assert!(e.to_string().contains("openni2:no-such-device-uri"), "{e}");

    let e = err(&format!("replay:{}/take.avi", dir.display()));
    assert!(
        e.to_string().contains("no such file") || e.to_string().contains(".mcap or .oni"),
        "{e}"
    );
}
