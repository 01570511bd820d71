//! A take's curves as morph-target weight animation on the user's own avatar
//! (`mouthpiece export --onto AVATAR`).
//!
//! The avatar (glTF or GLB) is read as hostile input and kept as it is ([`read`]); its
//! meshes' morph targets are matched by name to the take's curves ([`names`]); one
//! animation with a `weights` channel per node whose mesh has a matching target is appended,
//! its data after the GLB's binary chunk or, for `.gltf`, in a new embedded buffer
//! ([`mod@write`]). Nothing else in the document changes.

pub mod names;
pub mod read;
pub mod write;

use std::fmt;
use std::path::Path;

pub use names::CurveTable;
pub use read::{Avatar, AvatarMesh, MAX_AVATAR_BYTES};
pub use write::OntoSummary;

use crate::asset::shown;
use crate::ExportError;

pub(crate) fn avatar_error(path: &Path, problem: impl Into<String>) -> ExportError {
    ExportError::Avatar {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

/// Where one morph target's weight comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Source {
    /// The take's curve of this index.
    Curve(usize),
    /// No curve: the mesh's default weight, held.
    Default(f32),
}

/// One mesh to animate.
#[derive(Clone, Debug)]
pub struct MeshPlan {
    pub mesh: usize,
    /// One per morph target, in the mesh's order.
    pub sources: Vec<Source>,
}

/// What drives what: the meshes to animate and the report of the match.
#[derive(Clone, Debug)]
pub struct Plan {
    pub meshes: Vec<MeshPlan>,
    pub report: MatchReport,
}

/// What matched and what did not, printed after an `--onto` export.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MatchReport {
    pub meshes: Vec<MeshReport>,
    /// The take's curves that no target of the avatar matched.
    pub curves_without_target: Vec<String>,
    /// Meshes with morph targets but no `extras.targetNames` (nothing to match them by).
    pub unnamed: Vec<String>,
}

/// One mesh with named morph targets.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshReport {
    /// `meshes[3] (`Face`)`.
    pub mesh: String,
    /// The nodes showing it (each gets a channel when anything matched).
    pub nodes: Vec<String>,
    /// (target name, curve name) pairs.
    pub matched: Vec<(String, String)>,
    /// Targets that no curve drives.
    pub without_curve: Vec<String>,
}

/// Most names a report line lists before `… and N more`.
const LISTED: usize = 40;

fn list(names: impl ExactSizeIterator<Item = String>) -> String {
    let total = names.len();
    let mut shown_names: Vec<String> = names.take(LISTED).collect();
    if total > LISTED {
        shown_names.push(format!("… and {} more", total - LISTED));
    }
    shown_names.join(", ")
}

impl fmt::Display for MatchReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // An avatar may have thousands of meshes: their lines are cut like the lists.
        for mesh in self.meshes.iter().take(LISTED) {
            let targets = mesh.matched.len() + mesh.without_curve.len();
            let nodes = if mesh.nodes.is_empty() {
                "no node shows it: not animated".to_owned()
            } else {
                list(mesh.nodes.iter().cloned())
            };
            writeln!(
                f,
                "{}: {} of {targets} morph targets matched ({nodes})",
                mesh.mesh,
                mesh.matched.len()
            )?;
            if !mesh.matched.is_empty() {
                let pairs = mesh.matched.iter().map(|(target, curve)| {
                    if target == curve {
                        shown(target)
                    } else {
                        format!("{} ← {}", shown(target), shown(curve))
                    }
                });
                writeln!(f, "  matched: {}", list(pairs))?;
            }
            if !mesh.without_curve.is_empty() {
                let names = mesh.without_curve.iter().map(|n| shown(n));
                writeln!(f, "  no curve for: {}", list(names))?;
            }
        }
        if self.meshes.len() > LISTED {
            writeln!(
                f,
                "… and {} more meshes with morph targets",
                self.meshes.len() - LISTED
            )?;
        }
        if !self.unnamed.is_empty() {
            writeln!(
                f,
                "morph targets without names (no extras.targetNames), not animated: {}",
                list(self.unnamed.iter().cloned())
            )?;
        }
        if self.curves_without_target.is_empty() {
            writeln!(f, "every curve of the take has a target")
        } else {
            writeln!(
                f,
                "curves with no target: {}",
                list(self.curves_without_target.iter().map(|n| shown(n)))
            )
        }
    }
}

impl Avatar {
    /// Matches the avatar's morph targets to the take's curves. No target matching any curve
    /// is an error naming the file and some of its targets.
    pub fn plan(&self, table: &CurveTable) -> Result<Plan, ExportError> {
        let mut report = MatchReport::default();
        let mut meshes = Vec::new();
        let mut used = vec![false; table.names().len()];
        for (m, mesh) in self.meshes.iter().enumerate() {
            if mesh.target_names.is_empty() {
                if mesh.targets > 0 {
                    report.unnamed.push(mesh.label.clone());
                }
                continue;
            }
            let mut row = MeshReport {
                mesh: mesh.label.clone(),
                nodes: mesh.nodes.iter().map(|(_, name)| name.clone()).collect(),
                ..Default::default()
            };
            let mut sources = Vec::new();
            for (name, &default) in mesh.target_names.iter().zip(&mesh.default_weights) {
                match table.lookup(name) {
                    Some(c) => {
                        row.matched.push((name.clone(), table.names()[c].clone()));
                        if !mesh.nodes.is_empty() {
                            used[c] = true;
                        }
                        sources.push(Source::Curve(c));
                    }
                    None => {
                        row.without_curve.push(name.clone());
                        sources.push(Source::Default(default));
                    }
                }
            }
            if !row.matched.is_empty() && !mesh.nodes.is_empty() {
                meshes.push(MeshPlan { mesh: m, sources });
            }
            report.meshes.push(row);
        }
        report.curves_without_target = table
            .names()
            .iter()
            .zip(&used)
            .filter(|(_, used)| !**used)
            .map(|(n, _)| n.clone())
            .collect();
        if meshes.is_empty() {
            return Err(self.no_match(&report));
        }
        Ok(Plan { meshes, report })
    }

    fn no_match(&self, report: &MatchReport) -> ExportError {
        let names: Vec<&String> = self.meshes.iter().flat_map(|m| &m.target_names).collect();
        let unnamed = self
            .meshes
            .iter()
            .filter(|m| m.targets > 0 && m.target_names.is_empty())
            .count();
        let problem = if names.is_empty() {
            format!(
                "no mesh has named morph targets (mesh.extras.targetNames){}",
                if unnamed > 0 {
                    format!("; {unnamed} mesh(es) have morph targets without names")
                } else {
                    String::new()
                }
            )
        } else if report.meshes.iter().any(|m| !m.matched.is_empty()) {
            "the meshes whose morph targets match the take's curves are shown by no node".into()
        } else {
            const FEW: usize = 8;
            let few: Vec<String> = names
                .iter()
                .take(FEW)
                .map(|n| format!("`{}`", shown(n)))
                .collect();
            format!(
                "no morph target matches a curve of the take (ARKit names such as `jawOpen`, \
                 case ignored; VRM visemes `aa ih ou ee oh`/`A I U E O` when the take has \
                 them); its {} target(s) include {}{}",
                names.len(),
                few.join(", "),
                if names.len() > FEW { ", …" } else { "" }
            )
        };
        avatar_error(&self.path, problem)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::{json, Value};

    /// Mesh 0 (`Face`, targets `JAWOPEN`, `blink` default 0.25) shown by two nodes, mesh 1
    /// (target `jawOpen`) by none.
    fn avatar() -> Avatar {
        let b64 = "A".repeat(64);
        let doc = json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": 48, "uri": format!("data:application/octet-stream;base64,{b64}")}],
            "bufferViews": [{"buffer": 0, "byteLength": 48}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"}],
            "meshes": [
                {"name": "Face", "extras": {"targetNames": ["JAWOPEN", "blink"]}, "weights": [0, 0.25],
                 "primitives": [{"attributes": {"POSITION": 0}, "targets": [{"POSITION": 0}, {"POSITION": 0}]}]},
                {"extras": {"targetNames": ["jawOpen"]},
                 "primitives": [{"attributes": {"POSITION": 0}, "targets": [{"POSITION": 0}]}]},
                {"name": "Body", "primitives": [{"attributes": {"POSITION": 0}, "targets": [{"POSITION": 0}]}]}
            ],
            "nodes": [{"mesh": 0, "name": "A"}, {"mesh": 0, "name": "B"}],
            "extras": {"kept": [1, 2]}
        });
        Avatar::from_bytes(&serde_json::to_vec(&doc).unwrap(), Path::new("avatar.gltf")).unwrap()
    }

    #[test]
    fn every_node_of_a_matched_mesh_gets_a_channel_with_all_its_targets() {
        let avatar = avatar();
        let table = CurveTable::new(&["jawOpen", "mouthClose"]);
        let plan = avatar.plan(&table).unwrap();
        assert_eq!(plan.meshes.len(), 1);
        assert_eq!(
            plan.meshes[0].sources,
            [Source::Curve(0), Source::Default(0.25)]
        );
        let report = plan.report.to_string();
        assert!(
            report.contains(
                "meshes[1]: 1 of 1 morph targets matched (no node shows it: not animated)"
            ),
            "{report}"
        );
        assert!(
            report.contains("matched: JAWOPEN ← jawOpen\n  no curve for: blink"),
            "{report}"
        );
        assert!(
            report.contains("curves with no target: mouthClose"),
            "{report}"
        );
        assert!(
            report.contains(
                "without names (no extras.targetNames), not animated: meshes[2] (`Body`)\n"
            ),
            "{report}"
        );

        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out.gltf");
        let summary = avatar
            .write_onto(&plan, &[0.0, 0.5], &[0.25, 0.0, 1.0, 0.0], 2, &out, false)
            .unwrap();
        assert_eq!(summary.channels, 2);
        let doc: Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
        assert_eq!(doc["extras"], json!({"kept": [1, 2]}));
        let animation = &doc["animations"][0];
        assert_eq!(animation["samplers"].as_array().unwrap().len(), 1);
        assert_eq!(
            animation["channels"][1]["target"],
            json!({"node": 1, "path": "weights"})
        );
        let output =
            &doc["accessors"][animation["samplers"][0]["output"].as_u64().unwrap() as usize];
        assert_eq!(output["count"], 4);
        use base64::Engine as _;
        let uri = doc["buffers"][1]["uri"].as_str().unwrap();
        let data = base64::engine::general_purpose::STANDARD
            .decode(uri.split_once(",").unwrap().1)
            .unwrap();
        let floats: Vec<f32> = data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        assert_eq!(floats, [0.0, 0.5, 0.25, 0.25, 1.0, 0.25]);
    }

    /// 2 000 meshes, each with a hostile target name: the report stays a few kilobytes,
    /// every line cut at 40 names, and no control character reaches the terminal.
    #[test]
    fn the_report_is_cut_at_40_names_and_escapes_the_names() {
        let b64 = "A".repeat(64);
        let meshes: Vec<Value> = (0..2_000)
            .map(|i| {
                json!({"name": format!("m{i}\u{1b}[2J"), "extras": {"targetNames": ["jawOpen", "x\nforged: row"]},
                       "primitives": [{"attributes": {"POSITION": 0}, "targets": [{"POSITION": 0}, {"POSITION": 0}]}]})
            })
            .collect();
        let nodes: Vec<Value> = (0..100)
            .map(|i| json!({"mesh": 0, "name": format!("n{i}")}))
            .collect();
        let doc = json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": 48, "uri": format!("data:application/octet-stream;base64,{b64}")}],
            "bufferViews": [{"buffer": 0, "byteLength": 48}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"}],
            "meshes": meshes,
            "nodes": nodes,
        });
        let avatar =
            Avatar::from_bytes(&serde_json::to_vec(&doc).unwrap(), Path::new("avatar.gltf"))
                .unwrap();
        let report = avatar
            .plan(&CurveTable::new(&["jawOpen"]))
            .unwrap()
            .report
            .to_string();
        assert!(report.len() < 16_000, "{} bytes", report.len());
        assert!(!report.contains('\u{1b}'), "{report}");
        assert!(report.contains("meshes[0] (`m0\\u{1b}[2J`)"), "{report}");
        assert!(
            report.contains("no curve for: x\\nforged: row\n"),
            "{report}"
        );
        assert!(
            report.contains("… and 1960 more meshes with morph targets"),
            "{report}"
        );
        assert!(report.contains("(`n39`), … and 60 more)"), "{report}");
        assert_eq!(
            report.lines().filter(|l| l.starts_with("meshes[")).count(),
            40
        );
    }

    #[test]
    fn no_match_names_the_targets_and_the_output_must_keep_the_format() {
        let avatar = avatar();
        let err = avatar.plan(&CurveTable::new(&["mouthClose"])).unwrap_err();
        let text = err.to_string();
        assert!(err.is_bad_input());
        assert!(
            text.contains("avatar avatar.gltf: no morph target matches")
                && text.contains("`JAWOPEN`, `blink`, `jawOpen`"),
            "{text}"
        );
        let plan = avatar.plan(&CurveTable::new(&["jawOpen"])).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out.glb");
        let err = avatar
            .write_onto(&plan, &[0.0], &[0.5], 1, &out, true)
            .unwrap_err();
        assert!(err.to_string().contains("--out NAME.gltf"), "{err}");
        assert!(!out.exists());
    }
}
