//! Helpers shared by the integration tests: independent references written here, not in src/.
#![allow(dead_code)]

use std::path::PathBuf;

/// Path of a file in the repository.
pub fn repo(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(path)
}

/// The paper's 2-DOF arm in closed form (docs/method.md, "Plant"), the oracle for the physics.
#[derive(Clone, Copy, Debug)]
pub struct PaperArm {
    pub l1: f64,
    pub lc1: f64,
    pub lc2: f64,
    pub m1: f64,
    pub m2: f64,
    pub i1: f64,
    pub i2: f64,
    pub d1: f64,
    pub d2: f64,
    pub g: f64,
}

impl Default for PaperArm {
    fn default() -> Self {
        Self {
            l1: 1.0446,
            lc1: 0.5451,
            lc2: 0.5075,
            m1: 2.1368,
            m2: 2.2418,
            i1: 1.0209,
            i2: 1.0218,
            d1: 101.519,
            d2: 103.8566,
            g: 9.81,
        }
    }
}

impl PaperArm {
    /// M(q).
    pub fn mass_matrix(&self, q: [f64; 2]) -> [[f64; 2]; 2] {
        let c2 = q[1].cos();
        let m11 = self.i1
            + self.i2
            + self.m1 * self.lc1 * self.lc1
            + self.m2 * (self.l1 * self.l1 + self.lc2 * self.lc2 + 2.0 * self.l1 * self.lc2 * c2);
        let m12 = self.i2 + self.m2 * (self.lc2 * self.lc2 + self.l1 * self.lc2 * c2);
        let m22 = self.i2 + self.m2 * self.lc2 * self.lc2;
        [[m11, m12], [m12, m22]]
    }

    /// G(q).
    pub fn gravity(&self, q: [f64; 2]) -> [f64; 2] {
        let c1 = q[0].cos();
        let c12 = (q[0] + q[1]).cos();
        [
            self.g * (self.m1 * self.lc1 * c1 + self.m2 * (self.lc2 * c12 + self.l1 * c1)),
            self.g * self.m2 * self.lc2 * c12,
        ]
    }

    /// C(q, qd) qd.
    pub fn coriolis(&self, q: [f64; 2], qd: [f64; 2]) -> [f64; 2] {
        let h = self.m2 * self.l1 * self.lc2 * q[1].sin();
        [
            -h * qd[1] * qd[1] - 2.0 * h * qd[0] * qd[1],
            h * qd[0] * qd[0],
        ]
    }

    /// qdd = M^-1 (tau - C qd - D qd - G).
    pub fn acceleration(&self, q: [f64; 2], qd: [f64; 2], tau: [f64; 2]) -> [f64; 2] {
        let m = self.mass_matrix(q);
        let c = self.coriolis(q, qd);
        let g = self.gravity(q);
        let f = [
            tau[0] - c[0] - self.d1 * qd[0] - g[0],
            tau[1] - c[1] - self.d2 * qd[1] - g[1],
        ];
        solve2(m, f)
    }

    /// Classic RK4 from (q, qd) over `duration` with step `h`, constant torque.
    pub fn rk4(
        &self,
        q: [f64; 2],
        qd: [f64; 2],
        tau: [f64; 2],
        duration: f64,
        h: f64,
    ) -> ([f64; 2], [f64; 2]) {
        let steps = (duration / h).round() as usize;
        let mut x = [q[0], q[1], qd[0], qd[1]];
        let f = |x: [f64; 4]| {
            let a = self.acceleration([x[0], x[1]], [x[2], x[3]], tau);
            [x[2], x[3], a[0], a[1]]
        };
        for _ in 0..steps {
            let k1 = f(x);
            let k2 = f(add(x, k1, h / 2.0));
            let k3 = f(add(x, k2, h / 2.0));
            let k4 = f(add(x, k3, h));
            for i in 0..4 {
                x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
        }
        ([x[0], x[1]], [x[2], x[3]])
    }
}

fn add(x: [f64; 4], k: [f64; 4], s: f64) -> [f64; 4] {
    [
        x[0] + s * k[0],
        x[1] + s * k[1],
        x[2] + s * k[2],
        x[3] + s * k[3],
    ]
}

/// Solves a 2x2 linear system.
pub fn solve2(m: [[f64; 2]; 2], f: [f64; 2]) -> [f64; 2] {
    let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    [
        (m[1][1] * f[0] - m[0][1] * f[1]) / det,
        (m[0][0] * f[1] - m[1][0] * f[0]) / det,
    ]
}

/// A prepared scenario from `assets/scenarios/`, with overrides.
pub fn setup(file: &str, overrides: &[&str]) -> aift::scenario::RunSetup {
    let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let loaded = aift::scenario::LoadedScenario::from_file(
        &repo(&format!("assets/scenarios/{file}")),
        &overrides,
    )
    .expect("bundled scenario loads");
    aift::scenario::RunSetup::prepare(loaded).expect("bundled scenario prepares")
}

/// A bundled scenario (`assets/scenarios/`) with faults appended (TOML snippets) and overrides.
/// Faults go in through a scenario file of their own: --set cannot add array entries.
pub fn with_faults(file: &str, faults: &[&str], overrides: &[&str]) -> aift::scenario::RunSetup {
    let base = std::fs::read_to_string(repo(&format!("assets/scenarios/{file}")))
        .unwrap()
        .replace("../../urdf/", &format!("{}/", repo("urdf").display()));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(file);
    std::fs::write(&path, format!("{base}\n{}\n", faults.join("\n"))).unwrap();
    let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let loaded = aift::scenario::LoadedScenario::from_file(&path, &overrides).unwrap();
    aift::scenario::RunSetup::prepare(loaded).unwrap()
}

/// Runs one method and seed, recording the trajectory.
pub fn run_recorded(
    setup: &aift::scenario::RunSetup,
    method: aift::scenario::Method,
    seed: u64,
    calibration: Option<&aift::precision::Calibration>,
) -> (
    aift::scenario::RunResult,
    aift::scenario::TrajectoryRecorder,
) {
    let mut rec = aift::scenario::TrajectoryRecorder::new(&setup.layout);
    let result = aift::scenario::Run::new(setup, method)
        .seed(seed)
        .calibration(calibration)
        .observe(&mut rec, aift::scenario::ObserverMode::Always)
        .execute()
        .expect("run");
    (result, rec)
}

/// The value of a recorded column at time t.
pub fn at(rec: &aift::scenario::TrajectoryRecorder, column: &str, t: f64) -> f64 {
    let c = rec.column(column).expect("column");
    let dt = rec.rows[1][0] - rec.rows[0][0];
    let k = ((t / dt).round() as usize).min(rec.rows.len() - 1);
    rec.rows[k][c]
}

/// Minimum of a recorded column over [from, to).
pub fn min_between(
    rec: &aift::scenario::TrajectoryRecorder,
    column: &str,
    from: f64,
    to: f64,
) -> f64 {
    let c = rec.column(column).expect("column");
    rec.rows
        .iter()
        .filter(|r| r[0] >= from - 1e-9 && r[0] < to - 1e-9)
        .map(|r| r[c])
        .fold(f64::INFINITY, f64::min)
}

/// The `aift` binary with `args`, to run in `dir` (calibration cache off), for callers that set
/// its streams or environment further.
pub fn aift_command(args: &[&str], dir: &std::path::Path) -> std::process::Command {
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_aift"));
    command
        .args(args)
        .current_dir(dir)
        .env("AIFT_CACHE_DIR", "off");
    command
}

/// Runs the `aift` binary in `dir` (calibration cache off).
pub fn aift_in(args: &[&str], dir: &std::path::Path) -> std::process::Output {
    aift_command(args, dir).output().unwrap()
}

/// A bundled scenario's text with its URDF path made absolute (to be written anywhere).
pub fn scenario_text(file: &str) -> String {
    std::fs::read_to_string(repo(&format!("assets/scenarios/{file}")))
        .unwrap()
        .replace("../../urdf/", &format!("{}/", repo("urdf").display()))
}

/// `aift run` on `paper_healthy.toml` with `extra` appended refuses it before any work: exit 2,
/// the file and `key` named on stderr, no output folder.
pub fn assert_refused(extra: &str, key: &str) {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("bad.toml");
    std::fs::write(
        &path,
        format!("{}\n{extra}\n", scenario_text("paper_healthy.toml")),
    )
    .unwrap();
    let out = aift_in(&["run", path.to_str().unwrap(), "--out", "out"], tmp.path());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{extra}: {stderr}");
    assert!(
        stderr.contains(key),
        "{extra}: {stderr} does not name {key}"
    );
    assert!(stderr.contains("bad.toml"), "{extra}: {stderr}");
    assert!(
        !tmp.path().join("out").exists(),
        "{extra}: no output written"
    );
}

/// The `*.toml` files of a folder of the repository, sorted.
pub fn toml_files(folder: &str) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(repo(folder))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    files
}

/// Runs the `aift` binary in `dir` (calibration cache off) and asserts it succeeded.
pub fn aift_ok(args: &[&str], dir: &std::path::Path) -> std::process::Output {
    let out = aift_in(args, dir);
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// `aift gen-arm --seed seed` and `aift init` in `dir` (files `arm{seed}.urdf`, `arm{seed}.toml`):
/// the scenario's file name and the joint count, or None where `init` refuses the arm.
pub fn generated_arm(seed: u64, dir: &std::path::Path) -> Option<(String, usize)> {
    let urdf = format!("arm{seed}.urdf");
    let scenario = format!("arm{seed}.toml");
    aift_ok(
        &["gen-arm", "--seed", &seed.to_string(), "--out", &urdf],
        dir,
    );
    let init = aift_in(&["init", "--urdf", &urdf, "--out", &scenario], dir);
    if init.status.code() != Some(0) {
        return None;
    }
    let n = aift::arm::load_urdf(&dir.join(&urdf)).unwrap().joints.len();
    Some((scenario, n))
}

/// A one-cell campaign on the paper arm (no-ft and the oracle, an encoder freeze while moving,
/// 9 s on the articulated engine), named `name`, with `extra` TOML appended.
pub fn tiny_campaign(name: &str, extra: &str) -> String {
    format!(
        r#"
name = "{name}"
seeds = 1
methods = ["no-ft", "oracle"]
defaults = {{ duration = 9.0, plant = {{ engine = "articulated" }} }}
channels = ["enc*"]

[[arms]]
name = "paper"
scenario = "{}"

[[kinds]]
kind = "freeze"
onsets = ["moving"]
{extra}"#,
        repo("assets/scenarios/paper_healthy.toml").display()
    )
}

/// The arm model of a URDF in the repository.
pub fn model(file: &str) -> std::sync::Arc<aift::arm::ArmModel> {
    std::sync::Arc::new(aift::arm::load_urdf(&repo(file)).expect("the arm loads"))
}

/// The end effector on link `ee` of a model.
pub fn ee(model: &aift::arm::ArmModel) -> aift::arm::EndEffector {
    aift::arm::EndEffector::new(model, "ee", [0.0; 3]).expect("the arm has a link named ee")
}

/// A plant of a URDF in the repository under standard gravity: `engine`, its integrator (the
/// articulated engine's) and `iterations` (rapier's solver iterations or the substeps).
pub fn plant_of(
    file: &str,
    engine: aift::plant::Engine,
    integrator: aift::plant::Integrator,
    iterations: usize,
) -> Box<dyn aift::plant::Plant> {
    let mut settings = aift::plant::PlantSettings {
        engine,
        ..Default::default()
    };
    match engine {
        aift::plant::Engine::Rapier => settings.rapier.solver_iterations = iterations,
        aift::plant::Engine::Articulated => {
            settings.articulated.substeps = iterations;
            settings.articulated.integrator = integrator;
        }
    }
    aift::plant::build(model(file), [0.0, 0.0, -9.81], &settings).expect("the plant builds")
}

/// The rapier plant of a URDF in the repository with the default settings.
pub fn rapier(file: &str) -> Box<dyn aift::plant::Plant> {
    plant_of(
        file,
        aift::plant::Engine::Rapier,
        aift::plant::Integrator::Euler,
        2,
    )
}

/// The Panda actuator faults both detectors are checked on (joint, the fault's kind lines), each
/// starting at 7.6 s, during the motion to the second target.
pub const PANDA_ACTUATOR_FAULTS: [(usize, &str); 3] = [
    (4, "kind = \"locked\""),
    (2, "kind = \"effectiveness\"\nfactor = 0.2"),
    (6, "kind = \"dead\""),
];

/// One run of the Panda's healthy template with an actuator fault on `joint` (1-based) from
/// 7.6 s, `kind` its kind lines, under `overrides`.
pub fn panda_actuator_fault_run(
    joint: usize,
    kind: &str,
    overrides: &[&str],
    method: aift::scenario::Method,
    seed: u64,
) -> aift::scenario::RunResult {
    let fault = format!("[[actuator_faults]]\njoint = {joint}\nstart = 7.6\n{kind}");
    let setup = with_faults("panda_healthy.toml", &[&fault], overrides);
    aift::scenario::Run::new(&setup, method)
        .seed(seed)
        .execute()
        .unwrap()
}
