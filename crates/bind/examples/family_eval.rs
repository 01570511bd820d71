//! The binders on meshes the generator did not make (docs/bind.md, "Meshes from outside
//! the generator"). Run through `bench/bind_families.py`, which calls
//!
//!     family_eval bases DIR      # writes held-out generator heads (OBJ + JSON) for Blender
//!     family_eval eval DIR [--large] [--ratios]   # --ratios: only each mesh's lip path ratio
//!
//! `eval` builds families (a) subdivided, (b) shells and (c) seams from the held-out heads
//! itself, reads (a) decimated and (d) Blender-modelled heads from DIR (written by
//! bench/blender/bind_families.py: `NAME.obj` with `NAME.json` holding the family, the mouth
//! points and the hinge, mouth frame, mouth widths), and prints a Markdown table: deformation
//! RMS (% of the mouth width) per family and method over all vertices and over the chin and
//! lips, against the position-defined reference motion (`families::LipField`).

use std::path::{Path, PathBuf};

use mouthpiece_bind::families::{
    errors, fins_and_holes, lip_path_ratio, lips_welded, method_weights, read_obj, reference,
    subdivide, truth, with_shells, write_obj, Part, Subject,
};
use mouthpiece_bind::procedural::{HeadParams, MouthState};
use mouthpiece_bind::training::EVAL_STATES;
use rand::SeedableRng;

/// `bind evaluate`'s held-out seed.
const HELD_OUT_SEED: u64 = 1_319_952;
/// Held-out heads each family is made from.
const HEADS: usize = 3;
/// The best-fit reference is computed up to this many vertices (its cost is per vertex).
const REFERENCE_LIMIT: usize = 30_000;

/// One family's meshes: how many, their vertex range, and per method the sums of the
/// (all, chin/lips) RMS and how many meshes were scored.
struct Family {
    name: String,
    count: usize,
    lo: usize,
    hi: usize,
    sums: [[f64; 2]; 4],
    counts: [usize; 4],
}

fn held_out() -> Vec<mouthpiece_bind::procedural::Head> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(HELD_OUT_SEED);
    (0..HEADS)
        .map(|_| HeadParams::random(&mut rng).build())
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = PathBuf::from(args.get(1).expect("usage: family_eval bases|eval DIR"));
    match args[0].as_str() {
        "bases" => bases(&dir),
        "eval" => eval(
            &dir,
            args.iter().any(|a| a == "--large"),
            args.iter().any(|a| a == "--ratios"),
        ),
        other => panic!("unknown action {other}"),
    }
}

fn json(points: &[[f64; 3]; 12], hinge: [f64; 3], family: &str) -> String {
    serde_json::json!({"family": family, "points": points, "hinge": hinge}).to_string()
}

fn bases(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    for (i, head) in held_out().iter().enumerate() {
        // denser than the generator's own resolutions, so decimation has room to work
        let mut params = head.params.clone();
        params.around = 96;
        params.face_rings = 24;
        params.tube_rings = 16;
        let dense = params.build();
        write_obj(&dir.join(format!("base{i}.obj")), &dense.mesh).unwrap();
        std::fs::write(
            dir.join(format!("base{i}.json")),
            json(&dense.params.points, dense.hinge, "base"),
        )
        .unwrap();
    }
}

fn eval(dir: &Path, large: bool, ratios_only: bool) {
    let network = mouthpiece_bind::shipped_network().unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0xe7a1);
    let states = MouthState::set(EVAL_STATES, &mut rng);
    let heads = held_out();
    let mut subjects: Vec<(String, Subject)> = Vec::new();
    for (i, head) in heads.iter().enumerate() {
        subjects.push((
            "generator (control)".into(),
            Subject::from_head(&format!("h{i}"), head),
        ));
    }
    for (i, head) in heads.iter().enumerate() {
        let base = Subject::from_head(&format!("h{i}"), head);
        let mut s = base.clone();
        for level in 1..=3 {
            let (mesh, parts) = subdivide(&s.mesh, &s.parts);
            s.mesh = mesh;
            s.parts = parts;
            if level >= 2 {
                subjects.push((format!("(a) subdivided ×{}", 4usize.pow(level)), s.clone()));
            }
        }
        if large && i == 0 {
            let (mesh, parts) = subdivide(&s.mesh, &s.parts);
            s.mesh = mesh;
            s.parts = parts;
            subjects.push(("(a) subdivided ×256".into(), s.clone()));
        }
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "obj"))
        .collect();
    files.sort();
    for path in files {
        let meta: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(path.with_extension("json")).unwrap())
                .unwrap();
        let family = meta["family"].as_str().unwrap().to_owned();
        if family == "base" {
            continue;
        }
        let points: [[f64; 3]; 12] = serde_json::from_value(meta["points"].clone()).unwrap();
        let hinge: [f64; 3] = serde_json::from_value(meta["hinge"].clone()).unwrap();
        let mesh = read_obj(&path).unwrap();
        let n = mesh.len();
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        subjects.push((
            family,
            Subject {
                name,
                mesh,
                points,
                hinge,
                parts: vec![Part::Skin; n],
            },
        ));
    }
    for (i, head) in heads.iter().enumerate() {
        subjects.push((
            "(b) eye, teeth, tongue shells".into(),
            with_shells(&format!("h{i}"), head),
        ));
    }
    for (i, head) in heads.iter().enumerate() {
        subjects.push((
            "(c) lips welded".into(),
            lips_welded(&format!("h{i}"), head),
        ));
        subjects.push((
            "(c) fins and holes".into(),
            fins_and_holes(&format!("h{i}"), head),
        ));
    }
    // per family: vertices range, and per method the sums of (all, region)
    let methods = ["network", "heat", "distance", "reference"];
    let mut families: Vec<Family> = Vec::new();
    eprintln!(
        "| family | mesh | vertices | shells | lip path ratio | method | RMS all | RMS chin/lips |"
    );
    eprintln!("|---|---|---:|---:|---:|---|---:|---:|");
    for (family, subject) in &subjects {
        if ratios_only {
            let ratio = lip_path_ratio(&subject.mesh, &subject.points);
            println!(
                "{family} {} {} {ratio:.2}",
                subject.name,
                subject.mesh.len()
            );
            continue;
        }
        let t = truth(subject, &states);
        let mut all = method_weights(subject, &network).to_vec();
        let ratio = lip_path_ratio(&subject.mesh, &subject.points);
        if subject.mesh.len() <= REFERENCE_LIMIT {
            all.push(("reference", reference(&t, subject.mesh.len())));
        }
        let at = match families.iter().position(|f| &f.name == family) {
            Some(at) => at,
            None => {
                families.push(Family {
                    name: family.clone(),
                    count: 0,
                    lo: usize::MAX,
                    hi: 0,
                    sums: [[0.0; 2]; 4],
                    counts: [0; 4],
                });
                families.len() - 1
            }
        };
        let f = &mut families[at];
        f.count += 1;
        f.lo = f.lo.min(subject.mesh.len());
        f.hi = f.hi.max(subject.mesh.len());
        let shells = subject.mesh.topology().shells;
        for (m, w) in &all {
            let (rms, region) = errors(subject, w, &t);
            let k = methods.iter().position(|x| x == m).unwrap();
            f.sums[k][0] += rms;
            f.sums[k][1] += region;
            f.counts[k] += 1;
            eprintln!(
                "| {family} | {} | {} | {shells} | {ratio:.2} | {m} | {rms:.2} | {region:.2} |",
                subject.name,
                subject.mesh.len()
            );
        }
    }
    println!("| family | meshes | vertices | method | RMS all | RMS chin/lips |");
    println!("|---|---:|---:|---|---:|---:|");
    for Family {
        name: family,
        count,
        lo,
        hi,
        sums,
        counts,
    } in &families
    {
        for (k, m) in methods.iter().enumerate() {
            if counts[k] == 0 {
                continue;
            }
            let n = counts[k] as f64;
            let vertices = if lo == hi {
                format!("{lo}")
            } else {
                format!("{lo}–{hi}")
            };
            println!(
                "| {family} | {count} | {vertices} | {m} | {:.2} | {:.2} |",
                sums[k][0] / n,
                sums[k][1] / n
            );
        }
    }
}
