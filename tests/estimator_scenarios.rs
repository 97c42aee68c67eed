//! The estimator on simulated drives: rejection of bad windows and load changes.

use leveld::estimator::{Estimator, EstimatorConfig, Event, RejectReason};
use leveld::sim::{Input, Road, Scenario, Sensors, SpeedProfile, Vehicle, simulate};

fn run(sc: &Scenario, cfg: EstimatorConfig) -> (Vec<Event>, Estimator, leveld::sim::Drive) {
    let drive = simulate(sc);
    let mut est = Estimator::new(cfg).unwrap();
    let mut events = Vec::new();
    for i in drive.merged() {
        match i {
            Input::Imu(s) => est.push_imu(s, &mut |e| events.push(e)),
            Input::Wheels(w) => est.push_wheels(w, &mut |e| events.push(e)),
        }
    }
    est.finish(drive.imu.last().unwrap().t_s, &mut |e| events.push(e));
    (events, est, drive)
}

fn accepted(ev: &[Event]) -> usize {
    ev.iter()
        .filter(|e| matches!(e, Event::WindowAccepted { .. }))
        .count()
}

fn rejected_by(ev: &[Event], f: impl Fn(&RejectReason) -> bool) -> usize {
    ev.iter()
        .filter(|e| matches!(e, Event::WindowRejected { reason, .. } if f(reason)))
        .count()
}

fn base(seed: u64) -> Scenario {
    Scenario {
        speed: SpeedProfile::default()
            .stop_go(3.0, 2.0, 5.0, 2.0, 2.0)
            .hold(3.0),
        road: Road::default(),
        load_pitch_deg: 0.5,
        load_changes: vec![],
        vehicle: Vehicle::rigid(),
        sensors: Sensors::default(),
        shocks: Vec::new(),
        imu_gaps: Vec::new(),
        seed,
    }
}

#[test]
fn straight_drive_gives_both_windows() {
    let (ev, est, _) = run(&base(1), EstimatorConfig::default());
    assert_eq!(accepted(&ev), 2, "{ev:#?}");
    assert!((est.estimate().unwrap().road_to_body_deg - 0.5).abs() < 0.3);
}

#[test]
fn turning_windows_are_rejected() {
    // A 20 m radius turn starting right at the stop line and right before the next stop.
    let mut sc = base(2);
    sc.road.curves = vec![(0.0, 6.0, 1.0 / 20.0), (16.0, 40.0, -1.0 / 20.0)];
    let (ev, _, _) = run(&sc, EstimatorConfig::default());
    assert_eq!(accepted(&ev), 0, "{ev:#?}");
    assert_eq!(
        rejected_by(&ev, |r| matches!(r, RejectReason::Turning { .. })),
        2,
        "{ev:#?}"
    );
    // Control: the same drive without the turns is accepted, so the rejection is the turn's doing.
    let (ev, _, _) = run(&base(2), EstimatorConfig::default());
    assert_eq!(accepted(&ev), 2);
}

#[test]
fn slope_change_inside_a_window_is_rejected() {
    // The body rests on both axles (wheelbase 2.7 m), so its pitch-centre path bends
    // when an axle crosses a grade change. Place a 12 % grade so that the front axle
    // meets it 1 m into the window after the first stop, and leaves it 1 m before the
    // second stop (22.5 m of travel).
    let mut sc = base(3);
    sc.sensors = Sensors::ideal();
    let g = 0.12f64.atan().to_degrees();
    let half_wb = sc.vehicle.wheelbase_m / 2.0;
    let (up, down) = (1.0 + half_wb, 21.5 + half_wb);
    sc.road.grade_deg = vec![(up, 0.0), (up + 0.1, g), (down, g), (down + 0.1, 0.0)];
    let (ev, _, _) = run(&sc, EstimatorConfig::default());
    assert_eq!(accepted(&ev), 0, "{ev:#?}");
    assert_eq!(
        rejected_by(&ev, |r| matches!(r, RejectReason::SlopeNotConstant { .. })),
        2,
        "{ev:#?}"
    );
    // Control: the same grade reached well outside the windows is accepted.
    sc.road.grade_deg = vec![(6.0, 0.0), (6.1, g), (16.0, g), (16.1, 0.0)];
    let (ev, _, _) = run(&sc, EstimatorConfig::default());
    assert_eq!(accepted(&ev), 2, "{ev:#?}");
}

#[test]
fn load_step_at_standstill_is_followed_before_and_after_moving_off() {
    // Four stop-go cycles to converge, then a 1.0 deg load step during a long stop, then more cycles.
    let mut speed = SpeedProfile::default();
    for _ in 0..4 {
        speed = speed.stop_go(4.0, 2.0, 6.0, 3.0, 2.0);
    }
    speed = speed.hold(12.0);
    let t_step = speed.duration_s() - 9.0;
    for _ in 0..3 {
        speed = speed.stop_go(4.0, 2.0, 6.0, 3.0, 2.0);
    }
    speed = speed.hold(4.0);
    let sc = Scenario {
        speed,
        road: Road::constant(2.0),
        load_pitch_deg: 0.2,
        load_changes: vec![(t_step, 1.2, 1.5)],
        vehicle: Vehicle::default(),
        sensors: Sensors::default(),
        shocks: Vec::new(),
        imu_gaps: Vec::new(),
        seed: 9,
    };
    let (ev, est, drive) = run(&sc, EstimatorConfig::default());
    let change = ev.iter().find_map(|e| match e {
        Event::LoadChanged {
            t_s,
            delta_deg,
            estimate,
        } => Some((*t_s, *delta_deg, *estimate)),
        _ => None,
    });
    let (t_change, delta, estimate) = change.expect("the load change must be detected");
    // Seen while the car still stands (before the next drive-off at t_step + 9 s).
    assert!(t_change > t_step && t_change < t_step + 9.0, "{t_change}");
    assert!((delta - 1.0).abs() < 0.05, "delta {delta}");
    let after = estimate
        .expect("there was an estimate to shift")
        .road_to_body_deg;
    assert!(
        (after - 1.2).abs() < 0.1,
        "estimate right after the step: {after}"
    );
    // Within 3 accepted windows after moving off it is still within 0.1 deg.
    let mut n = 0;
    for e in ev.iter() {
        if let Event::WindowAccepted { window, estimate } = e
            && window.t_s > t_change
        {
            n += 1;
            assert!(
                (estimate.road_to_body_deg - 1.2).abs() < 0.1,
                "window {n}: {estimate:?}"
            );
            if n == 3 {
                break;
            }
        }
    }
    assert_eq!(n, 3, "three windows must follow the step");
    let truth = drive.truth.last().unwrap().load_pitch_deg;
    assert!((est.estimate().unwrap().road_to_body_deg - truth).abs() < 0.1);
}

/// A drive that starts and ends at rest on a constant grade.
fn parked_drive(grade_deg: f64, load_pitch_deg: f64, seed: u64) -> Scenario {
    let mut speed = SpeedProfile::default();
    for _ in 0..3 {
        speed = speed.stop_go(8.0, 2.0, 6.0, 3.0, 2.0);
    }
    Scenario {
        speed: speed.hold(8.0),
        road: Road::constant(grade_deg),
        load_pitch_deg,
        load_changes: vec![],
        vehicle: Vehicle::default(),
        sensors: Sensors::default(),
        shocks: Vec::new(),
        imu_gaps: Vec::new(),
        seed,
    }
}

fn feed(est: &mut Estimator, sc: &Scenario) -> Vec<Event> {
    let drive = simulate(sc);
    let mut events = Vec::new();
    for i in drive.merged() {
        match i {
            Input::Imu(s) => est.push_imu(s, &mut |e| events.push(e)),
            Input::Wheels(w) => est.push_wheels(w, &mut |e| events.push(e)),
        }
    }
    events
}

#[test]
fn after_a_restart_a_different_grade_is_not_taken_for_a_load_change() {
    // Parked on level ground; restarted (a crash, or a tow) on a 4 % grade with the same load.
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    feed(&mut est, &parked_drive(0.0, 0.5, 1));
    let saved = est.state();
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    est.restore(&saved).unwrap();
    let ev = feed(&mut est, &parked_drive(0.04f64.atan().to_degrees(), 0.5, 2));
    assert!(
        ev.iter()
            .any(|e| matches!(e, Event::LoadChangeSuspected { .. })),
        "the step must be noticed"
    );
    assert!(
        !ev.iter().any(|e| matches!(e, Event::LoadChanged { .. })),
        "and refuted by the windows"
    );
    assert!(
        (est.estimate().unwrap().road_to_body_deg - 0.5).abs() < 0.1,
        "{:?}",
        est.estimate()
    );
}

#[test]
fn loading_while_parked_is_confirmed_by_the_first_window_after_restart() {
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    feed(&mut est, &parked_drive(0.0, 0.5, 3));
    let saved = est.state();
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    est.restore(&saved).unwrap();
    // Same place, boot loaded while off: the body pitches up by 1 deg.
    let ev = feed(&mut est, &parked_drive(0.0, 1.5, 4));
    let applied = ev.iter().find_map(|e| match e {
        Event::LoadChanged { delta_deg, .. } => Some(*delta_deg),
        _ => None,
    });
    assert!((applied.expect("confirmed load change") - 1.0).abs() < 0.05);
    assert!(
        (est.estimate().unwrap().road_to_body_deg - 1.5).abs() < 0.1,
        "{:?}",
        est.estimate()
    );
}

#[test]
fn the_accelerometer_bias_learnt_at_stops_survives_a_restart_and_a_corrupt_one_is_refused() {
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    feed(&mut est, &parked_drive(0.0, 0.5, 5));
    let saved = est.state();
    let stop = saved
        .stop_gravity_mps2
        .expect("a settled stop feeds the bias filter");
    let mut restored = Estimator::new(EstimatorConfig::default()).unwrap();
    restored.restore(&saved).unwrap();
    assert_eq!(restored.state().stop_gravity_mps2, Some(stop));
    for bad in [
        [f64::NAN, 0.0, 0.0],
        [9.8, 3.0, 0.0],
        [9.8, 0.0, f64::INFINITY],
        [0.5, 0.0, 0.0],
    ] {
        let corrupt = leveld::estimator::EstimatorState {
            stop_gravity_mps2: Some(bad),
            ..saved.clone()
        };
        let err = Estimator::new(EstimatorConfig::default())
            .unwrap()
            .restore(&corrupt)
            .expect_err("an implausible bias must be refused");
        assert!(err.to_string().contains("stop_gravity_mps2"), "{err}");
    }
    // What the stops knew of the bias, and the windows' travel yaw, are refused when
    // they cannot be.
    let sd = saved.stop_bias_sd_mps2.expect("kept with the bias");
    assert!(sd.iter().all(|s| s.is_finite() && *s > 0.0), "{sd:?}");
    for (bad_sd, bad_yaw, field) in [
        (Some([-0.1, 0.2]), None, "stop_bias_sd_mps2"),
        (Some([0.2, f64::NAN]), None, "stop_bias_sd_mps2"),
        (None, Some((f64::INFINITY, 3)), "travel_yaw"),
        (None, Some((0.5, 3)), "travel_yaw"),
    ] {
        let corrupt = leveld::estimator::EstimatorState {
            stop_bias_sd_mps2: bad_sd,
            travel_yaw: bad_yaw,
            ..saved.clone()
        };
        let err = Estimator::new(EstimatorConfig::default())
            .unwrap()
            .restore(&corrupt)
            .expect_err("an implausible record must be refused");
        assert!(err.to_string().contains(field), "{err}");
    }
    // A pitch-mode fit no set of stops could give (a negative sum of squares).
    let mut json = serde_json::to_value(&saved).unwrap();
    json["pitch_mode_fit"] =
        serde_json::json!({"m": [-1.0, 0.0, 1.0], "v": [0.0, 0.0], "stops": 3});
    let corrupt: leveld::estimator::EstimatorState = serde_json::from_value(json).unwrap();
    let err = Estimator::new(EstimatorConfig::default())
        .unwrap()
        .restore(&corrupt)
        .expect_err("an implausible pitch-mode fit must be refused");
    assert!(err.to_string().contains("pitch_mode_fit"), "{err}");
}

/// Estimate minus the load's pitch after ten stops on a constant grade of `grade_pct`,
/// in a car that dives 0.3 deg per m/s^2 and so squats or dives on the grade, deg.
fn error_on_grade(grade_pct: f64, correct: bool) -> f64 {
    let mut speed = SpeedProfile::default();
    for _ in 0..10 {
        speed = speed.stop_go(8.0, 1.5, 6.0, 1.0, 1.5);
    }
    let sc = Scenario {
        speed: speed.hold(8.0),
        road: Road::constant(grade_pct.atan2(100.0).to_degrees()),
        vehicle: Vehicle::default(),
        ..base(7)
    };
    assert!(sc.vehicle.pitch_from_grade && sc.vehicle.pitch_per_accel_deg == 0.3);
    let cfg = EstimatorConfig {
        correct_grade_pitch: correct,
        ..EstimatorConfig::default()
    };
    let (_, est, drive) = run(&sc, cfg);
    let t = drive.imu.last().unwrap().t_s;
    if correct {
        // What braking and pulling away taught is kept across a restart; a corrupt
        // record is refused.
        let saved = est.state();
        let mut restored = Estimator::new(EstimatorConfig::default()).unwrap();
        restored.restore(&saved).unwrap();
        assert_eq!(restored.pitch_per_force_deg(), est.pitch_per_force_deg());
        assert_eq!(restored.squat_per_force_deg(), est.squat_per_force_deg());
        for (record, key) in [("grade_pitch", "sum_aa"), ("squat_pitch", "sum_pp")] {
            let mut json = serde_json::to_value(&saved).unwrap();
            json[record][key] = serde_json::json!(-1.0);
            let corrupt: leveld::estimator::EstimatorState = serde_json::from_value(json).unwrap();
            let err = restored
                .restore(&corrupt)
                .expect_err("a negative sum of squares");
            assert!(err.to_string().contains(record), "{err}");
        }
    }
    est.estimate().unwrap().road_to_body_deg - drive.truth_at(t).load_pitch_deg
}

#[test]
fn the_squat_of_a_body_standing_on_a_grade_is_not_taken_for_load() {
    // Held on a 15 % grade the brakes pass the body g sin(grade) = 1.46 m/s^2: 0.44 deg
    // of squat facing uphill, of dive facing downhill, in every window's reference.
    let (up, down) = (error_on_grade(15.0, false), error_on_grade(-15.0, false));
    assert!(
        up > 0.3 && down < -0.3,
        "uncorrected: {up:+.3} / {down:+.3}"
    );
    // The dive learnt from braking takes it out. Left: the dive's lag behind the
    // braking and the prior, a few percent of it, and the windows' own noise.
    let (up, down) = (error_on_grade(15.0, true), error_on_grade(-15.0, true));
    assert!(
        up.abs() < 0.1 && down.abs() < 0.1,
        "corrected: {up:+.3} / {down:+.3}"
    );
}

/// The body still rocks (1.3 Hz, 0.1 deg, decaying over seconds) as the first
/// standstill begins, where the gyro bias is first taken from the mean rate.
#[test]
fn a_first_standstill_begun_on_a_rocking_body_does_not_keep_the_bias_from_settling() {
    let mut speed = SpeedProfile::default().hold(10.0);
    for _ in 0..4 {
        speed = speed.stop_go(0.0, 1.5, 6.0, 1.0, 1.5).hold(8.0);
    }
    let sc = Scenario {
        speed,
        shocks: vec![leveld::sim::scenario::Shock {
            t_s: 0.0,
            amplitude_deg: 0.1,
            freq_hz: 1.3,
            decay_s: 1.5,
        }],
        ..base(3)
    };
    let (ev, _, _) = run(&sc, EstimatorConfig::default());
    let ended_early = ev
        .iter()
        .filter(|e| matches!(e, Event::StandstillEnded { duration_s, .. } if *duration_s < 5.0))
        .count();
    assert_eq!(
        ended_early, 0,
        "standstills ended while the car stood: {ev:?}"
    );
    assert!(accepted(&ev) >= 6, "{} windows", accepted(&ev));
}
