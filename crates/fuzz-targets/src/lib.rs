//! One entry point per parser that takes outside input, shared by the coverage-guided
//! fuzzers (`fuzz/`, built with libFuzzer's instrumentation) and by the corpus replay test
//! (`tests/corpora.rs`, a plain `cargo test`). Each function takes arbitrary bytes and must
//! return without panicking, aborting, hanging or allocating without bound, whatever the
//! bytes; errors are the expected outcome for most inputs and are dropped.
//!
//! Files are written to a scratch directory first where the parser reads paths (MCAP
//! sessions, `.oni` files), under the temporary directory (`TMPDIR`; `scripts/fuzz` points
//! it at the memory file system `/dev/shm` when there is one).

use std::io::Write;
use std::path::{Path, PathBuf};

/// A fuzz target: arbitrary bytes in, nothing out, never a panic.
pub type Target = fn(&[u8]);

/// Every target: its name (the corpus folder and the fuzzer binary) and its function.
pub const TARGETS: &[(&str, Target)] = &[
    ("mcap", mcap),
    ("oni", oni),
    ("cdr", cdr),
    ("config_toml", config_toml),
    ("character_toml", character_toml),
    ("retarget_jsonl", retarget_jsonl),
    ("take_jsonl", take_jsonl),
    ("take_play", take_play),
    ("protocol_v1", protocol_v1),
    ("protocol_foxglove", protocol_foxglove),
    ("http_head", http_head),
    ("lipsync_phones", lipsync_phones),
    ("gltf_mesh", gltf_mesh),
    ("gltf_rig", gltf_rig),
    ("wav", wav),
    ("lipsync_tables", lipsync_tables),
    ("retarget_options", retarget_options),
    ("gltf_onto", gltf_onto),
    ("store_object_info", store_object_info),
];

/// Runs the target called `name`; `false` when there is none.
pub fn run(name: &str, data: &[u8]) -> bool {
    match TARGETS.iter().find(|(n, _)| *n == name) {
        Some((_, f)) => {
            f(data);
            true
        }
        None => false,
    }
}

/// A per-process scratch file holding `data`.
fn scratch(name: &str, data: &[u8]) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mouthpiece-fuzz-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join(name);
    // A new file each time: truncating one that holds data makes ext4 flush it on close,
    // which costs the fuzzers most of their speed.
    let _ = std::fs::remove_file(&path);
    let mut file = std::fs::File::create(&path).expect("scratch file");
    file.write_all(data).expect("scratch write");
    path
}

/// An MCAP session: read every frame (at most 64), as replay and `process` do.
pub fn mcap(data: &[u8]) {
    let path = scratch("session.mcap", data);
    if let Ok(mut reader) = mouthpiece_recording::SessionReader::open(&path) {
        for _ in 0..64 {
            match reader.next_frame() {
                Ok(Some(_)) => {}
                _ => break,
            }
        }
    }
    if let Ok(reader) = mouthpiece_recording::MessageReader::open(&path) {
        for message in reader.take(256) {
            if message.is_err() {
                break;
            }
        }
    }
}

/// An `.oni` file: validate it, list its records, repair a truncated copy, add missing
/// cropping.
pub fn oni(data: &[u8]) {
    use openni2::oni_file;
    let path = scratch("take.oni", data);
    let _ = openni2::oni_check::validate(&path, true);
    let _ = openni2::oni_check::validate(&path, false);
    let _ = oni_file::list_records(&path, true);
    let _ = oni_file::list_records(&path, false);
    let repaired = path.with_extension("repaired.oni");
    let _ = oni_file::repair_truncated(&path, &repaired);
    let _ = oni_file::add_missing_cropping(&path, |_| (1.0, 0.8));
    let _ = std::fs::remove_file(&repaired);
}

/// The three CDR message types of a session.
pub fn cdr(data: &[u8]) {
    use mouthpiece_recording::cdr::{CameraCalibration, CompressedImage, RawImage};
    let _ = RawImage::decode(data);
    let _ = CompressedImage::decode(data);
    let _ = CameraCalibration::decode(data);
}

/// The daemon's configuration file.
pub fn config_toml(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(config) =
            mouthpiece_config::Config::parse(text, Path::new("/nonexistent/mouthpiece.toml"))
        {
            let _ = config.summary();
        }
    }
}

/// A character file.
pub fn character_toml(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = mouthpiece_retarget::Character::from_toml_str(text);
    }
}

/// `mouthpiece retarget` input lines, checked against a 12-dot layout as the command does.
pub fn retarget_jsonl(data: &[u8]) {
    use mouthpiece_retarget::jsonl::InputLine;
    use mouthpiece_retarget::{PerformerDots, PerformerLayout};
    let mut dots = PerformerDots::default();
    for line in String::from_utf8_lossy(data).lines() {
        if let Ok(input) = InputLine::parse(line) {
            let layout = PerformerLayout {
                lip_dots: 12,
                forehead_dots: input.forehead_count(),
            };
            let _ = input.dots_into(layout, &mut dots);
        }
    }
}

/// A take's JSONL (what `export` reads).
pub fn take_jsonl(data: &[u8]) {
    let mut reader = mouthpiece_export::TakeReader::new(data, "fuzz");
    for _ in 0..1024 {
        match reader.next_frame() {
            Ok(Some(_)) => {}
            _ => break,
        }
    }
}

/// `mouthpiece play`'s path through a take: the first line is the `--speed` argument (read
/// as clap reads an `f64`), the rest a take checked against a character's points and name,
/// each frame paced by the play clock and encoded as the VMC bundles `play` sends (to no
/// receiver). A speed or a time that made a wait unbounded would panic in `Duration`.
pub fn take_play(data: &[u8]) {
    use mouthpiece_export::{PlayClock, TakeReader};
    use mouthpiece_output::{CurveNaming, VisemeNaming};
    let split = data.iter().position(|&b| b == b'\n').unwrap_or(data.len());
    let Some(speed) = std::str::from_utf8(&data[..split])
        .ok()
        .and_then(|s| s.trim().parse::<f64>().ok())
    else {
        return;
    };
    let Ok(mut clock) = PlayClock::new(speed, "fuzz") else {
        return;
    };
    let take = data.get(split + 1..).unwrap_or_default();
    let names = ["P1", "P2"].map(String::from).to_vec();
    let mut reader = TakeReader::with_points(take, "fuzz", names);
    let Ok(mut sender) = mouthpiece_osc::VmcSender::new(
        &[],
        &nalgebra::Matrix3::identity(),
        true,
        true,
        CurveNaming::Arkit,
        VisemeNaming::Vrm0,
    ) else {
        return;
    };
    for line in 0..1024 {
        let Ok(Some(frame)) = reader.next_frame() else {
            break;
        };
        if line == 0 && reader.check_character("wolf").is_err() {
            break;
        }
        if clock.due(&frame).is_err() {
            break;
        }
        sender.send(&mouthpiece_osc::VmcFrame::from(&frame));
    }
}

/// A `mouthpiece.v1` client message.
pub fn protocol_v1(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = mouthpiece_server::protocol::parse_client_message(text);
    }
}

/// A `foxglove.websocket.v1` client message.
pub fn protocol_foxglove(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = mouthpiece_server::check_foxglove_client_message(text);
    }
}

/// The HTTP front door: a request head, then every decision taken on it.
pub fn http_head(data: &[u8]) {
    use mouthpiece_server::http::read_head;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .build()
        .expect("runtime");
    let mut input = data;
    if let Ok((request, _rest)) = runtime.block_on(read_head(&mut input)) {
        let config = mouthpiece_server::ServerConfig {
            allowed_origins: vec!["https://app.foxglove.dev".into()],
            allowed_hosts: vec!["booth.local".into()],
            ..mouthpiece_server::ServerConfig::default()
        };
        let local = "127.0.0.1:9870".parse().expect("address");
        let _ = config.host_allowed(request.header("host"), local);
        let _ = config.origin_allowed(request.header("origin"), request.header("host"));
        let _ = request.subprotocols();
        let _ = request.query_param("token");
        let _ = request.is_upgrade();
        let _ = config.access_for(request.query_param("token").as_deref());
    }
}

/// A phone timing file of `mouthpiece lipsync`, read as every format it could be (TIMIT,
/// TextGrid, HTK/Festival label, JSONL); what reads is classified with the shipped class
/// table, mapped onto the generated segments and stitched as the command does, at 10
/// samples per second (a day of phones is then 864 000 samples: every input stays quick;
/// the sample cap itself is unit-tested).
pub fn lipsync_phones(data: &[u8]) {
    use mouthpiece_lipsync::phones::{self, PhoneFormat};
    let (table, segments) = shipped_lipsync_tables();
    // As the command reads files: UTF-8, or UTF-16 with a byte order mark.
    let Ok(text) = mouthpiece_lipsync::input::decode_text(data, "fuzz") else {
        return;
    };
    let text = text.as_str();
    for format in [
        PhoneFormat::Timit,
        PhoneFormat::TextGrid,
        PhoneFormat::Label,
        PhoneFormat::Jsonl,
    ] {
        if let Ok(spans) = phones::read(text, format, "fuzz") {
            let _ = mouthpiece_lipsync::weights_for_phones(
                &spans,
                "fuzz",
                table,
                segments,
                mouthpiece_lipsync::DEFAULT_T_CHANGE,
                10.0,
            );
        }
    }
}

/// The JSON before the first NUL byte and the bytes after it, as one GLB file (so a fuzzer
/// reaches the binary chunk through ordinary JSON).
fn split_glb(data: &[u8]) -> Vec<u8> {
    let (json, bin) = match data.iter().position(|&b| b == 0) {
        Some(i) => (&data[..i], &data[i + 1..]),
        None => (data, &[][..]),
    };
    let mut glb = Vec::new();
    let _ = mouthpiece_export::onto_rig::write_glb(json, bin, &mut glb);
    glb
}

/// A mesh for `mouthpiece bind`: the bytes as the file (GLB when they start with its magic,
/// glTF JSON otherwise) and split at their first NUL into a GLB's JSON and binary chunks;
/// what reads is checked as the binder checks it. The file's folder does not exist, so a
/// buffer URI other than `data:` is refused.
pub fn gltf_mesh(data: &[u8]) {
    let path = Path::new("/nonexistent/mouthpiece-fuzz/mesh.gltf");
    let read = |bytes: &[u8]| {
        if let Ok(mesh) = mouthpiece_bind::gltf_io::read_mesh_bytes(bytes, path) {
            let _ = mesh.check(path);
            for t in 0..mesh.welded.triangles.len().min(4) {
                let _ = mesh.triangle_source(t);
            }
        }
    };
    read(data);
    read(&split_glb(data));
}

/// A take's animation (twelve points P1…P12, two keys) as GLB, what `export --rig` copies.
fn take_glb() -> &'static [u8] {
    use std::sync::OnceLock;
    static TAKE: OnceLock<Vec<u8>> = OnceLock::new();
    TAKE.get_or_init(|| {
        let mut bin = Vec::new();
        for v in [0.0f32, 1.0 / 30.0] {
            bin.extend_from_slice(&v.to_le_bytes());
        }
        for k in 0..6 {
            bin.extend_from_slice(&(k as f32 * 0.01).to_le_bytes());
        }
        let names: Vec<String> = (1..=12).map(|k| format!("P{k}")).collect();
        let doc = serde_json::json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": bin.len()}],
            "bufferViews": [
                {"buffer": 0, "byteOffset": 0, "byteLength": 8},
                {"buffer": 0, "byteOffset": 8, "byteLength": 24}
            ],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 2, "type": "SCALAR",
                 "min": [0.0], "max": [1.0 / 30.0]},
                {"bufferView": 1, "componentType": 5126, "count": 2, "type": "VEC3"}
            ],
            "nodes": names.iter().map(|n| serde_json::json!({"name": n})).collect::<Vec<_>>(),
            "animations": [{
                "channels": (0..12).map(|k| serde_json::json!(
                    {"sampler": 0, "target": {"node": k, "path": "translation"}}
                )).collect::<Vec<_>>(),
                "samplers": [{"input": 0, "output": 1}]
            }]
        });
        let mut glb = Vec::new();
        let json = serde_json::to_vec(&doc).expect("take JSON");
        mouthpiece_export::onto_rig::write_glb(&json, &bin, &mut glb).expect("take GLB");
        glb
    })
}

/// A rigged mesh for `export --rig` (as `mouthpiece bind` writes it, or anything else): the
/// bytes as the rig GLB and split at their first NUL into one, with a fixed take animating
/// P1…P12 copied onto it.
pub fn gltf_rig(data: &[u8]) {
    use mouthpiece_export::onto_rig::animate_rig_bytes;
    let rig = Path::new("/nonexistent/mouthpiece-fuzz/rig.glb");
    let take = Path::new("/nonexistent/mouthpiece-fuzz/take.glb");
    let _ = animate_rig_bytes(data, rig, take_glb(), take);
    let _ = animate_rig_bytes(&split_glb(data), rig, take_glb(), take);
}

/// An avatar for `export --onto`: the bytes as the file (GLB when they start with its magic,
/// glTF JSON otherwise) and split at their first NUL into a GLB's JSON and binary chunks;
/// read, matched to the take's curves and, when a target matches, written with a two-frame
/// animation into the scratch directory. The file's folder does not exist, so a buffer URI
/// other than `data:` is refused.
pub fn gltf_onto(data: &[u8]) {
    use mouthpiece_export::onto::{Avatar, CurveTable};
    use mouthpiece_retarget::rig::{CURVES, CURVE_NAMES};
    let table = CurveTable::new(&CURVE_NAMES);
    let path = Path::new("/nonexistent/mouthpiece-fuzz/avatar.gltf");
    let values: Vec<f32> = (0..2 * CURVES)
        .map(|k| k as f32 / (2 * CURVES) as f32)
        .collect();
    for bytes in [data.to_vec(), split_glb(data)] {
        let Ok(avatar) = Avatar::from_bytes(&bytes, path) else {
            continue;
        };
        let Ok(plan) = avatar.plan(&table) else {
            continue;
        };
        let _ = plan.report.to_string();
        let glb = avatar.glb;
        let out = scratch("onto-out", b"");
        let _ = avatar.write_onto(&plan, &[0.0, 0.5], &values, CURVES, &out, glb);
        let _ = std::fs::remove_file(&out);
    }
}

/// The shipped class table and its generated segments, built once per fuzzing process.
fn shipped_lipsync_tables() -> &'static (
    mouthpiece_lipsync::ClassTable,
    mouthpiece_lipsync::SegmentTable,
) {
    use mouthpiece_lipsync::{ClassTable, SegmentTable};
    static TABLES: std::sync::OnceLock<(ClassTable, SegmentTable)> = std::sync::OnceLock::new();
    TABLES.get_or_init(|| {
        let table = ClassTable::from_toml_str(
            include_str!("../../../config/lipsync/classes.toml"),
            "classes.toml",
        )
        .expect("the shipped class table reads");
        let segments = SegmentTable::generate(&table);
        (table, segments)
    })
}

/// A WAV file of `mouthpiece lipsync --audio`: read (first channel) and resampled to 16 kHz,
/// as the command does before decoding.
pub fn wav(data: &[u8]) {
    let _ = mouthpiece_speech::wav::read_16k(std::io::Cursor::new(data), "fuzz.wav");
}

/// The TOML tables of `mouthpiece lipsync`, each read from the same bytes: a class table
/// (and its generated segments), segment overrides against the shipped class table, and a
/// basic-pose file, which must come back unchanged through its writer (the writer of
/// `lipsync poses`: whatever names it holds, what it writes parses to the same poses).
pub fn lipsync_tables(data: &[u8]) {
    use mouthpiece_lipsync::{BasicPoses, ClassTable, SegmentTable};
    let (shipped, shipped_segments) = shipped_lipsync_tables();
    let Ok(text) = mouthpiece_lipsync::input::decode_text(data, "fuzz") else {
        return;
    };
    if let Ok(table) = ClassTable::from_toml_str(&text, "fuzz") {
        let mut segments = SegmentTable::generate(&table);
        let _ = segments.apply_overrides(&table, &text, "fuzz");
    }
    let mut segments = shipped_segments.clone();
    let _ = segments.apply_overrides(shipped, &text, "fuzz");
    if let Ok(poses) = BasicPoses::from_toml_str(&text, "fuzz") {
        let _ = poses.order_for(shipped, "fuzz");
        let written = poses.to_toml_string(&text);
        let back = BasicPoses::from_toml_str(&written, "fuzz")
            .unwrap_or_else(|e| panic!("the pose writer wrote a file that does not read: {e}"));
        assert_eq!(back, poses, "the pose writer changed the poses");
    }
}

/// Retarget options: the `[rig]` table (the performer's rig settings, as the daemon reads
/// it) and the shape smoothing and One Euro options of `[retarget]` (the keys of
/// `mouthpiece retarget`'s flags and the configuration's table). Whatever passes the checks
/// must then run cheaply: one curve over a 64-point loop and a few filter steps, so that a
/// size that allocates or loops without bound shows as a fuzzer timeout or memory failure.
pub fn retarget_options(data: &[u8]) {
    use mouthpiece_retarget::smooth::smooth_closed;
    use mouthpiece_retarget::{
        MovingAverageKind, OneEuroGroup, OneEuroParams, RigSettings, ShapeSmoothing,
    };
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(table) = text.parse::<toml::Table>() else {
        return;
    };
    if let Some(rig) = table.get("rig") {
        if let Ok(settings) = rig.clone().try_into::<RigSettings>() {
            let _ = settings.validate("rig");
        }
    }
    let Some(options) = table.get("retarget").and_then(|v| v.as_table()) else {
        return;
    };
    // The mapping of `mouthpiece retarget --smooth` and `[retarget] smooth` to the smoothing.
    let size = |key: &str, default: usize| match options.get(key) {
        Some(toml::Value::Integer(i)) => usize::try_from(*i).ok(),
        None => Some(default),
        _ => None,
    };
    let (Some(radius), Some(samples_per_span)) =
        (size("ma_radius", 1), size("samples_per_span", 8))
    else {
        return;
    };
    let alpha = match options.get("ma_alpha") {
        Some(toml::Value::Float(f)) => *f,
        Some(toml::Value::Integer(i)) => *i as f64,
        _ => 0.5,
    };
    let ma = |kind| ShapeSmoothing::MovingAverage { kind, radius };
    let smoothing = match options.get("smooth").and_then(|v| v.as_str()) {
        Some("none") => ShapeSmoothing::None,
        Some("ma") => ma(MovingAverageKind::Plain),
        Some("ma-weighted") => ma(MovingAverageKind::Weighted),
        Some("ma-exp") => ma(MovingAverageKind::Exponential { alpha }),
        Some("sg5") => ShapeSmoothing::SavitzkyGolay5,
        _ => ShapeSmoothing::BSpline { samples_per_span },
    };
    if smoothing.validate().is_ok() {
        let n = 64;
        let points: Vec<_> = (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                mouthpiece_retarget::Vec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let mut out = Vec::new();
        smooth_closed(&points, &smoothing, &mut out);
    }
    let number = |v: &toml::Value| v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
    if let Some(pair) = options.get("one_euro").and_then(|v| v.as_array()) {
        if let [a, b] = &pair[..] {
            if let (Some(a), Some(b)) = (number(a), number(b)) {
                if let Ok(params) = OneEuroParams::new(a, b) {
                    let mut group = OneEuroGroup::new(params, 3);
                    for i in 0..8 {
                        let mut xs = [Some(i as f64), None, Some(-1.0)];
                        group.filter(i as f64 / 30.0, &mut xs);
                    }
                }
            }
        }
    }
}

/// An object's info as the take store holds it (JSON), through every check `takes fetch`
/// makes before and while reading its data (the link, the bucket, the digest, then the
/// size and digest of the data, here the input itself); and the input as a take's record,
/// whose texts `takes list` prints escaped.
pub fn store_object_info(data: &[u8]) {
    use mouthpiece_nats::store;
    const BUCKET: &str = "mouthpiece-takes-studio";
    if let Ok(info) = store::info_from_json(data) {
        let _ = store::link_target(&info, BUCKET);
        if let Ok(expected) = store::verified_info(&info, BUCKET) {
            let mut received = store::Received::new(expected);
            for piece in data.chunks(7) {
                if received.update(piece).is_err() {
                    return;
                }
            }
            let _ = received.finish();
        }
    }
    if let Ok(record) = serde_json::from_slice::<store::TakeRecord>(data) {
        for text in [
            &record.booth,
            &record.slate,
            &record.object,
            &record.timecode,
        ] {
            let _ = mouthpiece_output::shown(text);
        }
    }
}
