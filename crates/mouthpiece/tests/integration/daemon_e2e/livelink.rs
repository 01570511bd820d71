//! `[livelink]` end to end (part of `daemon_e2e`): the daemon replays the demo session and
//! streams the wolf as Live Link Face datagrams, decoded here by a decoder written from the
//! published layout (not the daemon's encoder) and compared with the WebSocket frames of the
//! same steps; and Live Link Face's OSC remote control starts, slates and stops a take.

use super::*;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};

/// Apple's ARKit blend shapes in the order Unreal's `EARFaceBlendShape` (and so the
/// datagram) lists them, then the nine angles.
const LIVE_LINK_NAMES: [&str; 61] = [
    "EyeBlinkLeft",
    "EyeLookDownLeft",
    "EyeLookInLeft",
    "EyeLookOutLeft",
    "EyeLookUpLeft",
    "EyeSquintLeft",
    "EyeWideLeft",
    "EyeBlinkRight",
    "EyeLookDownRight",
    "EyeLookInRight",
    "EyeLookOutRight",
    "EyeLookUpRight",
    "EyeSquintRight",
    "EyeWideRight",
    "JawForward",
    "JawLeft",
    "JawRight",
    "JawOpen",
    "MouthClose",
    "MouthFunnel",
    "MouthPucker",
    "MouthLeft",
    "MouthRight",
    "MouthSmileLeft",
    "MouthSmileRight",
    "MouthFrownLeft",
    "MouthFrownRight",
    "MouthDimpleLeft",
    "MouthDimpleRight",
    "MouthStretchLeft",
    "MouthStretchRight",
    "MouthRollLower",
    "MouthRollUpper",
    "MouthShrugLower",
    "MouthShrugUpper",
    "MouthPressLeft",
    "MouthPressRight",
    "MouthLowerDownLeft",
    "MouthLowerDownRight",
    "MouthUpperUpLeft",
    "MouthUpperUpRight",
    "BrowDownLeft",
    "BrowDownRight",
    "BrowInnerUp",
    "BrowOuterUpLeft",
    "BrowOuterUpRight",
    "CheekPuff",
    "CheekSquintLeft",
    "CheekSquintRight",
    "NoseSneerLeft",
    "NoseSneerRight",
    "TongueOut",
    "HeadYaw",
    "HeadPitch",
    "HeadRoll",
    "LeftEyeYaw",
    "LeftEyePitch",
    "LeftEyeRoll",
    "RightEyeYaw",
    "RightEyePitch",
    "RightEyeRoll",
];

/// One datagram as the published layout describes it.
#[derive(Debug, Clone)]
struct Packet {
    version: u32,
    device_id: String,
    subject: String,
    frame: i32,
    sub_frame: f32,
    rate: (i32, i32),
    values: Vec<f32>,
}

/// Reads `n` bytes at `*at`, moving on.
fn take<'a>(data: &'a [u8], at: &mut usize, n: usize) -> &'a [u8] {
    let bytes = &data[*at..*at + n];
    *at += n;
    bytes
}

fn be_i32(data: &[u8], at: &mut usize) -> i32 {
    i32::from_be_bytes(take(data, at, 4).try_into().unwrap())
}

/// Decodes one datagram: version as a little-endian u32; `$` and the 36-character device
/// id; then big-endian: name length and name, frame number, sub-frame, rate numerator and
/// denominator, a one-byte count and that many floats. The whole datagram is used.
fn decode(data: &[u8]) -> Packet {
    let mut at = 0;
    let version = u32::from_le_bytes(take(data, &mut at, 4).try_into().unwrap());
    let id = take(data, &mut at, 37);
    assert_eq!(id[0], b'$', "{data:?}");
    let device_id = String::from_utf8(id[1..].to_vec()).unwrap();
    let len = be_i32(data, &mut at) as usize;
    let subject = String::from_utf8(take(data, &mut at, len).to_vec()).unwrap();
    let frame = be_i32(data, &mut at);
    let sub_frame = f32::from_be_bytes(take(data, &mut at, 4).try_into().unwrap());
    let rate = (be_i32(data, &mut at), be_i32(data, &mut at));
    let count = take(data, &mut at, 1)[0] as usize;
    let values = (0..count)
        .map(|_| f32::from_be_bytes(take(data, &mut at, 4).try_into().unwrap()))
        .collect();
    assert_eq!(at, data.len(), "bytes left over");
    Packet {
        version,
        device_id,
        subject,
        frame,
        sub_frame,
        rate,
        values,
    }
}

/// Receives datagrams on `socket` into a list until `stop`.
fn collect_datagrams(
    socket: UdpSocket,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<Vec<Packet>> {
    socket
        .set_read_timeout(Some(Duration::from_millis(100)))
        .unwrap();
    std::thread::spawn(move || {
        let mut out = Vec::new();
        let mut buf = [0u8; 2048];
        while !stop.load(Ordering::Acquire) {
            if let Ok(n) = socket.recv(&mut buf) {
                out.push(decode(&buf[..n]));
            }
        }
        out
    })
}

/// A rotation `[w, x, y, z]` as a row-major matrix.
fn matrix(q: [f64; 4]) -> [[f64; 3]; 3] {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let [w, x, y, z] = q.map(|v| v / n);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// Yaw, pitch, roll in radians as Live Link Face sends them, of a model-frame rotation
/// `q`, for a character whose head axes (left, up, forward) are the columns of `axes`:
/// the rotation is written in the head's axes; yaw is how far the face (the turned forward
/// axis) points to the character's right, pitch how far it points down, roll how far the
/// turned left axis drops (a tilt towards the left shoulder).
fn live_link_angles(q: [f64; 4], axes: &[[f64; 3]; 3]) -> [f64; 3] {
    let r = matrix(q);
    let column = |m: &[[f64; 3]; 3], j: usize| [m[0][j], m[1][j], m[2][j]];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let apply = |v: [f64; 3]| [dot(r[0], v), dot(r[1], v), dot(r[2], v)];
    let (left, up, forward) = (column(axes, 0), column(axes, 1), column(axes, 2));
    // The turned axes, in head-frame coordinates.
    let face = apply(forward);
    let face = [dot(face, left), dot(face, up), dot(face, forward)];
    let turned_left = apply(left);
    let turned_up = apply(up);
    let yaw = -face[0].atan2(face[2]);
    let pitch = (-face[1]).clamp(-1.0, 1.0).asin();
    let roll = -dot(turned_left, up).atan2(dot(turned_up, up));
    [yaw, pitch, roll]
}

fn quat(v: &Value) -> [f64; 4] {
    std::array::from_fn(|i| v[i].as_f64().unwrap())
}

/// Frames since midnight (UTC) at 30000/1001 fps of a Unix time in µs, and the fraction.
fn frame_at_29_97(wall_us: i64) -> (i64, f64) {
    let micros = wall_us.rem_euclid(86_400_000_000) as i128;
    let scaled = micros * 30_000;
    let per = 1001 * 1_000_000;
    ((scaled / per) as i64, (scaled % per) as f64 / per as f64)
}

fn udp_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

const DEVICE_ID: &str = "0B2C5E4F-6A7D-4E8F-9A0B-1C2D3E4F5A6B";

/// The wolf streamed as Live Link Face datagrams at 29.97 drop-frame: each datagram equals
/// the WebSocket frame of the same step (frame number and sub-frame from its wall clock,
/// every rig curve by name, head and eye angles), the curves nothing measures are 0, and a
/// second target where nothing listens changes nothing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn livelink_datagrams_decode_to_the_websocket_frames_of_the_same_steps() {
    let repo = crate::repo();
    let wolf = mouthpiece_retarget::Character::from_toml_str(
        &std::fs::read_to_string(repo.join("config/characters/wolf.toml")).unwrap(),
    )
    .unwrap();
    let axes: [[f64; 3]; 3] =
        std::array::from_fn(|r| std::array::from_fn(|c| wolf.frame.axes[(r, c)]));
    let receiver = UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = receiver.local_addr().unwrap().port();
    let closed = udp_port();
    let demo = repo.join("recordings/demo.mcap").canonicalize().unwrap();
    let daemon = Daemon::start(
        &format!("replay:{}?loop=1", demo.display()),
        &format!(
            "[timecode]\nrate = \"29.97df\"\n[livelink.characters.wolf]\nsubject = \"Wolf\"\ndevice_id = \"{}\"\ntargets = [\"127.0.0.1:{port}\", \"127.0.0.1:{closed}\"]\n",
            DEVICE_ID.to_lowercase()
        ),
        &[],
        &[],
    );
    let stop = Arc::new(AtomicBool::new(false));
    let datagrams = collect_datagrams(receiver, stop.clone());
    let mut ws = daemon.connect().await;
    send(
        &mut ws,
        json!({"type": "subscribe", "fields": ["rig"], "characters": ["wolf"]}),
    )
    .await;
    wait_for(&mut ws, Duration::from_secs(20), |v| {
        v["type"] == "frame" && v["characters"][0]["rig"].is_object()
    })
    .await;
    let mut frames = Vec::new();
    while frames.len() < 90 {
        let f = wait_for(&mut ws, Duration::from_secs(5), |v| v["type"] == "frame").await;
        if f["characters"][0]["rig"].is_object() {
            frames.push(f);
        }
    }
    // The datagram of the last frame may still be on its way.
    let deadline = Instant::now() + Duration::from_secs(2);
    while Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    stop.store(true, Ordering::Release);
    let packets = datagrams.join().unwrap();
    assert!(
        packets.len() >= 90,
        "{} datagrams\n{}",
        packets.len(),
        daemon.log()
    );
    // Both targets' counters are in `/metrics`: the listening one has sent, and the closed
    // one's sends are counted whichever way they went.
    let metrics = http_body(daemon.port, "/metrics");
    let sent = |target: String| {
        osc_counter(&metrics, "mouthpiece_livelink_sent_total", &target)
            .unwrap_or_else(|| panic!("no Live Link counter for {target} in\n{metrics}"))
    };
    assert!(sent(format!("127.0.0.1:{port}")) > 0, "{metrics}");
    let closed_target = format!("127.0.0.1:{closed}");
    assert!(
        sent(closed_target.clone())
            + osc_counter(&metrics, "mouthpiece_livelink_errors_total", &closed_target).unwrap()
            > 0,
        "{metrics}"
    );

    for p in &packets {
        assert_eq!(p.version, 6);
        assert_eq!(p.device_id, DEVICE_ID);
        assert_eq!(p.subject, "Wolf");
        assert_eq!(p.rate, (30000, 1001));
        assert_eq!(p.values.len(), 61);
        assert!((0.0..1.0).contains(&p.sub_frame), "{p:?}");
    }
    let index = |name: &str| {
        LIVE_LINK_NAMES
            .iter()
            .position(|n| n.eq_ignore_ascii_case(name))
            .unwrap_or_else(|| panic!("{name} is not an ARKit name"))
    };
    let mut matched = 0;
    let mut turned = 0.0f64;
    for f in &frames {
        let (frame, sub) = frame_at_29_97(f["wall_us"].as_i64().unwrap());
        let Some(p) = packets
            .iter()
            .find(|p| i64::from(p.frame) == frame && (f64::from(p.sub_frame) - sub).abs() < 1e-5)
        else {
            continue;
        };
        matched += 1;
        let wolf = &f["characters"][0];
        let curves = wolf["rig"]["curves"].as_object().unwrap();
        for (name, v) in curves {
            let expected = v.as_f64().unwrap().clamp(0.0, 1.0);
            let got = f64::from(p.values[index(name)]);
            assert!((got - expected).abs() < 1e-6, "{name}: {got} vs {expected}");
        }
        // What the dots cannot see is sent as 0.
        for name in [
            "EyeBlinkLeft",
            "EyeWideRight",
            "BrowInnerUp",
            "CheekPuff",
            "TongueOut",
        ] {
            assert_eq!(p.values[index(name)], 0.0, "{name}");
        }
        let head = &wolf["head"];
        for (rotation, first) in [("rotation", 52), ("eye_left", 55), ("eye_right", 58)] {
            let expected = live_link_angles(quat(&head[rotation]), &axes);
            for k in 0..3 {
                let got = f64::from(p.values[first + k]);
                assert!(
                    (got - expected[k]).abs() < 1e-4,
                    "{} {got} vs {}",
                    LIVE_LINK_NAMES[first + k],
                    expected[k]
                );
            }
            if rotation == "rotation" {
                turned = turned.max(expected[0].abs());
            }
        }
    }
    assert!(
        matched >= 60,
        "{matched} of {} frames matched a datagram",
        frames.len()
    );
    // The demo's head turns: the yaw compared is not a constant 0.
    assert!(turned > 0.01, "largest head yaw {turned} rad");
}

/// One OSC message, encoded.
fn osc(addr: &str, args: Vec<rosc::OscType>) -> Vec<u8> {
    rosc::encoder::encode(&rosc::OscPacket::Message(rosc::OscMessage {
        addr: addr.into(),
        args,
    }))
    .unwrap()
}

/// The next OSC message on `socket` (at most 20 s).
fn reply(socket: &UdpSocket) -> rosc::OscMessage {
    socket
        .set_read_timeout(Some(Duration::from_secs(20)))
        .unwrap();
    let mut buf = [0u8; 4096];
    let n = socket.recv(&mut buf).expect("a reply in time");
    match rosc::decoder::decode_udp(&buf[..n]).unwrap().1 {
        rosc::OscPacket::Message(m) => m,
        other => panic!("{other:?}"),
    }
}

fn text(arg: &rosc::OscType) -> String {
    match arg {
        rosc::OscType::String(s) => s.clone(),
        other => panic!("{other:?}"),
    }
}

/// Live Link Face's remote control: a take started, slated and stopped over OSC is an
/// ordinary take (its file in the takes folder), confirmed with its timecode and path; the
/// queries are answered as a mains-powered booth; a sender outside the allow list gets no
/// answer; garbage, bundles and unknown commands are ignored and the daemon keeps going; a
/// flood from the allowed address is cut to the control's rate and counted in `/metrics`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn livelink_remote_control_records_a_take_and_refuses_strangers() {
    let repo = crate::repo();
    let demo = repo.join("recordings/demo.mcap").canonicalize().unwrap();
    let control_port = udp_port();
    let control: SocketAddr = format!("127.0.0.1:{control_port}").parse().unwrap();
    let mut daemon = Daemon::start(
        &format!("replay:{}?loop=1", demo.display()),
        &format!("[livelink]\ncontrol = \"{control}\"\nallow = [\"127.0.0.1\"]\n"),
        &[],
        &[],
    );
    let booth = UdpSocket::bind("127.0.0.1:0").unwrap();
    let stranger = UdpSocket::bind("127.0.0.2:0").unwrap();
    stranger.set_nonblocking(true).unwrap();
    // The control thread may still be starting: ask until it answers.
    booth
        .set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut buf = [0u8; 512];
    loop {
        booth
            .send_to(&osc("/ThermalsQuery", vec![]), control)
            .unwrap();
        if booth.recv(&mut buf).is_ok() {
            break;
        }
        assert!(Instant::now() < deadline, "no answer\n{}", daemon.log());
    }
    // A stranger's query, then garbage of every kind, then the booth's: the control takes
    // datagrams in order, so by the booth's answer the others have been dealt with.
    stranger
        .send_to(&osc("/BatteryQuery", vec![]), control)
        .unwrap();
    let bundle = rosc::encoder::encode(&rosc::OscPacket::Bundle(rosc::OscBundle {
        timetag: rosc::OscTime {
            seconds: 0,
            fractional: 1,
        },
        content: vec![rosc::OscPacket::Message(rosc::OscMessage {
            addr: "/BatteryQuery".into(),
            args: vec![],
        })],
    }))
    .unwrap();
    let mut nested = b"/RecordStart\0\0\0\0,".to_vec();
    nested.extend(vec![b'['; 3000]);
    nested.extend([0, 0, 0]);
    for garbage in [
        vec![0xffu8; 100],
        Vec::new(),
        bundle,
        nested,
        osc("/Nope", vec![]),
        osc("/RecordStart", vec![rosc::OscType::Int(1)]),
        osc(
            "/AddLiveLinkAddress",
            vec![rosc::OscType::String("no-ip".into()), rosc::OscType::Int(1)],
        ),
        osc("/BatteryQuery", vec![])[..8].to_vec(),
    ] {
        booth.send_to(&garbage, control).unwrap();
    }
    booth
        .send_to(&osc("/BatteryQuery", vec![]), control)
        .unwrap();
    let battery = reply(&booth);
    assert_eq!(battery.addr, "/Battery");
    assert_eq!(battery.args, vec![rosc::OscType::Float(1.0)]);
    assert!(
        stranger.recv(&mut buf).is_err(),
        "a refused sender was answered"
    );
    assert!(
        daemon.process.0.try_wait().unwrap().is_none(),
        "{}",
        daemon.log()
    );

    // A flood from the allowed address: 3000 queries at once. The control takes its rate of
    // them (a burst of 50, then 50 a second), drops the rest unread and counts them, and
    // answers the booth again once it slows down.
    let flood_started = Instant::now();
    for _ in 0..3000 {
        booth
            .send_to(&osc("/BatteryQuery", vec![]), control)
            .unwrap();
    }
    booth
        .set_read_timeout(Some(Duration::from_millis(500)))
        .unwrap();
    let mut answered = 0u32;
    while booth.recv(&mut buf).is_ok() {
        answered += 1;
    }
    // Ends after half a second without an answer: the rate allows a burst of 50 plus 50 for
    // each second since the flood began, whatever the machine's load.
    let allowed = 50.0 + 50.0 * flood_started.elapsed().as_secs_f64();
    assert!(
        answered >= 1 && f64::from(answered) <= allowed,
        "{answered} answers to a flood, the rate allows {allowed:.0}"
    );
    let metrics = http_body(daemon.port, "/metrics");
    let flooded: u64 = metrics
        .lines()
        .find_map(|l| {
            l.strip_prefix("mouthpiece_livelink_control_datagrams_total{outcome=\"flooded\"} ")
        })
        .unwrap_or_else(|| panic!("no flood counter in\n{metrics}"))
        .parse()
        .unwrap();
    assert!(flooded > 0, "{metrics}");
    assert!(
        metrics.contains("mouthpiece_livelink_control_datagrams_total{outcome=\"refused\"} 1"),
        "{metrics}"
    );
    // A second without commands fills the bucket again: the next command is answered.
    std::thread::sleep(Duration::from_millis(1100));
    booth
        .send_to(&osc("/BatteryQuery", vec![]), control)
        .unwrap();
    assert_eq!(reply(&booth).addr, "/Battery");

    // Replies go to the send target once one is set.
    let target = UdpSocket::bind("127.0.0.1:0").unwrap();
    let target_port = i32::from(target.local_addr().unwrap().port());
    booth
        .send_to(
            &osc(
                "/OSCSetSendTarget",
                vec![
                    rosc::OscType::String("127.0.0.1".into()),
                    rosc::OscType::Int(target_port),
                ],
            ),
            control,
        )
        .unwrap();
    assert_eq!(reply(&target).addr, "/OSCSetSendTargetConfirm");
    booth
        .send_to(&osc("/ThermalsQuery", vec![]), control)
        .unwrap();
    let thermals = reply(&target);
    assert_eq!(thermals.addr, "/Thermals");
    assert_eq!(thermals.args, vec![rosc::OscType::Int(0)]);

    // Slate and take, then a take started and stopped.
    booth
        .send_to(
            &osc("/Slate", vec![rosc::OscType::String("oscslate".into())]),
            control,
        )
        .unwrap();
    booth
        .send_to(&osc("/Take", vec![rosc::OscType::Int(7)]), control)
        .unwrap();
    booth
        .send_to(&osc("/RecordStart", vec![]), control)
        .unwrap();
    let started = reply(&target);
    assert_eq!(
        started.addr,
        "/RecordStartConfirm",
        "{started:?}\n{}",
        daemon.log()
    );
    let start_timecode = text(&started.args[0]);
    // HH:MM:SS:FF at the default 30 fps.
    assert!(
        start_timecode.len() == 11 && start_timecode.split(':').count() == 4,
        "{start_timecode}"
    );
    let mut ws = daemon.connect().await;
    wait_for(&mut ws, Duration::from_secs(10), |v| v["type"] == "frame").await;
    for _ in 0..30 {
        wait_for(&mut ws, Duration::from_secs(5), |v| v["type"] == "frame").await;
    }
    booth.send_to(&osc("/RecordStop", vec![]), control).unwrap();
    let stopped = reply(&target);
    assert_eq!(
        stopped.addr,
        "/RecordStopConfirm",
        "{stopped:?}\n{}",
        daemon.log()
    );
    assert_eq!(stopped.args.len(), 3, "{stopped:?}");
    assert_eq!(text(&stopped.args[0]), start_timecode);
    let file = PathBuf::from(text(&stopped.args[1]));
    assert_eq!(text(&stopped.args[2]), "");
    let takes = takes_in(daemon.dir.path());
    assert_eq!(takes.len(), 1, "{takes:?}");
    assert_eq!(
        takes[0].canonicalize().unwrap(),
        file.canonicalize().unwrap()
    );
    let name = file.file_name().unwrap().to_string_lossy().into_owned();
    assert!(name.starts_with("oscslate_T007_"), "{name}");
    assert!(
        topics(&file).values().sum::<usize>() > 30,
        "{:?}",
        topics(&file)
    );

    daemon.signal(libc::SIGTERM);
    assert!(daemon.wait_exit(Duration::from_secs(5)).unwrap().success());
}
