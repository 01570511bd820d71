use super::*;
use mouthpiece_output::{
    CharacterFrame, CharacterHead, RigState, CURVES, CURVE_NAMES, PASCAL_NAMES, VISEMES,
};
use std::net::UdpSocket;
use std::time::Instant;

fn frame_with(t: f64, curves: Option<[f32; CURVES]>, head: [f32; 4]) -> StreamFrame {
    StreamFrame {
        t,
        characters: vec![
            CharacterFrame {
                name: "human".into(),
                ..CharacterFrame::default()
            },
            CharacterFrame {
                name: "wolf".into(),
                rig: curves.map(|c| {
                    let mut rig = RigState {
                        curves: RigCurves(c),
                        ..RigState::default()
                    };
                    rig.set_visemes();
                    rig
                }),
                head: Some(CharacterHead {
                    rotation: head,
                    ..CharacterHead::default()
                }),
                ..CharacterFrame::default()
            },
        ],
        ..StreamFrame::default()
    }
}

fn messages(packet: &OscPacket) -> Vec<OscMessage> {
    match packet {
        OscPacket::Bundle(b) => b.content.iter().flat_map(messages).collect(),
        OscPacket::Message(m) => vec![m.clone()],
    }
}

/// Every bundle of a packet, encoded and decoded, and the messages in order.
fn sent_messages(packet: &VmcPacket) -> Vec<OscMessage> {
    let mut got = Vec::new();
    let mut bytes = Vec::new();
    for i in 0..packet.packets().len() {
        packet.encode(i, &mut bytes);
        // Each a datagram under the 1472 bytes of an unfragmented Ethernet UDP payload.
        assert!(bytes.len() <= MAX_DATAGRAM, "{}", bytes.len());
        assert_eq!(&bytes[..8], b"#bundle\0");
        let (rest, decoded) = rosc::decoder::decode_udp(&bytes).unwrap();
        assert!(rest.is_empty());
        got.extend(messages(&decoded));
    }
    got
}

#[test]
fn a_frame_encodes_as_vmc_bundles_that_decode_to_the_same_values() {
    let mut curves = [0.0f32; CURVES];
    for (i, c) in curves.iter_mut().enumerate() {
        *c = i as f32 / (CURVES - 1) as f32;
    }
    let half = std::f32::consts::FRAC_1_SQRT_2;
    // A quarter turn about the model's y axis (up: the head turns to its left).
    let frame = VmcFrame::from_stream(
        &frame_with(2.5, Some(curves), [half, 0.0, half, 0.0]),
        "wolf",
    )
    .unwrap();
    let mut packet = VmcPacket::new(true, true, CurveNaming::Arkit, VisemeNaming::None);
    packet.fill(&frame, &UnitQuaternion::identity());
    let got = sent_messages(&packet);
    let addrs: Vec<&str> = got.iter().map(|m| m.addr.as_str()).collect();
    let mut expected = vec![
        address::OK,
        address::TIME,
        address::BONE,
        address::BONE,
        address::BONE,
    ];
    expected.extend([address::BLEND_VAL; CURVES]);
    expected.extend([address::SOURCE, address::BLEND_APPLY]);
    assert_eq!(addrs, expected);
    assert_eq!(got[1].args, [OscType::Float(2.5)]);
    // Head: the model's turn about +y (towards its left) is a turn about Unity's −y.
    assert_eq!(got[2].args[0], OscType::String("Head".into()));
    let q: Vec<f32> = got[2].args[1..]
        .iter()
        .map(|a| a.clone().float().unwrap())
        .collect();
    assert_eq!(&q[..3], &[0.0, 0.0, 0.0]);
    for (a, b) in q[3..].iter().zip([0.0, -half, 0.0, half]) {
        assert!((a - b).abs() < 1e-6, "{q:?}");
    }
    assert_eq!(got[3].args[0], OscType::String("LeftEye".into()));
    assert_eq!(got[4].args[0], OscType::String("RightEye".into()));
    for (i, m) in got[5..5 + CURVES].iter().enumerate() {
        assert_eq!(
            m.args,
            [
                OscType::String(CURVE_NAMES[i].into()),
                OscType::Float(curves[i])
            ]
        );
    }
    assert_eq!(got[5 + CURVES].args, [OscType::String("camera".into())]);
    assert!(got[6 + CURVES].args.is_empty());
}

/// Each frame says which source drove the mouth, as the WebSocket frame's
/// `characters[].source` does.
#[test]
fn the_source_of_each_frame_goes_out() {
    let mut packet = VmcPacket::new(false, false, CurveNaming::Arkit, VisemeNaming::None);
    for source in [
        MouthSource::Speech,
        MouthSource::Blend,
        MouthSource::Camera,
        MouthSource::Speech,
    ] {
        let mut stream = frame_with(1.0, None, [1.0, 0.0, 0.0, 0.0]);
        stream.characters[1].source = source;
        let frame = VmcFrame::from_stream(&stream, "wolf").unwrap();
        assert_eq!(frame.source, source);
        packet.fill(&frame, &UnitQuaternion::identity());
        let got = sent_messages(&packet);
        let sent: Vec<_> = got.iter().filter(|m| m.addr == address::SOURCE).collect();
        assert_eq!(sent.len(), 1);
        assert_eq!(sent[0].args, [OscType::String(source.as_str().into())]);
    }
}

/// `names = "arkit-pascal"` names the curves in PascalCase; `visemes` adds the rig's visemes
/// after the curves by VRM 0.x's or VRM 1.0's names, or none.
#[test]
fn curve_names_and_visemes_follow_the_settings() {
    let mut curves = [0.0f32; CURVES];
    curves[0] = 0.8; // jawOpen: an open, unrounded mouth: aa
    let frame = VmcFrame::from_stream(&frame_with(1.0, Some(curves), [1.0, 0.0, 0.0, 0.0]), "wolf")
        .unwrap();
    let vals = |names, visemes| {
        let mut packet = VmcPacket::new(true, true, names, visemes);
        packet.fill(&frame, &UnitQuaternion::identity());
        let got = sent_messages(&packet);
        assert_eq!(got.last().unwrap().addr, address::BLEND_APPLY);
        got.into_iter()
            .filter(|m| m.addr == address::BLEND_VAL)
            .map(|m| {
                (
                    m.args[0].clone().string().unwrap(),
                    m.args[1].clone().float().unwrap(),
                )
            })
            .collect::<Vec<_>>()
    };
    let pascal = vals(CurveNaming::ArkitPascal, VisemeNaming::None);
    let names: Vec<&str> = pascal.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, PASCAL_NAMES);
    assert_eq!(pascal[0], ("JawOpen".to_string(), 0.8));
    for (visemes, want) in [
        (VisemeNaming::Vrm0, ["A", "I", "U", "E", "O"]),
        (VisemeNaming::Vrm1, ["aa", "ih", "ou", "ee", "oh"]),
    ] {
        let got = vals(CurveNaming::Arkit, visemes);
        assert_eq!(got.len(), CURVES + VISEMES);
        let names: Vec<&str> = got[CURVES..].iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, want);
        assert_eq!(got[CURVES].1, 0.8, "aa: {got:?}");
        assert!(got[CURVES + 1..].iter().all(|(_, v)| *v == 0.0), "{got:?}");
    }
}

#[test]
fn the_message_bytes_follow_osc_1_0() {
    // A Val message as the OSC 1.0 specification lays it out: address, type tags and
    // string padded with NULs to 4 bytes, the float big-endian.
    let packet = message(
        address::BLEND_VAL,
        vec![OscType::String("jawOpen".into()), OscType::Float(0.5)],
    );
    let bytes = rosc::encoder::encode(&packet).unwrap();
    let mut expected = b"/VMC/Ext/Blend/Val\0\0,sf\0jawOpen\0".to_vec();
    expected.extend(0.5f32.to_be_bytes());
    assert_eq!(bytes, expected);
}

#[test]
fn without_a_rig_every_curve_is_at_rest_and_bones_can_be_left_out() {
    let frame =
        VmcFrame::from_stream(&frame_with(1.0, None, [1.0, 0.0, 0.0, 0.0]), "wolf").unwrap();
    assert_eq!(frame.curves, None);
    assert!(VmcFrame::from_stream(&frame_with(1.0, None, [1.0, 0.0, 0.0, 0.0]), "ghost").is_none());
    let mut packet = VmcPacket::new(false, false, CurveNaming::Arkit, VisemeNaming::Vrm1);
    packet.fill(&frame, &UnitQuaternion::identity());
    let got = sent_messages(&packet);
    assert!(got.iter().all(|m| m.addr != address::BONE));
    let vals: Vec<_> = got
        .iter()
        .filter(|m| m.addr == address::BLEND_VAL)
        .collect();
    assert_eq!(vals.len(), CURVES + VISEMES);
    assert!(vals.iter().all(|m| m.args[1] == OscType::Float(0.0)));
    let packet = VmcPacket::new(true, false, CurveNaming::Arkit, VisemeNaming::None);
    let bones: Vec<_> = sent_messages(&packet)
        .into_iter()
        .filter(|m| m.addr == address::BONE)
        .collect();
    assert_eq!(bones.len(), 1);
}

#[test]
fn rotations_are_written_in_the_head_frame_then_in_unity_axes() {
    // A character modelled with x forward, y left, z up: its head frame (left, up,
    // forward) as columns in model coordinates.
    let axes = Matrix3::new(0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0);
    // Its head nods down: a turn about the model's y (its left) by 20°.
    let nod = UnitQuaternion::from_axis_angle(&nalgebra::Vector3::y_axis(), 20f64.to_radians());
    let q = [nod.w, nod.i, nod.j, nod.k].map(|v| v as f32);
    let u = unity_rotation(q, &axes_rotation(&axes));
    // In the head frame that is +20° about x (left); Unity's x is right: (x, -y, -z, w)
    // of it, i.e. the same +x component.
    let s = (10f64.to_radians().sin()) as f32;
    let c = (10f64.to_radians().cos()) as f32;
    for (a, b) in u.iter().zip([s, 0.0, 0.0, c]) {
        assert!((a - b).abs() < 1e-6, "{u:?}");
    }
    // The angle of any rotation is kept; the result is a unit quaternion with w >= 0.
    let any = UnitQuaternion::<f64>::from_euler_angles(0.3, -0.7, 1.1);
    let u = unity_rotation(
        [-any.w, -any.i, -any.j, -any.k].map(|v| v as f32),
        &axes_rotation(&axes),
    );
    let norm = u.iter().map(|v| v * v).sum::<f32>().sqrt();
    assert!((norm - 1.0).abs() < 1e-6);
    assert!(
        u[3] >= 0.0 && (u[3] - any.w.abs() as f32).abs() < 1e-6,
        "{u:?}"
    );
}

#[test]
fn a_full_queue_drops_its_oldest_frame_and_counts_it() {
    let (tx, rx) = crossbeam_channel::bounded(2);
    let dropped = std::sync::atomic::AtomicU64::new(0);
    let count = || {
        dropped.fetch_add(1, Ordering::Relaxed);
    };
    for i in 0..5 {
        push_drop_oldest(&tx, &rx, i, &count);
    }
    assert_eq!(dropped.load(Ordering::Relaxed), 3);
    assert_eq!(rx.try_iter().collect::<Vec<_>>(), [3, 4]);
}

fn settings_for(targets: &[SocketAddr]) -> OscSettings {
    OscSettings {
        targets: targets
            .iter()
            .map(|a| Target {
                label: a.to_string(),
                addr: *a,
                character: 0,
            })
            .collect(),
        characters: vec![OscCharacter {
            name: "wolf".into(),
            axes: Matrix3::identity(),
        }],
        head: true,
        eyes: true,
        names: CurveNaming::Arkit,
        visemes: VisemeNaming::Vrm0,
    }
}

/// The `jawOpen` value of every datagram `receiver` gets within a second (the bundle holding
/// it).
fn jaw_values(receiver: &UdpSocket, frames: usize, per_frame: usize) -> Vec<f32> {
    let mut buf = [0u8; 4096];
    let mut values = Vec::new();
    for _ in 0..frames * per_frame {
        let n = receiver
            .recv(&mut buf)
            .expect("a datagram within the timeout");
        let (_, packet) = rosc::decoder::decode_udp(&buf[..n]).unwrap();
        for m in messages(&packet) {
            if m.addr == address::BLEND_VAL && m.args[0] == OscType::String("jawOpen".into()) {
                let OscType::Float(v) = m.args[1] else {
                    panic!("{m:?}")
                };
                values.push(v);
            }
        }
    }
    values
}

/// Each target gets its own character: two receivers, the wolf's and the human's values.
#[test]
fn each_target_gets_its_own_characters_values() {
    let receivers: Vec<UdpSocket> = (0..2)
        .map(|_| {
            let r = UdpSocket::bind("127.0.0.1:0").unwrap();
            r.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            r
        })
        .collect();
    let mut settings = settings_for(&[]);
    settings.characters.push(OscCharacter {
        name: "human".into(),
        axes: Matrix3::identity(),
    });
    for (character, r) in receivers.iter().enumerate() {
        let addr = r.local_addr().unwrap();
        settings.targets.push(Target {
            label: addr.to_string(),
            addr,
            character,
        });
    }
    let counters = Arc::new(OscCounters::default());
    let output = OscOutput::new(counters, Duration::from_secs(60));
    output.configure(settings).unwrap();
    let per_frame = VmcPacket::new(true, true, CurveNaming::Arkit, VisemeNaming::Vrm0)
        .packets()
        .len();
    for i in 0..3 {
        let mut frame = frame_with(i as f64, Some([0.25; CURVES]), [1.0, 0.0, 0.0, 0.0]);
        let mut human = RigState::default();
        human.curves.0[0] = 0.75;
        frame.characters[0].rig = Some(human);
        output.offer(&frame);
        assert_eq!(
            jaw_values(&receivers[0], 1, per_frame),
            [0.25],
            "the wolf's"
        );
        assert_eq!(
            jaw_values(&receivers[1], 1, per_frame),
            [0.75],
            "the human's"
        );
    }
}

#[test]
fn a_refusing_target_is_counted_and_the_others_still_get_every_frame() {
    let receiver = UdpSocket::bind("127.0.0.1:0").unwrap();
    receiver
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    // A port nothing listens on.
    let closed = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap();
    let counters = Arc::new(OscCounters::default());
    let output = OscOutput::new(counters.clone(), Duration::from_secs(60));
    output
        .configure(settings_for(&[closed, receiver.local_addr().unwrap()]))
        .unwrap();
    let mut buf = [0u8; 4096];
    let mut received = 0;
    // Datagrams per frame.
    let per_frame = VmcPacket::new(true, true, CurveNaming::Arkit, VisemeNaming::Vrm0)
        .packets()
        .len() as u64;
    let sent = 40 * per_frame;
    for i in 0..40 {
        let started = Instant::now();
        output.offer(&frame_with(
            i as f64,
            Some([0.25; CURVES]),
            [1.0, 0.0, 0.0, 0.0],
        ));
        // Never waits on the sender (a blocked queue would hang here, not take seconds).
        assert!(started.elapsed() < Duration::from_secs(5));
        // Paced like frames, so that the refusals come back between sends.
        for _ in 0..per_frame {
            if receiver.recv(&mut buf).is_ok() {
                received += 1;
            }
        }
    }
    assert_eq!(received, sent);
    // The counter moves just after the send that the receiver may already have seen.
    let deadline = Instant::now() + Duration::from_secs(5);
    while counters.targets()[1].sent < sent && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    let figures = counters.targets();
    assert_eq!(figures.len(), 2);
    assert!(figures[0].errors > 0, "{figures:?}");
    assert_eq!(figures[1].sent, sent, "{figures:?}");
    assert_eq!(figures[1].errors, 0, "{figures:?}");
    assert!(output.status().unwrap().contains(" sent "));
    // A reload keeps a target's counters and drops the target no longer listed.
    output
        .configure(settings_for(&[receiver.local_addr().unwrap()]))
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    while counters.targets().len() != 1 {
        assert!(Instant::now() < deadline);
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(counters.targets()[0].sent, sent);
    // No target: nothing offered, the thread idles.
    output.configure(settings_for(&[])).unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    while !counters.targets().is_empty() {
        assert!(Instant::now() < deadline);
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(output.status(), None);
}
