//! Hostile and malformed meshes: the reader refuses them with an error naming the file and
//! where in it, without reading outside the asset's folder, allocating what a header claims
//! or panicking.

use std::path::{Path, PathBuf};

use mouthpiece_bind::gltf_io::{read_mesh, read_mesh_bytes, MAX_INSTANCES};
use mouthpiece_bind::{BindError, BindOptions, Method, ModelUp};
use mouthpiece_export::MouthRig;
use serde_json::{json, Value};

/// A unit square in the xy plane: 4 vertices (f32 VEC3), 2 triangles (u16 indices).
fn square_bytes() -> Vec<u8> {
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
    bin
}

/// A glTF document of the square, its one buffer at `uri`.
fn square_doc(uri: &str) -> Value {
    json!({
        "asset": {"version": "2.0"},
        "buffers": [{"uri": uri, "byteLength": 60}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 12}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0
    })
}

fn data_uri(bytes: &[u8]) -> String {
    use base64::Engine as _;
    format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

/// Reads `doc` as a `.gltf` at a made-up path (buffers must be `data:` URIs).
fn read_doc(doc: &Value) -> Result<usize, String> {
    let bytes = serde_json::to_vec(doc).unwrap();
    read_mesh_bytes(&bytes, Path::new("/nonexistent/hostile.gltf"))
        .map(|m| m.original.len())
        .map_err(|e| e.to_string())
}

fn refused(doc: &Value, expected: &[&str]) {
    let err = read_doc(doc).expect_err("the file must be refused");
    assert!(err.contains("/nonexistent/hostile.gltf"), "{err}");
    for e in expected {
        assert!(err.contains(e), "expected `{e}` in: {err}");
    }
    assert!(err.len() < 600, "an error of {} bytes: {err}", err.len());
}

#[test]
fn buffers_outside_the_asset_folder_are_never_read() {
    let dir = tempfile::tempdir().unwrap();
    let asset = dir.path().join("asset");
    std::fs::create_dir(&asset).unwrap();
    // The "secret" outside the folder is a valid buffer: read, it would make a mesh.
    let secret = dir.path().join("secret.bin");
    std::fs::write(&secret, square_bytes()).unwrap();
    std::fs::write(asset.join("square.bin"), square_bytes()).unwrap();
    std::os::unix::fs::symlink(&secret, asset.join("link.bin")).unwrap();
    let write = |name: &str, uri: &str| -> PathBuf {
        let path = asset.join(name);
        std::fs::write(&path, serde_json::to_vec(&square_doc(uri)).unwrap()).unwrap();
        path
    };
    // inside the folder: read
    let ok = read_mesh(&write("ok.gltf", "square.bin")).unwrap();
    assert_eq!(ok.original.len(), 4);
    let long = format!("{}secret.bin", "../".repeat(400));
    for (uri, why) in [
        (secret.to_str().unwrap(), "absolute"),
        ("../secret.bin", "climbs out"),
        ("link.bin", "symbolic link"),
        (&format!("file://{}", secret.display()), "scheme"),
        (long.as_str(), "climbs out"),
    ] {
        let path = write("hostile.gltf", uri);
        let err = read_mesh(&path).expect_err(uri).to_string();
        assert!(err.contains(&path.display().to_string()), "{err}");
        assert!(
            err.contains("buffer 0") && err.contains(why),
            "{uri}: {err}"
        );
        assert!(err.contains("nothing was read"), "{err}");
        assert!(err.contains(&uri[..uri.len().min(60)]), "{err}");
        assert!(err.len() < 400, "the URI is not cut: {err}");
    }
    // an image naming a file outside is refused too (never read either way)
    let mut doc = square_doc("square.bin");
    doc["images"] = json!([{"uri": "../../../../etc/passwd"}]);
    let path = asset.join("image.gltf");
    std::fs::write(&path, serde_json::to_vec(&doc).unwrap()).unwrap();
    let err = read_mesh(&path).unwrap_err().to_string();
    assert!(
        err.contains("image 0") && err.contains("climbs out"),
        "{err}"
    );
}

#[test]
fn a_mesh_file_that_never_ends_is_refused_at_the_limit() {
    let err = read_mesh(Path::new("/dev/zero")).unwrap_err().to_string();
    assert!(
        err.contains("/dev/zero") && err.contains("more than the"),
        "{err}"
    );
}

#[test]
fn sizes_are_checked_before_anything_is_allocated() {
    let square = data_uri(&square_bytes());
    // a billion vertices read from one element (stride 0), or every 12 bytes
    for stride in [0, 12, 252] {
        let mut doc = square_doc(&square);
        doc["accessors"][0]["count"] = json!(1_000_000_000u64);
        doc["bufferViews"][0]["byteStride"] = json!(stride);
        refused(
            &doc,
            &[
                "POSITION accessor 0",
                "1000000000 vertices",
                "at most 1000000",
            ],
        );
    }
    // a stride shorter than the element reads overlapping elements
    let mut doc = square_doc(&square);
    doc["bufferViews"][0]["byteStride"] = json!(4);
    refused(&doc, &["byteStride 4"]);
    // offsets whose sums wrap around 2^64
    let huge = u64::MAX - 7;
    for (at, key) in [
        ("accessors", "byteOffset"),
        ("bufferViews", "byteOffset"),
        ("bufferViews", "byteLength"),
    ] {
        let mut doc = square_doc(&square);
        doc[at][0][key] = json!(huge);
        refused(&doc, &["mesh 0 primitive 0", "accessor 0", "runs past"]);
    }
    // indices claiming more triangles than the cap
    let mut doc = square_doc(&square);
    doc["accessors"][1]["count"] = json!(4_000_000_002u64);
    refused(&doc, &["indices accessor 1", "at most 2000000 triangles"]);
}

#[test]
fn node_cycles_and_instance_floods_are_refused() {
    let square = data_uri(&square_bytes());
    let mut doc = square_doc(&square);
    doc["nodes"] = json!([{"mesh": 0, "children": [1]}, {"children": [0]}]);
    refused(&doc, &["node 0 is reached twice"]);
    // the same root listed 100 000 times
    let mut doc = square_doc(&square);
    doc["scenes"][0]["nodes"] = json!(vec![0; 100_000]);
    refused(&doc, &["node 0 is reached twice"]);
    // 100 000 nodes instancing the mesh
    let mut doc = square_doc(&square);
    doc["nodes"] = json!(vec![json!({"mesh": 0}); 100_000]);
    doc["scenes"][0]["nodes"] = json!((0..100_000).collect::<Vec<_>>());
    refused(
        &doc,
        &[&format!("more than {MAX_INSTANCES} mesh instances")],
    );
}

#[test]
fn absurd_numbers_and_wrong_types_are_refused_at_the_door() {
    let mut bytes = square_bytes();
    let with_x = |bytes: &mut Vec<u8>, x: f32| bytes[12..16].copy_from_slice(&x.to_le_bytes());
    for (x, shown) in [
        (3e38f32, "300000000"),
        (f32::NAN, "NaN"),
        (f32::INFINITY, "inf"),
    ] {
        with_x(&mut bytes, x);
        refused(
            &square_doc(&data_uri(&bytes)),
            &["POSITION accessor 0", "element 1", shown],
        );
    }
    let square = data_uri(&square_bytes());
    // float-typed indices
    let mut doc = square_doc(&square);
    doc["accessors"][1]["componentType"] = json!(5126);
    doc["accessors"][1]["count"] = json!(3);
    refused(&doc, &["indices accessor 1", "UNSIGNED"]);
    // a node scale that carries sane coordinates to 1e30
    let mut doc = square_doc(&square);
    doc["nodes"][0]["scale"] = json!([1e30, 1e30, 1e30]);
    refused(
        &doc,
        &[
            "mesh 0 primitive 0 (node 0)",
            "vertex 1",
            "after the node transforms",
        ],
    );
}

fn human() -> MouthRig {
    MouthRig::load_character(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/characters/human.toml"),
    )
    .unwrap()
}

/// Binds `doc` (written to a file) to the human; the error's text.
fn bind_error(doc: &Value) -> (String, String) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mesh.gltf");
    std::fs::write(&path, serde_json::to_vec(doc).unwrap()).unwrap();
    let err = mouthpiece_bind::bind(
        &human(),
        &path,
        &dir.path().join("out.glb"),
        &BindOptions::new(ModelUp::Y, Method::Distance),
    )
    .unwrap_err();
    assert!(!dir.path().join("out.glb").exists(), "nothing is written");
    assert!(
        matches!(
            err,
            BindError::BadMesh { .. } | BindError::PointFarFromMesh { .. }
        ) && err.is_bad_input()
    );
    (err.to_string(), path.display().to_string())
}

#[test]
fn binding_errors_name_the_mesh_file_and_where() {
    let square = data_uri(&square_bytes());
    // no triangles: the only primitive is points
    let mut doc = square_doc(&square);
    doc["meshes"][0]["primitives"][0]["mode"] = json!(0);
    let (err, path) = bind_error(&doc);
    assert!(err.contains(&path) && err.contains("no triangles"), "{err}");
    // every triangle collapses when identical positions merge
    let mut doc = square_doc(&data_uri(&[0u8; 60]));
    doc["accessors"][1]["count"] = json!(6);
    let (err, path) = bind_error(&doc);
    assert!(err.contains(&path) && err.contains("no triangles"), "{err}");
    // a non-manifold edge is no refusal (the mouth is still far from this square)
    let mut bin = square_bytes();
    bin.truncate(48);
    bin.extend_from_slice(&[0.5f32, 0.5, 1.0].map(f32::to_le_bytes).concat());
    for i in [0u16, 1, 2, 0, 2, 3, 0, 2, 4] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let mut doc = square_doc(&data_uri(&bin));
    doc["buffers"][0]["byteLength"] = json!(bin.len());
    doc["bufferViews"] = json!([
        {"buffer": 0, "byteOffset": 0, "byteLength": 60},
        {"buffer": 0, "byteOffset": 60, "byteLength": 18}
    ]);
    doc["accessors"][0]["count"] = json!(5);
    doc["accessors"][1]["count"] = json!(9);
    let (err, path) = bind_error(&doc);
    assert!(
        err.contains(&path) && !err.contains("non-manifold") && err.contains("surface"),
        "{err}"
    );
    // a mesh far from the mouth (the square at the origin, the human's mouth elsewhere)
    let mut doc = square_doc(&square);
    doc["nodes"][0]["translation"] = json!([5.0, 5.0, 5.0]);
    let (err, path) = bind_error(&doc);
    assert!(
        err.contains(&path)
            && err.contains("from the mesh's surface")
            && err.contains("units")
            && err.contains("the mesh spans 1.0000, the mouth is 0.0500 wide"),
        "{err}"
    );
}

#[test]
fn the_size_caps_are_computed_as_built() {
    use mouthpiece_bind::network::{Network, Widths};
    use mouthpiece_bind::{character_head, head_vertices, mesh::MAX_VERTICES, MAX_HEAD_RESOLUTION};
    for r in [1, 2, 3] {
        let head = character_head(&human(), ModelUp::Y, 0.5, r).unwrap();
        assert_eq!(head.len(), head_vertices(r));
    }
    assert!(head_vertices(MAX_HEAD_RESOLUTION) <= MAX_VERTICES);
    assert!(head_vertices(MAX_HEAD_RESOLUTION + 1) > MAX_VERTICES);
    let err = character_head(&human(), ModelUp::Y, 0.5, MAX_HEAD_RESOLUTION + 1).unwrap_err();
    assert!(err.to_string().contains("--resolution"), "{err}");
    // A model file's parameter count is checked from its widths before a layer is built.
    for w in [Widths::TINY, Widths::SMALL, Widths::PAPER] {
        assert_eq!(w.parameter_count(), Network::new(w, 1).parameter_count());
    }
    let header = b"mouthpiece-bind-network 1 4096 4096 4096 4096 4096 12\n\0\0\0\0";
    let err = Network::from_bytes(header, Path::new("big.bin")).unwrap_err();
    assert!(err.to_string().contains("big.bin"), "{err}");
}

#[test]
fn a_skin_with_a_hundred_thousand_joints_is_refused_naming_the_node() {
    let mut doc = square_doc(&data_uri(&square_bytes()));
    doc["nodes"][0]["skin"] = json!(0);
    doc["skins"] = json!([{ "joints": vec![0; 100_000] }]);
    refused(&doc, &["node 0", "skin 0", "100000 joints", "4096"]);
    // a joint past the nodes
    doc["skins"] = json!([{ "joints": [0, 7] }]);
    refused(&doc, &["node 0", "skin 0", "joint 1 is node 7"]);
}
