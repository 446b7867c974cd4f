//! The closed loop allocates nothing per tick (issue 15): a counting global allocator counts the
//! allocations of 1000 ticks of sense-estimate-learn-act with the run's metrics (after 300 ticks
//! of warm-up), for every method on the paper arm and the Panda. On aift's articulated engine the
//! whole loop allocates nothing (with either integrator). rapier's `PhysicsPipeline::step`
//! allocates inside (its island solver's per-step cursors and active-set vectors; no public
//! option turns that off): there the loop's count is rapier's alone, the same for every method
//! and constant per tick.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use aift::scenario::{Method, Observer, RunMetrics, Simulation};

struct Counting;

thread_local! {
    // Per thread: the test harness runs the tests of this file on threads of their own.
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

fn count() {
    // `try_with`: a thread's allocations while its locals are torn down are not counted.
    let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
}

fn allocations() -> u64 {
    ALLOCATIONS.with(|c| c.get())
}

// SAFETY: forwards to the system allocator, counting calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations_per_tick(file: &str, overrides: &[&str], method: Method) -> f64 {
    counted_ticks(&common::setup(file, overrides), method).0
}

/// Allocations per tick over ticks 300-1300, each channel's lowest precision there as a
/// fraction of its nominal (what happened in the counted ticks), and the detector's alarms
/// raised there.
fn counted_ticks(setup: &aift::scenario::RunSetup, method: Method) -> (f64, Vec<f64>, usize) {
    let cal = method
        .needs_detector()
        .then(|| aift::scenario::calibrate::calibrate(setup, 4).unwrap());
    let mut sim = Simulation::new(setup, method, 1, cal.as_ref()).unwrap();
    let mut metrics = RunMetrics::new(setup, sim.nominal());
    let mut lowest = vec![f64::INFINITY; setup.layout.len()];
    let mut step = |sim: &mut Simulation, lowest: &mut [f64]| {
        sim.decide(None);
        let record = sim.record();
        for (l, (p, n)) in lowest
            .iter_mut()
            .zip(record.precisions.iter().zip(record.nominal))
        {
            *l = l.min(p / n);
        }
        metrics.iter(&record);
        sim.actuate(None);
    };
    let mut warm_up = vec![f64::INFINITY; setup.layout.len()];
    for _ in 0..300 {
        step(&mut sim, &mut warm_up);
    }
    let alarms = |sim: &Simulation| sim.detection().map_or(0, |d| d.alarms.len());
    let alarms_before = alarms(&sim);
    let before = allocations();
    for _ in 0..1000 {
        step(&mut sim, &mut lowest);
    }
    let per_tick = (allocations() - before) as f64 / 1000.0;
    (per_tick, lowest, alarms(&sim) - alarms_before)
}

#[test]
fn the_closed_loop_allocates_nothing_per_tick() {
    let mut failures = Vec::new();
    for file in ["paper_encoder_freeze.toml", "panda_healthy.toml"] {
        let articulated = ["gp.points=100", "plant.engine=\"articulated\""];
        for method in Method::ALL {
            let a = allocations_per_tick(file, &articulated, method);
            eprintln!(
                "{file} articulated {}: {a} allocations per tick",
                method.name()
            );
            if a != 0.0 {
                failures.push(format!("{file} articulated {}: {a}", method.name()));
            }
        }
        // rapier: the count is the physics step's own, whatever the method.
        let physics = allocations_per_tick(file, &["gp.points=100"], Method::NoFt);
        for method in Method::ALL {
            let a = allocations_per_tick(file, &["gp.points=100"], method);
            eprintln!("{file} rapier {}: {a} allocations per tick", method.name());
            if a != physics {
                failures.push(format!(
                    "{file} rapier {}: {a} against {physics}",
                    method.name()
                ));
            }
        }
        assert!(physics <= 16.0, "{file}: rapier {physics} per tick");
        // The articulated engine's RK4 keeps its stages between steps too.
        let rk4 = [
            "gp.points=100",
            "plant.engine=\"articulated\"",
            "plant.articulated.integrator=\"rk4\"",
        ];
        let a = allocations_per_tick(file, &rk4, Method::NoFt);
        eprintln!("{file} articulated rk4 no-ft: {a} allocations per tick");
        if a != 0.0 {
            failures.push(format!("{file} articulated rk4: {a}"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The same while faults start and end in the counted ticks (0.3-1.3 s): isolations, the banks'
/// winner changes and re-anchoring (the test checks that the hybrid dropped the biased encoder
/// and the frozen tachometer there) and, on the Panda, joint limits engaged allocate nothing
/// either. The detector (`pl-detect`, `deterministic`) tests the channels not isolated in its
/// kept storage (it allocated a matrix every tick while a channel was isolated, 1-5 per tick);
/// each alarm it raises allocates the list of the channels it isolated, once. The hybrid with
/// its opt-in actuator hypotheses (`actuators`; the model-error state, its default, is off there
/// since the actuator hypotheses need it off; `restart_ruled_out`, the default) allocates nothing
/// either.
#[test]
fn the_closed_loop_allocates_nothing_while_faults_come_and_go() {
    let faults = [
        "[[faults]]\nchannel = \"enc1\"\nkind = \"bias\"\noffset = 0.3\nstart = 0.4\nend = 0.9",
        "[[faults]]\nchannel = \"tach2\"\nkind = \"freeze\"\nstart = 0.5",
        "[[faults]]\nchannel = \"cam\"\nkind = \"bias\"\noffset = 0.05\nstart = 0.7",
    ];
    let mut failures = Vec::new();
    for file in ["paper_healthy.toml", "panda_healthy.toml"] {
        let setup = common::with_faults(
            file,
            &faults,
            &["gp.points=100", "plant.engine=\"articulated\""],
        );
        for method in Method::ALL {
            let (a, lowest, alarms) = counted_ticks(&setup, method);
            eprintln!(
                "{file} with faults {}: {a} allocations per tick, {alarms} alarms",
                method.name()
            );
            // An alarm keeps the list of the channels it isolated: one allocation per alarm
            // raised, none per tick.
            if a * 1000.0 > alarms as f64 {
                failures.push(format!(
                    "{file} with faults {}: {a} per tick, {alarms} alarms",
                    method.name()
                ));
            }
            if method.needs_detector() && alarms == 0 {
                failures.push(format!("{file} {}: no alarm, not a test", method.name()));
            }
            // Not vacuous: in the counted ticks the hybrid dropped the biased encoder and the
            // frozen tachometer (winner changes, re-anchoring).
            let channel =
                |name: &str| (0..setup.layout.len()).find(|&c| setup.layout.name(c) == name);
            if method == Method::Hybrid {
                for name in ["enc1", "tach2"] {
                    let c = channel(name).expect("channel");
                    if lowest[c].is_nan() || lowest[c] >= 1e-3 {
                        failures.push(format!(
                            "{file} hybrid: {name} never dropped ({})",
                            lowest[c]
                        ));
                    }
                }
            }
        }
        // The hybrid's opt-in bank option: actuator hypotheses (with the white model error they
        // need), ruled-out hypotheses restarted every tick (the default, set to say so).
        let options = common::with_faults(
            file,
            &faults,
            &[
                "gp.points=100",
                "plant.engine=\"articulated\"",
                "hybrid.actuators=true",
                "hybrid.restart_ruled_out=true",
                "hybrid.model_error_state=false",
            ],
        );
        let (a, _, _) = counted_ticks(&options, Method::Hybrid);
        eprintln!("{file} with faults, hybrid with its options: {a} allocations per tick");
        if a != 0.0 {
            failures.push(format!("{file} hybrid with its options: {a} per tick"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
