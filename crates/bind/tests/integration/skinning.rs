//! Weights from every binder on a procedural head: rows, the neutral pose, one joint moving.

use mouthpiece_bind::network::{Graph, Network, Widths};
use mouthpiece_bind::procedural::{HeadParams, POINTS};
use mouthpiece_bind::weights::{distance_weights, heat_weights, joint_distances, MAX_INFLUENCES};
use mouthpiece_bind::Weights;
use nalgebra::Vector3;

fn all_methods() -> (Vec<Vector3<f64>>, Vec<(&'static str, Weights)>) {
    let head = HeadParams::around_points(HeadParams::mouth_points(0.18, 0.22, 0.4), 0.5, 2).build();
    let points = head.params.points.map(Vector3::from);
    let d = joint_distances(&head.mesh, &points);
    let net = Network::new(Widths::TINY, 1);
    let mut methods = vec![
        (
            "network",
            net.predict(&Graph::new(&head.mesh, &head.params.points)),
        ),
        ("heat", heat_weights(&head.mesh, &d, 1.0)),
        ("distance", distance_weights(&d, 1.0)),
    ];
    for (_, w) in &mut methods {
        w.limit_influences();
    }
    let rest = (0..head.mesh.len()).map(|v| head.mesh.vertex(v)).collect();
    (rest, methods)
}

#[test]
fn rows_sum_to_one_with_at_most_four_influences() {
    let (_, methods) = all_methods();
    for (name, w) in methods {
        for (v, row) in w.rows.iter().enumerate() {
            let sum: f64 = row.iter().sum();
            assert!((sum - 1.0).abs() <= 1e-6, "{name} vertex {v}: sum {sum}");
            assert!(row.iter().all(|&x| x >= 0.0));
            assert!(
                row.iter().filter(|&&x| x > 0.0).count() <= MAX_INFLUENCES,
                "{name} vertex {v}: {row:?}"
            );
        }
    }
}

#[test]
fn the_neutral_pose_is_the_input_exactly() {
    let (rest, methods) = all_methods();
    for (name, w) in methods {
        let skinned = w.skin(&rest, &[Vector3::zeros(); POINTS]);
        assert_eq!(skinned, rest, "{name}");
    }
}

#[test]
fn moving_one_joint_moves_each_vertex_by_its_weight_times_the_motion() {
    let (rest, methods) = all_methods();
    let d = Vector3::new(0.03, -0.2, 0.07);
    for (name, w) in methods {
        for k in [0, 4, 9] {
            let mut motion = [Vector3::zeros(); POINTS];
            motion[k] = d;
            let skinned = w.skin(&rest, &motion);
            let mut moved = 0;
            for v in 0..rest.len() {
                let want = rest[v] + w.rows[v][k] * d;
                assert!(
                    (skinned[v] - want).norm() <= 1e-12,
                    "{name} joint {k} vertex {v}"
                );
                if w.rows[v][k] > 0.0 {
                    moved += 1;
                }
            }
            // (the untrained network's top four need not include every joint)
            assert!(
                moved > 0 || name == "network",
                "{name}: joint {k} moves nothing"
            );
        }
    }
}
