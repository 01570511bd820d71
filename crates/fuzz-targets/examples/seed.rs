//! Writes small valid starting inputs for every fuzz target into `fuzz/corpus/<target>/`
//! (`cargo run -p mouthpiece-fuzz-targets --example seed`). The fuzzers mutate from these;
//! the corpora committed are these plus what the fuzzers found, minimised.

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mouthpiece_frame::{Calibration, ColorImage, DepthImage, Frame, Intrinsics};
use mouthpiece_recording::{ColorEncoding, SessionWriter, WriterOptions};

/// A character with every `[head]` key and a `[rig]` with its ranges and jaw hinge.
const HEAD_RIG_CHARACTER: &str = "name = \"sq\"\n[points]\nP1 = [1.0, 0.0, 0.0]\nP2 = [0.0, 1.0, 0.5]\nP3 = [-1.0, 0.0, 0.0]\nP4 = [0.0, -1.0, 0.5]\n[head]\npivot = [0.0, 0.5, -3.0]\neye_left = [0.8, 2.0, 0.5]\neye_right = [-0.8, 2.0, 0.5]\nreach_side = 0.8\nreach_up = 0.5\nreach_down = 0.7\nreach_diagonal = 0.6\nturn_time_s = 0.4\nfollow_gain = 1.5\nfollow_max_deg = 60.0\neye_max_deg = 25.0\n[rig]\njaw_pivot = [0.0, 0.4, -1.5]\n[rig.ranges]\njawOpen = 25\nmouthFunnel = 0.2\nmouthClose = 0.05\n";

/// A daemon configuration with an `[osc]` table and the performer's `[rig]`.
const OSC_CONFIG: &str = "[osc]\ntargets = [\"127.0.0.1:39539\", \"[::1]:39540\", \"avatar.local:9000\"]\ncharacter = \"wolf\"\nhead = true\neyes = false\n[rig]\nhinge_up = 0.4\nlearn_s = 3.0\n[rig.ranges]\njawOpen = 20\n[retarget]\nsmooth = \"ma-exp\"\nma_radius = 3\nma_alpha = 0.4\none_euro = [1.0, 0.007]\n";

/// Retarget options, one per smoothing, and a performer's `[rig]`.
const RETARGET_OPTIONS: [(&str, &str); 4] = [
    ("bspline.toml", "[retarget]\nsmooth = \"bspline\"\nsamples_per_span = 8\none_euro = [1.0, 0.007]\n"),
    ("ma.toml", "[retarget]\nsmooth = \"ma-weighted\"\nma_radius = 2\n"),
    ("ma-exp.toml", "[retarget]\nsmooth = \"ma-exp\"\nma_radius = 4\nma_alpha = 0.3\n"),
    ("rig.toml", "[rig]\nhinge_up = 0.5\nhinge_back = 1.6\nlearn_s = 4.0\ndepth_noise_m = 0.0012\npixel_noise_m = 0.0003\n[rig.ranges]\njawOpen = 30\nmouthSmileLeft = 0.1\n[retarget]\nsmooth = \"sg5\"\n"),
];

fn put(target: &str, name: &str, data: &[u8]) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../fuzz/corpus")
        .join(target);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join(name), data).unwrap();
}

fn session(color: ColorEncoding, compression: Option<mcap::Compression>) -> Vec<u8> {
    let (w, h) = (8u32, 6u32);
    let cal = Arc::new(Calibration::registered(Intrinsics::ideal(
        w, h, 8.0, 8.0, 4.0, 3.0,
    )));
    let mut sink = std::io::Cursor::new(Vec::new());
    {
        let mut writer = SessionWriter::new(
            &mut sink,
            "seed".into(),
            WriterOptions {
                color,
                compression,
                flush_interval: Duration::from_millis(1),
                ..WriterOptions::default()
            },
        )
        .unwrap();
        for i in 0..2u64 {
            let mut color = ColorImage::new(w, h);
            color
                .data
                .iter_mut()
                .enumerate()
                .for_each(|(k, v)| *v = (k * 7) as u8);
            let mut depth = DepthImage::new(w, h);
            depth.data.iter_mut().for_each(|v| *v = 600);
            writer
                .write_frame(&Frame {
                    seq: i,
                    device_ts_us: i * 33_333,
                    host_rx: Instant::now(),
                    wall_clock: None,
                    color,
                    depth,
                    calibration: cal.clone(),
                })
                .unwrap();
        }
        writer.finish().unwrap();
    }
    sink.into_inner()
}

fn main() {
    put("mcap", "raw.mcap", &session(ColorEncoding::Raw, None));
    put(
        "mcap",
        "jpeg-zstd.mcap",
        &session(
            ColorEncoding::Jpeg { quality: 50 },
            Some(mcap::Compression::Zstd),
        ),
    );
    put(
        "mcap",
        "raw-lz4.mcap",
        &session(ColorEncoding::Raw, Some(mcap::Compression::Lz4)),
    );

    let dir = std::env::temp_dir().join(format!("mouthpiece-seed-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let oni = dir.join("seed.oni");
    let spec = openni2::oni_writer::OniStreamSpec {
        width: 4,
        height: 3,
        fps: 30,
        hfov: 1.0,
        vfov: 0.8,
    };
    let mut writer = openni2::oni_writer::OniWriter::create(&oni, spec, spec).unwrap();
    for i in 0..2u64 {
        writer.write_depth(i * 33_333, &[600u16; 12]).unwrap();
        writer.write_color(i * 33_333, &[90u8; 36]).unwrap();
    }
    writer.finish().unwrap();
    put("oni", "seed.oni", &std::fs::read(&oni).unwrap());
    let _ = std::fs::remove_dir_all(&dir);

    use mouthpiece_recording::cdr::{CameraCalibration, CompressedImage, RawImage, Time};
    put(
        "cdr",
        "raw_image",
        &RawImage {
            timestamp: Time::from_micros(1),
            frame_id: "depth".into(),
            width: 2,
            height: 1,
            encoding: "16UC1".into(),
            step: 4,
            data: vec![1, 2, 3, 4],
        }
        .encode(),
    );
    put(
        "cdr",
        "compressed_image",
        &CompressedImage {
            timestamp: Time::from_micros(1),
            frame_id: "color".into(),
            data: vec![0xFF, 0xD8, 0xFF, 0xD9],
            format: "jpeg".into(),
        }
        .encode(),
    );
    put(
        "cdr",
        "camera_calibration",
        &CameraCalibration {
            timestamp: Time::from_micros(1),
            frame_id: "camera".into(),
            width: 640,
            height: 480,
            distortion_model: "plumb_bob".into(),
            d: vec![0.0; 5],
            k: [500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [0.0; 12],
        }
        .encode(),
    );

    put(
        "config_toml",
        "example.toml",
        &std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/mouthpiece.toml"))
            .unwrap(),
    );
    put(
        "config_toml",
        "tokens.toml",
        b"[server]\nlisten = \"0.0.0.0:9870\"\nallowed_hosts = [\"booth.local\"]\nread_token = { value = \"read-token-0123456789\" }\ncontrol_token = { env = \"NOPE\" }\n[takes]\nqueue_frames = 10\n[source]\nspec = \"replay:x.mcap?loop=1&speed=2&start=1\"\n",
    );
    for name in ["human", "wolf"] {
        put(
            "character_toml",
            &format!("{name}.toml"),
            &std::fs::read(
                Path::new(env!("CARGO_MANIFEST_DIR"))
                    .join(format!("../../config/characters/{name}.toml")),
            )
            .unwrap(),
        );
    }
    put(
        "character_toml",
        "contour.toml",
        b"name = \"c\"\nunits = \"cm\"\n[contour]\npoints_per_lip = 4\nupper = [[1, 0, 0], [0, 1, 0], [-1, 0, 0]]\nlower = [[1, 0, 0], [0, -1, 0], [-1, 0, 0]]\n",
    );
    put(
        "character_toml",
        "head-rig.toml",
        HEAD_RIG_CHARACTER.as_bytes(),
    );
    put("config_toml", "osc.toml", OSC_CONFIG.as_bytes());
    for (name, text) in RETARGET_OPTIONS {
        put("retarget_options", name, text.as_bytes());
    }
    put(
        "retarget_jsonl",
        "lines.jsonl",
        b"{\"t\": 0.033, \"points\": {\"D1\": [0.0457, 0.0436, 0.6868], \"D2\": null, \"F1\": [-0.014, -0.053, 0.703]}, \"neutral\": true}\n{\"t\": 0.066, \"points\": {\"D3\": [0.01, 0.02, 0.6], \"F3\": [0, 0, 1]}}\n",
    );
    const TAKE: &[u8] = b"{\"t\": 1.966667, \"seq\": 59, \"character\": \"wolf\", \"points\": {\"P1\": [0.0717, 0.0004, 0.0296], \"P2\": [0.01, 0.02, 0.03]}, \"confidence\": {\"P1\": 1.0, \"P2\": 0.0}, \"head\": {\"rotation\": [0.9995, 0.012, -0.021, 0.004], \"translation\": [0.0035, 0.0008, 0.0002]}, \"head_lost\": false, \"curve\": {\"method\": \"bspline\", \"closed\": true, \"points\": [[0.0707, -0.0010, 0.0229]]}}\n{\"t\": 2.0, \"seq\": 60, \"character\": \"wolf\", \"points\": {\"P1\": [0.07, 0.0, 0.03], \"P2\": [0.01, 0.02, 0.03]}, \"confidence\": {\"P1\": 1.0, \"P2\": 1.0}, \"head\": {\"rotation\": [1, 0, 0, 0], \"translation\": [0, 0, 0]}, \"head_lost\": true, \"curve\": {\"method\": \"ma\", \"closed\": true, \"points\": []}}\n";
    put("take_jsonl", "take.jsonl", TAKE);
    // `play`'s first line is its `--speed`: in range, at each end, and refused ones.
    for (name, speed) in [
        ("one", "1"),
        ("slow", "0.01"),
        ("fast", "1000"),
        ("tiny", "1e-300"),
        ("nan", "NaN"),
    ] {
        put(
            "take_play",
            &format!("take-{name}.jsonl"),
            &[speed.as_bytes(), b"\n", TAKE].concat(),
        );
    }
    for (name, text) in [
        (
            "subscribe",
            r#"{"type":"subscribe","id":1,"characters":["wolf"],"fields":["curve","performer"],"max_rate":10,"format":"binary"}"#,
        ),
        (
            "calibrate",
            r#"{"type":"calibrate","id":2,"duration_s":1.5}"#,
        ),
        (
            "record",
            r#"{"type":"record","id":3,"action":"start","slate":"scene4","take":2}"#,
        ),
        ("stop", r#"{"type":"record","id":"x","action":"stop"}"#),
        ("ping", r#"{"type":"ping","id":"p1"}"#),
    ] {
        put("protocol_v1", name, text.as_bytes());
    }
    for (name, text) in [
        (
            "subscribe",
            r#"{"op":"subscribe","subscriptions":[{"id":7,"channelId":1},{"id":8,"channelId":2}]}"#,
        ),
        (
            "unsubscribe",
            r#"{"op":"unsubscribe","subscriptionIds":[7,9]}"#,
        ),
    ] {
        put("protocol_foxglove", name, text.as_bytes());
    }
    put(
        "http_head",
        "upgrade",
        b"GET /ws?token=a%2Db&x=1 HTTP/1.1\r\nHost: localhost:9870\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nOrigin: http://localhost:9870\r\nSec-WebSocket-Protocol: mouthpiece.v1, mouthpiece.token.abc\r\n\r\n",
    );
    put(
        "http_head",
        "health",
        b"GET /healthz HTTP/1.1\r\nHost: [::1]:9870\r\nAuthorization: Bearer x\r\n\r\n",
    );
    for (name, text) in [
        ("timit.phn", "0 3050 h#\n3050 4559 sh\n4559 5723 ix\n7000 8000 m\n"),
        ("htk.lab", "0 2000000 sil\n2000000 3500000 SH -12.5\n3500000 5000000 aa1\n"),
        (
            "festival.segs",
            "separator ;\nnfields 1\n#\n    0.2100 100 pau\n    0.3499 100 sh\n 0.41 100 iy\n",
        ),
        (
            "phones.jsonl",
            "{\"start\": 0.1, \"end\": 0.2, \"phone\": \"AH0\"}\n\n{\"start\": 0.2, \"end\": 0.3, \"phone\": \"M\"}\n",
        ),
        (
            "short.TextGrid",
            "\"ooTextFile\"\n\"TextGrid\"\n0\n0.5\n<exists>\n1\n\"IntervalTier\"\n\"phn\"\n0\n0.5\n3\n0\n0.1\n\"\"\n0.1\n0.3\n\"sh\"\n0.3\n0.5\n\"iy\"\n",
        ),
        (
            "long.TextGrid",
            "File type = \"ooTextFile\"\nObject class = \"TextGrid\"\n\nxmin = 0\nxmax = 0.5\ntiers? <exists>\nsize = 2\nitem []:\n    item [1]:\n        class = \"IntervalTier\"\n        name = \"words\"\n        xmin = 0\n        xmax = 0.5\n        intervals: size = 1\n        intervals [1]:\n            xmin = 0\n            xmax = 0.5\n            text = \"she\"\n    item [2]:\n        class = \"IntervalTier\"\n        name = \"phones\"\n        xmin = 0\n        xmax = 0.5\n        intervals: size = 2\n        intervals [1]:\n            xmin = 0.1\n            xmax = 0.3\n            text = \"SH\"\n        intervals [2]:\n            xmin = 0.3\n            xmax = 0.5\n            text = \"IY1\"\n    item [3]:\n        class = \"TextTier\"\n        name = \"marks\"\n        xmin = 0\n        xmax = 0.5\n        points: size = 1\n        points [1]:\n            number = 0.2\n            mark = \"x\"\n",
        ),
    ] {
        put("lipsync_phones", name, text.as_bytes());
    }
    glb_seeds();
    onto_seeds();
}

/// `gltf_mesh`: a square as glTF JSON (data URI) and as JSON, NUL, binary chunk; a procedural
/// head around the human's mouth (`bind head --resolution 1`) as GLB. `gltf_rig`: that head
/// bound by `mouthpiece bind` (distance weights).
fn glb_seeds() {
    use mouthpiece_bind::{gltf_io, Method, ModelUp};
    let mut bin = Vec::new();
    for p in [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ] {
        for c in p {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let doc = |uri: Option<String>| {
        let mut buffer = serde_json::json!({"byteLength": 60});
        if let Some(uri) = uri {
            buffer["uri"] = uri.into();
        }
        serde_json::to_vec(&serde_json::json!({
            "asset": {"version": "2.0"},
            "buffers": [buffer],
            "bufferViews": [
                {"buffer": 0, "byteOffset": 0, "byteLength": 48, "byteStride": 12},
                {"buffer": 0, "byteOffset": 48, "byteLength": 12}
            ],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
                {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}
            ],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
            "nodes": [{"children": [1], "translation": [0.0, 1.0, 0.0]},
                      {"mesh": 0, "scale": [2.0, 2.0, 2.0]}],
            "scenes": [{"nodes": [0]}],
            "scene": 0
        }))
        .unwrap()
    };
    use base64::Engine as _;
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    );
    put("gltf_mesh", "square.gltf", &doc(Some(uri)));
    let mut split = doc(None);
    split.push(0);
    split.extend_from_slice(&bin);
    put("gltf_mesh", "square-split", &split);

    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let rig =
        mouthpiece_export::MouthRig::load_character(&repo.join("config/characters/human.toml"))
            .unwrap();
    let dir = std::env::temp_dir().join(format!("mouthpiece-seed-glb-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let head = mouthpiece_bind::character_head(&rig, ModelUp::Y, 0.0, 1).unwrap();
    let head_path = dir.join("head.glb");
    gltf_io::write_plain_glb(&head_path, &head, "head").unwrap();
    put("gltf_mesh", "head.glb", &std::fs::read(&head_path).unwrap());
    let rigged = dir.join("rig.glb");
    let options = mouthpiece_bind::BindOptions::new(ModelUp::Y, Method::Distance);
    mouthpiece_bind::bind(&rig, &head_path, &rigged, &options).unwrap();
    put("gltf_rig", "rig.glb", &std::fs::read(&rigged).unwrap());
    let _ = std::fs::remove_dir_all(&dir);
    // Praat's UTF-16 TextGrid (little-endian, with its byte order mark).
    let short = "\"ooTextFile\"\n\"TextGrid\"\n0\n0.5\n<exists>\n1\n\"IntervalTier\"\n\"phones\"\n0\n0.5\n2\n0\n0.2\n\"ʃ\"\n0.2\n0.5\n\"iy\"\n";
    let mut utf16 = vec![0xFF, 0xFE];
    for u in short.encode_utf16() {
        utf16.extend(u.to_le_bytes());
    }
    put("lipsync_phones", "utf16.TextGrid", &utf16);

    // WAVs: 16 kHz mono 16-bit, 8 kHz stereo 16-bit, 44.1 kHz mono float, 22.05 kHz 8-bit.
    for (name, channels, rate, format, bits) in [
        ("mono16k.wav", 1u16, 16_000u32, 1u16, 16u16),
        ("stereo8k.wav", 2, 8_000, 1, 16),
        ("float44k.wav", 1, 44_100, 3, 32),
        ("u8-22k.wav", 1, 22_050, 1, 8),
    ] {
        let frames = 64u32;
        let block = channels * bits / 8;
        let mut data = Vec::new();
        for i in 0..frames * u32::from(channels) {
            let x = ((i as f64) * 0.7).sin();
            match (format, bits) {
                (3, _) => data.extend((x as f32 * 0.5).to_le_bytes()),
                (_, 8) => data.push((128.0 + 60.0 * x) as u8),
                _ => data.extend(((x * 8000.0) as i16).to_le_bytes()),
            }
        }
        let mut v = b"RIFF".to_vec();
        v.extend((36 + data.len() as u32).to_le_bytes());
        v.extend(b"WAVEfmt ");
        v.extend(16u32.to_le_bytes());
        v.extend(format.to_le_bytes());
        v.extend(channels.to_le_bytes());
        v.extend(rate.to_le_bytes());
        v.extend((rate * u32::from(block)).to_le_bytes());
        v.extend(block.to_le_bytes());
        v.extend(bits.to_le_bytes());
        v.extend(b"data");
        v.extend((data.len() as u32).to_le_bytes());
        v.extend(&data);
        put("wav", name, &v);
    }

    // Lip-sync tables: a class table, segment overrides, a pose file.
    put(
        "lipsync_tables",
        "classes.toml",
        b"poses = [\"closed\", \"open\"]\n[[class]]\nname = \"sil\"\nphones = [\"sil\", \"h#\"]\n[[class]]\nname = \"m\"\nphones = [\"M\", \"b1\"]\ntarget = { closed = 1.0 }\n",
    );
    put(
        "lipsync_tables",
        "segments.toml",
        b"[[segment]]\nfrom = \"bilabial\"\nto = \"open\"\nstable.open = [[0.0, 0.0], [0.6, 0.05], [1.0, 0.1]]\nchange.open = [[0.0, 0.1], [1.0, 1.0]]\n",
    );
    put(
        "lipsync_tables",
        "poses.toml",
        b"[neutral]\nlip = [[0.02, 0.0, 0.0], [0.0, 0.005, 0.0], [-0.02, 0.0, 0.0], [0.0, -0.006, 0.0]]\nforehead = [[0.03, 0.1, 0.0], [-0.03, 0.1, 0.0], [0.0, 0.12, 0.0]]\n[[pose]]\nname = \"open\"\nmouth = { jaw = 0.2 }\ndisplacement = [[0.0, 0.0, 0.0], [0.0, 0.001, 0.0], [0.0, 0.0, 0.0], [0.0, -0.01, 0.0]]\n[[pose]]\nname = \"a\\\"]\\n[[pose]]\"\ndisplacement = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]\n",
    );
}

/// `gltf_onto`: an avatar square with two morph targets (`JawOpen`, matched, and
/// `eyeBlinkLeft`, not), a material and an animation of its own, as glTF JSON (data URI), as
/// JSON, NUL, binary chunk, and as GLB.
fn onto_seeds() {
    let mut bin = Vec::new();
    let floats = [
        0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0, // positions
        0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, // JawOpen
        0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0, // eyeBlinkLeft
        0.0, 1.0, // animation times
        0.0, 0.0, 0.0, 0.0, 0.5, 0.0, // translations
    ];
    for f in floats {
        bin.extend_from_slice(&f.to_le_bytes());
    }
    let doc = |uri: Option<String>| {
        let mut buffer = serde_json::json!({"byteLength": bin.len()});
        if let Some(uri) = uri {
            buffer["uri"] = uri.into();
        }
        serde_json::to_vec(&serde_json::json!({
            "asset": {"version": "2.0", "generator": "seed"},
            "buffers": [buffer],
            "bufferViews": [
                {"buffer": 0, "byteOffset": 0, "byteLength": 144},
                {"buffer": 0, "byteOffset": 144, "byteLength": 32}
            ],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                 "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]},
                {"bufferView": 0, "byteOffset": 48, "componentType": 5126, "count": 4, "type": "VEC3"},
                {"bufferView": 0, "byteOffset": 96, "componentType": 5126, "count": 4, "type": "VEC3"},
                {"bufferView": 1, "componentType": 5126, "count": 2, "type": "SCALAR",
                 "min": [0.0], "max": [1.0]},
                {"bufferView": 1, "byteOffset": 8, "componentType": 5126, "count": 2, "type": "VEC3"}
            ],
            "materials": [{"name": "Skin"}],
            "meshes": [{
                "name": "Face",
                "primitives": [{"attributes": {"POSITION": 0}, "material": 0,
                                "targets": [{"POSITION": 1}, {"POSITION": 2}]}],
                "weights": [0.0, 0.25],
                "extras": {"targetNames": ["JawOpen", "eyeBlinkLeft"]}
            }],
            "nodes": [{"mesh": 0, "name": "Face"}, {"name": "Other"}],
            "scenes": [{"nodes": [0, 1]}],
            "scene": 0,
            "animations": [{"name": "Other", "samplers": [{"input": 3, "output": 4}],
                            "channels": [{"sampler": 0, "target": {"node": 1, "path": "translation"}}]}]
        }))
        .unwrap()
    };
    use base64::Engine as _;
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    );
    put("gltf_onto", "avatar.gltf", &doc(Some(uri)));
    let mut split = doc(None);
    split.push(0);
    split.extend_from_slice(&bin);
    put("gltf_onto", "avatar-split", &split);
    let mut glb = Vec::new();
    mouthpiece_export::onto_rig::write_glb(&doc(None), &bin, &mut glb).unwrap();
    put("gltf_onto", "avatar.glb", &glb);
}
