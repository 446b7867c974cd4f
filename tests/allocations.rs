//! The closed loop allocates nothing per tick (issue 15): a counting global allocator counts the
//! allocations of 1000 ticks of sense-estimate-learn-act with the run's metrics (after 300 ticks
//! of warm-up), for every method on the paper arm and the Panda. On aift's articulated engine the
//! whole loop allocates nothing (with either integrator). rapier's `PhysicsPipeline::step`
//! allocates inside (its island solver's per-step cursors and active-set vectors; no public
//! option turns that off): there the loop's count is rapier's alone, the same for every method
//! and constant per tick.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering};

use aift::scenario::{Method, Observer, RunMetrics, Simulation};

struct Counting;

static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

// SAFETY: forwards to the system allocator, counting calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations_per_tick(file: &str, overrides: &[&str], method: Method) -> f64 {
    let setup = common::setup(file, overrides);
    let cal = method
        .needs_detector()
        .then(|| aift::scenario::calibrate::calibrate(&setup, 4).unwrap());
    let mut sim = Simulation::new(&setup, method, 1, cal.as_ref()).unwrap();
    let mut metrics = RunMetrics::new(&setup, sim.nominal());
    let mut step = |sim: &mut Simulation| {
        sim.decide(None);
        metrics.on_tick(&sim.record());
        sim.actuate(None);
    };
    for _ in 0..300 {
        step(&mut sim);
    }
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    for _ in 0..1000 {
        step(&mut sim);
    }
    (ALLOCATIONS.load(Ordering::Relaxed) - before) as f64 / 1000.0
}

#[test]
fn the_closed_loop_allocates_nothing_per_tick() {
    let mut failures = Vec::new();
    for file in ["paper_encoder_freeze.toml", "panda_healthy.toml"] {
        let articulated = ["gp.points=100", "robot.engine=\"articulated\""];
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
            "robot.engine=\"articulated\"",
            "robot.integrator=\"rk4\"",
        ];
        let a = allocations_per_tick(file, &rk4, Method::NoFt);
        eprintln!("{file} articulated rk4 no-ft: {a} allocations per tick");
        if a != 0.0 {
            failures.push(format!("{file} articulated rk4: {a}"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
