//! `mouthpiece export --onto AVATAR`: the take's curves as morph-target weight animation on
//! an avatar built at test time by headless Blender (`tests/blender/onto_avatar.py`: a mesh
//! with ARKit-named shape keys, a material, and a second object with its own animation),
//! judged by Khronos' glTF-Validator and by Blender importing the result.

use crate::repo;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use serde_json::Value;

fn mouthpiece(args: &[&str]) -> Output {
    crate::mouthpiece()
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("run mouthpiece")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// The Khronos validator's report (installed into tests/js/node_modules from the lock file).
fn validate(path: &Path) -> Value {
    static READY: OnceLock<PathBuf> = OnceLock::new();
    let script = READY.get_or_init(|| {
        let js = repo().join("tests/js");
        if !js.join("node_modules/gltf-validator/package.json").exists() {
            let status = Command::new("npm")
                .args(["ci", "--silent", "--no-audit", "--no-fund"])
                .current_dir(&js)
                .status()
                .expect("npm (Debian package `npm`, installed by scripts/test)");
            assert!(status.success(), "npm ci in tests/js failed");
        }
        js.join("validate-gltf.js")
    });
    let out = Command::new("node").arg(script).arg(path).output().unwrap();
    assert!(out.status.success(), "validator: {}", stderr(&out));
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Validator report with no errors, warnings, infos or hints.
fn assert_clean(path: &Path) {
    let issues = &validate(path)["issues"];
    for kind in ["numErrors", "numWarnings", "numInfos", "numHints"] {
        assert_eq!(
            issues[kind],
            0,
            "{}: {kind}: {}",
            path.display(),
            serde_json::to_string_pretty(&issues["messages"]).unwrap()
        );
    }
}

fn blender(args: &[&str]) -> String {
    let out = Command::new("blender")
        .args([
            "-b",
            "--factory-startup",
            "--python-exit-code",
            "1",
            "--python",
        ])
        .arg(repo().join("tests/blender/onto_avatar.py"))
        .arg("--")
        .args(args)
        .output()
        .expect("blender (Debian package `blender`, installed by scripts/test)");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "blender {args:?} failed:\n{stdout}\n{}",
        stderr(&out)
    );
    stdout
}

/// Builds the avatar with Blender's glTF exporter (`format`: GLB, GLTF_SEPARATE).
fn make_avatar(path: &Path, format: &str, shape_keys: &[&str]) {
    let path = path.to_str().unwrap();
    blender(&[&["make", path, format], shape_keys].concat());
    assert!(Path::new(path).exists(), "Blender wrote no {path}");
}

/// Imports `file` into Blender and samples its shape keys at `times` with `animation` active.
fn blender_samples(file: &Path, animation: &str, times: &[f64]) -> Value {
    let times: Vec<String> = times.iter().map(|t| format!("{t:?}")).collect();
    let times: Vec<&str> = times.iter().map(String::as_str).collect();
    let stdout = blender(&[&["sample", file.to_str().unwrap(), animation], &times[..]].concat());
    let line = stdout
        .lines()
        .find_map(|l| l.strip_prefix("SAMPLES "))
        .unwrap_or_else(|| panic!("no SAMPLES line from Blender:\n{stdout}"));
    serde_json::from_str(line).unwrap()
}

use mouthpiece_output::CURVE_NAMES;

/// Frames without `rig` at the start (before the neutral pose: every curve 0).
const NO_RIG: usize = 3;

/// Curve `k` at time `t` in the test take; past the curves, the VRM visemes the curves give
/// (`mouthpiece_output::visemes_from`, as the rig computes them).
fn curve(k: usize, t: f64) -> f64 {
    let raw = |k: usize| 0.5 + 0.5 * (3.0 * t + k as f64).sin();
    match k.checked_sub(mouthpiece_output::CURVES) {
        None => raw(k),
        Some(v) => {
            let curves: [f64; mouthpiece_output::CURVES] = std::array::from_fn(raw);
            mouthpiece_output::visemes_from(&curves)[v]
        }
    }
}

/// A take of `frames` lines at slightly uneven times with every curve moving, the first
/// [`NO_RIG`] lines without `rig`. Returns the frames' times.
fn write_take(path: &Path, frames: usize) -> Vec<f64> {
    use std::fmt::Write as _;
    let mut text = String::new();
    let mut times = Vec::new();
    for seq in 0..frames {
        let t = seq as f64 / 30.0 + 0.003 * ((seq * 7) % 5) as f64;
        let rig = if seq < NO_RIG {
            String::new()
        } else {
            let curves: Vec<String> = CURVE_NAMES
                .iter()
                .enumerate()
                .map(|(k, n)| format!("\"{n}\": {:?}", curve(k, t)))
                .collect();
            format!(
                r#", "rig": {{"jaw": {{"angle_deg": 3, "slide_m": 0}}, "lips": {{"upper": {{"rotation": [1, 0, 0, 0], "translation": [0, 0, 0], "residual": 0}}, "lower": {{"rotation": [1, 0, 0, 0], "translation": [0, 0, 0], "residual": 0}}}}, "curves": {{{}}}}}"#,
                curves.join(", ")
            )
        };
        writeln!(
            text,
            r#"{{"t": {t:?}, "seq": {seq}, "character": "human", "points": {{"P1": [0, 0, 0]}}, "confidence": {{"P1": 1.0}}, "head": {{"rotation": [1, 0, 0, 0], "translation": [0, 0, 0.6]}}, "head_lost": false, "curve": null{rig}}}"#
        )
        .unwrap();
        times.push(t);
    }
    std::fs::write(path, text).unwrap();
    times
}

/// The weight the exported animation holds for curve `k` at `at`: the take's values (f32)
/// at its times (f32), linearly interpolated, held past the ends.
fn expected(times: &[f64], k: usize, at: f64) -> f64 {
    let keys: Vec<(f64, f64)> = times
        .iter()
        .enumerate()
        .map(|(i, &t)| {
            let v = if i < NO_RIG { 0.0 } else { curve(k, t) };
            (t as f32 as f64, v as f32 as f64)
        })
        .collect();
    if at <= keys[0].0 {
        return keys[0].1;
    }
    for w in keys.windows(2) {
        let ((t0, v0), (t1, v1)) = (w[0], w[1]);
        if at <= t1 {
            return v0 + (v1 - v0) * (at - t0) / (t1 - t0);
        }
    }
    keys.last().unwrap().1
}

/// A GLB's JSON and binary chunks.
fn glb_chunks(path: &Path) -> (Value, Vec<u8>) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..4], b"glTF");
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
    let json_len = u32_at(12);
    let json = serde_json::from_slice(&bytes[20..20 + json_len]).unwrap();
    let at = 20 + json_len;
    let bin = if at < bytes.len() {
        bytes[at + 8..at + 8 + u32_at(at)].to_vec()
    } else {
        Vec::new()
    };
    (json, bin)
}

/// `after` is `before` with only animation data appended: every top-level property equal
/// but the arrays the animation adds to, which start with `before`'s items; `buffers`
/// may differ in buffer `grown`'s `byteLength` (the GLB chunk the data went into).
fn assert_only_appended(before: &Value, after: &Value, grown: Option<usize>) {
    let appended = ["accessors", "bufferViews", "buffers", "animations"];
    for (key, value) in before.as_object().unwrap() {
        if !appended.contains(&key.as_str()) {
            assert_eq!(&after[key], value, "`{key}` changed");
        }
    }
    for key in appended {
        let old = before[key].as_array().cloned().unwrap_or_default();
        let new = after[key].as_array().unwrap();
        assert!(new.len() >= old.len(), "`{key}` lost items");
        for (i, (o, n)) in old.iter().zip(new).enumerate() {
            if key == "buffers" && Some(i) == grown {
                let (mut o, mut n) = (o.clone(), n.clone());
                o.as_object_mut().unwrap().remove("byteLength");
                n.as_object_mut().unwrap().remove("byteLength");
                assert_eq!(o, n, "buffers[{i}] changed beyond its length");
            } else {
                assert_eq!(o, n, "`{key}[{i}]` changed");
            }
        }
    }
    let keys = |v: &Value| v.as_object().unwrap().keys().cloned().collect::<Vec<_>>();
    assert_eq!(
        keys(before)
            .into_iter()
            .chain(["animations".to_owned()])
            .collect::<std::collections::BTreeSet<_>>(),
        keys(after).into_iter().collect(),
    );
}

/// The shape keys Blender reads back at each sample time equal the take's curves (≤ 1e-4):
/// `matched` are (shape key, curve index) pairs; `held` keys keep their value.
fn assert_shape_keys(
    samples: &Value,
    times: &[f64],
    probes: &[f64],
    matched: &[(&str, usize)],
    held: &[(&str, f64)],
) {
    for &at in probes {
        let keys = &samples["shape_keys"][format!("{at:?}")]["Face"];
        for &(name, k) in matched {
            let got = keys[name]
                .as_f64()
                .unwrap_or_else(|| panic!("no {name} at {at}: {keys}"));
            let want = expected(times, k, at);
            assert!(
                (got - want).abs() <= 1e-4,
                "{name} at t = {at}: Blender {got}, take {want}"
            );
        }
        for &(name, value) in held {
            let got = keys[name].as_f64().unwrap();
            assert!(
                (got - value).abs() <= 1e-6,
                "{name} at t = {at}: {got}, not {value}"
            );
        }
    }
}

#[test]
fn onto_glb_animates_the_arkit_named_shape_keys_and_keeps_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let avatar = dir.path().join("avatar.glb");
    // Case differs from the take's `jawOpen`, `mouthSmileLeft`; `eyeBlinkLeft` (default 0.25)
    // has no curve; the VRM 0.x viseme `A` is the rig's `aa`, from the take's curves.
    make_avatar(
        &avatar,
        "GLB",
        &[
            "JawOpen",
            "mouthsmileleft",
            "mouthFunnel",
            "eyeBlinkLeft=0.25",
            "A",
        ],
    );
    assert_clean(&avatar);
    let take = dir.path().join("take.jsonl");
    let times = write_take(&take, 40);
    let out = dir.path().join("animated.glb");
    let run = mouthpiece(&[
        "export",
        take.to_str().unwrap(),
        "--onto",
        avatar.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let report = stderr(&run);
    assert!(run.status.success(), "{report}");

    // The report: what matched (and from which curve), what did not, on both meshes.
    for line in [
        "meshes[0] (`FaceMesh`): 4 of 5 morph targets matched (node 0 (`Face`))",
        "  matched: JawOpen ← jawOpen, mouthsmileleft ← mouthSmileLeft, mouthFunnel, A ← aa\n",
        "  no curve for: eyeBlinkLeft\n",
        "meshes[1] (`SpinnerMesh`): 0 of 1 morph targets matched",
        "  no curve for: Bulge\n",
        "wrote ",
    ] {
        assert!(report.contains(line), "report lacks {line:?}:\n{report}");
    }
    let unused: Vec<&str> = CURVE_NAMES
        .iter()
        .chain(&mouthpiece_output::VISEME_NAMES)
        .copied()
        .filter(|n| !["jawOpen", "mouthSmileLeft", "mouthFunnel", "aa"].contains(n))
        .collect();
    assert!(
        report.contains(&format!("curves with no target: {}\n", unused.join(", "))),
        "{report}"
    );

    assert_clean(&out);
    // Nothing of the avatar changed: its JSON is a prefix of the output's, its binary chunk
    // too; one animation added, a weights channel on the `Face` node only.
    let (before, before_bin) = glb_chunks(&avatar);
    let (after, after_bin) = glb_chunks(&out);
    assert_only_appended(&before, &after, Some(0));
    assert_eq!(&after_bin[..before_bin.len()], &before_bin[..]);
    let animations = after["animations"].as_array().unwrap();
    assert_eq!(animations.len(), 2);
    assert_eq!(animations[1]["name"], "take");
    assert_eq!(
        animations[1]["channels"],
        serde_json::json!([{"sampler": 0, "target": {"node": 0, "path": "weights"}}])
    );

    // Blender reads the weights back: at frame times, between frames, before the rig starts.
    let probes = [
        times[0],
        times[1],
        (times[2] + times[3]) / 2.0,
        times[5],
        (times[17] + times[18]) / 2.0,
        times[39],
    ];
    let samples = blender_samples(&out, "take", &probes);
    assert_shape_keys(
        &samples,
        &times,
        &probes,
        &[
            ("JawOpen", 0),
            ("mouthsmileleft", 6),
            ("mouthFunnel", 2),
            ("A", mouthpiece_output::CURVES),
        ],
        &[("eyeBlinkLeft", 0.25)],
    );
    // The untouched parts: objects, material, and the Spinner's own animation.
    assert_eq!(samples["objects"], serde_json::json!(["Face", "Spinner"]));
    assert!(samples["materials"]
        .as_array()
        .unwrap()
        .contains(&"Skin".into()));
    assert!(
        samples["tracks"]["Spinner"]
            .as_array()
            .unwrap()
            .contains(&"Spin".into()),
        "{}",
        samples["tracks"]
    );
    let spin = samples["actions"]
        .as_object()
        .unwrap()
        .iter()
        .find(|(name, _)| name.starts_with("Spin"))
        .unwrap_or_else(|| panic!("no Spin action: {}", samples["actions"]));
    assert_eq!(spin.1, &serde_json::json!(["rotation_quaternion"]));
    for at in probes {
        assert_eq!(
            samples["shape_keys"][format!("{at:?}")]["Spinner"]["Bulge"],
            0.0
        );
    }
}

#[test]
fn onto_gltf_keeps_its_bin_and_embeds_the_animation_in_a_new_buffer() {
    let dir = tempfile::tempdir().unwrap();
    let folder = dir.path().join("avatar");
    std::fs::create_dir(&folder).unwrap();
    let avatar = folder.join("avatar.gltf");
    make_avatar(
        &avatar,
        "GLTF_SEPARATE",
        &["JAWOPEN", "mouthPucker", "Smile"],
    );
    let take = dir.path().join("take.jsonl");
    let times = write_take(&take, 20);
    let export = |out: &Path| {
        mouthpiece(&[
            "export",
            take.to_str().unwrap(),
            "--onto",
            avatar.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
    };

    // Beside the avatar, where its `avatar.bin` resolves.
    let out = folder.join("animated.gltf");
    let run = export(&out);
    assert!(run.status.success(), "{}", stderr(&run));
    assert_clean(&out);
    let read = |p: &Path| -> Value { serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap() };
    let (before, after) = (read(&avatar), read(&out));
    assert_only_appended(&before, &after, None);
    let buffers = after["buffers"].as_array().unwrap();
    assert_eq!(buffers.len(), 2);
    assert!(buffers[1]["uri"]
        .as_str()
        .unwrap()
        .starts_with("data:application/octet-stream;base64,"));
    let probes = [times[4], (times[10] + times[11]) / 2.0];
    let samples = blender_samples(&out, "take", &probes);
    assert_shape_keys(
        &samples,
        &times,
        &probes,
        &[("JAWOPEN", 0), ("mouthPucker", 3)],
        &[("Smile", 0.0)],
    );

    // Elsewhere `avatar.bin` would not resolve: refused, nothing written. A .glb from a
    // .gltf is refused too.
    for (out, says) in [
        (dir.path().join("animated.gltf"), "same folder"),
        (folder.join("animated.glb"), "--out NAME.gltf"),
    ] {
        let run = export(&out);
        let err = stderr(&run);
        assert_eq!(run.status.code(), Some(2), "{err}");
        assert!(
            err.contains(avatar.to_str().unwrap()) && err.contains(says),
            "{err}"
        );
        assert!(!out.exists());
    }
}

#[test]
fn onto_an_avatar_without_a_matching_target_is_exit_2_naming_its_targets() {
    let dir = tempfile::tempdir().unwrap();
    let avatar = dir.path().join("avatar.glb");
    make_avatar(&avatar, "GLB", &["eyeBlinkLeft", "browInnerUp", "jaw_open"]);
    let take = dir.path().join("take.jsonl");
    write_take(&take, 5);
    let out = dir.path().join("animated.glb");
    let run = mouthpiece(&[
        "export",
        take.to_str().unwrap(),
        "--onto",
        avatar.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{err}");
    for part in [
        avatar.to_str().unwrap(),
        "no morph target matches",
        "`eyeBlinkLeft`",
        "`browInnerUp`",
        "`jaw_open`",
    ] {
        assert!(err.contains(part), "lacks {part:?}: {err}");
    }
    assert!(!out.exists());
}

#[test]
fn onto_a_malformed_avatar_is_exit_2_naming_the_file_and_element() {
    let dir = tempfile::tempdir().unwrap();
    let take = dir.path().join("take.jsonl");
    write_take(&take, 5);
    let gltf = |extra: &str| {
        format!(
            r#"{{"asset": {{"version": "2.0"}},
                "buffers": [{{"byteLength": 48, "uri": "data:application/octet-stream;base64,{}"}}],
                "bufferViews": [{{"buffer": 0, "byteLength": 48}}],
                "accessors": [{{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"}}],
                "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}, "targets": [{{"POSITION": 0}}]}}],
                             "extras": {{"targetNames": ["jawOpen"]}}}}],
                "nodes": [{{"mesh": 0}}]{extra}}}"#,
            "A".repeat(64)
        )
    };
    let cases = [
        // A sound file, to show the cases below fail for their own reason.
        (gltf(""), None),
        (
            gltf("").replace(r#""byteLength": 48}]"#, r#""byteLength": 4800}]"#),
            Some("bufferViews[0]"),
        ),
        (
            gltf("").replace(r#""count": 4"#, r#""count": 40"#),
            Some("accessors[0]"),
        ),
        (
            gltf("").replace(r#"["jawOpen"]"#, r#"["jawOpen", "mouthClose"]"#),
            Some("meshes[0].extras.targetNames"),
        ),
        (
            gltf("").replace(r#""mesh": 0"#, r#""mesh": 7"#),
            Some("nodes[0].mesh"),
        ),
        (
            gltf(r#", "images": [{"uri": "../../../etc/passwd"}]"#),
            Some("images[0]"),
        ),
        (
            gltf("").replace(
                r#""uri": "data:application/octet-stream;base64,"#,
                r#""uri": "/etc/passwd", "x": ""#,
            ),
            Some("buffers[0]"),
        ),
        ("{\"asset\": ".to_owned(), Some("not glTF JSON")),
    ];
    for (i, (text, element)) in cases.iter().enumerate() {
        let avatar = dir.path().join(format!("avatar{i}.gltf"));
        std::fs::write(&avatar, text).unwrap();
        let out = dir.path().join(format!("out{i}.gltf"));
        let run = mouthpiece(&[
            "export",
            take.to_str().unwrap(),
            "--onto",
            avatar.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        let err = stderr(&run);
        match element {
            None => {
                assert!(run.status.success(), "case {i}: {err}");
                assert!(out.exists(), "case {i}");
            }
            Some(element) => {
                assert_eq!(run.status.code(), Some(2), "case {i}: {err}");
                assert!(
                    err.contains(avatar.to_str().unwrap()) && err.contains(element),
                    "case {i}: lacks {element:?}: {err}"
                );
                assert!(!out.exists(), "case {i}");
            }
        }
    }
}

/// A speech-driven take (`mouthpiece lipsync`) drives an ARKit- and VRM-named avatar as a
/// camera take does: its rig's `jawOpen` and the `aa` viseme it gives reach the shape keys.
#[test]
fn onto_a_lipsync_take_moves_the_avatars_mouth() {
    let dir = tempfile::tempdir().unwrap();
    let avatar = dir.path().join("avatar.glb");
    make_avatar(&avatar, "GLB", &["jawOpen", "A"]);
    let phn = dir.path().join("ah.phn");
    // Silence, "aa" for half a second, silence (TIMIT samples at 16 kHz).
    std::fs::write(&phn, "0 4000 h#\n4000 12000 aa\n12000 16000 h#\n").unwrap();
    let take = dir.path().join("speech.jsonl");
    let character = repo().join("config/characters/human.toml");
    let made = mouthpiece(&[
        "lipsync",
        "--phonemes",
        phn.to_str().unwrap(),
        "--character",
        character.to_str().unwrap(),
        "--out",
        take.to_str().unwrap(),
    ]);
    assert!(made.status.success(), "{}", stderr(&made));
    let out = dir.path().join("animated.glb");
    let run = mouthpiece(&[
        "export",
        take.to_str().unwrap(),
        "--onto",
        avatar.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let report = stderr(&run);
    assert!(run.status.success(), "{report}");
    assert!(report.contains("matched: jawOpen, A ← aa\n"), "{report}");
    assert_clean(&out);
    // Blender at the middle of the "aa": the jaw open and the viseme on.
    let samples = blender_samples(&out, "take", &[0.5]);
    let keys = &samples["shape_keys"]["0.5"]["Face"];
    for name in ["jawOpen", "A"] {
        let v = keys[name]
            .as_f64()
            .unwrap_or_else(|| panic!("{name}: {keys}"));
        assert!(v > 0.2, "{name} {v} at the middle of \"aa\": {keys}");
    }
}
