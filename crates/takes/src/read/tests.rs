use super::*;
use crate::tests::{derived, settings, start_wait, stop_wait};
use crate::{unix_us, Takes};
use mouthpiece_recording::{SessionWriter, WriterOptions};

/// A take of `steps` steps of the character `wolf` from a booth without a camera, written by
/// the crate's own writer; `edit` changes a step before it is written.
fn steps_take(dir: &Path, steps: u64, edit: impl Fn(&mut crate::Derived)) -> crate::TakeInfo {
    let mut takes = Takes::new(settings(dir));
    let info = start_wait(&mut takes, "scene1", Some(7)).unwrap();
    for seq in 0..steps {
        let mut step = derived(seq);
        edit(&mut step);
        takes.push_step(step);
    }
    stop_wait(&mut takes).unwrap();
    info
}

#[test]
fn the_take_record_is_read_once_with_its_fields() {
    let dir = tempfile::tempdir().unwrap();
    let info = steps_take(dir.path(), 3, |_| {});
    let take = TakeMetadata::read(&info.path)
        .unwrap()
        .expect("a daemon's take");
    assert_eq!(
        take,
        TakeMetadata {
            slate: "scene1".into(),
            take: 7,
            started_unix_us: unix_us(info.started),
            timecode_rate: "30".into(),
            source: "replay:test.mcap".into(),
        }
    );
    assert_eq!(take.rate(), Some(TimecodeRate::Fps30));
    assert_eq!(
        take.start_timecode(),
        Timecode::from_unix_micros(take.started_unix_us, TimecodeRate::Fps30).to_string()
    );
    assert!(is_daemon_take(&info.path).unwrap());
    assert!(has_no_images(&info.path).unwrap());

    // A plain recording has no take record.
    let plain = dir.path().join("plain.mcap");
    SessionWriter::create(&plain, WriterOptions::default())
        .unwrap()
        .finish()
        .unwrap();
    assert_eq!(TakeMetadata::read(&plain).unwrap(), None);
    assert!(!is_daemon_take(&plain).unwrap());

    // A record without a take number is the file's fault, and says where.
    let record: BTreeMap<String, String> = [("take".to_owned(), "seven".to_owned())].into();
    let err = TakeMetadata::from_record(&info.path, &record).unwrap_err();
    assert!(err.is_bad_input());
    let text = err.to_string();
    assert_eq!(
        text,
        format!(
            "{}: the mouthpiece.take metadata record has no take number (take = seven)",
            info.path.display()
        )
    );

    // A file that is not there cannot be opened: the user's to fix.
    let err = TakeMetadata::read(&dir.path().join("missing.mcap")).unwrap_err();
    assert!(
        matches!(err, ReadError::Open { .. }) && err.is_bad_input(),
        "{err}"
    );
}

#[test]
fn recorded_steps_become_take_lines_from_the_first_step() {
    let dir = tempfile::tempdir().unwrap();
    let info = steps_take(dir.path(), 4, |_| {});
    let mut out = Vec::new();
    assert_eq!(write_lines(&info.path, "wolf", &mut out).unwrap(), 4);
    let lines: Vec<Value> = String::from_utf8(out)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 4);
    for (seq, line) in lines.iter().enumerate() {
        assert_eq!(line["seq"], seq);
        assert_eq!(line["character"], "wolf");
        assert!((line["t"].as_f64().unwrap() - seq as f64 * 0.033_333).abs() < 1e-6);
        assert_eq!(line["points"]["P1"][0].as_f64().unwrap() as f32, 0.07f32);
        assert_eq!(line["head_lost"], false);
        assert!(line.get("character_head").is_some(), "{line}");
    }
    assert_eq!(
        timecodes(&info.path, "wolf").unwrap(),
        ["03:04:05:00", "03:04:05:01", "03:04:05:02", "03:04:05:03"]
    );
    let (span, take) = frame_span(&info.path).unwrap();
    let span = span.expect("the steps are the frames");
    assert_eq!(span.frames, 4);
    assert_eq!(span.first_ns, 1_795_316_645_000_000_000);
    assert_eq!(span.last_ns, (1_795_316_645_000_000 + 3 * 33_333) * 1000);
    assert_eq!(span.first_label.as_deref(), Some("03:04:05:00"));
    assert_eq!(take.map(|t| t.take), Some(7));
}

#[test]
fn a_take_without_the_character_names_what_it_recorded() {
    let dir = tempfile::tempdir().unwrap();
    let info = steps_take(dir.path(), 2, |_| {});
    let err = write_lines(&info.path, "fox\u{1b}[2J", &mut Vec::new()).unwrap_err();
    assert!(matches!(err, ReadError::NoSteps { .. }) && err.is_bad_input());
    let text = err.to_string();
    assert!(text.starts_with(&info.path.display().to_string()), "{text}");
    assert!(
        text.contains("no step of character fox\\u{1b}[2J (/character/fox\\u{1b}[2J)"),
        "{text}"
    );
    assert!(!text.contains('\u{1b}'), "{text:?}");
    assert!(text.ends_with("it recorded: wolf"), "{text}");

    // A take without any character says so.
    let plain = dir.path().join("plain.mcap");
    SessionWriter::create(&plain, WriterOptions::default())
        .unwrap()
        .finish()
        .unwrap();
    let err = write_lines(&plain, "wolf", &mut Vec::new()).unwrap_err();
    assert!(
        err.to_string().ends_with("it recorded: no character"),
        "{err}"
    );
}

#[test]
fn a_bad_timecode_label_names_its_message() {
    let dir = tempfile::tempdir().unwrap();
    let info = steps_take(dir.path(), 3, |step| {
        if step.seq == 2 {
            step.timecode = "03:04:xx:02".into();
        }
    });
    let err = timecodes(&info.path, "wolf").unwrap_err();
    assert!(err.is_bad_input());
    let log_time = (1_795_316_645_000_000u64 + 2 * 33_333) * 1000;
    assert_eq!(
        err.to_string(),
        format!(
            "{}: /character/wolf at log time {log_time} ns: timecode 03:04:xx:02 is not HH:MM:SS:FF",
            info.path.display()
        )
    );
}

#[test]
fn timecode_labels_are_checked_and_parsed() {
    for good in ["10:00:00:00", "23:59:59;29"] {
        assert!(is_timecode_label(good), "{good}");
    }
    for bad in [
        "",
        "10:00:00",
        "10:00:00:0x",
        "10:00:00:00,1",
        "1\n:00:00:00",
        "+1:00:00:00",
        "10-20-30-04",
    ] {
        assert!(!is_timecode_label(bad), "{bad:?}");
        assert!(parse_timecode_label(bad).is_none(), "{bad:?}");
    }
    let tc = parse_timecode_label("10:20:30;04").unwrap();
    assert_eq!(
        (tc.hours, tc.minutes, tc.seconds, tc.frames, tc.drop_frame),
        (10, 20, 30, 4, true)
    );
}

#[test]
fn recorded_heads_follow_the_frames_and_a_refused_head_names_its_message() {
    use mouthpiece_output::CharacterHead;
    let dir = tempfile::tempdir().unwrap();
    let info = steps_take(dir.path(), 3, |step| {
        if step.seq == 1 {
            step.characters[0].head = None;
        }
    });
    let at = |seq: u64| (1_795_316_645_000_000 + seq * 33_333) * 1000;
    let mut heads = RecordedHeads::<CharacterHead>::open(&info.path, "wolf").unwrap();
    assert_eq!(
        heads.at(at(0) - 1, Ok).unwrap(),
        None,
        "before the first step"
    );
    assert_eq!(heads.at(at(0), Ok).unwrap(), Some(CharacterHead::default()));
    // Step 1 recorded no head: the one before it holds.
    assert_eq!(heads.at(at(1), Ok).unwrap(), Some(CharacterHead::default()));
    let mut refused = RecordedHeads::<CharacterHead>::open(&info.path, "wolf").unwrap();
    let err = refused.at(at(2), |_| Err("not wanted")).unwrap_err();
    assert!(err.is_bad_input());
    assert_eq!(
        err.to_string(),
        format!(
            "{}: /character/wolf at log time {} ns: not wanted",
            info.path.display(),
            at(0)
        )
    );
}
