//! The rapier plant against the closed-form 2-link dynamics of docs/method.md, "Plant".

mod common;

use aift::arm::kinematics;
use aift::plant::{Engine, Integrator, Plant};
use common::{PaperArm, solve2};

fn paper_arm(iterations: usize) -> Box<dyn Plant> {
    common::plant_of(
        "urdf/planar_2dof.urdf",
        Engine::Rapier,
        Integrator::Euler,
        iterations,
    )
}

fn simulate(
    arm: &mut dyn Plant,
    q0: [f64; 2],
    tau: [f64; 2],
    duration: f64,
    dt: f64,
) -> ([f64; 2], [f64; 2]) {
    arm.set_state(&q0, &[0.0, 0.0]);
    arm.set_torques(&tau);
    let steps = (duration / dt).round() as usize;
    for _ in 0..steps {
        arm.step(dt);
    }
    let (q, qd) = arm.state();
    ([q[0], q[1]], [qd[0], qd[1]])
}

fn max_error(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).abs().max((a[1] - b[1]).abs())
}

#[test]
fn matches_rk4_reference_with_zero_and_constant_torques() {
    let oracle = PaperArm::default();
    for tau in [[0.0, 0.0], [30.0, -8.0]] {
        let (q_ref, _) = oracle.rk4([0.3, 0.2], [0.0, 0.0], tau, 2.0, 1e-5);
        // Default settings (2 solver iterations).
        let mut arm = common::rapier("urdf/planar_2dof.urdf");
        let (q, _) = simulate(arm.as_mut(), [0.3, 0.2], tau, 2.0, 1e-3);
        let err = max_error(q, q_ref);
        eprintln!("tau {tau:?}: q {q:?} ref {q_ref:?} error {err:.3e}");
        assert!(err <= 1e-3, "max |q - q_ref| = {err} for tau {tau:?}");
    }
}

#[test]
fn error_shrinks_as_solver_iterations_grow() {
    let oracle = PaperArm::default();
    let (q_ref, _) = oracle.rk4([0.3, 0.2], [0.0, 0.0], [0.0, 0.0], 2.0, 1e-5);
    let errors: Vec<f64> = [1, 4, 16]
        .iter()
        .map(|&it| {
            let mut arm = paper_arm(it);
            max_error(
                simulate(arm.as_mut(), [0.3, 0.2], [0.0, 0.0], 2.0, 1e-3).0,
                q_ref,
            )
        })
        .collect();
    eprintln!("errors for 1, 4, 16 iterations: {errors:?}");
    assert!(errors[0] > errors[1] && errors[1] > errors[2], "{errors:?}");
}

#[test]
fn one_tick_from_rest_equals_the_implicit_damping_map() {
    let oracle = PaperArm::default();
    let dt = 1e-3;
    for (q0, tau) in [([0.3, 0.2], [0.0, 0.0]), ([-1.0, 0.7], [40.0, -5.0])] {
        let mut arm = paper_arm(1);
        let (q, qd) = simulate(arm.as_mut(), q0, tau, dt, dt);
        // rapier applies joint damping implicitly: qd1 = dt (M + dt D)^-1 (tau - G).
        let mut m = oracle.mass_matrix(q0);
        m[0][0] += dt * oracle.d1;
        m[1][1] += dt * oracle.d2;
        let g = oracle.gravity(q0);
        let acc = solve2(m, [tau[0] - g[0], tau[1] - g[1]]);
        for i in 0..2 {
            let qd_ref = dt * acc[i];
            let q_ref = q0[i] + dt * qd_ref;
            let rel_v = (qd[i] - qd_ref).abs() / qd_ref.abs();
            let rel_q = (q[i] - q_ref).abs() / (q_ref - q0[i]).abs();
            eprintln!(
                "joint {i}: qd {} ref {qd_ref} rel {rel_v:.2e}; q rel {rel_q:.2e}",
                qd[i]
            );
            assert!(rel_v <= 1e-9, "joint {i}: qd {} vs {qd_ref}", qd[i]);
            assert!(rel_q <= 1e-9, "joint {i}: q {} vs {q_ref}", q[i]);
        }
    }
}

#[test]
fn viscous_friction_from_the_urdf_is_applied() {
    // With the URDF's damping the arm falls far slower than it would without.
    let oracle = PaperArm::default();
    let undamped = PaperArm {
        d1: 0.0,
        d2: 0.0,
        ..oracle
    };
    let (q_damped, _) = oracle.rk4([0.3, 0.2], [0.0, 0.0], [0.0, 0.0], 0.5, 1e-5);
    let (q_free, _) = undamped.rk4([0.3, 0.2], [0.0, 0.0], [0.0, 0.0], 0.5, 1e-5);
    let mut arm = paper_arm(4);
    let (q, _) = simulate(arm.as_mut(), [0.3, 0.2], [0.0, 0.0], 0.5, 1e-3);
    let to_damped = max_error(q, q_damped);
    let to_free = max_error(q, q_free);
    eprintln!("distance to damped {to_damped:.3e}, to undamped {to_free:.3e}");
    assert!(to_damped < 1e-3 && to_free > 0.1, "{to_damped} {to_free}");
}

#[test]
fn hanging_pose_is_an_equilibrium() {
    let mut arm = paper_arm(4);
    let down = -std::f64::consts::FRAC_PI_2;
    let (q, qd) = simulate(arm.as_mut(), [down, 0.0], [0.0, 0.0], 2.0, 1e-3);
    eprintln!("after 2 s hanging: q {q:?} qd {qd:?}");
    assert!(max_error(q, [down, 0.0]) < 1e-9, "{q:?}");
    assert!(max_error(qd, [0.0, 0.0]) < 1e-9, "{qd:?}");
}

#[test]
fn end_effector_and_jacobian_follow_forward_kinematics() {
    let mut arm = paper_arm(4);
    let q = [0.4, -0.9];
    arm.set_state(&q, &[0.0, 0.0]);
    let (l1, l2) = (1.0446, 1.0111);
    let ee = common::ee(arm.model());
    let p = arm.ee_position(&ee);
    let x = l1 * q[0].cos() + l2 * (q[0] + q[1]).cos();
    let z = l1 * q[0].sin() + l2 * (q[0] + q[1]).sin();
    assert!(
        (p.x - x).abs() < 1e-12 && p.y.abs() < 1e-12 && (p.z - z).abs() < 1e-12,
        "{p}"
    );
    let mut poses = vec![nalgebra::Isometry3::identity(); arm.model().bodies.len()];
    arm.body_poses_into(&mut poses);
    let jac = kinematics::ee_jacobian(arm.model(), &ee, &poses);
    let dx = [
        -l1 * q[0].sin() - l2 * (q[0] + q[1]).sin(),
        -l2 * (q[0] + q[1]).sin(),
    ];
    let dz = [
        l1 * q[0].cos() + l2 * (q[0] + q[1]).cos(),
        l2 * (q[0] + q[1]).cos(),
    ];
    for j in 0..2 {
        assert!((jac[(0, j)] - dx[j]).abs() < 1e-12, "{jac}");
        assert!(jac[(1, j)].abs() < 1e-12, "{jac}");
        assert!((jac[(2, j)] - dz[j]).abs() < 1e-12, "{jac}");
    }
}
