//! Sensing all channels of the paper arm once (encoders, tachometers, camera with occlusion).

use std::path::PathBuf;

use aift::sensors::{
    Camera, CameraConfig, CameraModel, ChannelLayout, Readings, SensorConfig, SensorSuite,
};
use criterion::{Criterion, criterion_group, criterion_main};

fn sensing(c: &mut Criterion) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("urdf/planar_2dof.urdf");
    let model = std::sync::Arc::new(aift::arm::load_urdf(&path).expect("paper arm"));
    let ee = aift::arm::EndEffector::new(&model, "ee", [0.0; 3]).expect("an ee link");
    let mut arm = aift::plant::build(model, [0.0, 0.0, -9.81], &Default::default())
        .expect("the plant builds");
    arm.set_state(&[-0.6, 0.2], &[0.1, 0.0]);
    let layout = ChannelLayout::new(2, CameraModel::Pinhole);
    let mut suite = SensorSuite::new(
        layout,
        &SensorConfig::default(),
        Camera::new(CameraConfig::default()),
        ee,
        &[],
        1e-3,
        1,
    );
    let mut readings = Readings::missing(&layout);
    let mut tick = 0u64;
    c.bench_function("sense_all_channels_2dof", |b| {
        b.iter(|| {
            suite.read(arm.as_ref(), tick, &mut readings);
            tick += 1;
        })
    });
}

criterion_group!(benches, sensing);
criterion_main!(benches);
