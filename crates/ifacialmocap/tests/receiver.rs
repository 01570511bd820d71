//! A receiver written from iFacialMocap's published description (not from the encoder): it
//! sends the handshake, reads the text datagrams (`name-value|…|=head#…|rightEye#…|leftEye#…|`,
//! names with `_L`/`_R` for a side, integers 0–100, angles in degrees) and compares them
//! with the ARKit face of the same frame.

use std::collections::HashMap;
use std::net::UdpSocket;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use mouthpiece_ifacialmocap::{IfmOutput, IfmSettings, HANDSHAKE};
use mouthpiece_output::{
    arkit_index, curve_index, ArkitFace, CharacterFrame, CharacterHead, HeadAxes, RigState,
    StreamFrame,
};

/// One decoded datagram: blend shapes by ARKit name, and the transform fields by name.
struct Decoded {
    shapes: HashMap<String, i64>,
    transforms: HashMap<String, Vec<f64>>,
}

/// The published grammar: blend shapes and transforms are split by the one `=`; fields by
/// `|`; a blend shape is `name-value` (`name&value` in v2); a transform `name#a,b,c`.
fn decode(text: &str, sep: char) -> Decoded {
    let (shapes_part, transforms_part) = text.split_once('=').expect("one '='");
    assert!(!transforms_part.contains('='), "{text}");
    assert!(text.ends_with('|'), "{text}");
    let mut shapes = HashMap::new();
    for field in shapes_part.split('|').filter(|f| !f.is_empty()) {
        let (name, value) = field.split_once(sep).expect(field);
        let value: i64 = value.parse().expect(field);
        assert!((0..=100).contains(&value), "{field}");
        // The app's spelling back to ARKit's: `_L` / `_R` are the side suffixes.
        let arkit = if let Some(stem) = name.strip_suffix("_L") {
            format!("{stem}Left")
        } else if let Some(stem) = name.strip_suffix("_R") {
            format!("{stem}Right")
        } else {
            name.to_string()
        };
        assert!(shapes.insert(arkit, value).is_none(), "{name} twice");
    }
    let mut transforms = HashMap::new();
    for field in transforms_part.split('|').filter(|f| !f.is_empty()) {
        let (name, values) = field.split_once('#').expect(field);
        let values = values.split(',').map(|v| v.parse().expect(field)).collect();
        transforms.insert(name.to_string(), values);
    }
    Decoded { shapes, transforms }
}

/// A turn by `deg` about a model-frame axis, `[w, x, y, z]`.
fn turn(axis: [f64; 3], deg: f64) -> [f32; 4] {
    let h = deg.to_radians() / 2.0;
    [
        h.cos(),
        axis[0] * h.sin(),
        axis[1] * h.sin(),
        axis[2] * h.sin(),
    ]
    .map(|v| v as f32)
}

fn frame() -> StreamFrame {
    let mut rig = RigState::default();
    rig.curves.0[curve_index("jawOpen").unwrap()] = 0.424;
    rig.curves.0[curve_index("mouthSmileLeft").unwrap()] = 0.8;
    rig.curves.0[curve_index("mouthPressRight").unwrap()] = 0.05;
    rig.curves.0[curve_index("jawLeft").unwrap()] = 0.3;
    StreamFrame {
        characters: vec![
            CharacterFrame {
                name: "human".into(),
                ..Default::default()
            },
            CharacterFrame {
                name: "wolf".into(),
                rig: Some(rig),
                // The head turned 20° to the character's left (about up, +y: forward towards
                // left, +x), the eyes 10° down.
                head: Some(CharacterHead {
                    rotation: turn([0.0, 1.0, 0.0], 20.0),
                    eye_left: turn([1.0, 0.0, 0.0], 10.0),
                    eye_right: turn([1.0, 0.0, 0.0], 10.0),
                    ..Default::default()
                }),
                ..Default::default()
            },
        ],
        ..Default::default()
    }
}

/// Offers frames until `peer` receives a datagram (generous deadline: a loaded machine).
fn receive(out: &IfmOutput, peer: &UdpSocket, frame: &StreamFrame) -> String {
    peer.set_read_timeout(Some(Duration::from_millis(50)))
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut buf = [0u8; 4096];
    while Instant::now() < deadline {
        out.offer(frame);
        if let Ok((n, _)) = peer.recv_from(&mut buf) {
            return String::from_utf8(buf[..n].to_vec()).expect("ASCII");
        }
    }
    panic!("no datagram within 30 s");
}

#[test]
fn a_receiver_that_sends_the_handshake_gets_the_face() {
    let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
    let out = IfmOutput::new();
    out.configure(Some(IfmSettings {
        listen: "127.0.0.1:0".parse().unwrap(),
        reply_port: peer.local_addr().unwrap().port(),
        character: "wolf".into(),
        axes: HeadAxes::IDENTITY,
    }))
    .unwrap();
    let port = out.local_addr().unwrap();
    // Garbage first: counted, ignored, nothing sent back.
    for junk in [
        &b"hello"[..],
        b"",
        &[0xff; 600],
        b"iFacialMocap_lookForward",
    ] {
        peer.send_to(junk, port).unwrap();
    }
    let frame = frame();
    peer.set_read_timeout(Some(Duration::from_millis(300)))
        .unwrap();
    out.offer(&frame);
    let mut buf = [0u8; 64];
    assert!(peer.recv_from(&mut buf).is_err(), "sent before a handshake");

    peer.send_to(HANDSHAKE.as_bytes(), port).unwrap();
    let text = receive(&out, &peer, &frame);
    let got = decode(&text, '-');
    let face = ArkitFace::from_character(&frame.characters[1], &HeadAxes::IDENTITY);
    assert_eq!(got.shapes.len(), 52, "{text}");
    for (name, value) in &got.shapes {
        let i = arkit_index(name).unwrap_or_else(|| panic!("{name} is not ARKit's"));
        let want = (f64::from(face.blendshapes[i]) * 100.0).round() as i64;
        assert_eq!(*value, want, "{name}");
    }
    assert_eq!(got.shapes["jawOpen"], 42);
    assert_eq!(got.shapes["mouthSmileLeft"], 80);
    assert_eq!(got.shapes["jawLeft"], 30);
    assert_eq!(got.shapes["eyeBlinkLeft"], 0);
    // Eyes 10° down: eyeLookDown at a third of the 30° full scale.
    assert_eq!(got.shapes["eyeLookDownLeft"], 33);
    // Head: Euler x (pitch), y (yaw), z (roll) in degrees, then the position (0).
    let head = &got.transforms["head"];
    assert_eq!(head.len(), 6);
    let deg = |r: f32| f64::from(r).to_degrees();
    assert!((head[0] - deg(face.head[1])).abs() < 1e-4);
    assert!((head[1] - deg(face.head[0])).abs() < 1e-4);
    assert!((head[2] - deg(face.head[2])).abs() < 1e-4);
    // A turn to the character's left is a negative yaw.
    assert!((head[1] + 20.0).abs() < 1e-3, "{head:?}");
    assert_eq!(&head[3..], &[0.0, 0.0, 0.0]);
    for (name, eye) in [("leftEye", face.eye_left), ("rightEye", face.eye_right)] {
        let e = &got.transforms[name];
        assert_eq!(e.len(), 3);
        assert!((e[0] - deg(eye[1])).abs() < 1e-4, "{name} {e:?}");
        assert!((e[0] - 10.0).abs() < 1e-3, "{name} {e:?}");
        assert!((e[1] - deg(eye[0])).abs() < 1e-4);
    }
    let counters = out.counters();
    assert_eq!(counters.malformed.load(Ordering::Relaxed), 4);
    assert!(counters.handshakes.load(Ordering::Relaxed) >= 1);

    // Reloaded to answer at the handshake's own port (the receivers asked for the old one
    // are forgotten), a receiver asks for v2: `&` between name and value.
    let v2 = UdpSocket::bind("127.0.0.2:0").unwrap();
    out.configure(Some(IfmSettings {
        listen: "127.0.0.1:0".parse().unwrap(),
        reply_port: 0,
        character: "wolf".into(),
        axes: HeadAxes::IDENTITY,
    }))
    .unwrap();
    v2.send_to(format!("{HANDSHAKE}|sendDataVersion=v2").as_bytes(), port)
        .unwrap();
    let text = receive(&out, &v2, &frame);
    assert_eq!(decode(&text, '&').shapes["jawOpen"], 42, "{text}");
}
