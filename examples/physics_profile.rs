//! Steps the paper arm for a while: a target for profilers (`perf record`, callgrind).
use aift::plant::PlantSettings;

fn main() {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("urdf/planar_2dof.urdf");
    let iterations: usize = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(4);
    let mut settings = PlantSettings::default();
    settings.rapier.solver_iterations = iterations;
    let model = std::sync::Arc::new(aift::arm::load_urdf(&path).expect("paper arm"));
    let mut arm = aift::plant::build(model, [0.0, 0.0, -9.81], &settings).expect("rapier plant");
    arm.set_state(&[-1.2, 0.8], &[0.5, -0.3]);
    arm.set_torques(&[20.0, 5.0]);
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(200_000);
    let t = std::time::Instant::now();
    for _ in 0..n {
        arm.step(1e-3);
    }
    let (q, _) = arm.state();
    println!(
        "{:?} {:.2} us/tick",
        q,
        t.elapsed().as_secs_f64() * 1e6 / n as f64
    );
}
