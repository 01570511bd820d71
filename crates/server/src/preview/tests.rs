//! Preview tests: downscaling, the message layout, requests, rates and the encoder slot.

use super::*;
use crate::hub::Hub;

fn gradient(w: u32, h: u32) -> OwnedBgr {
    let mut data = Vec::with_capacity((w * h * 3) as usize);
    for y in 0..h {
        for x in 0..w {
            data.extend_from_slice(&[(x % 256) as u8, (y % 256) as u8, 128]);
        }
    }
    OwnedBgr {
        width: w,
        height: h,
        data,
    }
}

#[test]
fn box_filter_averages_blocks() {
    let img = OwnedBgr {
        width: 4,
        height: 2,
        data: vec![
            0, 0, 0, 10, 10, 10, 100, 0, 0, 100, 0, 0, //
            20, 20, 20, 30, 30, 30, 100, 0, 0, 100, 0, 4,
        ],
    };
    let (w, h, px) = downscale_bgr(&img, 2);
    assert_eq!((w, h), (2, 1));
    assert_eq!(px, vec![15, 15, 15, 100, 0, 1]);
    assert_eq!(downscale_factor(640, 480), 2);
    assert_eq!(downscale_factor(640, 640), 1);
    assert_eq!(downscale_factor(640, 200), 4);
}

#[test]
fn encoded_message_follows_the_layout_and_decodes() {
    let input = PreviewInput {
        seq: 42,
        t: 1.5,
        capture_us: 1_500_000,
        wall_us: Some(1_700_000_000_000_000),
        image: Arc::new(gradient(640, 480)),
        overlay: Overlay {
            dots: vec![ImageDot {
                name: "D1".into(),
                x: 300.0,
                y: 200.0,
                state: DotState::Tracked,
            }],
            search: Vec::new(),
        },
    };
    let p = encode(&input, 320, 70).unwrap();
    assert_eq!((p.width, p.height), (320, 240));
    let m = &p.message[..];
    assert_eq!(&m[0..4], b"MPP1");
    assert_eq!(u16::from_le_bytes([m[4], m[5]]), 1);
    assert_eq!(u16::from_le_bytes([m[6], m[7]]), 1);
    assert_eq!(u64::from_le_bytes(m[8..16].try_into().unwrap()), 42);
    assert_eq!(f64::from_le_bytes(m[16..24].try_into().unwrap()), 1.5);
    assert_eq!(u16::from_le_bytes([m[40], m[41]]), 320);
    assert_eq!(u16::from_le_bytes([m[44], m[45]]), 640);
    let json_len = u32::from_le_bytes(m[48..52].try_into().unwrap()) as usize;
    let jpeg_len = u32::from_le_bytes(m[52..56].try_into().unwrap()) as usize;
    assert_eq!(m.len(), 56 + json_len + jpeg_len);
    let overlay: serde_json::Value = serde_json::from_slice(&m[56..56 + json_len]).unwrap();
    assert_eq!(overlay["type"], "preview_frame");
    assert_eq!(overlay["dots"][0]["name"], "D1");
    assert_eq!(overlay["dots"][0]["state"], "tracked");
    let jpeg = &m[56 + json_len..];
    assert_eq!(&jpeg[..2], &[0xFF, 0xD8], "a JPEG file");
    let mut decoder = jpeg_decoder::Decoder::new(jpeg);
    let pixels = decoder.decode().unwrap();
    let info = decoder.info().unwrap();
    assert_eq!((info.width, info.height), (320, 240));
    // The gradient survives: blue (x) grows to the right, green (y) down (RGB out).
    let at = |x: usize, y: usize| &pixels[(y * 320 + x) * 3..(y * 320 + x) * 3 + 3];
    assert!(at(100, 10)[2] > at(10, 10)[2] + 100, "{:?}", at(100, 10));
    assert!(at(10, 100)[1] > at(10, 10)[1] + 100);
}

#[test]
fn a_bad_image_is_refused() {
    let input = PreviewInput {
        seq: 0,
        t: 0.0,
        capture_us: 0,
        wall_us: None,
        image: Arc::new(OwnedBgr {
            width: 10,
            height: 10,
            data: vec![0; 20],
        }),
        overlay: Overlay::default(),
    };
    assert!(matches!(
        encode(&input, 320, 70),
        Err(PreviewError::BadImage { .. })
    ));
}

#[test]
fn requests_are_checked_and_combined() {
    assert!(PreviewRequest::new(Some(0.0), None).is_err());
    assert!(PreviewRequest::new(Some(30.0), None).is_err());
    assert!(PreviewRequest::new(None, Some(10)).is_err());
    let shared = Arc::new(PreviewShared::new());
    let a = register(&shared, PreviewRequest::new(Some(2.0), Some(200)).unwrap());
    let b = register(&shared, PreviewRequest::new(Some(5.0), Some(100)).unwrap());
    let both = lock(&shared.demand).combined().unwrap();
    assert_eq!((both.max_rate, both.max_width), (5.0, 200));
    drop(b);
    let one = lock(&shared.demand).combined().unwrap();
    assert_eq!((one.max_rate, one.max_width), (2.0, 200));
    drop(a);
    assert!(lock(&shared.demand).combined().is_none());
}

#[test]
fn images_are_due_at_the_highest_rate_asked_for_and_only_when_asked() {
    let (hub, _control) = Hub::new(&crate::HubConfig::default());
    assert!(!hub.preview_due(0.0), "nobody asked");
    let _guard = register(
        &hub.inner.preview,
        PreviewRequest::new(Some(10.0), None).unwrap(),
    );
    let due = (0..60)
        .filter(|i| hub.preview_due(f64::from(*i) / 60.0))
        .count();
    assert_eq!(due, 10, "one second at 60 fps, 10 images asked for");
    let mut gate = RateGate::new(5.0);
    let sent = (0..60).filter(|i| gate.admit(f64::from(*i) / 60.0)).count();
    assert_eq!(sent, 5);
    assert!(gate.admit(0.0), "a replay that loops starts over");
}

#[test]
fn offers_reach_the_latest_cell_and_newer_ones_replace_waiting_ones() {
    let (hub, _control) = Hub::new(&crate::HubConfig::default());
    let image: Arc<dyn BgrImage> = Arc::new(gradient(64, 48));
    let offer = |seq| PreviewInput {
        seq,
        t: seq as f64,
        capture_us: 0,
        wall_us: None,
        image: image.clone(),
        overlay: Overlay::default(),
    };
    hub.offer_preview(offer(1));
    assert!(hub.latest_preview().is_none(), "nobody asked: not encoded");
    let _guard = register(&hub.inner.preview, PreviewRequest::default());
    for seq in 2..50 {
        hub.offer_preview(offer(seq));
    }
    let deadline = Instant::now() + Duration::from_secs(10);
    while hub.latest_preview().map(|p| p.seq) != Some(49) {
        assert!(Instant::now() < deadline, "the newest offer gets encoded");
        std::thread::sleep(Duration::from_millis(5));
    }
    let c = &hub.inner.preview.counters;
    assert_eq!(
        c.encoded.load(Ordering::Relaxed) + c.replaced.load(Ordering::Relaxed),
        48,
        "every offer was either encoded or replaced by a newer one"
    );
}
