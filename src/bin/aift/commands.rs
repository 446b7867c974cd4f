//! The commands: each parses nothing itself, calls the library, prints, and maps errors to exit
//! codes.

use anyhow::{Context, anyhow};

use aift::plant::{self, Arm, ArmOptions};
use aift::report;

use crate::args::{CheckUrdfArgs, Cli, Command, SimulateArgs};

/// A failed command: the error and the exit code it maps to.
pub struct Failure {
    pub error: anyhow::Error,
    pub code: u8,
}

/// Exit code 2: the input is at fault.
fn bad_input(error: impl Into<anyhow::Error>) -> Failure {
    Failure {
        error: error.into(),
        code: 2,
    }
}

/// Exit code 1: aift or the machine is at fault.
fn internal(error: impl Into<anyhow::Error>) -> Failure {
    Failure {
        error: error.into(),
        code: 1,
    }
}

pub fn dispatch(cli: Cli) -> Result<(), Failure> {
    match cli.command {
        Command::CheckUrdf(args) => check_urdf(args),
        Command::Simulate(args) => simulate(args),
    }
}

fn check_urdf(args: CheckUrdfArgs) -> Result<(), Failure> {
    let model = plant::load_urdf(&args.path).map_err(bad_input)?;
    if let Some(ee) = args.ee.as_deref().filter(|ee| model.link(ee).is_none()) {
        return Err(bad_input(model.unknown_link_error(ee)));
    }
    println!("arm '{}' from {}", model.name, args.path.display());
    println!("movable joints: {}", model.joints.len());
    for (i, j) in model.joints.iter().enumerate() {
        let axis = j.axis.into_inner();
        let limits = match j.limits {
            Some((lo, hi)) => format!("[{lo}, {hi}]"),
            None => "none".into(),
        };
        let effort = j.effort.map_or("none".into(), |e| format!("{e}"));
        println!(
            "  {}. {} ({}) parent '{}' child '{}' axis ({}, {}, {}) limits {} effort {} damping {} friction {}",
            i + 1,
            j.name,
            j.kind.name(),
            model.bodies[j.parent_body].link,
            model.bodies[j.child_body].link,
            axis.x,
            axis.y,
            axis.z,
            limits,
            effort,
            j.damping,
            j.friction
        );
    }
    println!("links:");
    for l in &model.links {
        let body = &model.bodies[l.body].link;
        if l.has_inertial {
            println!("  {} mass {} kg (body '{}')", l.name, l.mass, body);
        } else {
            println!("  {} massless frame (body '{}')", l.name, body);
        }
    }
    println!("total mass: {} kg", model.total_mass());
    match &args.ee {
        Some(ee) => println!("end effector: {ee}"),
        None => match model.link("ee") {
            Some(_) => println!("end effector: ee (default)"),
            None => println!("end effector: none named 'ee'; pass --ee LINK"),
        },
    }
    for w in &model.warnings {
        println!("warning: {w}");
    }
    Ok(())
}

fn check_positive(name: &str, value: f64) -> Result<(), Failure> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(bad_input(anyhow!(
            "--{name} = {value} must be finite and > 0"
        )))
    }
}

fn simulate(args: SimulateArgs) -> Result<(), Failure> {
    check_positive("duration", args.duration)?;
    check_positive("dt", args.dt)?;
    if args.duration / args.dt > 1e8 {
        return Err(bad_input(anyhow!(
            "--duration / --dt = {} steps; more than 1e8 is refused",
            args.duration / args.dt
        )));
    }
    let mut options = ArmOptions {
        ee_link: args.ee.clone(),
        ..ArmOptions::default()
    };
    if let Some(it) = args.iterations {
        options.solver_iterations = it;
    }
    let mut arm = Arm::from_urdf(&args.urdf, options).map_err(bad_input)?;
    let n = arm.n_joints();
    let check_len = |name: &str, v: &[f64]| {
        if v.len() == n {
            Ok(())
        } else {
            Err(bad_input(anyhow!(
                "--{name} has {} values; {} has {n} movable joints ({})",
                v.len(),
                args.urdf.display(),
                arm.joint_names().join(", ")
            )))
        }
    };
    let qd0 = args.qd0.map_or(vec![0.0; n], |l| l.0);
    let torque = args.torque.map_or(vec![0.0; n], |l| l.0);
    check_len("q0", &args.q0.0)?;
    check_len("qd0", &qd0)?;
    check_len("torque", &torque)?;
    let samples = plant::run_open_loop(&mut arm, &args.q0.0, &qd0, &torque, args.duration, args.dt);
    let rows: Vec<Vec<f64>> = samples
        .iter()
        .map(|s| {
            let mut row = vec![s.t];
            row.extend(&s.q);
            row.extend(&s.qd);
            row.extend(s.ee);
            row
        })
        .collect();
    let text = report::csv_text(&plant::open_loop_header(n), rows.iter().map(Vec::as_slice));
    report::write_atomic(&args.out, text.as_bytes())
        .with_context(|| "writing the trajectory")
        .map_err(internal)?;
    println!(
        "wrote {} rows ({} joints, {} s at dt {}) to {}",
        rows.len(),
        n,
        args.duration,
        args.dt,
        args.out.display()
    );
    Ok(())
}
