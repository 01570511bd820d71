//! Our plain-Rust `.oni` writer against OpenNI2's own recorder, through the real library:
//! the Dummy device recorded by OpenNI2's recorder, its replayed frames written again by
//! `OniFrameWriter`, and both files replayed by OpenNI2's player.
//!
//! One test function on purpose (OpenNI2 is process-global; the steps feed each other).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use mouthpiece_capture::oni_write::OniFrameWriter;
use mouthpiece_capture::record::{record_oni, RecordLimits};
use mouthpiece_capture::{open_source, CaptureConfig, Frame, SourceSpec};
use openni2::oni_file::{list_records, record_type};

fn read_all(path: &Path) -> Vec<Frame> {
    let spec = format!("replay:{}?speed=0", path.display());
    let mut src = open_source(&spec, &CaptureConfig::default()).unwrap();
    let mut frames = Vec::new();
    while let Some(f) = src.next_frame().unwrap() {
        frames.push(f);
        assert!(frames.len() < 10_000, "{spec} does not end");
    }
    frames
}

/// Property names per node id, and each node's name and type from `NODE_ADDED`.
fn properties(path: &Path) -> BTreeMap<u32, BTreeSet<String>> {
    let mut props: BTreeMap<u32, BTreeSet<String>> = BTreeMap::new();
    for r in list_records(path, false).unwrap() {
        if let Some(p) = r.property {
            props.entry(r.node_id).or_default().insert(p);
        }
        if r.kind == record_type::NODE_ADDED {
            props.entry(r.node_id).or_default();
        }
    }
    props
}

#[test]
fn writer_replays_like_the_recorder_and_has_its_properties() {
    let dir = tempfile::tempdir().unwrap();
    let recorded = dir.path().join("recorder.oni");
    let config = CaptureConfig::default();
    let limits = RecordLimits {
        seconds: Some(1.0),
        ..Default::default()
    };
    let spec = SourceSpec::parse("openni2:Dummy").unwrap();
    let summary = record_oni(&spec, &config, &recorded, &limits, |_| {}).unwrap();
    assert!(summary.frames >= 20, "{summary:?}");

    // The recorder's file, replayed, written again by our writer and replayed again.
    let from_recorder = read_all(&recorded);
    assert!(from_recorder.len() >= 20);
    let ours = dir.path().join("ours.oni");
    let mut writer = OniFrameWriter::create(&ours, &from_recorder[0].calibration, 30.0).unwrap();
    for f in &from_recorder {
        writer.write_frame(f).unwrap();
    }
    writer.finish().unwrap();
    let from_ours = read_all(&ours);
    assert_eq!(from_ours.len(), from_recorder.len(), "every frame");
    for (i, (a, b)) in from_recorder.iter().zip(&from_ours).enumerate() {
        assert_eq!(a.device_ts_us, b.device_ts_us, "frame {i}: timestamp");
        assert!(a.color.data == b.color.data, "frame {i}: colour");
        assert!(a.depth.data == b.depth.data, "frame {i}: depth");
    }
    // Same intrinsics: the field of view survives (f64 in the file, f32 through OpenNI2).
    let (ka, kb) = (&from_recorder[0].calibration, &from_ours[0].calibration);
    assert!((ka.color.fx - kb.color.fx).abs() < 1e-3, "{ka:?} vs {kb:?}");
    assert!((ka.color.fy - kb.color.fy).abs() < 1e-3, "{ka:?} vs {kb:?}");
    assert_eq!((ka.color.cx, ka.color.cy), (kb.color.cx, kb.color.cy));

    // Every property record the recorder writes for the Dummy's nodes (after mouthpiece's
    // cropping fix), ours writes too, for the same node ids.
    let theirs = properties(&recorded);
    let mine = properties(&ours);
    assert_eq!(
        theirs.keys().collect::<Vec<_>>(),
        mine.keys().collect::<Vec<_>>()
    );
    for (node, names) in &theirs {
        let missing: Vec<_> = names.difference(&mine[node]).collect();
        assert!(
            missing.is_empty(),
            "node {node}: we do not write {missing:?}"
        );
    }
}
