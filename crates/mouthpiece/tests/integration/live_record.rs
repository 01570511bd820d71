//! A take's export against what subscribers received live: each exported row is a frame a
//! WebSocket client received during the take, the next row the next frame, and the numbers
//! the same to float32 (the points and, where the frame had a rig, every named curve).

use std::collections::BTreeMap;
use std::path::Path;

use serde_json::Value;

/// `export TAKE --character config/characters/<character>.toml --out OUT` (CSV), which must
/// succeed reading the take as recorded live; the file's text.
pub fn export_as_recorded(take: &Path, character: &str, out: &Path) -> String {
    let exported = crate::mouthpiece()
        .arg("export")
        .arg(take)
        .arg("--character")
        .arg(crate::repo().join(format!("config/characters/{character}.toml")))
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&exported.stderr);
    assert!(exported.status.success(), "{stderr}");
    assert!(stderr.contains("as recorded live"), "{stderr}");
    std::fs::read_to_string(out).unwrap()
}

/// One character's entry of each frame received, by the frame's `seq`.
pub type LiveSteps = BTreeMap<u64, Value>;

/// Keeps `character`'s entry of `message` when it is a frame.
pub fn keep(message: &Value, character: &str, live: &mut LiveSteps) {
    if message["type"] != "frame" {
        return;
    }
    if let Some(entry) = message["characters"]
        .as_array()
        .and_then(|cs| cs.iter().find(|c| c["name"] == character))
    {
        live.insert(message["seq"].as_u64().unwrap(), entry.clone());
    }
}

/// Checks every row of an `export --format csv` (header first) against the frames received
/// live; returns each row's frame `seq` and its time (the CSV's first column). Panics on a row that differs from its frame, or when
/// fewer than 9 rows in 10 have a frame received live to compare with (a client on a loaded
/// machine may lag and lose a few).
pub fn assert_rows_are_live(csv: &str, live: &LiveSteps) -> Vec<(u64, f64)> {
    let mut lines = csv.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().expect("a header").split(',').collect();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert!(!rows.is_empty(), "no rows");
    // Empty cells (and JSON `null`) are `None`.
    let f32_of = |cell: &str| -> Option<f32> { cell.parse::<f64>().ok().map(|v| v as f32) };
    let json_f32 = |v: &Value| -> Option<f32> { v.as_f64().map(|v| v as f32) };
    let curve_columns: Vec<(usize, &str)> = header
        .iter()
        .enumerate()
        .filter(|(_, h)| mouthpiece_output::CURVE_NAMES.contains(h))
        .map(|(i, h)| (i, *h))
        .collect();
    assert_eq!(curve_columns.len(), mouthpiece_output::CURVES, "{header:?}");
    let same = |row: &[&str], frame: &Value| -> bool {
        let points = frame["points"].as_array().unwrap();
        // A point the frame did not carry (`null`) is a row's three empty cells.
        let points_equal = points.iter().enumerate().all(|(p, xyz)| {
            (0..3).all(|k| f32_of(row[1 + 3 * p + k]) == xyz.get(k).and_then(json_f32))
        });
        // A frame without a rig is a row with empty curve cells.
        let curves_equal = curve_columns
            .iter()
            .all(|(i, name)| f32_of(row[*i]) == json_f32(&frame["rig"]["curves"][name]));
        points_equal && curves_equal
    };
    // The seq of the take's first row. Frames can repeat (a mouth at rest, speech in a
    // pause), so one row can match several frames: every offset that puts one of the first
    // rows on a frame it equals is tried, and the one under which every received row equals
    // its frame, with the most rows compared, is the take's.
    let candidates: std::collections::BTreeSet<u64> = rows
        .iter()
        .take(10)
        .enumerate()
        .flat_map(|(k, row)| {
            live.iter()
                .filter(|(_, frame)| same(row, frame))
                .filter_map(move |(seq, _)| seq.checked_sub(k as u64))
        })
        .collect();
    assert!(
        !candidates.is_empty(),
        "none of the export's first rows is a frame received live: {:?}",
        rows[0]
    );
    // (compared, first row that differs) per offset.
    let trial = |first: u64| -> (usize, Option<usize>) {
        let mut compared = 0;
        for (k, row) in rows.iter().enumerate() {
            if let Some(frame) = live.get(&(first + k as u64)) {
                if !same(row, frame) {
                    return (compared, Some(k));
                }
                compared += 1;
            }
        }
        (compared, None)
    };
    let best = candidates
        .iter()
        .map(|&first| (first, trial(first)))
        .max_by_key(|(_, (compared, differs))| (differs.is_none(), *compared))
        .unwrap();
    let (first, (compared, differs)) = best;
    if let Some(k) = differs {
        let seq = first + k as u64;
        panic!(
            "row {k} differs from frame {seq} under the best alignment: {:?}\n{}",
            rows[k], live[&seq]
        );
    }
    // (A frame this client did not receive, had it lagged on a loaded machine, is skipped;
    // nearly all must be there.)
    assert!(
        compared * 10 >= rows.len() * 9,
        "{compared} of {} rows received live",
        rows.len()
    );
    rows.iter()
        .enumerate()
        .map(|(k, row)| (first + k as u64, row[0].parse().unwrap()))
        .collect()
}
