//! The camera GP on the bundled arms: accuracy against the noise-free distorted camera, the
//! closed-form Jacobian against finite differences, save and reload bit for bit.

mod common;

use aift::arm::{EndEffector, Kinematics};
use aift::gp::{FitOptions, GpModel, derive_box, evaluate_held_out, sample_training_set};
use aift::sensors::{Camera, CameraConfig};

const DOWN: f64 = -std::f64::consts::FRAC_PI_2;

fn trained(
    file: &str,
    points: &[Vec<f64>],
    count: usize,
) -> (Kinematics, EndEffector, Camera, GpModel) {
    let model = common::model(file);
    let ee = common::ee(&model);
    let mut arm = Kinematics::new(model);
    let camera = Camera::new(CameraConfig::default());
    let bounds = derive_box(points, 0.3);
    let set = sample_training_set(&mut arm, &ee, &camera, &bounds, count, 1);
    assert_eq!(
        set.inputs.len(),
        count,
        "the default camera sees every configuration"
    );
    let (model, report) = set.fit(&FitOptions::default()).unwrap();
    eprintln!(
        "{file} N={count}: LML {:.3} after {} evaluations, {:?}",
        report.log_marginal_likelihood, report.evaluations, model.hyperparameters
    );
    (arm, ee, camera, model)
}

fn paper_points() -> Vec<Vec<f64>> {
    vec![vec![DOWN, 0.0], vec![-0.2, 0.5], vec![-0.6, 0.2]]
}

#[test]
fn paper_arm_gp_learns_the_distortion_with_200_points() {
    let (mut arm, ee, camera, model) = trained("urdf/planar_2dof.urdf", &paper_points(), 200);
    let err = evaluate_held_out(&model, &mut arm, &ee, &camera, 2000, 2);
    eprintln!(
        "2-DOF, 200 points: RMS {:.2} mm, max {:.2} mm",
        err.rms * 1e3,
        err.max * 1e3
    );
    // A third of the camera noise; the distortion alone is about 1 cm at 2 m.
    assert!(err.rms < 3.3e-3, "RMS {}", err.rms);
    // The fitted noise level is the camera's.
    assert!((model.hyperparameters.noise_std - 0.01).abs() < 0.002);
}

#[test]
fn three_dof_gp_reaches_the_same_accuracy_with_400_points() {
    let points = vec![
        vec![DOWN, 0.0, 0.0],
        vec![-0.4, 0.6, 0.3],
        vec![-0.8, 0.4, -0.2],
    ];
    let (mut arm, ee, camera, model) = trained("urdf/planar_3dof.urdf", &points, 400);
    let err = evaluate_held_out(&model, &mut arm, &ee, &camera, 2000, 2);
    eprintln!(
        "3-DOF, 400 points: RMS {:.2} mm, max {:.2} mm",
        err.rms * 1e3,
        err.max * 1e3
    );
    assert!(err.rms < 3.3e-3, "RMS {}", err.rms);
}

#[test]
fn trained_jacobian_equals_central_differences() {
    let (_, _, _, model) = trained("urdf/planar_2dof.urdf", &paper_points(), 100);
    for q in [[-1.2, 0.3], [-0.6, 0.2], [-0.25, 0.45]] {
        let (mut g, mut jac) = ([0.0; 2], [0.0; 4]);
        model.predict(&q, &mut g, &mut jac);
        // Five-point central differences (truncation O(h^4)): the GP mean is a sum of large,
        // cancelling terms, so a tiny step would drown in rounding.
        let h = 1e-3;
        let at = |d: usize, s: f64| {
            let mut x = q;
            x[d] += s;
            let mut g = [0.0; 2];
            model.predict_mean(&x, &mut g);
            g
        };
        for d in 0..2 {
            let (p1, m1, p2, m2) = (at(d, h), at(d, -h), at(d, 2.0 * h), at(d, -2.0 * h));
            for r in 0..2 {
                let fd = (8.0 * (p1[r] - m1[r]) - (p2[r] - m2[r])) / (12.0 * h);
                let rel = (jac[r * 2 + d] - fd).abs() / fd.abs().max(1e-3);
                assert!(
                    rel < 1e-6,
                    "q {q:?} r {r} d {d}: {} vs {fd}",
                    jac[r * 2 + d]
                );
            }
        }
    }
}

#[test]
fn saved_model_reloads_and_predicts_bit_for_bit() {
    let (_, _, _, model) = trained("urdf/planar_2dof.urdf", &paper_points(), 60);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("gp.json");
    std::fs::write(&path, model.to_json()).unwrap();
    let back = GpModel::load(&path).unwrap();
    assert_eq!(back, model);
    for q in [[-1.0, 0.1], [-0.3, 0.6]] {
        let (mut a, mut ja, mut b, mut jb) = ([0.0; 2], [0.0; 4], [0.0; 2], [0.0; 4]);
        model.predict(&q, &mut a, &mut ja);
        back.predict(&q, &mut b, &mut jb);
        assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits));
        assert_eq!(ja.map(f64::to_bits), jb.map(f64::to_bits));
    }
}

#[test]
fn training_is_deterministic_for_a_seed() {
    let (_, _, _, a) = trained("urdf/planar_2dof.urdf", &paper_points(), 50);
    let (_, _, _, b) = trained("urdf/planar_2dof.urdf", &paper_points(), 50);
    assert_eq!(a.to_json(), b.to_json());
}
