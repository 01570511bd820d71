//! `mouthpiece bind` and `export --rig` end to end, judged by independent tools: Khronos'
//! glTF-Validator (npm `gltf-validator`) and Blender importing the rigged, animated mesh
//! headless (`tests/blender/skinned_vertex.py`).
//!
//! External tools come from `scripts/test` (Debian packages `nodejs`, `npm`, `blender`,
//! `python3-numpy`; the npm package is installed here on first use if it is missing).

use crate::repo;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use mouthpiece_export::onto_rig::parse_glb;
use mouthpiece_export::{ModelUp, MouthRig};
use serde_json::Value;

fn mouthpiece(args: &[&str]) -> Output {
    crate::mouthpiece()
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("run mouthpiece")
}

fn ok(args: &[&str]) -> String {
    let out = mouthpiece(args);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "mouthpiece {args:?} failed: {stderr}");
    stderr
}

fn character(name: &str) -> PathBuf {
    repo().join(format!("config/characters/{name}.toml"))
}

fn shipped_head(name: &str) -> PathBuf {
    repo().join(format!("config/characters/{name}-head.glb"))
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A tiny network trained here (the tests never use the long training).
fn tiny_model() -> PathBuf {
    static MODEL: OnceLock<PathBuf> = OnceLock::new();
    MODEL
        .get_or_init(|| {
            let dir = tempfile::tempdir().unwrap().keep();
            let path = dir.join("tiny.bin");
            ok(&[
                "bind",
                "train",
                "--widths",
                "tiny",
                "--heads",
                "2",
                "--epochs",
                "3",
                "--seed",
                "11",
                "--out",
                s(&path),
            ]);
            path
        })
        .clone()
}

/// The Khronos validator, installed into tests/js/node_modules from the committed lock file.
fn validator_script() -> PathBuf {
    static READY: OnceLock<PathBuf> = OnceLock::new();
    READY
        .get_or_init(|| {
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
        })
        .clone()
}

/// glTF-Validator's report must be clean: no errors, warnings, infos or hints.
fn assert_valid(path: &Path) {
    let out = Command::new("node")
        .arg(validator_script())
        .arg(path)
        .output()
        .expect("node (Debian package `nodejs`)");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "validator failed: {stdout}");
    let report: Value = serde_json::from_str(stdout.trim()).unwrap();
    let issues = &report["issues"];
    for kind in ["numErrors", "numWarnings", "numInfos", "numHints"] {
        assert_eq!(
            issues[kind],
            0,
            "{}: validator {kind}: {}",
            path.display(),
            serde_json::to_string_pretty(&issues["messages"]).unwrap()
        );
    }
}

/// A GLB's document and one accessor's components as f64.
struct Glb {
    doc: Value,
    bin: Vec<u8>,
}

impl Glb {
    fn read(path: &Path) -> Self {
        let glb = parse_glb(&std::fs::read(path).unwrap()).unwrap();
        Self {
            doc: serde_json::from_slice(&glb.json).unwrap(),
            bin: glb.bin,
        }
    }

    fn accessor(&self, index: usize) -> Vec<Vec<f64>> {
        let a = &self.doc["accessors"][index];
        let view = &self.doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
        let start = view["byteOffset"].as_u64().unwrap_or(0) as usize
            + a["byteOffset"].as_u64().unwrap_or(0) as usize;
        assert!(
            view.get("byteStride").is_none(),
            "strided views are not read here"
        );
        let n = match a["type"].as_str().unwrap() {
            "SCALAR" => 1,
            "VEC3" => 3,
            "VEC2" => 2,
            "VEC4" => 4,
            "MAT4" => 16,
            t => panic!("type {t}"),
        };
        let (size, read): (usize, fn(&[u8]) -> f64) = match a["componentType"].as_u64().unwrap() {
            5126 => (4, |b| f32::from_le_bytes(b.try_into().unwrap()) as f64),
            5121 => (1, |b| b[0] as f64),
            5123 => (2, |b| u16::from_le_bytes(b.try_into().unwrap()) as f64),
            5125 => (4, |b| u32::from_le_bytes(b.try_into().unwrap()) as f64),
            c => panic!("component type {c}"),
        };
        let count = a["count"].as_u64().unwrap() as usize;
        (0..count)
            .map(|e| {
                (0..n)
                    .map(|c| {
                        let at = start + (e * n + c) * size;
                        read(&self.bin[at..at + size])
                    })
                    .collect()
            })
            .collect()
    }

    fn attribute(&self, name: &str) -> Vec<Vec<f64>> {
        let index = self.doc["meshes"][0]["primitives"][0]["attributes"][name]
            .as_u64()
            .unwrap_or_else(|| panic!("no {name}"));
        self.accessor(index as usize)
    }

    fn joint_names(&self) -> Vec<String> {
        self.doc["skins"][0]["joints"]
            .as_array()
            .unwrap()
            .iter()
            .map(|j| {
                self.doc["nodes"][j.as_u64().unwrap() as usize]["name"]
                    .as_str()
                    .unwrap()
                    .to_owned()
            })
            .collect()
    }
}

#[test]
fn human_and_wolf_bind_with_every_method_into_valid_skinned_glbs() {
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model();
    for (name, up) in [("human", "y"), ("wolf", "z")] {
        for method in ["network", "heat", "distance"] {
            let out = dir.path().join(format!("{name}-{method}.glb"));
            ok(&[
                "bind",
                "--character",
                s(&character(name)),
                "--mesh",
                s(&shipped_head(name)),
                "--out",
                s(&out),
                "--method",
                method,
                "--model",
                s(&model),
                "--model-up",
                up,
            ]);
            let glb = Glb::read(&out);
            let mut names = vec!["root".to_owned(), "mouth".to_owned(), "jaw".to_owned()];
            names.extend((1..=12).map(|k| format!("P{k}")));
            assert_eq!(glb.joint_names(), names);
            let weights = glb.attribute("WEIGHTS_0");
            let joints = glb.attribute("JOINTS_0");
            assert_eq!(weights.len(), glb.attribute("POSITION").len());
            let mut moving = 0;
            for (w, j) in weights.iter().zip(&joints) {
                let sum: f64 = w.iter().sum();
                assert!(
                    (sum - 1.0).abs() <= 1e-6,
                    "{name} {method}: row sums to {sum}"
                );
                assert!(w.iter().all(|&x| x >= 0.0));
                assert!(w.iter().filter(|&&x| x > 0.0).count() <= 4);
                if w.iter().zip(j).any(|(&x, &k)| x > 0.0 && k >= 2.0) {
                    moving += 1;
                }
            }
            assert!(
                moving > 12,
                "{name} {method}: only {moving} vertices follow the mouth"
            );
            // every joint's rest world transform times its inverse bind matrix is the identity
            let ibm =
                glb.accessor(glb.doc["skins"][0]["inverseBindMatrices"].as_u64().unwrap() as usize);
            let rig = MouthRig::load_character(&character(name)).unwrap();
            let up = if up == "z" { ModelUp::Z } else { ModelUp::Y };
            let placement = mouthpiece_bind::file_placement(&rig, up).to_homogeneous();
            for (k, m) in ibm.iter().enumerate() {
                let world = match k {
                    0 => nalgebra::Matrix4::identity(),
                    1 => placement,
                    2 => {
                        // the jaw's node: where `bind` put the hinge (read from the face
                        // for the human, the character's pivot for the wolf)
                        let t = &glb.doc["nodes"][node_named(&glb.doc, "jaw")]["translation"];
                        let hinge = nalgebra::Vector3::from_fn(|k, _| t[k].as_f64().unwrap());
                        placement * nalgebra::Matrix4::new_translation(&hinge)
                    }
                    _ => {
                        let r = rig.points()[k - 3].rest;
                        placement * nalgebra::Matrix4::new_translation(&r.into())
                    }
                };
                let product = world * nalgebra::Matrix4::from_column_slice(m);
                assert!(
                    (product - nalgebra::Matrix4::identity()).abs().max() < 1e-5,
                    "{name}: joint {k}: world · inverse bind = {product}"
                );
            }
        }
        assert_valid(&dir.path().join(format!("{name}-network.glb")));
    }
}

/// Writes a GLB with the given positions and triangles (through `bind head`'s writer).
fn write_mesh(path: &Path, positions: Vec<[f64; 3]>, triangles: Vec<[u32; 3]>) {
    let mesh = mouthpiece_bind::Mesh {
        positions,
        triangles,
    };
    mouthpiece_bind::gltf_io::write_plain_glb(path, &mesh, "test").unwrap();
}

#[test]
fn bad_meshes_exit_2_saying_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let human = character("human");
    let bind = |mesh: &Path| {
        let out = dir.path().join("out.glb");
        let o = mouthpiece(&[
            "bind",
            "--character",
            s(&human),
            "--mesh",
            s(mesh),
            "--out",
            s(&out),
            "--method",
            "distance",
        ]);
        assert!(!out.exists(), "an output was written for a bad mesh");
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    // no triangles
    let empty = dir.path().join("empty.glb");
    write_mesh(&empty, vec![[0.0; 3]; 3], vec![]);
    let (code, err) = bind(&empty);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("no triangles"), "{err}");
    // the wolf's head is nowhere near the human's mouth
    let (code, err) = bind(&shipped_head("wolf"));
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("mouth point P1") && err.contains("surface"),
        "{err}"
    );
    // not glTF
    let junk = dir.path().join("junk.glb");
    std::fs::write(&junk, b"solid cube\n").unwrap();
    let (code, err) = bind(&junk);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("not a glTF/GLB"), "{err}");
    // huge (a sparse file: no disk used)
    let huge = dir.path().join("huge.glb");
    std::fs::File::create(&huge)
        .unwrap()
        .set_len(mouthpiece_bind::gltf_io::MAX_FILE_BYTES + 1)
        .unwrap();
    let (code, err) = bind(&huge);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("more than the"), "{err}");
}

/// A take for `rig`: its points moving in the mouth frame, `frames` frames at 30 fps.
fn write_take(path: &Path, rig: &MouthRig, frames: usize) -> Vec<(f64, Vec<[f64; 3]>)> {
    let w = rig.mouth_width();
    let mut text = String::new();
    let mut take = Vec::new();
    for seq in 0..frames {
        let t = seq as f64 / 30.0;
        let open = 0.5 - 0.5 * (2.0 * std::f64::consts::PI * 0.8 * t).cos();
        let pts: Vec<[f64; 3]> = rig
            .points()
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let lower = k >= 7;
                let r = p.rest;
                [
                    r[0] * (1.0 - 0.1 * open),
                    r[1] - if lower {
                        0.25 * w * open
                    } else {
                        -0.05 * w * open
                    },
                    r[2] + 0.03 * w * (3.0 * t + k as f64).sin(),
                ]
            })
            .collect();
        let field = |f: &dyn Fn(usize) -> String| -> String {
            let entries: Vec<String> = (0..pts.len())
                .map(|k| format!("\"{}\": {}", rig.points()[k].name, f(k)))
                .collect();
            format!("{{{}}}", entries.join(", "))
        };
        text.push_str(&format!(
            "{{\"t\": {t:?}, \"seq\": {seq}, \"character\": \"{}\", \"points\": {}, \"confidence\": {}, \
             \"head\": {{\"rotation\": [1.0, 0.0, 0.0, 0.0], \"translation\": [0.0, 0.0, 0.6]}}, \
             \"head_lost\": false, \"curve\": null}}\n",
            rig.character().unwrap(),
            field(&|k| serde_json::json!(pts[k]).to_string()),
            field(&|_| "1.0".to_owned()),
        ));
        take.push((t, pts));
    }
    std::fs::write(path, text).unwrap();
    take
}

#[test]
fn a_take_plays_on_the_bound_wolf_in_blender_where_mouthpiece_skins_it() {
    let dir = tempfile::tempdir().unwrap();
    let wolf = character("wolf");
    let rig = MouthRig::load_character(&wolf).unwrap();
    let rigged = dir.path().join("wolf-rigged.glb");
    ok(&[
        "bind",
        "--character",
        s(&wolf),
        "--mesh",
        s(&shipped_head("wolf")),
        "--out",
        s(&rigged),
        "--method",
        "heat",
        "--model-up",
        "z",
        // the points' translations only: what this test computes on its own
        "--no-jaw",
    ]);
    let take_path = dir.path().join("take.jsonl");
    let take = write_take(&take_path, &rig, 40);
    let animated = dir.path().join("wolf-take.glb");
    ok(&[
        "export",
        s(&take_path),
        "--character",
        s(&wolf),
        "--rig",
        s(&rigged),
        "--out",
        s(&animated),
    ]);
    assert_valid(&animated);

    // Lip vertices: the most mixed ones (largest second weight) among those on the mouth.
    let glb = Glb::read(&animated);
    let positions = glb.attribute("POSITION");
    let weights = glb.attribute("WEIGHTS_0");
    let joints = glb.attribute("JOINTS_0");
    let mut order: Vec<usize> = (0..positions.len()).collect();
    order.sort_by(|&a, &b| weights[b][1].total_cmp(&weights[a][1]));
    let probes: Vec<usize> = order.into_iter().take(3).collect();
    let (t, points) = &take[27];
    let rotation = mouthpiece_bind::file_placement(&rig, ModelUp::Z).rotation;
    let expected: Vec<[f64; 3]> = probes
        .iter()
        .map(|&v| {
            let mut d = nalgebra::Vector3::zeros();
            for slot in 0..4 {
                let j = joints[v][slot] as usize;
                if j >= 2 {
                    let k = j - 2;
                    let now = nalgebra::Vector3::from(points[k]);
                    let rest = nalgebra::Vector3::from(rig.points()[k].rest);
                    d += weights[v][slot] * (now - rest);
                }
            }
            let moved = nalgebra::Vector3::new(positions[v][0], positions[v][1], positions[v][2])
                + rotation * d;
            [moved.x, moved.y, moved.z]
        })
        .collect();
    for (&v, e) in probes.iter().zip(&expected) {
        let rest = nalgebra::Vector3::new(positions[v][0], positions[v][1], positions[v][2]);
        assert!(
            (nalgebra::Vector3::from(*e) - rest).norm() > 0.01 * rig.mouth_width(),
            "probe vertex {v} hardly moves: the test would prove nothing"
        );
    }

    let script = repo().join("tests/blender/skinned_vertex.py");
    let mut cmd = Command::new("blender");
    cmd.args([
        "-b",
        "--factory-startup",
        "--python-exit-code",
        "1",
        "--python",
    ])
    .arg(script)
    .arg("--")
    .arg(&animated)
    .arg(format!("{t:?}"));
    for &v in &probes {
        cmd.arg(format!(
            "{},{},{}",
            positions[v][0], positions[v][1], positions[v][2]
        ));
    }
    let out = cmd
        .output()
        .expect("blender (Debian package `blender`, installed by scripts/test)");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "blender failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let line = stdout
        .lines()
        .find_map(|l| l.strip_prefix("SKINNED "))
        .unwrap_or_else(|| panic!("no SKINNED line from Blender:\n{stdout}"));
    let report: Value = serde_json::from_str(line).unwrap();
    let tolerance = 1e-4 * rig.mouth_width();
    for (i, e) in expected.iter().enumerate() {
        let got = &report["vertices"][i];
        assert!(
            got["rest_distance"].as_f64().unwrap() < 1e-6,
            "Blender's nearest vertex is not the probe: {got}"
        );
        let at: Vec<f64> = got["at"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c.as_f64().unwrap())
            .collect();
        let err = ((at[0] - e[0]).powi(2) + (at[1] - e[1]).powi(2) + (at[2] - e[2]).powi(2)).sqrt();
        assert!(
            err <= tolerance,
            "vertex {}: Blender {at:?}, mouthpiece {e:?}: {err} apart (tolerance {tolerance})",
            probes[i]
        );
    }
}

#[test]
fn export_rig_refuses_a_mesh_that_is_not_a_rig() {
    let dir = tempfile::tempdir().unwrap();
    let wolf = character("wolf");
    let rig = MouthRig::load_character(&wolf).unwrap();
    let take_path = dir.path().join("take.jsonl");
    write_take(&take_path, &rig, 3);
    let out = dir.path().join("x.glb");
    let o = mouthpiece(&[
        "export",
        s(&take_path),
        "--character",
        s(&wolf),
        "--rig",
        s(&shipped_head("wolf")),
        "--out",
        s(&out),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("no skin"), "{err}");
}

#[test]
fn head_writes_a_valid_mesh_and_evaluate_prints_the_table() {
    let dir = tempfile::tempdir().unwrap();
    let head = dir.path().join("head.glb");
    ok(&[
        "bind",
        "head",
        "--character",
        s(&character("human")),
        "--resolution",
        "1",
        "--out",
        s(&head),
    ]);
    assert_valid(&head);
    let out = mouthpiece(&[
        "bind",
        "evaluate",
        "--heads",
        "1",
        "--model",
        s(&tiny_model()),
        "--character",
        s(&character("wolf")),
        "--snout",
        "1",
    ]);
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for method in ["network", "heat", "distance", "reference"] {
        assert!(
            table.contains(&format!("| **mean** | **{method}** |")),
            "{table}"
        );
        assert!(table.contains(&format!("| wolf | {method} |")), "{table}");
    }
    // the held-out heads' seed is not a training seed
    let o = mouthpiece(&[
        "bind",
        "train",
        "--seed",
        "1319952",
        "--out",
        s(&dir.path().join("x.bin")),
    ]);
    assert_eq!(o.status.code(), Some(2));
}

/// Runs `mouthpiece args`: exit 2, `what` in the error, nothing at `out`.
fn refused(args: &[&str], what: &str, out: &Path) {
    let o = mouthpiece(args);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
    assert!(err.contains(what), "{args:?}: {err}");
    assert!(!out.exists(), "{args:?} left {}", out.display());
}

#[test]
fn a_head_resolution_whose_head_is_too_large_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.glb");
    // 12·R·(5R + 2) vertices: 6·10^11 at R = 100000
    refused(
        &[
            "bind",
            "head",
            "--character",
            s(&character("human")),
            "--resolution",
            "100000",
            "--out",
            s(&out),
        ],
        "--resolution",
        &out,
    );
}

#[test]
fn a_billion_heads_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.bin");
    refused(
        &["bind", "evaluate", "--heads", "1000000000"],
        "--heads",
        &out,
    );
    refused(
        &[
            "bind",
            "train",
            "--seed",
            "1",
            "--heads",
            "1000000000",
            "--out",
            s(&out),
        ],
        "--heads",
        &out,
    );
}

#[test]
fn a_snout_of_nan_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    refused(
        &[
            "bind",
            "evaluate",
            "--heads",
            "0",
            "--character",
            s(&character("human")),
            "--snout",
            "NaN",
        ],
        "--snout",
        &dir.path().join("nothing"),
    );
}

#[test]
fn a_mesh_naming_a_buffer_outside_its_folder_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.glb");
    let asset = dir.path().join("asset");
    std::fs::create_dir(&asset).unwrap();
    let mesh = asset.join("mesh.gltf");
    std::fs::write(
        &mesh,
        serde_json::json!({
            "asset": {"version": "2.0"},
            "buffers": [{"uri": "/etc/passwd", "byteLength": 12}],
            "meshes": [],
        })
        .to_string(),
    )
    .unwrap();
    refused(
        &[
            "bind",
            "--character",
            s(&character("human")),
            "--mesh",
            s(&mesh),
            "--out",
            s(&out),
            "--method",
            "distance",
        ],
        "buffer 0: URI `/etc/passwd` is an absolute path",
        &out,
    );
}

#[test]
fn a_character_without_the_twelve_points_is_refused_naming_its_file() {
    let dir = tempfile::tempdir().unwrap();
    let four = dir.path().join("four.toml");
    std::fs::write(
        &four,
        "name = \"four\"\nunits = \"cm\"\nup = [0.0, 0.0, 1.0]\n[points]\n\
         P1 = [7.5, 0.0, 0.0]\nP2 = [0.0, 0.0, 4.0]\nP3 = [-7.5, 0.0, 0.0]\nP4 = [0.0, 0.0, -4.0]\n",
    )
    .unwrap();
    let out = dir.path().join("x.glb");
    for args in [
        vec!["bind", "head", "--character", s(&four), "--out", s(&out)],
        vec![
            "bind",
            "--character",
            s(&four),
            "--mesh",
            s(&shipped_head("human")),
            "--out",
            s(&out),
            "--method",
            "distance",
        ],
    ] {
        refused(
            &args,
            &format!("{}: the character has 4 mouth points", four.display()),
            &out,
        );
    }
}

/// Runs a Blender script headless; its stdout.
fn blender(script: &str, args: &[&Path]) -> String {
    let mut cmd = Command::new("blender");
    cmd.args([
        "-b",
        "--factory-startup",
        "--python-exit-code",
        "1",
        "--python",
    ])
    .arg(repo().join("tests/blender").join(script))
    .arg("--")
    .args(args);
    let out = cmd
        .output()
        .expect("blender (Debian package `blender`, installed by scripts/test)");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "blender {script} failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// The validator's message codes by severity (0 errors, 1 warnings).
fn validator_codes(path: &Path, severity: u64) -> std::collections::BTreeSet<String> {
    let out = Command::new("node")
        .arg(validator_script())
        .arg(path)
        .output()
        .expect("node (Debian package `nodejs`)");
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    report["issues"]["messages"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| m["severity"] == severity)
        .map(|m| m["code"].as_str().unwrap().to_owned())
        .collect()
}

fn node_named(doc: &Value, name: &str) -> usize {
    doc["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .position(|n| n["name"] == name)
        .unwrap_or_else(|| panic!("no node {name}"))
}

/// A rigger's head modelled in Blender at test time (tests/blender/make_rigged_head.py: a UV
/// sphere with a texture, a shape key, an armature with an action, eyes on the head bone,
/// teeth and a tongue on their own) comes back from `bind` with everything it had, the
/// mouth's joints joined to its skeleton under `head`; Blender opens it with its texture,
/// UVs and shape key, and a take exported onto it moves the lower lip.
#[test]
fn a_blender_head_comes_back_with_everything_it_had_joined_to_its_skeleton() {
    let dir = tempfile::tempdir().unwrap();
    let head = dir.path().join("head.glb");
    let toml = dir.path().join("head.toml");
    blender("make_rigged_head.py", &[&head, &toml]);
    let bound = dir.path().join("bound.glb");
    let report = ok(&[
        "bind",
        "--character",
        s(&toml),
        "--mesh",
        s(&head),
        "--out",
        s(&bound),
    ]);
    assert!(report.contains("the mouth under head"), "{report}");
    let (input, output) = (Glb::read(&head), Glb::read(&bound));
    // kept as they were: materials, textures, images, samplers, animations, scenes' roots
    for key in ["materials", "textures", "samplers", "animations"] {
        assert_eq!(input.doc[key], output.doc[key], "{key} changed");
    }
    assert_eq!(
        input.doc["images"].as_array().unwrap().len(),
        output.doc["images"].as_array().unwrap().len()
    );
    for node in input.doc["nodes"].as_array().unwrap() {
        let name = node["name"].as_str().unwrap();
        // a rigid part newly skinned moves to the scene's root; its old node keeps its place
        let out = &output.doc["nodes"][node_named(&output.doc, name)];
        let placed = output.doc["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|n| n["name"] == format!("{name}_transform"))
            .unwrap_or(out);
        for key in ["translation", "rotation", "scale"] {
            assert_eq!(node[key], placed[key], "node {name}: {key}");
        }
        // children kept, in order (the mouth joins the head's)
        let children = node["children"].as_array().cloned().unwrap_or_default();
        let now = placed["children"].as_array().cloned().unwrap_or_default();
        assert_eq!(children[..], now[..children.len()], "node {name}: children");
        assert_eq!(node["mesh"], out["mesh"], "node {name}: mesh");
    }
    // every attribute, index list and morph target holds the same numbers
    let meshes = input.doc["meshes"].as_array().unwrap();
    for (m, mesh) in meshes.iter().enumerate() {
        for (p, prim) in mesh["primitives"].as_array().unwrap().iter().enumerate() {
            let out_prim = &output.doc["meshes"][m]["primitives"][p];
            let mut accessors: Vec<(String, &Value, &Value)> =
                vec![("indices".into(), &prim["indices"], &out_prim["indices"])];
            for (name, a) in prim["attributes"].as_object().unwrap() {
                if !name.starts_with("JOINTS_") && !name.starts_with("WEIGHTS_") {
                    accessors.push((name.clone(), a, &out_prim["attributes"][name]));
                }
            }
            for (t, target) in prim["targets"].as_array().into_iter().flatten().enumerate() {
                for (name, a) in target.as_object().unwrap() {
                    accessors.push((
                        format!("target {t} {name}"),
                        a,
                        &out_prim["targets"][t][name],
                    ));
                }
            }
            for (name, a, b) in accessors {
                let (a, b) = (a.as_u64().unwrap(), b.as_u64().unwrap());
                assert_eq!(
                    input.accessor(a as usize),
                    output.accessor(b as usize),
                    "mesh {m} primitive {p}: {name}"
                );
            }
            assert_eq!(prim["material"], out_prim["material"]);
        }
    }
    // the skin: the old joints in order, then the mouth's, the mouth under `head`
    let face = node_named(&output.doc, "Head");
    let skin = output.doc["nodes"][face]["skin"].as_u64().unwrap() as usize;
    let old_joints = input.doc["skins"][0]["joints"].as_array().unwrap();
    let joints = output.doc["skins"][skin]["joints"].as_array().unwrap();
    assert_eq!(&joints[..old_joints.len()], &old_joints[..]);
    let names: Vec<&str> = joints[old_joints.len()..]
        .iter()
        .map(|j| {
            output.doc["nodes"][j.as_u64().unwrap() as usize]["name"]
                .as_str()
                .unwrap()
        })
        .collect();
    let mut expected = vec!["mouth".to_owned(), "jaw".to_owned()];
    expected.extend((1..=12).map(|k| format!("P{k}")));
    assert_eq!(names, expected);
    // the lower lip's joints ride on the jaw
    let jaw = node_named(&output.doc, "jaw");
    let jaw_children = output.doc["nodes"][jaw]["children"].as_array().unwrap();
    assert_eq!(jaw_children.len(), 5);
    for child in jaw_children {
        let name = output.doc["nodes"][child.as_u64().unwrap() as usize]["name"]
            .as_str()
            .unwrap();
        assert!(
            ["P8", "P9", "P10", "P11", "P12"].contains(&name),
            "{name} on the jaw"
        );
    }
    let mouth = node_named(&output.doc, "mouth");
    let head_bone = node_named(&output.doc, "head");
    assert!(output.doc["nodes"][head_bone]["children"]
        .as_array()
        .unwrap()
        .contains(&serde_json::json!(mouth)));
    // weights far from the mouth are the file's own
    let weights_in = input.attribute("WEIGHTS_0");
    let weights_out = output.attribute("WEIGHTS_0");
    let joints_in = input.attribute("JOINTS_0");
    let joints_out = output.attribute("JOINTS_0");
    let (mut kept, mut changed) = (0, 0);
    for v in 0..weights_in.len() {
        let mouth_weight: f64 = (0..4)
            .filter(|&k| joints_out[v][k] as usize >= old_joints.len())
            .map(|k| weights_out[v][k])
            .sum();
        if mouth_weight == 0.0 {
            assert_eq!(joints_in[v], joints_out[v], "vertex {v}");
            for k in 0..4 {
                assert!(
                    (weights_in[v][k] - weights_out[v][k]).abs() < 1e-6,
                    "vertex {v}"
                );
            }
            kept += 1;
        } else {
            changed += 1;
        }
    }
    assert!(
        kept > 1000 && changed > 12,
        "kept {kept}, changed {changed}"
    );
    // valid: no error, no warning the input did not have
    assert!(validator_codes(&bound, 0).is_empty());
    let new_warnings: Vec<String> = validator_codes(&bound, 1)
        .difference(&validator_codes(&head, 1))
        .cloned()
        .collect();
    assert!(new_warnings.is_empty(), "new warnings: {new_warnings:?}");

    // a take onto it
    let rig = MouthRig::load_character(&toml).unwrap();
    let take_path = dir.path().join("take.jsonl");
    let take = write_take(&take_path, &rig, 40);
    let animated = dir.path().join("take.glb");
    ok(&[
        "export",
        s(&take_path),
        "--character",
        s(&toml),
        "--rig",
        s(&bound),
        "--out",
        s(&animated),
    ]);
    assert!(validator_codes(&animated, 0).is_empty());
    // Blender: the texture, UVs and shape key are there, and the lower lip moves
    let p10 = rig.placement() * nalgebra::Point3::from(rig.points()[9].rest);
    let (t, _) = &take[15];
    let stdout = Command::new("blender")
        .args([
            "-b",
            "--factory-startup",
            "--python-exit-code",
            "1",
            "--python",
        ])
        .arg(repo().join("tests/blender/inspect_bound.py"))
        .arg("--")
        .arg(&animated)
        .arg(format!("{t:?}"))
        .arg(format!("{},{},{}", p10.x, p10.y, p10.z))
        .output()
        .expect("blender");
    let stdout = String::from_utf8_lossy(&stdout.stdout);
    let line = stdout
        .lines()
        .find_map(|l| l.strip_prefix("BOUND "))
        .unwrap_or_else(|| panic!("no BOUND line from Blender:\n{stdout}"));
    let seen: Value = serde_json::from_str(line).unwrap();
    let head_mesh = &seen["meshes"]["Head"];
    assert_eq!(
        head_mesh["uv_layers"],
        serde_json::json!(["UVMap"]),
        "{seen}"
    );
    assert_eq!(
        head_mesh["images"],
        serde_json::json!([["skin", 32, 32]]),
        "{seen}"
    );
    assert_eq!(
        head_mesh["shape_keys"],
        serde_json::json!(["Basis", "Puff"]),
        "{seen}"
    );
    assert_eq!(head_mesh["armature"], true);
    for part in ["EyeL", "EyeR", "TeethUpper", "Tongue"] {
        assert!(seen["meshes"][part].is_object(), "{part} missing: {seen}");
    }
    let bones: Vec<&str> = seen["bones"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b.as_str().unwrap())
        .collect();
    assert!(report.contains("\"Tongue\") follows jaw"), "{report}");
    assert!(report.contains("\"TeethUpper\") follows head"), "{report}");
    for bone in ["root", "neck", "head", "mouth", "jaw", "P1", "P12"] {
        assert!(bones.contains(&bone), "{bone} not among {bones:?}");
    }
    let moved = seen["moved"].as_f64().unwrap();
    assert!(
        moved > 0.05 * rig.mouth_width(),
        "the lower lip moved {moved} in Blender: {seen}"
    );
}

/// A head with a welded non-manifold seam (a fin on one of its edges) and a separate shell
/// binds, and the report says what was found.
#[test]
fn a_non_manifold_head_with_separate_shells_binds_and_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let human = character("human");
    let rig = MouthRig::load_character(&human).unwrap();
    let mut head = mouthpiece_bind::character_head(&rig, ModelUp::Y, 0.0, 2).unwrap();
    let [a, b, _] = head.triangles[0];
    let n = head.positions.len() as u32;
    let pa = head.positions[a as usize];
    head.positions.push([pa[0], pa[1] + 0.01, pa[2] - 0.01]);
    head.triangles.push([a, b, n]);
    // a tooth: a separate tetrahedron behind the lips
    let base = head.positions.len() as u32;
    head.positions.extend([
        [0.0, 0.0, -0.02],
        [0.01, 0.0, -0.02],
        [0.0, 0.01, -0.02],
        [0.0, 0.0, -0.03],
    ]);
    for t in [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]] {
        head.triangles.push(t.map(|i| base + i));
    }
    let path = dir.path().join("seams.glb");
    write_mesh(&path, head.positions, head.triangles);
    for method in ["heat", "distance", "network"] {
        let out = dir.path().join(format!("{method}.glb"));
        let report = ok(&[
            "bind",
            "--character",
            s(&human),
            "--mesh",
            s(&path),
            "--out",
            s(&out),
            "--method",
            method,
        ]);
        assert!(
            report.contains("2 shell(s), 1 non-manifold edge(s)"),
            "{method}: {report}"
        );
        assert_valid(&out);
    }
}

/// With empties named `P1` … `P12` in the file, the mouth's joints go where they are, not
/// where the character file says (here 0.3 m above, off the mesh, and with P10 2 mm higher
/// than the rigger's), and a take exported onto the rig moves each joint from its own rest.
#[test]
fn mouth_points_come_from_the_files_nodes_named_like_them() {
    let dir = tempfile::tempdir().unwrap();
    let rig = MouthRig::load_character(&character("human")).unwrap();
    let mut toml = "name = \"human\"\nunits = \"m\"\n\n[points]\n".to_owned();
    for p in rig.points() {
        let r = p.rest;
        toml.push_str(&format!(
            "{} = [{:?}, {:?}, {:?}]\n",
            p.name,
            r[0],
            r[1] + 0.3,
            r[2]
        ));
    }
    let shifted = dir.path().join("shifted.toml");
    std::fs::write(&shifted, toml).unwrap();
    let bind = |mesh: &Path, out: &Path| {
        mouthpiece(&[
            "bind",
            "--character",
            s(&shifted),
            "--mesh",
            s(mesh),
            "--out",
            s(out),
            "--method",
            "distance",
            // the joints' translations all in the mouth frame, as checked below
            "--no-jaw",
        ])
    };
    let plain = dir.path().join("plain.glb");
    let o = bind(&shipped_head("human"), &plain);
    assert_eq!(o.status.code(), Some(2), "the points are off the mesh");
    // the same head with the empties
    let mut glb = Glb::read(&shipped_head("human"));
    let placed = |k: usize| {
        let r = rig.points()[k].rest;
        [r[0], r[1] - if k == 9 { 0.002 } else { 0.0 }, r[2]]
    };
    for (k, p) in rig.points().iter().enumerate() {
        let nodes = glb.doc["nodes"].as_array_mut().unwrap();
        nodes.push(serde_json::json!({"name": p.name, "translation": placed(k)}));
        let k = nodes.len() - 1;
        glb.doc["scenes"][0]["nodes"]
            .as_array_mut()
            .unwrap()
            .push(serde_json::json!(k));
    }
    let with_nodes = dir.path().join("with-nodes.glb");
    let mut bytes = Vec::new();
    mouthpiece_export::onto_rig::write_glb(
        &serde_json::to_vec(&glb.doc).unwrap(),
        &glb.bin,
        &mut bytes,
    )
    .unwrap();
    std::fs::write(&with_nodes, bytes).unwrap();
    let bound = dir.path().join("bound.glb");
    let o = bind(&with_nodes, &bound);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(stderr.contains("the file's nodes"), "{stderr}");
    let out = Glb::read(&bound);
    let joints = out.doc["skins"][0]["joints"].as_array().unwrap().clone();
    for (k, p) in rig.points().iter().enumerate() {
        let node = &out.doc["nodes"][joints[2 + k].as_u64().unwrap() as usize];
        assert_eq!(node["name"], p.name.as_str());
        let t: Vec<f64> = node["translation"]
            .as_array()
            .map(|a| a.iter().map(|c| c.as_f64().unwrap()).collect())
            .unwrap_or(vec![0.0; 3]);
        for c in 0..3 {
            assert!(
                (t[c] - placed(k)[c]).abs() < 1e-6,
                "{}: {t:?} vs {:?}",
                p.name,
                placed(k)
            );
        }
    }
    // a take for the shifted character: each key moves by the joint's rest minus the take's
    let take_path = dir.path().join("take.jsonl");
    let shifted_rig = MouthRig::load_character(&shifted).unwrap();
    let take = write_take(&take_path, &shifted_rig, 10);
    let animated = dir.path().join("take.glb");
    ok(&[
        "export",
        s(&take_path),
        "--character",
        s(&shifted),
        "--rig",
        s(&bound),
        "--out",
        s(&animated),
    ]);
    let anim = Glb::read(&animated);
    for k in [0, 9] {
        let joint = joints[2 + k].as_u64().unwrap();
        let channel = anim.doc["animations"][0]["channels"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["target"]["node"] == joint && c["target"]["path"] == "translation")
            .unwrap()
            .clone();
        let sampler =
            &anim.doc["animations"][0]["samplers"][channel["sampler"].as_u64().unwrap() as usize];
        let first = &anim.accessor(sampler["output"].as_u64().unwrap() as usize)[0];
        let take_first = take[0].1[k];
        let expected = [
            take_first[0],
            take_first[1] + placed(k)[1] - rig.points()[k].rest[1],
            take_first[2],
        ];
        for c in 0..3 {
            assert!(
                (first[c] - expected[c]).abs() < 1e-5,
                "P{}'s first key {first:?}, expected {expected:?}",
                k + 1
            );
        }
    }
}

/// `export --rig` onto a rig with a jaw: the lower lip's joints ride on the jaw, so their keys
/// are in the jaw's frame; composed with the jaw's keys they land on the take's points.
#[test]
fn lower_lip_keys_on_the_jaw_land_on_the_takes_points() {
    let dir = tempfile::tempdir().unwrap();
    let human = character("human");
    let rig = MouthRig::load_character(&human).unwrap();
    let bound = dir.path().join("bound.glb");
    ok(&[
        "bind",
        "--character",
        s(&human),
        "--mesh",
        s(&shipped_head("human")),
        "--out",
        s(&bound),
        "--method",
        "distance",
    ]);
    let take_path = dir.path().join("take.jsonl");
    let take = write_take(&take_path, &rig, 30);
    // the jaw turning and sliding as the take goes
    let curves: Vec<String> = mouthpiece_output::CURVE_NAMES
        .iter()
        .map(|n| format!("\"{n}\": 0.0"))
        .collect();
    let text: String = std::fs::read_to_string(&take_path)
        .unwrap()
        .lines()
        .enumerate()
        .map(|(i, line)| {
            let rig = format!(
                r#", "rig": {{"jaw": {{"angle_deg": {:?}, "slide_m": {:?}}}, "lips": {{"upper": {{"rotation": [1, 0, 0, 0], "translation": [0, 0, 0], "residual": 0}}, "lower": {{"rotation": [1, 0, 0, 0], "translation": [0, 0, 0], "residual": 0}}}}, "curves": {{{}}}}}"#,
                15.0 * (0.3 * i as f64).sin().abs(),
                0.001 * (0.2 * i as f64).sin(),
                curves.join(", ")
            );
            format!("{}\n", line.replace("\"curve\": null", &format!("\"curve\": null{rig}")))
        })
        .collect();
    std::fs::write(&take_path, text).unwrap();
    let animated = dir.path().join("take.glb");
    ok(&[
        "export",
        s(&take_path),
        "--character",
        s(&human),
        "--rig",
        s(&bound),
        "--out",
        s(&animated),
    ]);
    assert_valid(&animated);
    let glb = Glb::read(&animated);
    let anim = &glb.doc["animations"][0];
    let keys = |node: usize, path: &str| -> (Vec<f64>, Vec<Vec<f64>>) {
        let c = anim["channels"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["target"]["node"] == node && c["target"]["path"] == path)
            .unwrap_or_else(|| panic!("no {path} keys on node {node}"));
        let sampler = &anim["samplers"][c["sampler"].as_u64().unwrap() as usize];
        let times = glb.accessor(sampler["input"].as_u64().unwrap() as usize);
        (
            times.iter().map(|t| t[0]).collect(),
            glb.accessor(sampler["output"].as_u64().unwrap() as usize),
        )
    };
    let jaw = node_named(&glb.doc, "jaw");
    let (jaw_times, rotations) = keys(jaw, "rotation");
    let (_, translations) = keys(jaw, "translation");
    assert!(
        rotations.iter().any(|q| q[0].abs() > 0.05),
        "the jaw never turns: the test would prove nothing"
    );
    let mut checked = 0;
    for k in [7usize, 9, 11] {
        let point = node_named(&glb.doc, &format!("P{}", k + 1));
        let (times, locals) = keys(point, "translation");
        for (t, local) in times.iter().zip(&locals) {
            let Some(f) = jaw_times.iter().position(|jt| jt == t) else {
                continue;
            };
            let q = &rotations[f];
            let r = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                q[3], q[0], q[1], q[2],
            ));
            let world = r * nalgebra::Vector3::new(local[0], local[1], local[2])
                + nalgebra::Vector3::new(
                    translations[f][0],
                    translations[f][1],
                    translations[f][2],
                );
            let frame = take
                .iter()
                .position(|(tt, _)| (*tt as f32) == (*t as f32))
                .expect("a key at a frame's time");
            let expected = take[frame].1[k];
            for c in 0..3 {
                assert!(
                    (world[c] - expected[c]).abs() < 1e-5,
                    "P{} at {t}: {world:?} vs {expected:?}",
                    k + 1
                );
            }
            checked += 1;
        }
    }
    assert!(checked >= 3, "only {checked} keys checked");
}

/// `bind` without `--method` follows the default's rule (docs/bind.md, "The default
/// method": the network, whatever the mouth): on an open mouth (the human head, its lips
/// apart) and a closed one (the same head with the lips welded into one surface) the output
/// is byte for byte what `--method network` writes, and not what heat diffusion writes.
#[test]
fn bind_without_a_method_uses_the_network_on_open_and_closed_mouths() {
    let dir = tempfile::tempdir().unwrap();
    let human = character("human");
    let rig = MouthRig::load_character(&human).unwrap();
    let head = mouthpiece_bind::character_head(&rig, ModelUp::Y, 0.0, 3).unwrap();
    let closed = mouthpiece_bind::families::weld_lips(&head, 36);
    let open_path = dir.path().join("open.glb");
    let closed_path = dir.path().join("closed.glb");
    write_mesh(&open_path, head.positions, head.triangles);
    write_mesh(&closed_path, closed.positions, closed.triangles);
    for mesh in [&open_path, &closed_path] {
        let bound = |method: Option<&str>| {
            let out = dir
                .path()
                .join(format!("{}.glb", method.unwrap_or("default")));
            let mut args = vec![
                "bind",
                "--character",
                s(&human),
                "--mesh",
                s(mesh),
                "--out",
                s(&out),
            ];
            if let Some(m) = method {
                args.extend(["--method", m]);
            }
            ok(&args);
            std::fs::read(&out).unwrap()
        };
        let default = bound(None);
        assert!(
            default == bound(Some("network")),
            "{}: the default's output is not --method network's",
            mesh.display()
        );
        assert!(
            default != bound(Some("heat")),
            "{}: heat and the network wrote the same file",
            mesh.display()
        );
    }
}

/// The jaw's hinge: read from the face when the character gives none (the human), the
/// character's `[rig] jaw_pivot` when it does (the wolf), and `--jaw-hinge` over both.
#[test]
fn the_jaw_hinge_comes_from_the_flag_the_character_or_the_face() {
    let dir = tempfile::tempdir().unwrap();
    let jaw_at = |name: &str, up: &str, extra: &[&str]| {
        let out = dir.path().join(format!("{name}-{}.glb", extra.len()));
        let (file, mesh) = (character(name), shipped_head(name));
        let mut args = vec![
            "bind",
            "--character",
            s(&file),
            "--mesh",
            s(&mesh),
            "--out",
            s(&out),
            "--method",
            "distance",
            "--model-up",
            up,
        ];
        args.extend(extra);
        ok(&args);
        let glb = Glb::read(&out);
        let jaw = node_named(&glb.doc, "jaw");
        let t = &glb.doc["nodes"][jaw]["translation"];
        nalgebra::Vector3::from_fn(|k, _| t[k].as_f64().unwrap_or(0.0))
    };
    let human = MouthRig::load_character(&character("human")).unwrap();
    assert!(human.jaw_pivot().is_none());
    let w = human.mouth_width();
    let found = jaw_at("human", "y", &[]);
    let default = nalgebra::Vector3::from(human.jaw_hinge());
    // at the mouth's level, behind it, and not the rig's default (0.5 up, 1.6 back)
    assert!(found.y.abs() < 1e-6 * w, "{found:?}");
    assert!(
        found.z <= -0.6 * w + 1e-6 && found.z >= -4.0 * w,
        "{found:?}"
    );
    assert!(
        (found - default).norm() > 0.1 * w,
        "{found:?} is the default"
    );
    // the flag wins over the face
    let flag = "0,-0.02,-0.06";
    let placement = mouthpiece_bind::file_placement(&human, ModelUp::Y);
    let want = placement.inverse_transform_point(&nalgebra::Point3::new(0.0, -0.02, -0.06));
    let given = jaw_at("human", "y", &["--jaw-hinge", flag]);
    assert!(
        (given - want.coords).norm() < 1e-6,
        "{given:?} against {want:?}"
    );
    // the character's pivot wins over the face
    let wolf = MouthRig::load_character(&character("wolf")).unwrap();
    let pivot = nalgebra::Vector3::from(wolf.jaw_pivot().unwrap());
    let at = jaw_at("wolf", "z", &[]);
    assert!((at - pivot).norm() < 1e-6, "{at:?} against {pivot:?}");
}
