//! Sensors: noise statistics and stream independence, the camera (distortion, poses, occlusion),
//! and every fault kind in time.

mod common;

use aift::plant::Plant;
use aift::sensors::{
    Camera, CameraConfig, CameraModel, Channel, ChannelLayout, Fault, FaultKind, FaultSpec,
    Readings, SensorConfig, SensorSuite,
};

fn arm(file: &str) -> Box<dyn Plant> {
    common::rapier(file)
}

fn suite(arm: &dyn Plant, faults: &[Fault], seed: u64) -> SensorSuite {
    SensorSuite::new(
        ChannelLayout::new(arm.n_joints(), CameraModel::Pinhole),
        &SensorConfig::default(),
        Camera::new(CameraConfig::default()),
        common::ee(arm.model()),
        faults,
        1e-3,
        seed,
    )
}

/// Noise samples per channel over `ticks` ticks of a resting arm.
fn noise_series(arm: &dyn Plant, suite: &mut SensorSuite, ticks: u64) -> Vec<Vec<f64>> {
    let layout = suite.layout();
    let mut out = vec![Vec::with_capacity(ticks as usize); layout.len()];
    let mut readings = Readings::missing(&layout);
    for k in 0..ticks {
        suite.read(arm, k, &mut readings);
        for (c, series) in out.iter_mut().enumerate() {
            series.push(suite.noise()[c]);
        }
    }
    out
}

fn mean_std(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    let v = x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (n - 1.0);
    (m, v.sqrt())
}

#[test]
fn noise_has_the_configured_mean_and_std() {
    let arm = arm("urdf/planar_2dof.urdf");
    let mut s = suite(arm.as_ref(), &[], 7);
    let n = 100_000;
    let series = noise_series(arm.as_ref(), &mut s, n);
    let sigmas = s.sigmas().to_vec();
    for (c, x) in series.iter().enumerate() {
        let (m, sd) = mean_std(x);
        let sigma = sigmas[c];
        // 5-sigma bounds of the sample mean and the sample standard deviation.
        assert!(
            m.abs() < 5.0 * sigma / (n as f64).sqrt(),
            "channel {c}: mean {m}"
        );
        assert!(
            (sd / sigma - 1.0).abs() < 5.0 / (2.0 * n as f64).sqrt(),
            "channel {c}: std {sd} vs {sigma}"
        );
    }
}

#[test]
fn streams_are_independent_of_each_other_and_of_the_channel_count() {
    let arm2 = arm("urdf/planar_2dof.urdf");
    let arm3 = arm("urdf/planar_3dof.urdf");
    let n = 100_000;
    let s2 = noise_series(arm2.as_ref(), &mut suite(arm2.as_ref(), &[], 11), n);
    let s3 = noise_series(arm3.as_ref(), &mut suite(arm3.as_ref(), &[], 11), n);
    let l2 = ChannelLayout::new(2, CameraModel::Pinhole);
    let l3 = ChannelLayout::new(3, CameraModel::Pinhole);
    // Same channel, same seed: the same noise, whatever the number of joints.
    for ch in [
        Channel::Encoder(0),
        Channel::Encoder(1),
        Channel::Tachometer(1),
        Channel::Camera(0),
        Channel::Camera(1),
    ] {
        let a = &s2[l2.index(ch)];
        let b = &s3[l3.index(ch)];
        assert!(
            a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()),
            "{ch:?}"
        );
    }
    // Different channels: uncorrelated (|r| < 5 / sqrt(n)).
    for i in 0..s2.len() {
        for j in 0..i {
            let (mi, si) = mean_std(&s2[i]);
            let (mj, sj) = mean_std(&s2[j]);
            let r = s2[i]
                .iter()
                .zip(&s2[j])
                .map(|(a, b)| (a - mi) * (b - mj))
                .sum::<f64>()
                / ((n as f64 - 1.0) * si * sj);
            assert!(
                r.abs() < 5.0 / (n as f64).sqrt(),
                "channels {i},{j}: r = {r}"
            );
        }
    }
    // A different seed gives different noise.
    let other = noise_series(arm2.as_ref(), &mut suite(arm2.as_ref(), &[], 12), 10);
    assert_ne!(other[0], s2[0][..10].to_vec());
}

#[test]
fn adding_a_fault_does_not_change_another_channels_noise() {
    let arm = arm("urdf/planar_2dof.urdf");
    let spikes = spec(
        "enc1",
        FaultKind::Spikes {
            probability: 0.5,
            magnitude: 1.0,
        },
        0.0,
        None,
    )
    .to_fault(&layout2(), 1e-3)
    .unwrap();
    let mut clean = suite(arm.as_ref(), &[], 3);
    let mut faulty = suite(arm.as_ref(), &[spikes], 3);
    let layout = clean.layout();
    let (mut a, mut b) = (Readings::missing(&layout), Readings::missing(&layout));
    let mut differed = false;
    for k in 0..2000 {
        clean.read(arm.as_ref(), k, &mut a);
        faulty.read(arm.as_ref(), k, &mut b);
        for c in 1..layout.len() {
            assert_eq!(a.values[c], b.values[c], "tick {k} channel {c}");
        }
        differed |= a.values[0] != b.values[0];
    }
    assert!(differed, "the spikes did hit encoder 1");
}

#[test]
fn readings_are_truth_plus_noise_and_the_camera_sees_the_distorted_tip() {
    let mut arm = arm("urdf/planar_2dof.urdf");
    arm.set_state(&[-0.2, 0.5], &[0.3, -0.1]);
    let mut s = suite(arm.as_ref(), &[], 5);
    let mut r = Readings::missing(&s.layout());
    s.read(arm.as_ref(), 0, &mut r);
    let noise = s.noise().to_vec();
    assert_eq!(r.values[0], Some(-0.2 + noise[0]));
    assert_eq!(r.values[3], Some(-0.1 + noise[3]));
    let p = arm.ee_position(&common::ee(arm.model()));
    let image = Camera::new(CameraConfig::default()).project(&p).unwrap();
    assert_eq!(r.values[4], Some(image[0] + noise[4]));
    assert_eq!(r.values[5], Some(image[1] + noise[5]));
    // The distorted image is within 2 cm of the true (x, z) but not equal to it.
    let (dx, dz) = (image[0] - p.x, image[1] - p.z);
    assert!(dx.hypot(dz) < 0.02 && dx.hypot(dz) > 1e-3, "{dx} {dz}");
}

#[test]
fn an_occluded_end_effector_reports_missing() {
    let mut arm = arm("urdf/planar_2dof.urdf");
    // A camera above the base looking down; hanging straight down, link 1 hides the tip.
    let camera = Camera::new(CameraConfig {
        position: [0.0, 0.0, 5.0],
        look_at: [0.0, 0.0, -1.0],
        up: [1.0, 0.0, 0.0],
        ..CameraConfig::default()
    });
    let ee = common::ee(arm.model());
    let mut s = SensorSuite::new(
        layout2(),
        &SensorConfig::default(),
        camera,
        ee,
        &[],
        1e-3,
        1,
    );
    let mut r = Readings::missing(&s.layout());
    arm.set_state(&[-std::f64::consts::FRAC_PI_2, 0.0], &[0.0, 0.0]);
    s.read(arm.as_ref(), 0, &mut r);
    assert_eq!((r.values[4], r.values[5]), (None, None));
    assert_eq!(s.camera_miss(), Some(aift::sensors::NotSeen::Occluded));
    assert!(r.values[0].is_some(), "encoders still read");
    // Stretched out horizontally the tip is in plain view.
    arm.set_state(&[0.0, 0.0], &[0.0, 0.0]);
    s.read(arm.as_ref(), 1, &mut r);
    assert!(r.values[4].is_some() && r.values[5].is_some());
}

fn layout2() -> ChannelLayout {
    ChannelLayout::new(2, CameraModel::Pinhole)
}

fn spec(channel: &str, kind: FaultKind, start: f64, end: Option<f64>) -> FaultSpec {
    FaultSpec {
        channel: channel.into(),
        kind,
        start,
        end,
    }
}

/// Runs a moving arm with one fault (start 0.1 s, end 0.2 s) and the same arm without, and
/// returns (faulty, clean, noise) series of the channel.
fn with_and_without(
    fault: FaultSpec,
    channel: usize,
) -> (Vec<Option<f64>>, Vec<Option<f64>>, Vec<f64>) {
    let mut arm = arm("urdf/planar_2dof.urdf");
    arm.set_state(&[-0.5, 0.5], &[0.0, 0.0]);
    arm.set_torques(&[60.0, 5.0]);
    let fault = fault.to_fault(&layout2(), 1e-3).unwrap();
    let mut clean = suite(arm.as_ref(), &[], 9);
    let mut faulty = suite(arm.as_ref(), &[fault], 9);
    let (mut a, mut b) = (
        Readings::missing(&clean.layout()),
        Readings::missing(&clean.layout()),
    );
    let (mut fa, mut cl, mut noise) = (vec![], vec![], vec![]);
    for k in 0..300 {
        clean.read(arm.as_ref(), k, &mut a);
        faulty.read(arm.as_ref(), k, &mut b);
        fa.push(b.values[channel]);
        cl.push(a.values[channel]);
        noise.push(clean.noise()[channel]);
        arm.step(1e-3);
    }
    (fa, cl, noise)
}

/// Before 0.1 s and from 0.2 s the faulty channel equals the clean one.
fn assert_only_between(fa: &[Option<f64>], cl: &[Option<f64>]) {
    for k in (0..100).chain(200..300) {
        assert_eq!(fa[k], cl[k], "tick {k} outside the fault");
    }
}

#[test]
fn freeze_holds_the_reading_of_its_first_tick() {
    let (fa, cl, _) = with_and_without(spec("enc1", FaultKind::Freeze {}, 0.1, Some(0.2)), 0);
    assert_only_between(&fa, &cl);
    for k in 100..200 {
        assert_eq!(fa[k], cl[100], "tick {k}");
    }
    assert_ne!(cl[150], cl[100], "the arm moved meanwhile");
}

#[test]
fn bias_adds_an_offset() {
    let s = spec("cam_u", FaultKind::Bias { offset: 0.04 }, 0.1, Some(0.2));
    let (fa, cl, _) = with_and_without(s, 4);
    assert_only_between(&fa, &cl);
    for k in 100..200 {
        assert!((fa[k].unwrap() - cl[k].unwrap() - 0.04).abs() < 1e-12);
    }
}

#[test]
fn drift_grows_at_its_rate() {
    let s = spec("tach2", FaultKind::Drift { rate: 2.0 }, 0.1, Some(0.2));
    let (fa, cl, _) = with_and_without(s, 3);
    assert_only_between(&fa, &cl);
    for k in 100..200 {
        let expected = 2.0 * (k - 100) as f64 * 1e-3;
        assert!(
            (fa[k].unwrap() - cl[k].unwrap() - expected).abs() < 1e-12,
            "tick {k}"
        );
    }
}

#[test]
fn gain_scales_the_reading() {
    let s = spec("enc2", FaultKind::Gain { factor: 1.5 }, 0.1, Some(0.2));
    let (fa, cl, _) = with_and_without(s, 1);
    assert_only_between(&fa, &cl);
    for k in 100..200 {
        assert!((fa[k].unwrap() - 1.5 * cl[k].unwrap()).abs() < 1e-12);
    }
}

#[test]
fn noise_fault_multiplies_the_noise() {
    let s = spec("enc1", FaultKind::Noise { factor: 10.0 }, 0.1, Some(0.2));
    let (fa, cl, noise) = with_and_without(s, 0);
    assert_only_between(&fa, &cl);
    for k in 100..200 {
        let truth = cl[k].unwrap() - noise[k];
        assert!((fa[k].unwrap() - (truth + 10.0 * noise[k])).abs() < 1e-12);
    }
}

#[test]
fn dropout_makes_the_reading_missing() {
    let (fa, cl, _) = with_and_without(spec("cam", FaultKind::Dropout {}, 0.1, Some(0.2)), 5);
    assert_only_between(&fa, &cl);
    assert!(fa[100..200].iter().all(Option::is_none));
}

#[test]
fn stuck_reports_a_constant() {
    let s = spec("tach1", FaultKind::Stuck { value: 3.0 }, 0.1, Some(0.2));
    let (fa, cl, _) = with_and_without(s, 2);
    assert_only_between(&fa, &cl);
    assert!(fa[100..200].iter().all(|v| *v == Some(3.0)));
}

#[test]
fn spikes_are_outliers_with_the_given_probability() {
    let s = spec(
        "enc1",
        FaultKind::Spikes {
            probability: 0.3,
            magnitude: 0.5,
        },
        0.1,
        Some(0.2),
    );
    let (fa, cl, _) = with_and_without(s, 0);
    assert_only_between(&fa, &cl);
    let mut spikes = 0;
    for k in 100..200 {
        let d = fa[k].unwrap() - cl[k].unwrap();
        assert!(d.abs() < 1e-12 || (d.abs() - 0.5).abs() < 1e-12, "{d}");
        spikes += usize::from(d.abs() > 0.25);
    }
    assert!(
        (10..=50).contains(&spikes),
        "{spikes} spikes in 100 ticks at p = 0.3"
    );
}

/// Timing faults (PX4's delayed, slow, intermittent, garbage), against the clean readings.
#[test]
fn delayed_delivers_the_reading_of_delay_seconds_before() {
    // 0.0234 s at 1 ms: 24 ticks (rounded up).
    let s = spec("enc2", FaultKind::Delayed { delay: 0.0234 }, 0.1, Some(0.2));
    let (fa, cl, _) = with_and_without(s, 1);
    assert_only_between(&fa, &cl);
    for k in 100..200 {
        assert_eq!(fa[k], cl[k - 24], "tick {k}");
    }
    assert_ne!(cl[150], cl[126], "the arm moved meanwhile");
}

#[test]
fn delayed_is_missing_until_the_run_is_old_enough() {
    let s = spec("tach2", FaultKind::Delayed { delay: 0.05 }, 0.0, None);
    let (fa, cl, _) = with_and_without(s, 3);
    assert!(fa[..50].iter().all(Option::is_none));
    for k in 50..300 {
        assert_eq!(fa[k], cl[k - 50], "tick {k}");
    }
}

#[test]
fn slow_holds_each_sample_for_its_period() {
    let s = spec("enc1", FaultKind::Slow { period: 0.02 }, 0.1, Some(0.2));
    let (fa, cl, _) = with_and_without(s, 0);
    assert_only_between(&fa, &cl);
    for k in 100..200 {
        let sampled = 100 + (k - 100) / 20 * 20;
        assert_eq!(fa[k], cl[sampled], "tick {k}");
    }
}

#[test]
fn intermittent_drops_the_first_duty_of_every_cycle() {
    let s = spec(
        "cam_v",
        FaultKind::Intermittent {
            period: 0.01,
            duty: 0.3,
        },
        0.1,
        Some(0.2),
    );
    let (fa, cl, _) = with_and_without(s, 5);
    assert_only_between(&fa, &cl);
    for k in 100..200 {
        let expected = if (k - 100) % 10 < 3 { None } else { cl[k] };
        assert_eq!(fa[k], expected, "tick {k}");
    }
}

#[test]
fn garbage_is_uniform_over_its_range_whatever_the_truth() {
    let s = spec(
        "tach1",
        FaultKind::Garbage {
            low: -2.0,
            high: 6.0,
        },
        0.1,
        Some(0.2),
    );
    let (fa, cl, _) = with_and_without(s, 2);
    assert_only_between(&fa, &cl);
    let values: Vec<f64> = fa[100..200].iter().map(|v| v.unwrap()).collect();
    assert!(values.iter().all(|v| (-2.0..=6.0).contains(v)));
    // Uniform on [-2, 6]: mean 2, sd 8 / sqrt(12) = 2.31; the mean of 100 within 4 sd / 10.
    let mean = values.iter().sum::<f64>() / 100.0;
    assert!((mean - 2.0).abs() < 4.0 * 2.31 / 10.0, "{mean}");
    let below = values.iter().filter(|v| **v < 2.0).count();
    assert!(
        (30..=70).contains(&below),
        "{below} of 100 below the middle"
    );
}

#[test]
fn fault_specs_are_validated_field_by_field() {
    let freeze = FaultKind::Freeze {};
    let cases = [
        (spec("enc3", freeze, 1.0, None), "channel"),
        (spec("enc1", freeze, -1.0, None), "start"),
        (spec("enc1", freeze, 2.0, Some(1.0)), "end"),
        (spec("enc1", freeze, f64::NAN, None), "start"),
        (
            spec("enc1", FaultKind::Bias { offset: f64::NAN }, 1.0, None),
            "offset",
        ),
        (
            spec(
                "enc1",
                FaultKind::Spikes {
                    probability: 2.0,
                    magnitude: 1.0,
                },
                1.0,
                None,
            ),
            "probability",
        ),
        (
            spec("enc1", FaultKind::Delayed { delay: 0.0 }, 1.0, None),
            "delay",
        ),
        // 2 s of 1 ms ticks is allowed, but not 11 s (longer than MAX_DELAY).
        (
            spec("enc1", FaultKind::Delayed { delay: 11.0 }, 1.0, None),
            "delay",
        ),
        // Half a tick: no lower rate.
        (
            spec("enc1", FaultKind::Slow { period: 5e-4 }, 1.0, None),
            "period",
        ),
        (
            spec(
                "enc1",
                FaultKind::Intermittent {
                    period: 0.1,
                    duty: 1.0,
                },
                1.0,
                None,
            ),
            "duty",
        ),
        (
            spec(
                "enc1",
                FaultKind::Garbage {
                    low: 1.0,
                    high: 1.0,
                },
                1.0,
                None,
            ),
            "high",
        ),
    ];
    for (s, field) in cases {
        assert_eq!(
            s.to_fault(&layout2(), 1e-3).unwrap_err().field,
            field,
            "{s:?}"
        );
    }
    // A delay's memory is bounded in ticks: 1 s of 1 us ticks is 1e6 readings per channel; and
    // over a scenario's faults in all (checked by the scenario: 200 delays of 10 s on the
    // paper arm's 6 channels would keep 12e6 readings).
    let many: String = (0..200)
        .map(|_| {
            "[[faults]]\nchannel = [\"enc\", \"tach\", \"cam\"]\nkind = \"delayed\"\n\
             start = 1.0\ndelay = 10.0\n"
        })
        .collect();
    common::assert_refused(&many, "faults");
    let long = spec("enc1", FaultKind::Delayed { delay: 1.0 }, 1.0, None);
    assert!(long.to_fault(&layout2(), 1e-3).is_ok());
    assert_eq!(long.to_fault(&layout2(), 1e-6).unwrap_err().field, "delay");
}

/// A fault as a file writes it: the kind is a tag, its parameters are typed, and a parameter
/// the kind does not have, a missing one or an unknown kind is refused by the parser.
#[test]
fn fault_kinds_parse_as_tagged_data() {
    let parse = |text: &str| toml::from_str::<FaultSpec>(text);
    let f = parse("channel = \"enc1\"\nkind = \"bias\"\nstart = 1.0\noffset = 0.04").unwrap();
    assert_eq!(f.kind, FaultKind::Bias { offset: 0.04 });
    let f =
        parse("channel = [\"enc1\", \"cam\"]\nkind = \"freeze\"\nstart = 1.0\nend = 2.0").unwrap();
    let fault = f.to_fault(&layout2(), 1e-3).unwrap();
    assert_eq!(fault.channels, vec![0, 4, 5]);
    assert_eq!(fault.end, Some(2.0));
    for bad in [
        "channel = \"enc1\"\nkind = \"freeze\"\nstart = 1.0\noffset = 0.04",
        "channel = \"enc1\"\nkind = \"bias\"\nstart = 1.0",
        "channel = \"enc1\"\nkind = \"frezee\"\nstart = 1.0",
        "channel = \"enc1\"\nkind = \"dropout\"\nstart = 1.0\nvalue = 3.0",
    ] {
        assert!(parse(bad).is_err(), "{bad}");
    }
    // Round trip.
    let f = parse(
        "channel = \"tach2\"\nkind = \"spikes\"\nstart = 1.0\nprobability = 0.1\nmagnitude = 2.0",
    )
    .unwrap();
    assert_eq!(parse(&toml::to_string(&f).unwrap()).unwrap(), f);
}

/// Two overlapping faults on one channel apply in file order; each ends on its own.
#[test]
fn overlapping_faults_apply_in_order_and_end_separately() {
    let mut arm = arm("urdf/planar_2dof.urdf");
    arm.set_state(&[-0.5, 0.5], &[0.0, 0.0]);
    let bias = spec("enc1", FaultKind::Bias { offset: 0.1 }, 0.1, Some(0.3))
        .to_fault(&layout2(), 1e-3)
        .unwrap();
    let gain = spec("enc", FaultKind::Gain { factor: 2.0 }, 0.2, Some(0.4))
        .to_fault(&layout2(), 1e-3)
        .unwrap();
    let mut clean = suite(arm.as_ref(), &[], 4);
    let mut faulty = suite(arm.as_ref(), &[bias, gain], 4);
    let l = layout2();
    let (mut a, mut b) = (Readings::missing(&l), Readings::missing(&l));
    for k in 0..500u64 {
        clean.read(arm.as_ref(), k, &mut a);
        faulty.read(arm.as_ref(), k, &mut b);
        let (c, f) = (a.values[0].unwrap(), b.values[0].unwrap());
        let expected = match k {
            100..200 => c + 0.1,
            200..300 => (c + 0.1) * 2.0,
            300..400 => c * 2.0,
            _ => c,
        };
        assert!((f - expected).abs() < 1e-12, "tick {k}: {f} vs {expected}");
        let (c2, f2) = (a.values[1].unwrap(), b.values[1].unwrap());
        let expected2 = if (200..400).contains(&k) {
            c2 * 2.0
        } else {
            c2
        };
        assert!((f2 - expected2).abs() < 1e-12, "enc2 tick {k}");
    }
}

/// An end effector inside another body's collision shape (a link folded back into its parent's
/// hull) is not hidden by that shape: seen from the side, the line of sight enters link 1's box,
/// which holds the tip.
#[test]
fn a_shape_that_contains_the_end_effector_does_not_hide_it() {
    let urdf = r#"<robot name="folded">
  <link name="base"/>
  <joint name="j1" type="revolute">
    <parent link="base"/><child link="l1"/><axis xyz="0 1 0"/>
    <limit lower="-1" upper="1" effort="10" velocity="1"/>
  </joint>
  <link name="l1">
    <inertial><origin xyz="0 0 0.5"/><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.5"/><geometry><box size="0.2 0.2 1.0"/></geometry></collision>
  </link>
  <joint name="j2" type="revolute">
    <parent link="l1"/><child link="l2"/><origin xyz="0 0 1.0" rpy="3.141592653589793 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="10" velocity="1"/>
  </joint>
  <link name="l2">
    <inertial><origin xyz="0 0 0.15"/><mass value="0.5"/><inertia ixx="0.01" iyy="0.01" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.15"/><geometry><cylinder radius="0.02" length="0.3"/></geometry></collision>
  </link>
  <joint name="tip" type="fixed"><parent link="l2"/><child link="ee"/><origin xyz="0 0 0.3"/></joint>
  <link name="ee"/>
</robot>"#;
    let model = std::sync::Arc::new(
        aift::arm::parse_urdf(urdf, std::path::Path::new("folded.urdf")).unwrap(),
    );
    let ee = aift::arm::EndEffector::new(&model, "ee", [0.0; 3]).unwrap();
    let mut arm = aift::arm::Kinematics::new(model.clone());
    arm.set(&[0.0, 0.3]);
    // The tip is at z = 0.7, inside link 1's box (0 <= z <= 1, |x|, |y| <= 0.1).
    let p = aift::plant::ArmPose::ee_position(&arm, &ee);
    assert!((p.z - 0.7).abs() < 1e-12 && p.x.abs() < 1e-12, "{p}");
    let side = Camera::new(CameraConfig {
        position: [3.0, 0.0, 0.7],
        look_at: [0.0, 0.0, 0.7],
        up: [0.0, 0.0, 1.0],
        ..CameraConfig::default()
    });
    let mut image = [0.0; 2];
    assert!(side.observe(&arm, &ee, &mut image).is_ok());
    // Shapes between the camera and the tip still hide it (an_occluded_end_effector_reports_missing).
}

/// docs/method.md, "Sensors": none of the bundled arms' end effectors is ever inside another
/// body's collision shape (on 2000 spread configurations each, joints over +-1.5 rad), so the
/// rule that such a shape does not hide it changes nothing on them.
#[test]
fn no_bundled_end_effector_sits_inside_another_bodys_shape() {
    use aift::plant::ArmPose;
    let mut files: Vec<String> = std::fs::read_dir(common::repo("urdf"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".urdf"))
        .map(|n| format!("urdf/{n}"))
        .collect();
    files.sort();
    assert!(files.len() >= 6, "{files:?}");
    for file in &files {
        let model = common::model(file);
        let ee = common::ee(&model);
        let mut arm = aift::arm::Kinematics::new(model.clone());
        let n = model.joints.len() as u64;
        for k in 0..2000u64 {
            let q: Vec<f64> = (0..n)
                .map(|j| (((k * 2_654_435_761 + j * 40_503) % 1000) as f64 / 1000.0 - 0.5) * 3.0)
                .collect();
            arm.set(&q);
            let p = arm.ee_position(&ee);
            let point = parry3d_f64::math::Vector::new(p.x, p.y, p.z);
            for c in model.colliders.iter().filter(|c| c.body != ee.body) {
                let pose = arm.collision_pose(c.body) * c.parry_pose;
                assert!(
                    !c.parry_shape.contains_point(&pose, point),
                    "{file}: the end effector is inside link {}'s shape at {q:?}",
                    c.link
                );
            }
        }
    }
}
