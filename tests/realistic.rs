//! The physics of real drives that leveld must not be fooled by, each on a short drive
//! of the realistic family with fixed seeds. Tolerances come from the measured spread
//! of single windows (about 0.2 deg rms on these drives) over the windows involved.

use leveld::bench::realistic::{RealisticSpec, StopKind};
use leveld::bench::stops::{StopChecks, check};
use leveld::bench::suite::{Case, DriveSpec};
use leveld::estimator::{Condition, Estimate, Estimator, EstimatorConfig, Event, RejectReason};
use leveld::sim::{Input, Sensors, simulate};

/// Text of a shipped realistic scenario file.
fn shipped(name: &str) -> String {
    std::fs::read_to_string(format!(
        "{}/scenarios/realistic/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap()
}

fn spec(seed: u64, stops: usize, r: RealisticSpec) -> DriveSpec {
    let text = shipped("urban");
    let mut s = DriveSpec::parse(&text).unwrap();
    s.seed = seed;
    s.stops = stops;
    s.distance_km = Some(0.25 * stops as f64);
    s.turn_share = 0.0;
    s.hold_s = [8.0, 15.0];
    s.realistic = Some(r);
    s
}

/// `s` with its sensors changed by `change`.
fn with_sensors(mut s: DriveSpec, change: impl FnOnce(&mut Sensors)) -> DriveSpec {
    let mut sensors = s
        .sensors
        .clone()
        .expect("the urban scenario sets its sensors");
    change(&mut sensors);
    s.sensors = Some(sensors);
    s
}

/// `s` with wheels that read zero below `kmh`.
fn with_dead_zone(s: DriveSpec, kmh: f64) -> DriveSpec {
    with_sensors(s, |x| x.wheel_zero_below_kmh = kmh)
}

/// Every event leveld, as configured by default, emits over `drive`.
fn drive_events(drive: &leveld::sim::Drive) -> Vec<Event> {
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    let mut ev = Vec::new();
    for input in drive.merged() {
        match input {
            Input::Imu(x) => est.push_imu(x, &mut |e| ev.push(e)),
            Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
        }
    }
    ev
}

/// The first load change leveld applied after `from_s` and before `to_s`, deg.
fn load_change_between(ev: &[Event], from_s: f64, to_s: f64) -> Option<f64> {
    ev.iter().find_map(|e| match e {
        Event::LoadChanged { t_s, delta_deg, .. } if *t_s > from_s && *t_s < to_s => {
            Some(*delta_deg)
        }
        _ => None,
    })
}

fn valid(e: &Estimate) -> bool {
    e.std_err_deg <= 0.06 && e.weight >= 4.0
}

fn checks(s: &DriveSpec, load: usize) -> StopChecks {
    check(&s.cases()[load], &valid)
}

/// Every stop is left gently, the wheels read zero below 1.8 km/h.
fn gentle() -> RealisticSpec {
    RealisticSpec {
        gentle_start_share: 1.0,
        rolling_stop_share: 0.0,
        short_stop_share: 0.0,
        door_shock_share: 0.0,
        imu_gap_share: 0.0,
        ..RealisticSpec::default()
    }
}

/// An INS-grade IMU: 30 ug/sqrt(Hz), gyro 0.003 deg/s/sqrt(Hz), little drift.
fn ins_grade(x: &mut Sensors) {
    x.acc_noise_ug_rthz = 30.0;
    x.acc_bias_walk_mps2_rts = 0.0001;
    x.gyro_noise_dps_rthz = 0.003;
    x.gyro_bias_walk_dps_rts = 0.0005;
}

/// Root mean square of window errors, deg.
fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// Loads that start to come in about a second into a stop of its full length, with a
/// door shock at every stop: on some stops nothing settles before the ramp.
fn early_ramp_with_shocks() -> RealisticSpec {
    RealisticSpec {
        load_stop_short_share: 0.0,
        load_change_delay_s: [0.8, 1.2],
        door_shock_share: 1.0,
        ..gentle()
    }
}

/// The family with every drive-off brisk, no rolling stop and no stop too short to settle.
fn brisk() -> RealisticSpec {
    RealisticSpec {
        gentle_start_share: 0.0,
        rolling_stop_share: 0.0,
        short_stop_share: 0.0,
        ..RealisticSpec::default()
    }
}

#[test]
fn gentle_drive_offs_in_the_wheel_dead_zone_give_unbiased_windows() {
    let (mut n, mut ok, mut errs) = (0, 0, Vec::new());
    for seed in [11, 12] {
        let s = spec(seed, 10, gentle());
        let c = checks(&s, 0);
        // Every stop but the first (the drive starts at rest) is left gently, except
        // the one that ends the drive: the car never pulls away from it.
        let case = &s.cases()[0];
        let drive = simulate(&case.scenario);
        let stops = &case.plan.as_ref().unwrap().stops;
        let left = stops[1..]
            .iter()
            .filter(|st| drive.truth.iter().any(|x| x.t_s > st.1 && x.v_mps > 1.0))
            .count();
        assert_eq!(left, stops.len() - 2, "seed {seed}: stops left");
        assert_eq!(c.gentle_drive_offs, left, "seed {seed}: drive-offs counted");
        // Every drive-off without a window has its reason counted, once.
        assert_eq!(
            c.gentle_lost.total(),
            c.gentle_drive_offs - c.gentle_accepted,
            "seed {seed}: reasons of lost drive-offs {:?}",
            c.gentle_lost
        );
        n += c.gentle_drive_offs;
        ok += c.gentle_accepted;
        errs.extend(c.window_errors);
    }
    assert_most_gentle_drive_offs_gave_windows(n, ok);
    // Before the IMU ended the standstill, drive-off samples joined the reference and
    // these windows sat about +0.2 deg off.
    assert_unbiased(&errs, 0.25);
}

#[test]
fn gentle_stops_whose_end_the_wheel_dead_zone_hides_are_not_taken_for_rest_while_braking() {
    // Wheels that read zero below 3 km/h hide the last 1-2 s of a gentle stop: steady
    // braking, a quiet IMU. Taken for rest, its force was the reference of a window
    // 2-4 deg off, the real stop found no standstill, and the drive never reached VALID.
    let (mut n, mut ok, mut errs) = (0, 0, Vec::new());
    for seed in [13, 14] {
        let mut s = with_dead_zone(spec(seed, 10, gentle()), 3.0);
        s.brake_mps2 = [0.5, 1.0];
        let c = checks(&s, 0);
        n += c.gentle_drive_offs;
        ok += c.gentle_accepted;
        errs.extend(c.window_errors);
    }
    assert_most_gentle_drive_offs_gave_windows(n, ok);
    let worst = errs.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    // Four times the 0.25 deg spread of single windows on these drives.
    assert!(worst <= 1.0, "a window {worst:.2} deg off: {errs:?}");
    assert_unbiased(&errs, 0.25);
}

#[test]
fn gentle_drive_offs_toward_a_speed_bump_keep_the_straight_road_before_it() {
    // A speed bump 3 m past every stop line: the front wheels reach it after about
    // 1.5 m, so the 3 m window bends and falls back to its first half. Pulling away at
    // 0.3-0.6 m/s^2, that half lasts 2-3 s, and the accelerometer's noise alone leaves
    // it 2-6 mm from its chord. Held to a quarter of the full window's limit (3 mm)
    // alone, about half of them were refused (13 of these 18 drive-offs gave a
    // window); the limit no longer goes below what the noise leaves.
    let (mut n, mut ok, mut errs) = (0, 0, Vec::new());
    for seed in [41, 42] {
        let mut s = spec(seed, 10, gentle());
        s.bump_share = 1.0;
        let c = checks(&s, 0);
        n += c.gentle_drive_offs;
        ok += c.gentle_accepted;
        errs.extend(c.window_errors);
    }
    assert_most_gentle_drive_offs_gave_windows(n, ok);
    // Gentle windows of 1.5 m are about 0.5 deg rms off on the realistic drives.
    assert_unbiased(&errs, 0.5);
}

/// Of `n` gentle drive-offs, at least 16, `ok` gave a window: 90 % or more.
fn assert_most_gentle_drive_offs_gave_windows(n: usize, ok: usize) {
    assert!(n >= 16, "{n} gentle drive-offs");
    assert!(
        ok as f64 >= 0.9 * n as f64,
        "{ok} of {n} gentle drive-offs gave a window"
    );
}

/// The mean of `errs` is within three standard errors of zero, for single windows of
/// `window_rms_deg` spread.
fn assert_unbiased(errs: &[f64], window_rms_deg: f64) {
    let mean = errs.iter().sum::<f64>() / errs.len() as f64;
    let bound = 3.0 * window_rms_deg / (errs.len() as f64).sqrt();
    assert!(
        mean.abs() <= bound,
        "mean window error {mean:+.3} over {} windows, bound {bound:.3}",
        errs.len()
    );
}

/// Stops of 1-2 s, too short for the body to stop rocking before the car pulls away
/// gently: where a standstill began, the drive-off must still give a window.
#[test]
fn gentle_drive_offs_from_stops_too_short_to_settle_give_windows() {
    let r = RealisticSpec {
        short_stop_share: 1.0,
        ..gentle()
    };
    let (mut n, mut ok, mut errs) = (0, 0, Vec::new());
    for seed in [31, 32, 33] {
        let c = checks(&spec(seed, 10, r.clone()), 0);
        // A stop of a second in the wheels' dead zone may end before a standstill can
        // begin (the wheels read zero for 1 s, the IMU quiet for 0.5 s): no window.
        n += c.gentle_drive_offs - c.gentle_lost.no_standstill;
        ok += c.gentle_accepted;
        errs.extend(c.window_errors);
    }
    assert!(n >= 20, "{n} gentle drive-offs from a standstill");
    // With the rest taken from the raw force, the rocking hid it: 16 of 25 gave a window.
    assert!(
        ok as f64 >= 0.9 * n as f64,
        "{ok} of {n} gentle drive-offs gave a window"
    );
    // Windows of stops that never settled are 0.62 deg rms off (realistic drives).
    assert_unbiased(&errs, 0.62);
}

/// With a quiet accelerometer a gentle window is nearly as good as a brisk one, and the
/// window of a stop too short to settle worse than its walk's noise says: the weights
/// follow the noise learnt at rest (`noise_scaled_weights`). INS-grade urban and
/// stop-and-go drives, both loads, reach VALID within five stops more often than when
/// weighed as at 300 ug/sqrt(Hz).
#[test]
fn a_quiet_imu_counts_its_gentle_windows_and_reaches_valid_sooner() {
    let (mut valid_soon, mut drives) = (0, 0);
    for (name, seeds) in [("urban", 101..105), ("stop-and-go", 301..305)] {
        for seed in seeds {
            let mut s = DriveSpec::parse(&shipped(name)).unwrap();
            s.seed = seed;
            let s = with_sensors(s, ins_grade);
            for load in 0..2 {
                let v = checks(&s, load).valid_within_5_stops.expect("16 stops");
                valid_soon += usize::from(v);
                drives += 1;
            }
        }
    }
    // Measured: 12 of 16; weighed as at 300 ug/sqrt(Hz), 9.
    assert!(
        valid_soon >= 11,
        "VALID within five stops on {valid_soon} of {drives} drives"
    );
}

/// The methods of a run that compares leveld as configured by default ("on") with
/// leveld as `off` configures it.
fn default_and<const N: usize>(
    offs: [EstimatorConfig; N],
) -> impl Fn() -> Vec<Box<dyn leveld::bench::baselines::PitchMethod>> {
    use leveld::bench::baselines::{Leveld, PitchMethod};
    move || {
        let mut methods: Vec<Box<dyn PitchMethod>> =
            vec![Box::new(Leveld::new(EstimatorConfig::default(), "on"))];
        for off in &offs {
            methods.push(Box::new(Leveld::new(off.clone(), "off")));
        }
        methods
    }
}

/// The stops learn the accelerometer's x bias from stops at different grades, over many
/// of them on roads that are nearly level. A window measured before then is off by what
/// the body's dive or squat turns of the bias not yet known into the vertical, and by as
/// much again through its reference's tilt, which moves the pitch taken out for its
/// grade: 0.1 deg for 0.2 m/s^2 on a body that pitches 0.25 deg per m/s^2, in every
/// window of the car. Read with the bias known now (`rebias_windows`), INS-grade urban
/// and bumpy drives (biases of up to 0.3 m/s^2, as drawn) are nearer the truth while
/// VALID.
#[test]
fn windows_measured_before_the_bias_was_known_are_read_with_the_bias_known_now() {
    use leveld::bench::accuracy::run_case;
    let make = default_and([EstimatorConfig {
        rebias_windows: false,
        ..EstimatorConfig::default()
    }]);
    let (mut on, mut off) = (Vec::new(), Vec::new());
    for (name, seeds) in [("urban", 101..105), ("bumpy", 401..405)] {
        for seed in seeds {
            let mut s = DriveSpec::parse(&shipped(name)).unwrap();
            s.seed = seed;
            let s = with_sensors(s, ins_grade);
            for case in s.cases() {
                let rows = run_case(&case, &make);
                on.push(rows[0].mean_err_deg);
                off.push(rows[1].mean_err_deg);
            }
        }
    }
    // Measured: 0.036 deg rms over the 16 drives, 0.046 with each window left as
    // measured (the worst drive 0.087 against 0.114).
    let (on, off) = (rms(&on), rms(&off));
    assert!(
        on < 0.85 * off,
        "drives' mean errors {on:.4} deg rms, {off:.4} with windows left as measured"
    );
}

/// A body that squats half as much pulling away as it dives braking (anti-squat and
/// anti-dive geometry differ): with a quiet accelerometer an acceleration window's walk
/// one wheelbase out takes out the pitch the force gave the body there, and with the
/// dive's k in place of the squat's every such window of the car is off alike. Learnt
/// apart (`learn_squat`), INS-grade hilly and urban drives of such a car are nearer the
/// truth while VALID, and those of a car that squats as it dives lose nothing. The
/// windows of a drive's first stops, taken before the squat was learnt, are read with
/// the squat learnt since (`follow_learnt_pitch`).
#[test]
fn a_body_that_squats_less_than_it_dives_has_its_squat_learnt_apart() {
    use leveld::bench::accuracy::run_case;
    let make = default_and([
        EstimatorConfig {
            learn_squat: false,
            ..EstimatorConfig::default()
        },
        EstimatorConfig {
            follow_learnt_pitch: false,
            ..EstimatorConfig::default()
        },
    ]);
    let drives = |squat_share: f64| {
        let (mut on, mut off, mut kept) = (Vec::new(), Vec::new(), Vec::new());
        for (name, seeds) in [("hilly", 201..205), ("urban", 101..105)] {
            for seed in seeds {
                let mut s = DriveSpec::parse(&shipped(name)).unwrap();
                s.seed = seed;
                let r = s.realistic.as_mut().expect("the scenario is realistic");
                r.squat_share = [squat_share; 2];
                let s = with_sensors(s, ins_grade);
                for case in s.cases() {
                    let rows = run_case(&case, &make);
                    on.push(rows[0].mean_err_deg);
                    off.push(rows[1].mean_err_deg);
                    kept.push(rows[2].mean_err_deg);
                }
            }
        }
        (rms(&on), rms(&off), rms(&kept))
    };
    // Measured: 0.018 deg rms over the 16 drives, 0.033 with the squat taken as the
    // dive and 0.024 with each window kept as measured; alike, 0.021, 0.021 and 0.020
    // (the bounds leave a thousandth of scatter against the dive, and the 16 drives'
    // spread against the windows kept: over each realistic file's 16 seeds, 128
    // drives, following the squat learnt gave 0.0376 against 0.0386).
    let (on, off, kept) = drives(0.5);
    assert!(
        on < 0.85 * off,
        "half the squat: drives' mean errors {on:.4} deg rms, {off:.4} with the squat as the dive"
    );
    assert!(
        on < 0.8 * kept,
        "half the squat: drives' mean errors {on:.4} deg rms, {kept:.4} with windows kept as measured"
    );
    let (on, off, kept) = drives(1.0);
    assert!(
        on < 1.05 * off,
        "squat as the dive: drives' mean errors {on:.4} deg rms, {off:.4} not learnt apart"
    );
    assert!(
        on < 1.1 * kept,
        "squat as the dive: drives' mean errors {on:.4} deg rms, {kept:.4} with windows kept as measured"
    );
}

/// A car that pulls away at 0.15-0.3 m/s^2 and turns right after is turning by the time
/// its wheels leave the dead zone: the outer wheels read 1.8 km/h while the inner ones
/// still read zero, and the mean of all four said half the speed. The first-speed check
/// refused such windows as a speed mismatch and took the stop's deceleration window
/// back out at 7 stops of 128 drives (4 scenarios, 16 seeds, both loads); the wheels
/// that read zero are now left out of that speed.
#[test]
fn a_wheel_still_in_the_dead_zone_does_not_halve_the_speed_a_window_is_checked_with() {
    let set = ["realistic.gentle_accel_mps2=[0.15, 0.3]".to_string()];
    let mut s = DriveSpec::parse_with(&shipped("urban"), &set).unwrap();
    s.seed = 107;
    for case in s.cases() {
        let ev = drive_events(&simulate(&case.scenario));
        let refused: Vec<_> = ev
            .iter()
            .filter(|e| {
                matches!(
                    e,
                    Event::WindowWithdrawn { .. }
                        | Event::WindowRejected {
                            reason: RejectReason::SpeedMismatch { .. },
                            ..
                        }
                )
            })
            .collect();
        assert!(refused.is_empty(), "{}: {refused:?}", case.load);
    }
}

/// An ESC derives its wheel speeds from tooth periods and filters them: a frame carries
/// a speed some tens of milliseconds old. Compared with the IMU's speed at the frame's
/// own time, a brisk drive-off (2 m/s^2) read 0.2 m/s apart at 0.1 s; its window was
/// refused as a speed mismatch, and braking read as much apart at the last wheel
/// reading before rest, so whole stops found no standstill (realistic urban, 4 seeds:
/// 188 -> 130 windows, 3 of 4 drives with a load change never VALID).
#[test]
fn wheel_speeds_a_tenth_of_a_second_old_cost_no_window() {
    for seed in [41, 42] {
        let s = spec(seed, 10, brisk());
        let count = |delay_s: f64| {
            let s = with_sensors(s.clone(), |x| x.wheel_delay_s = delay_s);
            let ev = drive_events(&simulate(&s.cases()[0].scenario));
            let n = |f: &dyn Fn(&Event) -> bool| ev.iter().filter(|e| f(e)).count();
            (
                n(&|e| matches!(e, Event::StandstillStarted { .. })),
                n(&|e| matches!(e, Event::WindowAccepted { .. })),
                n(&|e| {
                    matches!(
                        e,
                        Event::WindowRejected {
                            reason: RejectReason::SpeedMismatch { .. },
                            ..
                        }
                    )
                }),
            )
        };
        let (stops, windows, _) = count(0.0);
        assert!(
            windows >= 12,
            "seed {seed}: {windows} windows on fresh wheels"
        );
        let (late_stops, late_windows, mismatches) = count(0.1);
        assert_eq!(
            mismatches, 0,
            "seed {seed}: windows refused for the wheels' age"
        );
        assert_eq!(late_stops, stops, "seed {seed}: standstills");
        assert!(
            late_windows + 1 >= windows,
            "seed {seed}: {late_windows} windows with wheels 0.1 s old, {windows} fresh"
        );
    }
}

/// An accelerometer five times noisier than the family's (1500 ug/sqrt(Hz), 0.15 m/s^2
/// per 100 Hz sample, or an engine's vibration at idle) fails the stillness gate of
/// 0.15 m/s^2 on noise alone. The gates widen with the noise learnt while the wheels
/// read zero, so the stops are still found and give windows; with `scale_acc_gates`
/// off, none is.
#[test]
fn a_noisy_accelerometer_still_finds_its_stops() {
    let count = |s: &DriveSpec, cfg: EstimatorConfig| {
        let drive = simulate(&s.cases()[0].scenario);
        let mut est = Estimator::new(cfg).unwrap();
        let (mut stops, mut windows) = (0usize, 0usize);
        for input in drive.merged() {
            let mut seen = |e: Event| match e {
                Event::StandstillStarted { .. } => stops += 1,
                Event::WindowAccepted { .. } => windows += 1,
                _ => {}
            };
            match input {
                Input::Imu(x) => est.push_imu(x, &mut seen),
                Input::Wheels(w) => est.push_wheels(w, &mut seen),
            }
        }
        (stops, windows)
    };
    for seed in [43, 44] {
        let s = spec(seed, 10, brisk());
        let (stops, windows) = count(&s, EstimatorConfig::default());
        let noisy = with_sensors(s, |x| x.acc_noise_ug_rthz = 1500.0);
        let (noisy_stops, noisy_windows) = count(&noisy, EstimatorConfig::default());
        let fixed = EstimatorConfig {
            scale_acc_gates: false,
            ..EstimatorConfig::default()
        };
        let (_, fixed_windows) = count(&noisy, fixed);
        // Measured (seeds 43 / 44): 11 / 11 standstills and 20 / 20 windows at 300
        // ug/sqrt(Hz); 11 / 11 and 14 / 13 at 1500; with fixed gates 1 / 2 and 2 / 0.
        assert!(
            noisy_stops.abs_diff(stops) <= 1,
            "seed {seed}: {noisy_stops} standstills at 1500 ug/sqrt(Hz), {stops} at 300"
        );
        assert!(
            2 * noisy_windows >= windows,
            "seed {seed}: {noisy_windows} windows at 1500 ug/sqrt(Hz), {windows} at 300"
        );
        assert!(
            fixed_windows * 4 < noisy_windows,
            "seed {seed}: {fixed_windows} windows with fixed gates, {noisy_windows} widened"
        );
    }
}

/// Shipped urban drive `seed` with 5P, its events, and when its load stop began and
/// ended, s.
fn urban_load_stop(seed: u64) -> (leveld::sim::Drive, Vec<Event>, f64, f64) {
    let mut s = DriveSpec::parse(&shipped("urban")).unwrap();
    s.seed = seed;
    let case = &s.cases()[1];
    let plan = case.plan.as_ref().unwrap();
    let (k, _) = plan.load_change.unwrap();
    let (t_stop, t_go, ..) = plan.stops[k];
    let drive = simulate(&case.scenario);
    let ev = drive_events(&drive);
    (drive, ev, t_stop, t_go)
}

/// Urban seed 104, 5P: the load ramps in 1.9 s into a standstill that began while the
/// body still rocked, with a 0.16 s gap in the IMU frames. Anchored on the raw mean
/// force of the rocking body, the motion tracker saw 0.098 m/s and ended the standstill
/// while the car stood still; the load change was never measured at its stop.
#[test]
fn a_load_change_on_a_body_still_rocking_is_not_taken_for_a_drive_off() {
    let (drive, ev, t_stop, t_go) = urban_load_stop(104);
    // The standstill of the load stop lasts until the car pulls away.
    let ended = ev.iter().find_map(|e| match e {
        Event::StandstillEnded { t_s, .. } if *t_s > t_stop && *t_s < t_go + 2.0 => Some(*t_s),
        _ => None,
    });
    assert!(
        ended.is_some_and(|t| t >= t_go - 0.1),
        "standstill ended at {ended:?}, drive-off at {t_go}"
    );
    // And the step is measured there.
    let step = drive.truth_at(t_go + 1.0).load_pitch_deg - drive.truth_at(t_stop).load_pitch_deg;
    let delta = load_change_between(&ev, t_stop, t_go + 2.0);
    assert!(
        delta.is_some_and(|d| (d - step).abs() <= 0.1),
        "load change {delta:?} against a step of {step:.3}"
    );
}

/// Urban seed 101, 5P: the first quiet moment of the load stop lasted 0.05 s while the
/// body still swung from the stop, and became the reference. The half second of rest
/// after it sat 0.26 deg away and was held as the first half of a load change, until a
/// short block that agreed with the swing dropped it. The step was then measured from
/// the swing: 0.866 deg for 1.000.
#[test]
fn a_reference_caught_in_the_swing_after_a_stop_gives_way_to_the_rest_after_it() {
    let (drive, ev, t_stop, t_go) = urban_load_stop(101);
    let step = drive.truth_at(t_go).load_pitch_deg - drive.truth_at(t_stop).load_pitch_deg;
    let delta = load_change_between(&ev, t_stop, t_go);
    // Within the uncertainty the estimator gives a load step measured at rest.
    assert!(
        delta.is_some_and(|d| (d - step).abs() <= 0.05),
        "load change {delta:?} against a step of {step:.3}"
    );
}

/// A body on worn dampers (pitch mode 0.9-1.0 Hz, damping 0.12-0.18) still swings a
/// tenth of a degree two seconds after a stop. At each turning point its rate crosses
/// zero and the samples pass the rate gates; a reference begun at one stood that far
/// from the rest pitch, and the rest after it, which the gyro saw the body turn to,
/// became a load change. Bumpy seeds 403 and 407 with one person aboard (no load ever
/// changes): 0.13-0.21 deg load changes at stops 8 and 14 with the gate off.
#[test]
fn a_lightly_damped_body_swinging_after_a_stop_is_no_load_change() {
    for seed in [403, 407] {
        let (load_stop, loads) = worn_damper_load_changes("bumpy", seed, 0);
        assert!(load_stop.is_none());
        assert!(loads.is_empty(), "seed {seed}: load changes {loads:?}");
    }
}

/// A span of a drive (from, to), s.
type Span = (f64, f64);

/// The stop a drive's load changes at (stop time, drive-off time), if any, and every
/// load change (time, step in deg) over the drive on a body whose dampers are worn:
/// pitch mode 0.9-1.0 Hz, damping 0.12-0.18.
fn worn_damper_load_changes(name: &str, seed: u64, load: usize) -> (Option<Span>, Vec<(f64, f64)>) {
    let mut s = DriveSpec::parse(&shipped(name)).unwrap();
    s.seed = seed;
    let r = s.realistic.as_mut().expect("the scenario is realistic");
    r.pitch_freq_hz = [0.9, 1.0];
    r.pitch_damping = [0.12, 0.18];
    let case = &s.cases()[load];
    let plan = case.plan.as_ref().unwrap();
    let load_stop = plan
        .load_change
        .map(|(k, _)| (plan.stops[k].0, plan.stops[k].1));
    let loads = drive_events(&simulate(&case.scenario))
        .iter()
        .filter_map(|e| match e {
            Event::LoadChanged { t_s, delta_deg, .. } => Some((*t_s, *delta_deg)),
            _ => None,
        })
        .collect();
    (load_stop, loads)
}

/// Worn dampers again, on drives whose reference at a stop was a block of 5-7 samples
/// (0.05-0.06 s) at a turning point of the swing: the force's step to the rest after it
/// passed the 0.2 deg threshold (0.23-0.27 deg: the swing, the lever arm's acceleration
/// at the turning point, the noise of so few samples), the gyro turned 0.06-0.11 deg,
/// and the step applied, their mean, was 0.14-0.18 deg: below the threshold it was
/// detected by. Urban 103 and 107 with five aboard, hilly 208 with one: with a 1.0 deg
/// load at the sixth stop of the 5P drives, any load change elsewhere is false.
/// Urban 102 with one aboard: a 1.6 s stop settled on five samples 0.9 s after it came
/// to rest, their mean rate (the swing's) became the bias of the gyro's turn since the
/// standstill began, and a -0.43 deg load change followed.
#[test]
fn a_step_from_a_reference_caught_at_a_turning_point_of_the_swing_is_no_load_change() {
    let drives = [
        ("urban", 103, 1),
        ("urban", 107, 1),
        ("hilly", 208, 0),
        ("urban", 102, 0),
    ];
    for (name, seed, load) in drives {
        let (load_stop, loads) = worn_damper_load_changes(name, seed, load);
        let at_stop = |t: f64| load_stop.is_some_and(|(t0, t1)| t >= t0 && t <= t1 + 2.0);
        let elsewhere: Vec<_> = loads.iter().filter(|(t, _)| !at_stop(*t)).collect();
        assert!(
            elsewhere.is_empty(),
            "{name} {seed}: load changes away from the load's stop {elsewhere:?}"
        );
        if load_stop.is_some() {
            let found = loads.iter().any(|(t, _)| at_stop(*t));
            assert!(found, "{name} {seed}: the load's own change was not found");
        }
    }
}

/// Drives whose every stop but the first is rolling (down to 0.05-0.3 m/s, then away)
/// give no window and no load change around those stops.
fn assert_rolling_stops_give_nothing(seeds: &[u64], load: usize, dead_zone_kmh: f64) {
    let r = RealisticSpec {
        rolling_stop_share: 1.0,
        ..gentle()
    };
    assert_stops_give_nothing(r, seeds, load, dead_zone_kmh);
}

fn assert_stops_give_nothing(r: RealisticSpec, seeds: &[u64], load: usize, dead_zone_kmh: f64) {
    for &seed in seeds {
        let s = with_dead_zone(spec(seed, 10, r.clone()), dead_zone_kmh);
        let c = checks(&s, load);
        assert!(c.rolling_stops >= 8, "seed {seed}: {c:?}");
        assert_eq!(c.rolling_with_output, 0, "seed {seed}: {c:?}");
    }
}

#[test]
fn rolling_stops_give_no_window_and_no_load_change() {
    assert_rolling_stops_give_nothing(&[21, 22], 1, 1.8);
}

/// A rolling stop that pulls away at 0.15-0.3 m/s^2 spends 1-3 s in the wheels' dead
/// zone with a force as steady as at rest. Its speed left at the "rest" edge and the
/// pull-away its "gravity" holds make up for each other at any single wheel reading
/// 1.5-2.5 s back, and such stops were taken for standstills, with deceleration
/// windows 0.2-0.95 deg off (57 of 360 rolling stops over seeds 1-40 of this drive gave
/// an output, 2 once the drift is checked); over all the readings the pull-away shows
/// as a drift.
#[test]
fn rolling_stops_that_pull_away_very_gently_give_no_window() {
    assert_stops_give_nothing(very_gentle_rolling_stops(), &[1, 2, 4], 0, 1.8);
}

/// Every stop but the first is rolling, and every pull-away takes 0.15-0.3 m/s^2.
fn very_gentle_rolling_stops() -> RealisticSpec {
    RealisticSpec {
        rolling_stop_share: 1.0,
        gentle_accel_mps2: [0.15, 0.3],
        ..gentle()
    }
}

/// Over seeds 1-40 of the drives above (360 rolling stops), two stops of seed 34 still
/// passed every check at the "rest" edge and gave a deceleration window: 0.08 m/s left
/// at the bottom and a pull-away that made up for it. The IMU then found no drive-off
/// (the car never stopped) and had integrated nothing when the wheels read 0.5 m/s;
/// that speed check now takes the stop's window back out, and the estimate is as it
/// was before the stop.
#[test]
fn a_rolling_stop_taken_for_rest_has_its_window_withdrawn_at_the_first_wheel_speed() {
    let s = with_dead_zone(spec(34, 10, very_gentle_rolling_stops()), 1.8);
    let case = &s.cases()[0];
    let drive = simulate(&case.scenario);
    let ev = drive_events(&drive);
    let mut withdrawn = 0;
    for &(t_stop, _, kind, _) in &case.plan.as_ref().unwrap().stops {
        if kind != StopKind::Rolling {
            continue;
        }
        let near = |t: f64| t > t_stop - 2.0 && t < t_stop + 8.0;
        // The estimate as the events left it, before the stop's window came.
        let (mut current, mut before) = (None, None);
        let mut taken = None;
        for e in &ev {
            match e {
                Event::WindowAccepted { window, estimate } => {
                    if near(window.t_s) {
                        before = current;
                        taken = Some(window.road_to_body_deg);
                    }
                    current = Some(estimate.road_to_body_deg);
                }
                Event::LoadChanged { t_s, .. } if near(*t_s) => {
                    panic!("load change at the rolling stop of {t_stop:.1} s")
                }
                Event::WindowWithdrawn {
                    t_s,
                    road_to_body_deg,
                    estimate,
                    ..
                } if near(*t_s) => {
                    // The same window: its grade's pitch is taken out with the share
                    // fitted now, which that window itself moved by a hair.
                    let taken = taken.take().expect("a window accepted at this stop");
                    assert!(
                        (taken - road_to_body_deg).abs() < 1e-3,
                        "withdrew another window: {road_to_body_deg} for {taken}"
                    );
                    let after = estimate.map(|e| e.road_to_body_deg);
                    current = after;
                    assert!(
                        match (before, after) {
                            (Some(b), Some(a)) => (a - b).abs() < 1e-9,
                            (b, a) => b.is_none() && a.is_none(),
                        },
                        "estimate {before:?} before the window, {after:?} after withdrawing it"
                    );
                    withdrawn += 1;
                }
                Event::WindowWithdrawn { estimate, .. }
                | Event::LoadChanged { estimate, .. }
                | Event::PitchShifted { estimate, .. }
                | Event::WindowsRebiased { estimate, .. } => {
                    current = estimate.map(|e| e.road_to_body_deg)
                }
                _ => {}
            }
        }
        assert_eq!(
            taken, None,
            "a window of the rolling stop at {t_stop:.1} s stands"
        );
    }
    assert!(
        withdrawn >= 1,
        "no window withdrawn: the drive no longer tests this"
    );
}

#[test]
fn rolling_stops_hidden_by_a_wide_wheel_dead_zone_give_no_window() {
    // Wheels that read zero below 3 km/h hide the whole slow part of a rolling stop: the
    // IMU sees braking turn into a steady gentle pull-away and nothing else.
    assert_rolling_stops_give_nothing(&[21, 22, 23], 0, 3.0);
}

#[test]
fn a_load_ramping_in_while_the_stop_settles_is_applied_before_drive_off() {
    // On a smooth road: the check compares the estimate across the stop, and that
    // stop's deceleration window moves it too. On the urban roads' unevenness (0.08 deg
    // rms of body pitch at each stop) the steps were still 1.02, 1.00 and 0.99 deg, but
    // seed 32's window moved an estimate of few windows by 0.16 deg.
    let r = RealisticSpec {
        load_stop_short_share: 0.0,
        road_roughness_1e6_m3: 0.0,
        ..gentle()
    };
    let mut applied = 0;
    for seed in [31, 32, 33] {
        let mut s = spec(seed, 8, r.clone());
        s.load_change_at_stop = Some(4);
        let c = checks(&s, 1);
        assert_eq!(c.load_changes, 1, "{c:?}");
        applied += c.load_applied;
    }
    assert_eq!(
        applied, 3,
        "the load change must be applied at its stop in all three drives"
    );
}

#[test]
fn a_load_ramping_in_is_seen_at_its_stop_not_taken_for_a_drive_off() {
    // Every effect of the realistic family on (gyro bias and its drift, rocking, door
    // shocks, IMU gaps), stops long enough for the ramp to end 1 s before drive-off.
    // The body pitching 1 deg in 3 s tilts the specific force as a 0.17 m/s^2 pull
    // would; the gyro explains nearly all of it, and what it leaves (a bias not yet
    // learnt) adds up far slower than any drive-off picks up speed. So the standstill
    // lasts through the ramp and the change is measured there.
    let r = RealisticSpec {
        load_stop_short_share: 0.0,
        ..RealisticSpec::default()
    };
    let (mut stops, mut seen) = (0, 0);
    for seed in 41..49 {
        let mut s = spec(seed, 8, r.clone());
        s.load_change_at_stop = Some(4);
        let case = &s.cases()[1];
        let plan = case.plan.as_ref().unwrap();
        let (k, _) = plan.load_change.unwrap();
        let (t_stop, t_go, _, _) = plan.stops[k];
        let drive = simulate(&case.scenario);
        let step = drive.truth_at(t_go).load_pitch_deg - drive.truth_at(t_stop).load_pitch_deg;
        if step.abs() < 0.5 {
            continue; // the ramp fell after the drive-off
        }
        let ev = drive_events(&drive);
        let during = |t: f64| t > t_stop && t < t_go;
        let ended_early = ev
            .iter()
            .any(|e| matches!(e, Event::StandstillEnded { t_s, .. } if during(*t_s)));
        let measured = load_change_between(&ev, t_stop, t_go);
        stops += 1;
        let ok = !ended_early && measured.is_some_and(|d| (d - step).abs() <= 0.15);
        seen += usize::from(ok);
        eprintln!("seed {seed}: step {step:+.2}, measured {measured:?}, ended early {ended_early}");
    }
    assert!(stops >= 6, "{stops} load changes");
    assert!(
        seen * 10 >= stops * 9,
        "{seen} of {stops} load changes seen at their stop"
    );
}

#[test]
fn door_shocks_and_imu_gaps_at_every_stop_end_no_standstill_before_drive_off() {
    // A door shock of 0.2-0.4 deg (twice the family's) and a gap in the IMU data at
    // every stop of at least 1.5 s. Where the gap hides the shock's first swing, the
    // samples resume mid-swing; the motion tracker must neither integrate the missing
    // swing into a speed nor re-anchor on the ringing that follows.
    let r = RealisticSpec {
        door_shock_share: 1.0,
        door_shock_deg: [0.2, 0.4],
        imu_gap_share: 1.0,
        ..RealisticSpec::default()
    };
    let (mut stops, mut early) = (0, Vec::new());
    for seed in 51..55 {
        let s = spec(seed, 12, r.clone());
        let case = &s.cases()[0];
        let plan = case.plan.as_ref().unwrap();
        let drive = simulate(&case.scenario);
        let ev = drive_events(&drive);
        let loads = ev.iter().filter(|e| matches!(e, Event::LoadChanged { .. }));
        assert_eq!(
            loads.count(),
            0,
            "seed {seed}: no load changes on this drive"
        );
        for &(t_stop, t_go, kind, _) in &plan.stops {
            if !matches!(kind, StopKind::Full) || t_go - t_stop < 1.5 {
                continue;
            }
            stops += 1;
            // The standstill begins about 1 s after the car stops; it may end only as
            // the car pulls away.
            let ended = ev.iter().find_map(|e| match e {
                Event::StandstillEnded { t_s, .. } if *t_s > t_stop && *t_s < t_go - 0.1 => {
                    Some(*t_s)
                }
                _ => None,
            });
            if let Some(t) = ended {
                early.push((seed, t_stop, t_go, t));
            }
        }
    }
    assert!(stops >= 30, "{stops} stops");
    assert!(early.is_empty(), "standstills ended at rest: {early:?}");
}

#[test]
fn a_load_ramping_in_across_an_imu_gap_is_applied_at_its_stop() {
    // Seed 107 of shipped urban, 5P: the load stop lasts 5.8 s, its ramp ends as the car
    // pulls away, and 0.13 s of IMU data is missing in the middle of the ramp. No
    // settled block follows the gap, so the live pitch must carry the body's turn
    // across it; the turn a ramp makes there is a few hundredths of a degree.
    let mut s = DriveSpec::parse(&shipped("urban")).unwrap();
    s.seed = 107;
    let (drive, t_stop, t_go, step) = load_stop(&s);
    let gaps = &s.cases()[1].scenario.imu_gaps;
    assert!(
        gaps.iter().any(|g| g.0 > t_stop && g.0 < t_go),
        "the load stop has a gap: {gaps:?}"
    );
    let ev = drive_events(&drive);
    let delta = load_change_between(&ev, t_stop, t_go + 0.5);
    assert!(
        delta.is_some_and(|d| (d - step).abs() <= 0.1),
        "load change {delta:?} against a step of {step:.3}"
    );
}

/// Errors of the windows accepted on `case` (deg), of one condition or all.
fn window_errors(case: &Case, cfg: EstimatorConfig, only: Option<Condition>) -> Vec<f64> {
    let drive = simulate(&case.scenario);
    let mut est = Estimator::new(cfg).unwrap();
    let mut ev = Vec::new();
    for input in drive.merged() {
        match input {
            Input::Imu(s) => est.push_imu(s, &mut |e| ev.push(e)),
            Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
        }
    }
    ev.iter()
        .filter_map(|e| match e {
            Event::WindowAccepted { window, .. } if only.is_none_or(|c| c == window.condition) => {
                Some(window.road_to_body_deg - drive.truth_at(window.t_s).load_pitch_deg)
            }
            _ => None,
        })
        .collect()
}

/// Mean error of the deceleration windows of a drive whose IMU sits 0.2 m further out
/// and 0.15 m higher than configured.
fn decel_bias(learn: bool, velocity_free: bool) -> f64 {
    // The road's unevenness pitches the body by about 0.08 deg rms at each stop, which
    // two drives' windows do not average out; the arm's bias is measured without it.
    let r = RealisticSpec {
        lever_arm_m: [2.2, 0.0, 0.45],
        imu_mount_max_deg: [0.0; 3],
        road_roughness_1e6_m3: 0.0,
        ..gentle()
    };
    let mut errs = Vec::new();
    for seed in [41, 42] {
        let case: Case = spec(seed, 12, r.clone()).cases().remove(0);
        let cfg = EstimatorConfig {
            learn_lever_arm: learn,
            velocity_free_slope: velocity_free,
            ..EstimatorConfig::default()
        };
        errs.extend(window_errors(&case, cfg, Some(Condition::DecelBeforeStop)));
    }
    assert!(errs.len() >= 12, "{} deceleration windows", errs.len());
    errs.iter().sum::<f64>() / errs.len() as f64
}

/// A wrong arm mostly gives the walk a wrong start velocity at the stop, where the body
/// swings back from its dive: the chord to the window's end carries it, the
/// velocity-free slope does not. Learning is checked where the arm shows.
#[test]
fn the_lever_arm_learnt_from_rocking_removes_the_bias_of_a_misconfigured_one() {
    let (learnt, fixed) = (decel_bias(true, false), decel_bias(false, false));
    assert!(
        fixed.abs() > 0.1,
        "a 10 % longer arm must show without learning: {fixed:+.3}"
    );
    assert!(
        learnt.abs() < 0.06,
        "learnt {learnt:+.3}, fixed {fixed:+.3}"
    );
    let free = decel_bias(false, true);
    assert!(
        free.abs() < 0.06,
        "the velocity-free slope with the wrong arm, not learnt: {free:+.3}"
    );
}

/// The arm learnt from the rocking stays unbiased with a noisy gyro. Its fit regresses
/// the force on the angular acceleration differentiated from the gyro; samples chosen by
/// that noisy regressor were those whose noise added to the rocking, and with a gyro of
/// 0.05 deg/s/sqrt(Hz) the deceleration windows of these drives sat +0.098 deg off on
/// average (the arm 5 % short); now +0.019. Bound: two standard errors of the mean of
/// about 180 windows 0.38 deg rms.
#[test]
fn a_noisy_gyro_does_not_bias_the_deceleration_windows_through_the_learnt_arm() {
    let mut errs = Vec::new();
    for seed in 101..117 {
        let mut s = DriveSpec::parse(&shipped("urban")).unwrap();
        s.seed = seed;
        let s = with_sensors(s, |x| x.gyro_noise_dps_rthz = 0.05);
        let case: Case = s.cases().remove(0);
        errs.extend(window_errors(
            &case,
            EstimatorConfig::default(),
            Some(Condition::DecelBeforeStop),
        ));
    }
    assert!(errs.len() >= 150, "{} deceleration windows", errs.len());
    let n = errs.len() as f64;
    let mean = errs.iter().sum::<f64>() / n;
    let rms = (errs.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
    println!(
        "deceleration windows: {} mean {mean:+.3} rms {rms:.3}",
        errs.len()
    );
    assert!(
        mean.abs() <= 2.0 * 0.38 / n.sqrt(),
        "mean {mean:+.3} deg over {} windows",
        errs.len()
    );
}

/// Mean window error of a drive with an accelerometer bias of `bias_x_mps2` along the
/// IMU's x axis and a body that dives 0.3 deg per m/s^2.
fn window_mean_with_bias(seed: u64, bias_x_mps2: f64, correct: bool) -> (f64, usize) {
    let mut case: Case = spec(seed, 12, gentle()).cases().remove(0);
    case.scenario.sensors.acc_bias_mps2 = [bias_x_mps2, 0.0, 0.0];
    case.scenario.vehicle.pitch_per_accel_deg = 0.3;
    let cfg = EstimatorConfig {
        correct_acc_bias: correct,
        ..EstimatorConfig::default()
    };
    let errs = window_errors(&case, cfg, None);
    (
        errs.iter().sum::<f64>() / errs.len().max(1) as f64,
        errs.len(),
    )
}

/// The paper's cancellation of an accelerometer bias between the standstill reference
/// and the window holds only while the body keeps its reference attitude. A body that
/// dives 0.3 deg per m/s^2 turns a 0.3 m/s^2 bias into a vertical acceleration of
/// 1.6 mm/s^2 per m/s^2, 0.09 deg on every window, with the sign of the bias. The same
/// drive with the bias reversed (same noise, same stops) shows that split; removing the
/// bias that stops at different grades reveal must take most of it away.
#[test]
fn an_accelerometer_bias_on_a_diving_body_does_not_bias_the_windows() {
    for seed in [41, 42] {
        let split = |correct: bool| {
            let (plus, n) = window_mean_with_bias(seed, 0.3, correct);
            let (minus, m) = window_mean_with_bias(seed, -0.3, correct);
            assert!(n >= 12 && m >= 12, "seed {seed}: {n} and {m} windows");
            plus - minus
        };
        let (raw, corrected) = (split(false), split(true));
        eprintln!("seed {seed}: split {raw:+.3} deg uncorrected, {corrected:+.3} corrected");
        assert!(
            raw.abs() > 0.1,
            "seed {seed}: the coupling must show without the correction: {raw:+.3}"
        );
        assert!(
            corrected.abs() < 0.4 * raw.abs(),
            "seed {seed}: split {corrected:+.3} deg with the correction, {raw:+.3} without"
        );
    }
}

/// A whole realistic urban drive (16 stops, a load change at the 6th in the 5P case):
/// the estimate at the end is inside the 0.2 deg R48 budget, and leveld is more than
/// twice as close to the truth as the Kasaba-style baseline over the drive.
#[test]
fn realistic_urban_drives_end_inside_the_budget_and_beat_the_baseline() {
    // The full family runs in `leveld bench accuracy --scenarios scenarios/realistic/*.toml`.
    let text = shipped("urban");
    let mut s = DriveSpec::parse(&text).unwrap();
    let cases: Vec<_> = [101, 102]
        .into_iter()
        .flat_map(|seed| {
            s.seed = seed;
            s.cases()
        })
        .collect();
    let rows: Vec<Vec<leveld::bench::accuracy::Row>> = std::thread::scope(|sc| {
        let hs: Vec<_> = cases
            .iter()
            .map(|c| {
                sc.spawn(|| leveld::bench::accuracy::run_case(c, &leveld::bench::accuracy::methods))
            })
            .collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let (mut ours, mut theirs) = (0.0, 0.0);
    for (case, rows) in cases.iter().zip(&rows) {
        let seed = case.seed;
        let row = |m: &str| rows.iter().find(|r| r.method == m).unwrap();
        let r = row("leveld");
        let &(_, est, truth) = r
            .track
            .iter()
            .rev()
            .find(|x| x.1.is_finite())
            .expect("an estimate by the end of the drive");
        eprintln!(
            "{} seed {seed}: final {:+.3}, mean abs {:.3}, kasaba {:.3}",
            case.load,
            est - truth,
            r.mean_abs_err_deg,
            row("kasaba").mean_abs_err_deg
        );
        assert!(
            (est - truth).abs() <= 0.2,
            "{} seed {seed}: final estimate {est:.3} vs truth {truth:.3}",
            case.load
        );
        ours += track_abs_err(&r.track);
        theirs += track_abs_err(&row("kasaba").track);
    }
    assert!(
        2.0 * ours < theirs,
        "mean abs error over the drives: leveld {ours:.3}, kasaba {theirs:.3}"
    );
}

/// Replay a drive through the default estimator: its road-to-body estimate as it was
/// at each of `times` (the last one at or before it), deg.
fn estimates_at<const N: usize>(drive: &leveld::sim::Drive, times: [f64; N]) -> [Option<f64>; N] {
    let mut out = [None; N];
    replay(drive, |est, t| {
        let e = est.estimate().map(|e| e.road_to_body_deg);
        for (o, &at) in out.iter_mut().zip(&times) {
            if t <= at {
                *o = e;
            }
        }
    });
    out
}

/// Replay a drive through the default estimator, calling `after` with it and the
/// input's time after each input.
fn replay(drive: &leveld::sim::Drive, mut after: impl FnMut(&Estimator, f64)) {
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    for input in drive.merged() {
        let t = match input {
            Input::Imu(x) => {
                est.push_imu(x, &mut |_| {});
                x.t_s
            }
            Input::Wheels(w) => {
                est.push_wheels(w, &mut |_| {});
                w.t_s
            }
        };
        after(&est, t);
    }
}

/// Mean |estimate - truth| over the second half of a drive (every method has an
/// estimate by then), deg.
fn track_abs_err(track: &[(f64, f64, f64)]) -> f64 {
    let half = &track[track.len() / 2..];
    let e: Vec<f64> = half
        .iter()
        .filter(|x| x.1.is_finite())
        .map(|x| (x.1 - x.2).abs())
        .collect();
    assert!(
        e.len() * 2 > half.len(),
        "estimate missing over half the second half"
    );
    e.iter().sum::<f64>() / e.len() as f64
}

#[test]
fn a_load_still_ramping_in_at_drive_off_is_applied_as_the_car_moves() {
    // Stops of 4-5 s: the load ramp (1-3 s into the stop, over 3 s) ends around the
    // drive-off, too late for two settled blocks to confirm it. The gyro saw the body
    // turn: the step must be in the estimate as the car pulls away, and before it
    // moves wherever the stop had settled before the ramp.
    let r = RealisticSpec {
        load_stop_short_share: 1.0,
        load_stop_short_hold_s: [4.0, 5.0],
        ..gentle()
    };
    let (mut n, mut before_go, mut off) = (0, 0, Vec::new());
    for seed in 41..49 {
        let mut s = spec(seed, 6, r.clone());
        s.load_change_at_stop = Some(3);
        let case = &s.cases()[1];
        let c = check(case, &valid);
        n += c.load_changes;
        before_go += c.load_applied;
        let plan = case.plan.as_ref().unwrap();
        let (t_stop, t_go) = (plan.stops[3].0, plan.stops[3].1);
        let drive = simulate(&case.scenario);
        // The window after the stop ends 2 m on: the car has just begun to move.
        let [at_stop, moving] = estimates_at(&drive, [t_stop, t_go + 1.0]);
        let truth = |t: f64| drive.truth_at(t).load_pitch_deg;
        // A ramp that outlasts the stop goes on unseen while the car drives.
        let step = truth(t_go) - truth(t_stop);
        off.push(moving.unwrap() - at_stop.unwrap() - step);
    }
    assert_eq!(n, 8, "every drive has a load change of 0.5 deg or more");
    // Without the live standstill pitch, a second after drive-off all eight estimates
    // were still more than 0.5 deg short of the step (none applied before it). Measured
    // now: six are within 0.2 deg; two stops never had a quiet stretch before the ramp
    // and keep the old load until the windows move it.
    let half = off.iter().filter(|x| x.abs() <= 0.5).count();
    assert!(half >= 6, "estimate step minus true step: {off:+.3?}");
    eprintln!("{before_go} of {n} applied before drive-off; step errors {off:+.3?}");
    assert!(
        before_go >= n / 4,
        "{before_go} of {n} load changes applied before drive-off"
    )
}

#[test]
fn a_load_ramping_in_before_the_stop_settles_is_found_at_that_stop() {
    // The load starts to come in about a second into the stop, and every stop has a
    // door shock: on some stops the samples do not settle before the ramp, so neither
    // the settled blocks nor the live pitch have a reference from before it. The gyro
    // saw the whole turn from the start of the standstill.
    let r = early_ramp_with_shocks();
    let mut found = Vec::new();
    let mut after_ramp = Vec::new();
    for seed in 51..59 {
        let mut s = spec(seed, 6, r.clone());
        s.load_change_at_stop = Some(3);
        let case = &s.cases()[1];
        let plan = case.plan.as_ref().unwrap();
        let (t_stop, t_go) = (plan.stops[3].0, plan.stops[3].1);
        let drive = simulate(&case.scenario);
        let step = drive.truth_at(t_go).load_pitch_deg - drive.truth_at(t_stop).load_pitch_deg;
        assert!(
            (step - 1.0).abs() < 1e-9,
            "seed {seed}: the ramp ends in the stop"
        );
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        let mut changes = Vec::new();
        let mut decel = Vec::new();
        let mut on = |e: Event| match e {
            Event::LoadChanged { t_s, delta_deg, .. } => changes.push((t_s, delta_deg)),
            Event::WindowAccepted { window: w, .. }
                if w.condition == Condition::DecelBeforeStop && (w.t_s - t_stop).abs() < 2.0 =>
            {
                decel.push(w)
            }
            _ => {}
        };
        for input in drive.merged() {
            match input {
                Input::Imu(x) => est.push_imu(x, &mut on),
                Input::Wheels(w) => est.push_wheels(w, &mut on),
            }
        }
        let at_stop: Vec<f64> = changes
            .iter()
            .filter(|c| c.0 > t_stop && c.0 <= t_go + 0.5)
            .map(|c| c.1)
            .collect();
        // A stop whose reference settled only after the ramp measures its deceleration
        // window against the new load: the window says when its value held.
        let at = |t: f64| drive.truth_at(t).load_pitch_deg;
        for w in decel.iter().filter(|w| at(w.reference_s) - at(w.t_s) > 0.5) {
            let v = w.road_to_body_deg;
            after_ramp.push((seed, v - at(w.reference_s), v - at(w.t_s)));
        }
        found.push((seed, at_stop));
    }
    // The turn is read from the start of the standstill, where the body may still rock
    // by up to 0.1 deg; with the gyro's residual bias the step comes within 0.15 deg.
    for (seed, at_stop) in &found {
        assert!(
            at_stop.len() == 1 && (at_stop[0] - 1.0).abs() <= 0.15,
            "seed {seed}: load changes found at the stop {at_stop:?}, want one of +1.0 deg"
        );
    }
    // Three of the eight (52, 55, 57): 0.04-0.12 deg off the load at the reference,
    // 0.87-0.96 off the load before the ramp.
    assert!(!after_ramp.is_empty(), "no stop settled after its ramp");
    for (seed, at_ref, at_t) in &after_ramp {
        assert!(
            at_ref.abs() < at_t.abs(),
            "seed {seed}: deceleration window {at_ref:+.3} deg off the load at its \
             reference, {at_t:+.3} off the load at the stop"
        );
    }
}

/// A quiet accelerometer's deceleration window measures the road between the axles
/// from the body's pitch one wheelbase back, carried by the gyro from the rest edge.
/// Where the load came in before the stop settled, the reference the window is held
/// against carries the load's turn and the rest edge does not; that window keeps its
/// own slope. Measured on these stops (three settle after their ramp): 0.06-0.30 deg
/// off the load at the reference, the chord's own error on a body kept moving by a
/// door shock and the ramp; with the axle point against that reference, 0.77-0.83.
#[test]
fn a_load_before_the_stop_settles_is_not_read_as_the_roads_pitch_between_the_axles() {
    let r = early_ramp_with_shocks();
    let mut after_ramp = Vec::new();
    for seed in 51..59 {
        let mut s = spec(seed, 6, r.clone());
        s.load_change_at_stop = Some(3);
        let s = with_sensors(s, ins_grade);
        let case = &s.cases()[1];
        let t_stop = case.plan.as_ref().unwrap().stops[3].0;
        let drive = simulate(&case.scenario);
        let at = |t: f64| drive.truth_at(t).load_pitch_deg;
        for e in drive_events(&drive) {
            if let Event::WindowAccepted { window: w, .. } = e
                && w.condition == Condition::DecelBeforeStop
                && (w.t_s - t_stop).abs() < 2.0
                && at(w.reference_s) - at(w.t_s) > 0.5
            {
                after_ramp.push((seed, w.road_to_body_deg - at(w.reference_s)));
            }
        }
    }
    eprintln!("after the ramp: {after_ramp:?}");
    assert!(!after_ramp.is_empty(), "no stop settled after its ramp");
    for (seed, err) in &after_ramp {
        assert!(
            err.abs() < 0.4,
            "seed {seed}: {err:+.3} deg off the load at its reference"
        );
    }
}

#[test]
fn stop_and_go_drives_all_reach_valid() {
    // Short stops with door shocks move a stop's deceleration and acceleration windows
    // in opposite directions (they share its reference). Counted as independent, that
    // spread kept the standard error above the VALID bound for a whole drive on some of
    // these (2 of 8 with `pair_stop_windows` off).
    let text = shipped("stop-and-go");
    let mut never = Vec::new();
    for seed in 311..315 {
        let mut s = DriveSpec::parse(&text).unwrap();
        s.seed = seed;
        for case in s.cases() {
            let drive = simulate(&case.scenario);
            let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
            let mut reached = false;
            for input in drive.merged() {
                match input {
                    Input::Imu(x) => est.push_imu(x, &mut |_| {}),
                    Input::Wheels(w) => est.push_wheels(w, &mut |_| {}),
                }
                reached |= est.estimate().is_some_and(|e| valid(&e));
            }
            if !reached {
                never.push((seed, case.load.clone()));
            }
        }
    }
    assert!(never.is_empty(), "never VALID: {never:?}");
}

#[test]
fn a_speed_bump_past_the_stop_line_leaves_the_straight_half_of_the_window() {
    // A hump of 7 cm over 1.5 m starts 2.9 m past every stop: the front wheels reach it
    // about 1.6 m into the window after a gentle drive-off, so the 3 m path bends there.
    // Whole, such a window is rejected; its first 1.5 m are straight and are kept.
    let whole_only = EstimatorConfig {
        short_window_share: 0.0,
        ..EstimatorConfig::default()
    };
    let (mut drive_offs, mut kept, mut errs) = (0, 0, Vec::new());
    let (mut half, mut whole) = (0, 0);
    // On a smooth road. On the urban roads' unevenness the body's heave of a few mm
    // fails the half window's straightness check (3 mm, a quarter of the whole
    // window's, as a bend of one curvature gives): 11 of 18 kept. Allowing 3-5 mm more
    // for heave keeps more windows but left the family worse (docs/accuracy.md).
    let r = RealisticSpec {
        road_roughness_1e6_m3: 0.0,
        ..gentle()
    };
    for seed in [21, 22] {
        let mut s = spec(seed, 10, r.clone());
        s.bump_share = 1.0;
        let c = checks(&s, 0);
        drive_offs += c.gentle_drive_offs;
        kept += c.gentle_accepted;
        let after = Some(Condition::AccelAfterStop);
        let case = &s.cases()[0];
        let e = window_errors(case, EstimatorConfig::default(), after);
        half += e.len();
        whole += window_errors(case, whole_only.clone(), after).len();
        errs.extend(e);
    }
    // The bump does bend the whole window: without the fallback nearly all are lost
    // (measured: 16 windows after the stops with halves, none without). Measured 15 of
    // 18 gentle drive-offs kept; two binomial standard deviations below that is 2 / 3.
    assert!(
        half >= whole + 8,
        "{half} windows with halves, {whole} without"
    );
    assert!(
        kept * 3 >= drive_offs * 2,
        "{kept} of {drive_offs} gentle drive-offs kept"
    );
    // What was kept did not take the bump in. The same drives without bumps give whole
    // windows; a half window of the same drive-off is expected sqrt(0.124 / 0.091) =
    // 1.17 times as far off by the window law at 0.45 m/s^2 (x = T^3 / D^2 of 7.6
    // against 5.4), and the rms of n windows spreads by about 1/sqrt(2n) relative, two
    // of them allowed. A window bent by the bump is 0.5-1 deg off. Measured: 0.280 deg
    // over 16 half windows, 0.375 over 20 whole ones on the same drives without bumps.
    let rms = |e: &[f64]| (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
    let mut flat = Vec::new();
    for seed in [21, 22] {
        let case = &spec(seed, 10, gentle()).cases()[0];
        flat.extend(window_errors(
            case,
            EstimatorConfig::default(),
            Some(Condition::AccelAfterStop),
        ));
    }
    let bound = rms(&flat) * 1.17 * (1.0 + 2.0 / (2.0 * errs.len() as f64).sqrt());
    assert!(
        rms(&errs) <= bound,
        "window rms {:.3} deg over {} windows with bumps, bound {bound:.3}",
        rms(&errs),
        errs.len()
    );
}

/// The loaded case of `s`, simulated: its drive, when its load stop begins and ends
/// (s), and the true load step there (deg).
fn load_stop(s: &DriveSpec) -> (leveld::sim::Drive, f64, f64, f64) {
    let case = &s.cases()[1];
    let plan = case.plan.as_ref().unwrap();
    let (k, _) = plan.load_change.unwrap();
    let (t_stop, t_go, ..) = plan.stops[k];
    let drive = simulate(&case.scenario);
    let step = drive.truth_at(t_go).load_pitch_deg - drive.truth_at(t_stop).load_pitch_deg;
    (drive, t_stop, t_go, step)
}

/// The load step leveld applied at the load stop (at the stop or as the car pulls
/// away, not windows later) minus the true step, deg, one per seed. Every stop is left
/// gently; the load stop lasts `hold_s` and its ramp starts `delay_s` into it.
fn load_step_errors(hold_s: [f64; 2], delay_s: [f64; 2], seeds: std::ops::Range<u64>) -> Vec<f64> {
    let r = RealisticSpec {
        load_stop_short_share: 1.0,
        load_stop_short_hold_s: hold_s,
        load_change_delay_s: delay_s,
        ..gentle()
    };
    let mut errs = Vec::new();
    for seed in seeds {
        let mut s = spec(seed, 6, r.clone());
        s.load_change_at_stop = Some(3);
        let (drive, t_stop, t_go, step) = load_stop(&s);
        let ev = drive_events(&drive);
        let measured: f64 = ev
            .iter()
            .filter_map(|e| match e {
                Event::LoadChanged { t_s, delta_deg, .. } if *t_s > t_stop && *t_s < t_go + 1.0 => {
                    Some(*delta_deg)
                }
                _ => None,
            })
            .sum();
        eprintln!("seed {seed}: step {step:+.3}, measured {measured:+.3}");
        errs.push(measured - step);
    }
    errs
}

/// At least 5 of 6 load steps within 0.15 deg: the tolerance of the other ramp tests
/// (0.1 deg of tangential acceleration at the ramp's end and the body starting to
/// squat, plus noise).
fn assert_load_steps_measured(errs: &[f64]) {
    let seen = errs.iter().filter(|e| e.abs() <= 0.15).count();
    assert!(seen >= 5, "load steps measured off by {errs:?} deg");
}

#[test]
fn a_load_ramping_in_through_a_whole_stop_is_measured_as_the_car_pulls_away() {
    // The load starts to ramp in 1.0-1.2 s into a stop of 4.0-4.3 s, as the standstill
    // begins, and the car pulls away as the ramp ends: no sample of the stop settles.
    // Such a stop used to give no load change at all.
    assert_load_steps_measured(&load_step_errors([4.0, 4.3], [1.0, 1.2], 61..67));
}

#[test]
fn a_load_ramping_in_after_the_first_quiet_moment_of_a_stop_is_followed_to_drive_off() {
    // The ramp starts 1.3-1.5 s into a stop of 4.3-4.6 s, after the first few quiet
    // samples, and ends as the car pulls away. The block holding those samples used to stay open
    // through the ramp, as no further quiet sample came to close it: the stop had no
    // settled reference, and the live pitch could not follow the ramp.
    assert_load_steps_measured(&load_step_errors([4.3, 4.6], [1.3, 1.5], 71..77));
}

#[test]
fn a_load_change_reaches_the_estimate_before_drive_off_at_50_and_200_hz() {
    // Standstill spans were counted in samples of a 100 Hz IMU. At 50 Hz the few quiet
    // samples between the body's last swing and a load ramping in right after it were
    // too few for a reference; without one the live pitch could not follow the ramp,
    // and the load reached the estimate only as the car pulled away (seed 104, 1 deg
    // late). The gyro bias filter, stepped per sample, was twice as fast at 200 Hz.
    let text = shipped("urban");
    for rate_hz in [50.0, 200.0] {
        for seed in 101..105 {
            let mut s = DriveSpec::parse(&text).unwrap();
            s.seed = seed;
            if let Some(sensors) = s.sensors.as_mut() {
                sensors.imu_rate_hz = rate_hz;
            }
            let (drive, t_stop, t_go, step) = load_stop(&s);
            let [at_stop, before_go] = estimates_at(&drive, [t_stop, t_go]);
            let seen = before_go.unwrap() - at_stop.unwrap();
            eprintln!("{rate_hz} Hz seed {seed}: step {step:+.3}, before drive-off {seen:+.3}");
            // A step missed until drive-off is off by all of it (1 deg).
            assert!((seen - step).abs() <= 0.2, "{rate_hz} Hz seed {seed}");
        }
    }
}

#[test]
fn a_rest_swing_gate_below_the_gyros_noise_still_gives_every_stop_its_reference() {
    // The gate that keeps a door shock's swing out of the gravity reference (0.05 m/s^2)
    // is about five times the swing a 0.01 deg/s/sqrt(Hz) gyro shows at a 2 m arm. A gate
    // far below that noise (as a noisier gyro makes the default) passes hardly a sample:
    // the blocks and the gravity filter then take every settled sample, and the drive
    // gives the windows it gives without the gate.
    let errors = |s: &DriveSpec, gate: f64| {
        let cfg = EstimatorConfig {
            rest_swing_gate_mps2: gate,
            ..EstimatorConfig::default()
        };
        window_errors(&s.cases()[0], cfg, None)
    };
    for seed in 1..4 {
        let s = spec(seed, 8, RealisticSpec::default());
        let (gated, ungated) = (errors(&s, 0.001), errors(&s, 1e3));
        eprintln!("seed {seed}: with the gate {gated:+.3?}, without {ungated:+.3?}");
        assert!(ungated.len() >= 8, "seed {seed}: {} windows", ungated.len());
        assert_eq!(gated.len(), ungated.len(), "seed {seed}");
        let rms = |e: &[f64]| (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
        // Single windows are about 0.2 deg rms on these drives.
        assert!(rms(&gated) <= rms(&ungated) + 0.05, "seed {seed}");
    }
}

#[test]
fn the_gyro_bias_does_not_learn_the_bodys_swing_after_a_stop() {
    // The hilly and bumpy drives of the realistic family (5P, six seeds each) with
    // sensors free of noise and bias: what is left of a load step's error is the
    // estimator's own. Many of these stops are 5-7 s long and the ramp ends near the
    // drive-off, so the step is the gyro's turn since the settled reference, and every
    // error of the learnt bias shows in it over the 3-5 s the turn is carried. A bias
    // taught by the body still swinging back from its dive (block means of 0.03-0.27
    // deg/s, one sign, while each sample passes the per-window gate) gave steps
    // 0.84-1.00 deg for 1.0 (rms error 0.061, worst 0.162). Measured with blocks
    // from 1 s after the stop, within the gate: 0.915-1.00 (0.037, worst 0.085).
    let mut off = Vec::new();
    for name in ["hilly", "bumpy"] {
        let text = shipped(name);
        let quiet = [
            "sensors.acc_noise_ug_rthz=0.0",
            "sensors.gyro_noise_dps_rthz=0.0",
            "sensors.acc_bias_walk_mps2_rts=0.0",
            "sensors.gyro_bias_walk_dps_rts=0.0",
            "realistic.acc_bias_max_mps2=0.0",
            "realistic.gyro_bias_max_dps=0.0",
        ]
        .map(String::from);
        let mut s = DriveSpec::parse_with(&text, &quiet).unwrap();
        let base = s.seed;
        for k in 0..6 {
            s.seed = base + k;
            let case = &s.cases()[1];
            let plan = case.plan.as_ref().unwrap();
            let (stop, _) = plan.load_change.unwrap();
            let (t_stop, t_go) = (plan.stops[stop].0, plan.stops[stop].1);
            let drive = simulate(&case.scenario);
            let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
            let mut applied = 0.0;
            let mut take = |e: Event| {
                if let Event::LoadChanged { t_s, delta_deg, .. } = e
                    && t_s > t_stop
                    && t_s < t_go + 2.0
                {
                    applied += delta_deg;
                }
            };
            for input in drive.merged() {
                match input {
                    Input::Imu(x) => est.push_imu(x, &mut take),
                    Input::Wheels(w) => est.push_wheels(w, &mut take),
                }
            }
            let truth = |t: f64| drive.truth_at(t).load_pitch_deg;
            off.push(applied - (truth(t_go) - truth(t_stop)));
        }
    }
    let rms = (off.iter().map(|x| x * x).sum::<f64>() / off.len() as f64).sqrt();
    eprintln!("applied minus true step: {off:+.3?}, rms {rms:.3}");
    assert!(
        off.iter().all(|x| x.abs() <= 0.12) && rms <= 0.045,
        "applied minus true step: {off:+.3?}, rms {rms:.3}"
    );
}

#[test]
fn a_gyro_three_times_noisier_than_the_gates_are_sized_for_still_reaches_valid() {
    // The stillness and bias gates are sized for a gyro of 0.01 deg/s/sqrt(Hz). At
    // 0.03 (0.3 deg/s per 100 Hz sample) the 0.2 s mean's noise is about 0.07 deg/s per
    // axis against a bias gate of 0.1 deg/s on the norm: most settled samples failed
    // it, and 5 of these 8 stop-and-go drives never reached VALID. The gates now grow
    // with the noise learnt at rest. Each drive must reach VALID and stay inside the
    // 0.2 deg error budget while VALID (measured: worst 0.12; the last to reach VALID,
    // seed 304 5P, at 824 s of its 850, 843 while the stops still learnt the bias from
    // a load's first samples at its sixth stop). The IMU sits square in
    // yaw on these cars: a yawed one owns up to a y bias no stop shows in its standard
    // error (`an_imu_yawed_on_its_mount_owns_up_to_the_y_bias_no_stop_shows`), which
    // kept one of these drives (1.4 deg of yaw, windows 0.9 deg p95) just short of
    // VALID, and this test is about the gyro's gates.
    use leveld::bench::accuracy::run_case;
    use leveld::bench::baselines::{Leveld, PitchMethod};
    let text = shipped("stop-and-go");
    let noisy = [
        "sensors.gyro_noise_dps_rthz=0.03".to_string(),
        "realistic.imu_mount_max_deg=[0.8, 1.0, 0.0]".to_string(),
    ];
    let mut s = DriveSpec::parse_with(&text, &noisy).unwrap();
    let base = s.seed;
    let cases: Vec<Case> = (0..4)
        .flat_map(|k| {
            s.seed = base + k;
            s.cases()
        })
        .collect();
    let make = || -> Vec<Box<dyn PitchMethod>> {
        vec![Box::new(Leveld::new(EstimatorConfig::default(), "leveld"))]
    };
    let rows: Vec<_> = std::thread::scope(|sc| {
        let hs: Vec<_> = cases
            .iter()
            .map(|c| sc.spawn(move || run_case(c, &make)))
            .collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let mut bad = Vec::new();
    for (case, rows) in cases.iter().zip(&rows) {
        let r = &rows[0];
        eprintln!(
            "seed {} {}: mean abs err {:.3}, valid after {:?} s",
            case.seed, case.load, r.mean_abs_err_deg, r.time_to_valid_s
        );
        if r.time_to_valid_s.is_none() || !(r.mean_abs_err_deg <= 0.2) {
            bad.push((case.seed, case.load.clone(), r.mean_abs_err_deg));
        }
    }
    assert!(bad.is_empty(), "never VALID or over 0.2 deg: {bad:?}");
}

#[test]
fn a_load_change_on_a_soft_suspension_is_measured_from_force_and_gyro() {
    // A soft, lightly damped suspension (1.0-1.1 Hz, damping 0.15-0.25) still rocks
    // when the load starts to ramp in, and the stop's reference may be a few samples
    // of the swing. Its force carries the lever arm's acceleration and the gyro's turn
    // starts from wherever the swing was; the step is now the mean of the two. Urban
    // 5P, seeds 101-104: before 0 of 4 steps within 0.1 deg before drive-off (0.86,
    // 1.12, 0.86, 1.13 for 1.0); measured now 0.93, 1.04, 0.95, 1.11.
    //
    // The step is the estimate at drive-off against the estimate once the stop's own
    // deceleration window is in, not before the stop: that window measures the old
    // load and moves the estimate as any window does (-0.03 deg on seed 101).
    let text = shipped("urban");
    let soft = [
        "realistic.pitch_freq_hz=[1.0, 1.1]",
        "realistic.pitch_damping=[0.15, 0.25]",
        "realistic.pitch_per_accel_deg=[0.3, 0.45]",
    ]
    .map(String::from);
    let mut s = DriveSpec::parse_with(&text, &soft).unwrap();
    let mut steps = Vec::new();
    for seed in 101..105 {
        s.seed = seed;
        let case = &s.cases()[1];
        let plan = case.plan.as_ref().unwrap();
        let (stop, _) = plan.load_change.unwrap();
        let (t_stop, t_go) = (plan.stops[stop].0, plan.stops[stop].1);
        let drive = simulate(&case.scenario);
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        let (mut before, mut at_go) = (None, None);
        for input in drive.merged() {
            let t = match input {
                Input::Imu(x) => x.t_s,
                Input::Wheels(w) => w.t_s,
            };
            if t >= t_go {
                at_go = est.estimate().map(|e| e.road_to_body_deg);
                break;
            }
            if t >= t_stop && before.is_none() {
                before = est.estimate().map(|e| e.road_to_body_deg);
            }
            // The estimate as the window left it (a load change may follow in the
            // same step).
            let mut after_window = None;
            let mut see = |e: Event| {
                if let Event::WindowAccepted { window, estimate } = e
                    && window.condition == Condition::DecelBeforeStop
                {
                    after_window = Some(estimate.road_to_body_deg);
                }
            };
            match input {
                Input::Imu(x) => est.push_imu(x, &mut see),
                Input::Wheels(w) => est.push_wheels(w, &mut see),
            }
            if t >= t_stop && after_window.is_some() {
                before = after_window;
            }
        }
        let truth = |t: f64| drive.truth_at(t).load_pitch_deg;
        let (Some(before), Some(at_go)) = (before, at_go) else {
            panic!("seed {seed}: no estimate at the stop");
        };
        steps.push((seed, at_go - before - (truth(t_go) - truth(t_stop))));
    }
    let ok = steps.iter().filter(|(_, e)| e.abs() <= 0.1).count();
    eprintln!("step minus truth before drive-off: {steps:+.3?}");
    assert!(ok >= 3, "{ok} of 4 within 0.1 deg: {steps:+.3?}");
}

/// Median absolute window error of the shipped urban and stop-and-go drives (1P, two
/// seeds each: gentle drive-offs, short stops, doors shut at rest), and the count.
fn shipped_window_median(velocity_free: bool) -> (f64, usize) {
    let mut errs = Vec::new();
    for (file, seeds) in [("urban", [101, 102]), ("stop-and-go", [301, 302])] {
        let text = shipped(file);
        let mut s = DriveSpec::parse(&text).unwrap();
        for seed in seeds {
            s.seed = seed;
            let case: Case = s.cases().remove(0);
            let cfg = EstimatorConfig {
                velocity_free_slope: velocity_free,
                correct_grade_pitch: false,
                ..EstimatorConfig::default()
            };
            // Both slopes share the body's pitch on the grade of each stop (0.03 deg
            // rms once corrected, 0.1-0.16 on grades of 4 %); the start velocity is
            // what tells them apart, so it is measured on a body level with its road.
            let mut case = case;
            case.scenario.vehicle.pitch_from_grade = false;
            errs.extend(window_errors(&case, cfg, None).iter().map(|e| e.abs()));
        }
    }
    errs.sort_by(f64::total_cmp);
    (
        errs.get(errs.len() / 2).copied().unwrap_or(f64::NAN),
        errs.len(),
    )
}

/// The same windows, walked from the same starts: the chord to the window's end
/// carries the start velocity (a body still swinging, a drive-off found late, the
/// noise integrated at rest), the velocity-free slope does not. Measured: median 0.152
/// deg against 0.179 (with the body's pitch on each grade in the drives and taken out
/// by leveld, 0.163 against 0.176).
#[test]
fn windows_are_measured_without_the_velocity_the_walk_starts_with() {
    let (free, n) = shipped_window_median(true);
    let (chord, m) = shipped_window_median(false);
    assert!(n >= 100 && m >= 100, "{n} and {m} windows");
    assert!(
        free < 0.85 * chord,
        "median velocity-free {free:.3} deg, chord {chord:.3}"
    );
}

#[test]
fn the_standard_error_behind_valid_is_not_overconfident() {
    // At the start of stops 2-8 of realistic drives, the estimate's error against the
    // standard error it reports, where that standard error is within the VALID bound.
    // On the benchmark's 64 drives (8 seeds of every scenario and load) the rms of
    // error / standard error is 1.03 there; on pairs of seeds, 0.85-1.28. Before the
    // average counted residuals up to its Huber clip it was 0.67 (cautious), and a
    // standard error that claims half the true error would give 2. These are seeds
    // the benchmark does not run (the 9th to 12th of each scenario). On smooth roads
    // the 9th and 10th gave 28 such stops (0.90); the road's unevenness pitches the
    // body at each stop and VALID comes later, so four seeds each: measured 1.24 over
    // 30 stops.
    let cases: Vec<Case> = ["urban", "hilly", "stop-and-go", "bumpy"]
        .iter()
        .flat_map(|name| {
            let mut s = DriveSpec::parse(&shipped(name)).unwrap();
            let base = s.seed;
            (8..12).flat_map(move |k| {
                s.seed = base + k;
                s.cases()
            })
        })
        .collect();
    let ratios: Vec<f64> = std::thread::scope(|sc| {
        let hs: Vec<_> = cases
            .chunks(cases.len().div_ceil(2))
            .map(|chunk| {
                sc.spawn(move || {
                    let mut out = Vec::new();
                    for case in chunk {
                        let plan = case.plan.as_ref().unwrap();
                        let drive = simulate(&case.scenario);
                        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
                        let mut next = 2;
                        for input in drive.merged() {
                            let t = match input {
                                Input::Imu(x) => x.t_s,
                                Input::Wheels(w) => w.t_s,
                            };
                            while next <= 8 && next < plan.stops.len() && t >= plan.stops[next].0 {
                                if let Some(e) = est.estimate()
                                    && e.std_err_deg <= 0.06
                                {
                                    let err = e.road_to_body_deg - drive.truth_at(t).load_pitch_deg;
                                    out.push(err / e.std_err_deg);
                                }
                                next += 1;
                            }
                            match input {
                                Input::Imu(x) => est.push_imu(x, &mut |_| {}),
                                Input::Wheels(w) => est.push_wheels(w, &mut |_| {}),
                            }
                        }
                    }
                    out
                })
            })
            .collect();
        hs.into_iter().flat_map(|h| h.join().unwrap()).collect()
    });
    let n = ratios.len();
    let rms = (ratios.iter().map(|z| z * z).sum::<f64>() / n.max(1) as f64).sqrt();
    eprintln!("{n} stops within the VALID bound: rms of error / standard error {rms:.2}");
    assert!(n >= 15, "too few stops within the bound to judge: {n}");
    assert!(
        rms <= 1.5,
        "the standard error claims too much: rms ratio {rms:.2} over {n}"
    );
}

/// Window errors (deg) of the shipped urban and stop-and-go drives (1P, two seeds each)
/// with the accelerometer and gyro of `sensors`, the chord's slope taken below
/// `chord_below_ug` of learnt accelerometer noise.
fn windows_with_imu(sensors: impl Fn(&mut Sensors) + Copy, chord_below_ug: f64) -> Vec<f64> {
    let mut errs = Vec::new();
    for (file, seeds) in [("urban", [101, 102]), ("stop-and-go", [301, 302])] {
        let mut s = DriveSpec::parse(&shipped(file)).unwrap();
        for seed in seeds {
            s.seed = seed;
            let case: Case = with_sensors(s.clone(), sensors).cases().remove(0);
            let cfg = EstimatorConfig {
                chord_below_acc_noise_ug_rthz: chord_below_ug,
                ..EstimatorConfig::default()
            };
            errs.extend(window_errors(&case, cfg, None));
        }
    }
    errs
}

/// An INS-grade unit (30 ug/sqrt(Hz), gyro 0.003 deg/s/sqrt(Hz), little drift)
/// integrates little velocity over the rest before a walk, and the chord, which reads
/// the road nearer the car, is then the better slope; with the shipped 300
/// ug/sqrt(Hz) the noise learnt at rest keeps the velocity-free slope, window for
/// window. Measured: rms 0.163 deg with the chord against 0.183 velocity-free.
#[test]
fn a_quiet_accelerometer_takes_the_chords_slope() {
    let (chord, free) = (
        windows_with_imu(ins_grade, 150.0),
        windows_with_imu(ins_grade, 0.0),
    );
    eprintln!(
        "INS-grade: rms {:.3} deg chord ({} windows), {:.3} velocity-free ({})",
        rms(&chord),
        chord.len(),
        rms(&free),
        free.len()
    );
    assert!(chord.len() >= 100 && free.len() >= 100);
    assert!(
        rms(&chord) < 0.92 * rms(&free),
        "chord {:.3}, velocity-free {:.3}",
        rms(&chord),
        rms(&free)
    );
    let shipped = |_: &mut Sensors| {};
    assert_eq!(
        windows_with_imu(shipped, 150.0),
        windows_with_imu(shipped, 0.0),
        "at 300 ug/sqrt(Hz) the slope must stay velocity-free"
    );
}

/// The body stands on the chord between its axles' contact points; a window's chord
/// runs over the road ahead of them (behind, walking back). Where the road is not one
/// plane (its unevenness, a vertical curve) the two differ by what no longer window
/// averages out. One wheelbase out the rear wheels stand where the front ones stood,
/// and the gyro says how the road pitched the body on the way: with a quiet
/// accelerometer, whose windows take the chord, the window then measures the road the
/// body stood on. Measured on these eight drives (the first two seeds of each realistic
/// scenario, 1P, INS-grade unit): 226 windows, rms 0.134 deg with it, 0.157 without.
#[test]
fn a_chord_window_measures_the_road_between_the_axles_the_body_stood_on() {
    let errs = |axle_chord: bool| {
        let mut errs = Vec::new();
        for file in ["urban", "hilly", "stop-and-go", "bumpy"] {
            let mut s = DriveSpec::parse(&shipped(file)).unwrap();
            for seed in [s.seed, s.seed + 1] {
                s.seed = seed;
                let case: Case = with_sensors(s.clone(), ins_grade).cases().remove(0);
                let cfg = EstimatorConfig {
                    axle_chord,
                    ..EstimatorConfig::default()
                };
                errs.extend(window_errors(&case, cfg, None));
            }
        }
        errs
    };
    let (on, off) = (errs(true), errs(false));
    eprintln!(
        "INS-grade: rms {:.3} deg between the axles ({} windows), {:.3} over the window ({})",
        rms(&on),
        on.len(),
        rms(&off),
        off.len()
    );
    assert_eq!(on.len(), off.len(), "the same windows, measured otherwise");
    assert!(on.len() >= 100);
    assert!(
        rms(&on) < 0.9 * rms(&off),
        "axles {:.3}, window {:.3}",
        rms(&on),
        rms(&off)
    );
}

/// A stop shorter than the lever-arm fit's tail (half a second past the first settled
/// sample) is fitted when it ends, and the drive-off is then in the history: force
/// along x while the body squats, which a least-squares arm reads as an IMU metres
/// below the pitch centre. Realistic urban seed 13 (5P) and stop-and-go seed 14 (1P)
/// each have such a stop early; with the drive-off in the fit the learnt arm went
/// 1.9 and 2.1 m off the simulated [2.1, 0.65, 0.4] m, which tilts every later rest
/// reference the motion tracker starts from, and urban 13 then lost its load change
/// to a drive-off the tracker saw at rest. Over the 192 drives of seeds 1-24 of the
/// four scenarios, 7 went more than 0.3 m off; none does since.
#[test]
fn a_short_stops_drive_off_does_not_enter_the_lever_arm_fit() {
    for (file, seed, load) in [("urban", 13, 1), ("stop-and-go", 14, 0)] {
        let mut s = DriveSpec::parse(&shipped(file)).unwrap();
        s.seed = seed;
        let case: Case = s.cases().remove(load);
        let drive = simulate(&case.scenario);
        let truth = case.scenario.vehicle.lever_arm_m;
        let configured = nalgebra::Vector3::from(EstimatorConfig::default().lever_arm_m);
        let (mut worst_m, mut next_s, mut learnt) = (0.0f64, 0.0, 0);
        replay(&drive, |est, t| {
            if t >= next_s {
                next_s = t + 2.0;
                if let Some(fit) = est.state().lever_fit.filter(|f| f.mtm[0] > 0.0) {
                    let arm = fit.solve(&configured);
                    learnt += 1;
                    worst_m = worst_m
                        .max((arm.x - truth[0]).abs())
                        .max((arm.z - truth[2]).abs());
                }
            }
        });
        eprintln!("{file} seed {seed}: learnt arm at most {worst_m:.2} m off");
        assert!(learnt > 50, "{file} {seed}: the arm was never learnt");
        assert!(
            worst_m < 0.3,
            "{file} seed {seed}: learnt arm {worst_m:.2} m off the vehicle's"
        );
    }
}

/// Realistic hilly seed 14 (5P): the load ramps in from 1.1 s into a 6.3 s stop, just
/// after the standstill began and before any sample settled, and a door shock falls in
/// the ramp. The first quiet samples come as the ramp ends at 4.1 s, and `on_settled`
/// waits for 3 s of them: the turn the gyro saw was applied only as the car pulled
/// away, after its drive-off. It is now applied once 1 s of settled samples agree.
#[test]
fn a_load_ramping_in_before_anything_settled_is_applied_before_a_drive_off_soon_after() {
    let mut s = DriveSpec::parse(&shipped("hilly")).unwrap();
    s.seed = 14;
    let c = checks(&s, 1);
    assert_eq!(c.load_changes, 1);
    assert_eq!(c.load_applied, 1, "{c:?}");
}

/// A load that starts to ramp in within the first second of a stop keeps every sample
/// from settling, and a stop of 4-5 s ends with the car pulling away 0.1-1 s after the
/// ramp. The settled blocks had no reference to follow the ramp from, and the turn was
/// applied only once the drive-off was seen, after the car moved. The gyro's turn since
/// the standstill began is now shown while it happens, once the specific force agrees.
#[test]
fn a_load_ramping_in_from_the_first_second_of_a_short_stop_shows_before_drive_off() {
    for (name, seed) in [
        ("stop-and-go", 3),
        ("urban", 2),
        ("urban", 10),
        ("bumpy", 10),
    ] {
        let mut s = DriveSpec::parse(&shipped(name)).unwrap();
        s.seed = seed;
        let r = s.realistic.as_mut().expect("a realistic scenario");
        r.load_change_delay_s = [0.5, 1.0];
        let c = checks(&s, 1);
        assert_eq!(c.load_changes, 1, "{name} {seed}");
        assert_eq!(c.load_applied, 1, "{name} {seed}: {c:?}");
    }
}

/// An urban drive of 10 stops with an INS-grade IMU (so that a bias of hundredths of a
/// degree stands out), its sensors then changed by `change`.
fn ins_grade_urban(seed: u64, change: impl FnOnce(&mut Sensors)) -> leveld::sim::Scenario {
    let s = with_sensors(spec(seed, 10, RealisticSpec::default()), |x| {
        x.acc_noise_ug_rthz = 30.0;
        x.gyro_noise_dps_rthz = 0.003;
        change(x);
    });
    s.cases()[0].scenario.clone()
}

/// Mean error of the windows `est` accepts over the drive of `sc`, deg.
fn mean_window_error(sc: &leveld::sim::Scenario, mut est: Estimator) -> f64 {
    let drive = simulate(sc);
    let mut errs = Vec::new();
    for input in drive.merged() {
        let mut take = |e: Event| {
            if let Event::WindowAccepted { window, .. } = e {
                errs.push(window.road_to_body_deg - drive.truth_at(window.t_s).load_pitch_deg);
            }
        };
        match input {
            Input::Imu(x) => est.push_imu(x, &mut take),
            Input::Wheels(w) => est.push_wheels(w, &mut take),
        }
    }
    assert!(errs.len() >= 8, "{} windows", errs.len());
    errs.iter().sum::<f64>() / errs.len() as f64
}

/// Mean window error with the IMU yawed 1.5 deg on its mount, on lanes that fall
/// `cross_slope_pct` to the side, with or without the end-of-line roll, deg.
fn yawed_imu_window_bias(seed: u64, cross_slope_pct: f64, floor_roll: bool) -> f64 {
    let mut sc = ins_grade_urban(seed, |_| {});
    sc.vehicle.imu_mount_deg = [0.6, 0.4, 1.5];
    sc.road.cross_slope_pct = cross_slope_pct;
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    if floor_roll {
        est.set_floor_roll_deg(Some(leveld::sim::floor_roll_deg(&sc)));
    }
    mean_window_error(&sc, est)
}

#[test]
fn a_lane_falling_to_the_side_does_not_bias_an_imu_yawed_on_its_mount() {
    // Yaw x crossfall: 1.5 deg x 2.5 % is 0.037 deg of pitch the x axis reads and the
    // load does not have. With the floor's roll from the end-of-line calibration the
    // windows measure along the travel, and the crossfall moves them by a few
    // thousandths at most (the same drive and noise with and without it).
    for seed in [3, 4] {
        let flat = yawed_imu_window_bias(seed, 0.0, true);
        let crowned = yawed_imu_window_bias(seed, 2.5, true);
        assert!(
            (crowned - flat).abs() < 0.01,
            "seed {seed}: {flat} -> {crowned}"
        );
        // Without it the x axis' share of the lane's roll stays in every window: the
        // IMU yawed to the left reads the raised left side as nose-up.
        let kept =
            yawed_imu_window_bias(seed, 2.5, false) - yawed_imu_window_bias(seed, 0.0, false);
        assert!(kept > 0.025, "seed {seed}: {kept}");
    }
}

/// Mean window error with accelerometer axes `axes`, leveld configured by `cfg`, deg.
fn window_bias_with_axes(seed: u64, axes: [[f64; 3]; 3], cfg: EstimatorConfig) -> f64 {
    let sc = ins_grade_urban(seed, |x| x.acc_axes = axes);
    mean_window_error(&sc, Estimator::new(cfg).unwrap())
}

#[test]
fn an_accelerometer_whose_z_axis_leans_to_x_needs_its_calibration() {
    // The z axis reads 0.5 % of the force along x: every acceleration of a window
    // looks 0.29 deg steeper to it, and nothing in a drive tells that from the road.
    let square = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let mut leaning = square;
    leaning[2][0] = 0.005;
    let inverse = nalgebra::Matrix3::from_fn(|i, j| leaning[i][j])
        .try_inverse()
        .unwrap();
    let calibrated = EstimatorConfig {
        acc_matrix: std::array::from_fn(|i| std::array::from_fn(|j| inverse[(i, j)])),
        ..EstimatorConfig::default()
    };
    for seed in [3, 4] {
        let base = window_bias_with_axes(seed, square, EstimatorConfig::default());
        let off = window_bias_with_axes(seed, leaning, EstimatorConfig::default()) - base;
        let lean_deg = 0.005f64.atan().to_degrees();
        assert!((off + lean_deg).abs() < 0.05, "seed {seed}: {off}");
        let fixed = window_bias_with_axes(seed, leaning, calibrated.clone()) - base;
        assert!(fixed.abs() < 0.01, "seed {seed}: {fixed}");
    }
}

#[test]
fn a_load_whose_ramp_ends_just_before_drive_off_is_applied_within_a_tenth_of_a_degree() {
    // The ramp starts 1.6-2.0 s into a stop of 5.0-5.6 s and ends 0-1 s before the car
    // pulls away: the step is taken at the drive-off from the gyro's turn over the
    // ramp, averaged with the force of the quiet samples after it where they stand.
    // The bar of a load change applied within 0.1 deg at 90 % of the stops: 15 of 16
    // (14 with the gyro's turn alone; rms error 0.060 deg, 0.068 alone).
    let errs = load_step_errors([5.0, 5.6], [1.6, 2.0], 81..97);
    let within = errs.iter().filter(|e| e.abs() <= 0.1).count();
    assert!(
        within * 10 >= errs.len() * 9,
        "load steps off by {errs:?} deg"
    );
}

/// Load steps (applied minus true, deg) at the load stop of urban drives of 8 stops
/// (`load_change_at_stop` 4), whose load ramps in 1-3 s into a hold of 8-15 s, with the gyro's bias
/// drifting by `walk_dps_rts` deg/s per sqrt(s). NaN where no step was applied there.
fn load_steps_with_bias_walk(walk_dps_rts: f64, seeds: std::ops::RangeInclusive<u64>) -> Vec<f64> {
    let r = RealisticSpec {
        load_stop_short_share: 0.0,
        ..RealisticSpec::default()
    };
    seeds
        .map(|seed| {
            let mut s = with_sensors(spec(seed, 8, r.clone()), |x| {
                x.gyro_bias_walk_dps_rts = walk_dps_rts;
            });
            s.load_change_at_stop = Some(4);
            let (drive, t_stop, t_go, step) = load_stop(&s);
            let ev = drive_events(&drive);
            load_change_between(&ev, t_stop, t_go + 2.0).map_or(f64::NAN, |d| d - step)
        })
        .collect()
}

/// The gyro's bias was learnt at an earlier stop and has drifted since (the family's
/// 0.002 deg/s/sqrt(s) is 0.035 deg/s after five minutes); a load step carried with it
/// over the seconds between the reference and the rest after the ramp was off by up to
/// 0.3 deg. The step now takes the bias from the quiet samples after the turn. With a
/// gyro that drifts three times as fast, at most one step fewer is applied within 0.1
/// deg than with the family's (before: 19 of 24 against 22), and at least 90 % of them.
#[test]
fn a_load_step_is_carried_with_the_gyro_bias_of_the_rest_after_it() {
    let within = |e: &[f64]| e.iter().filter(|x| x.abs() <= 0.1).count();
    let family = load_steps_with_bias_walk(0.002, 1..=24);
    let drifting = load_steps_with_bias_walk(0.006, 1..=24);
    let (a, b) = (within(&family), within(&drifting));
    assert!(a >= 22 && b >= 22, "within 0.1 deg: {a} and {b} of 24");
    assert!(b + 1 >= a, "a drifting gyro lost steps: {a} -> {b} of 24");
}

/// The grade share leveld fits by the end of each of the first eight hilly drives (1P),
/// for a body that pitches on a grade as under braking or one that stands on every
/// grade as on level ground.
fn hilly_grade_shares(pitch_from_grade: bool) -> Vec<f64> {
    let text = shipped("hilly");
    let specs: Vec<DriveSpec> = (0..8)
        .map(|i| {
            let mut s = DriveSpec::parse(&text).unwrap();
            s.seed += i;
            s.realistic.as_mut().unwrap().pitch_from_grade = pitch_from_grade;
            s
        })
        .collect();
    std::thread::scope(|sc| {
        let hs: Vec<_> = specs
            .iter()
            .map(|s| {
                sc.spawn(move || {
                    let drive = simulate(&s.cases()[0].scenario);
                    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
                    for input in drive.merged() {
                        match input {
                            Input::Imu(x) => est.push_imu(x, &mut |_| {}),
                            Input::Wheels(w) => est.push_wheels(w, &mut |_| {}),
                        }
                    }
                    est.grade_share()
                })
            })
            .collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    })
}

#[test]
fn stops_at_different_grades_tell_whether_the_body_pitches_on_a_grade() {
    // Held by its brakes, a body dives or squats on a grade as under braking (share 1);
    // a vehicle model without that stands on every grade as on level ground (share 0),
    // and taking the braking pitch out there would add 0.2-0.4 deg to each window on
    // a 10-15 % grade. Each hilly drive has 16-26 windows at grades to 15 %; the share
    // they fit scatters about 0.2 per drive (measured: means 0.18 and 0.91).
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (none, full) = (hilly_grade_shares(false), hilly_grade_shares(true));
    eprintln!("without grade pitch {none:.2?}, with {full:.2?}");
    assert!(mean(&none) < 0.4, "a body level on every grade: {none:.2?}");
    assert!(
        mean(&full) > 0.7,
        "a body that pitches on grades: {full:.2?}"
    );
}

#[test]
fn the_end_of_line_reference_loses_the_accelerometer_bias_the_stops_learn() {
    // The floor's raw pitch carries the x bias as bias / g (the family draws up to 0.3
    // m/s^2, 1.7 deg); the windows do not, so a correction taken against the raw
    // reference tilts the beam by that much for good. Hilly drives, one load, fresh
    // seeds: the reference at the drive's end against the car's road-to-body pitch on
    // the floor.
    let text = shipped("hilly");
    let (mut raw, mut free) = (Vec::new(), Vec::new());
    for seed in 1101..1109 {
        let mut s = DriveSpec::parse(&text).unwrap();
        s.seed = seed;
        let case = s.cases().into_iter().find(|c| c.load == "1P").unwrap();
        let drive = simulate(&case.scenario);
        let (floor_pitch, floor_roll) = leveld::sim::floor_attitude_deg(&case.scenario);
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        est.set_floor_roll_deg(Some(floor_roll));
        est.seed_calibration(floor_pitch, 4.0);
        for input in drive.merged() {
            match input {
                Input::Imu(x) => est.push_imu(x, &mut |_| ()),
                Input::Wheels(w) => est.push_wheels(w, &mut |_| ()),
            }
        }
        let truth = drive.truth_at(0.0).load_pitch_deg;
        let (r, f) = (
            floor_pitch - truth,
            est.level_reference_deg(floor_pitch) - truth,
        );
        if case.scenario.sensors.acc_bias_mps2[0].abs() >= 0.1 {
            assert!(
                f.abs() < 0.5 * r.abs(),
                "seed {seed}: raw {r:+.3}, free {f:+.3}"
            );
        }
        raw.push(r);
        free.push(f);
    }
    // Measured: raw 0.74 deg rms, without the learnt bias 0.12 (what the stops have not
    // learnt of it, and its drift since the floor; the worst drive 0.26).
    assert!(rms(&raw) > 0.5, "these drives must carry a bias: {raw:?}");
    assert!(rms(&free) < 0.2, "{free:?}");
}

#[test]
fn an_imu_yawed_on_its_mount_owns_up_to_the_y_bias_no_stop_shows() {
    // Lanes without crossfall never show the y bias, and an IMU yawed psi on its mount
    // measures every window psi b / g off along its travel (1.5 deg and 0.25 m/s^2:
    // 0.038 deg), the same in every window. An INS-grade unit whose windows agree to a
    // standard error of about 0.015 deg would claim two or three times too much.
    let mut z = Vec::new();
    let mut by_sign = [0.0; 2];
    for seed in [3, 4, 5, 6] {
        for (k, by) in [0.25, -0.25].into_iter().enumerate() {
            let mut sc = ins_grade_urban(seed, |_| {});
            sc.sensors.acc_bias_mps2 = [0.0, by, 0.0];
            sc.vehicle.imu_mount_deg = [0.0, 0.0, 1.5];
            let drive = simulate(&sc);
            let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
            est.set_floor_roll_deg(Some(leveld::sim::floor_roll_deg(&sc)));
            for input in drive.merged() {
                match input {
                    Input::Imu(x) => est.push_imu(x, &mut |_| ()),
                    Input::Wheels(w) => est.push_wheels(w, &mut |_| ()),
                }
            }
            let e = est.estimate().unwrap();
            let t_end = drive.truth.last().unwrap().t_s;
            let err = e.road_to_body_deg - drive.truth_at(t_end).load_pitch_deg;
            by_sign[k] += err / 4.0;
            // A restart keeps what was unknown of the bias, and the yaw.
            let mut again = Estimator::new(EstimatorConfig::default()).unwrap();
            again.restore(&est.state()).unwrap();
            let se = again.estimate().unwrap().std_err_deg;
            assert!((se / e.std_err_deg - 1.0).abs() < 0.05, "{se} for {e:?}");
            z.push(err / e.std_err_deg);
        }
    }
    // The bias moves the estimate as psi b / g says: 0.0765 deg between +-0.25 m/s^2
    // (measured: 0.077).
    let split = by_sign[0] - by_sign[1];
    let psi_b = (1.5f64.to_radians() * 0.5 / 9.80665).to_degrees();
    assert!((split - psi_b).abs() < 0.2 * psi_b, "{by_sign:?}");
    // Measured: rms z 1.18; without the y bias in the standard error, 1.81 (two drives
    // 2.8 and 3.1 of it off).
    assert!(rms(&z) < 1.5, "{z:?}");
}

/// Deceleration-window errors of urban drives (12 stops, seeds 1101-1104, both loads)
/// with an INS-grade IMU on a body that rises `heave_mm` per m/s^2 of the force that
/// pitches it, deg.
fn heaving_body_decel_errors(heave_mm: f64) -> Vec<f64> {
    let r = RealisticSpec {
        heave_per_accel_mm: [heave_mm, heave_mm],
        ..RealisticSpec::default()
    };
    let mut errs = Vec::new();
    for seed in [1101, 1102, 1103, 1104] {
        let s = with_sensors(spec(seed, 12, r.clone()), ins_grade);
        for case in s.cases() {
            let only = Some(Condition::DecelBeforeStop);
            errs.extend(window_errors(&case, EstimatorConfig::default(), only));
        }
    }
    errs
}

/// A body that heaves as it pitches (2 mm per m/s^2, as anti-dive geometry or a pitch
/// node away from the centre of mass makes it) swings after a stop in a way rotation
/// about the pitch centre does not fully explain. A deceleration window starts at the
/// stop with the IMU's velocity there; read from the swing right at the stop it was
/// off by the heave's share, and these 73 windows sat +0.094 deg off on average (0.139
/// deg rms, 0.092 on the same drives without the heave). Read later in the stop, where
/// the swing has died out, and carried back by the quiet accelerometer: +0.017, 0.097.
/// Bounds: the mean within three standard errors of the windows' spread, the rms within
/// a fifth of the body that does not heave.
#[test]
fn a_body_that_heaves_as_it_pitches_does_not_bias_the_deceleration_windows() {
    let heaving = heaving_body_decel_errors(2.0);
    let level = heaving_body_decel_errors(0.0);
    assert!(
        heaving.len() >= 60,
        "{} deceleration windows",
        heaving.len()
    );
    let mean = heaving.iter().sum::<f64>() / heaving.len() as f64;
    let (r_heave, r_level) = (rms(&heaving), rms(&level));
    eprintln!(
        "heaving: {} windows, mean {mean:+.3}, rms {r_heave:.3}; not heaving: rms {r_level:.3}",
        heaving.len()
    );
    let bound = 3.0 * r_heave / (heaving.len() as f64).sqrt();
    assert!(mean.abs() < bound, "mean {mean:+.3}, bound {bound:.3}");
    assert!(
        r_heave < 1.2 * r_level,
        "rms {r_heave:.3} against {r_level:.3}"
    );
}

/// An INS-grade IMU next to an engine idling at 0.2 m/s^2 rms (25 Hz, at rest as in
/// motion), frames neither dropped nor late: the windows read as well as without the
/// engine. Counting the shaking as noise made the accelerometer look ten times worse
/// than it is (the velocity-free fit instead of the chord), means over spans that
/// were not a whole number of its periods kept mm/s^2 of it in the gravity magnitude
/// (0.1 deg of slope each on a gentle drive-off), and the first stop's magnitude held
/// to its first quarter-second.
#[test]
fn an_idling_engine_next_to_a_good_imu_leaves_its_windows_as_good() {
    let sensors = |x: &mut Sensors| {
        ins_grade(x);
        x.imu_drop_prob = 0.0;
        x.imu_jitter_ms = [0.0, 0.0];
    };
    let errs = |idle: f64| {
        let mut all = Vec::new();
        for seed in [1401, 1402, 1403] {
            let r = RealisticSpec {
                idle_vibration_mps2: idle,
                ..RealisticSpec::default()
            };
            for case in with_sensors(spec(seed, 10, r), sensors).cases() {
                all.extend(window_errors(&case, EstimatorConfig::default(), None));
            }
        }
        all
    };
    let (still, shaken) = (errs(0.0), errs(0.2));
    let (a, b) = (rms(&still), rms(&shaken));
    eprintln!(
        "windows {} / {}, rms {a:.3} / {b:.3}",
        still.len(),
        shaken.len()
    );
    // Measured: 94 windows at 0.085 deg rms without the engine, 92 at 0.091 with it;
    // 0.171 when the shaking counted as noise and the means kept it.
    assert!(
        shaken.len() * 10 >= still.len() * 9,
        "{} of {} windows",
        shaken.len(),
        still.len()
    );
    assert!(b < 1.25 * a, "rms {b:.3} with the engine, {a:.3} without");
}

#[test]
fn a_noise_free_imu_gives_brisk_drive_offs_after_short_stops_good_windows() {
    // A simulator's ideal IMU: no noise and no drift, biases kept. Stop-and-go seed 307
    // has stops of 1.1-1.4 s left at 0.9-1.2 m/s^2. Their windows take the gravity
    // magnitude from the filter along their own direction: one settled sample of a body
    // still moving, 74 mm/s^2 over it, had bent the filter's direction term (1.0 m/s^2
    // for a bias of 0.25), and these windows came out 0.3-1.9 deg off.
    let mut s = DriveSpec::parse(&shipped("stop-and-go")).unwrap();
    s.seed = 307;
    let s = with_sensors(s, |x| {
        x.acc_noise_ug_rthz = 0.0;
        x.acc_bias_walk_mps2_rts = 0.0;
        x.gyro_noise_dps_rthz = 0.0;
        x.gyro_bias_walk_dps_rts = 0.0;
    });
    let mut errs = Vec::new();
    for case in s.cases() {
        let plan = case
            .plan
            .clone()
            .expect("a realistic drive has a stop plan");
        let drive = simulate(&case.scenario);
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        est.set_floor_roll_deg(Some(leveld::sim::floor_roll_deg(&case.scenario)));
        let mut ev = Vec::new();
        for input in drive.merged() {
            match input {
                Input::Imu(x) => est.push_imu(x, &mut |e| ev.push(e)),
                Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
            }
        }
        // From the second stop on, whose gravity the filter holds from stops before; the
        // first one after the start (5P: +2.5 deg, another cause) is not this test's.
        for &(t_stop, t_go, kind, accel) in &plan.stops[2..] {
            if kind != StopKind::Full || t_go - t_stop > 2.0 || accel < 0.7 {
                continue;
            }
            errs.extend(ev.iter().filter_map(|e| match e {
                Event::WindowAccepted { window: w, .. }
                    if w.condition == Condition::AccelAfterStop
                        && w.t_s > t_go
                        && w.t_s < t_go + 15.0 =>
                {
                    Some(w.road_to_body_deg - drive.truth_at(w.reference_s).load_pitch_deg)
                }
                _ => None,
            }));
        }
    }
    eprintln!("{} windows: {errs:+.3?}", errs.len());
    // Measured: 5 windows at 0.08 deg rms; 4 at 1.16 with the filter's direction term
    // bent (updates not bounded). Noise-free brisk windows of settled stops are 0.06
    // deg rms over the family.
    assert!(errs.len() >= 4, "{} windows", errs.len());
    assert!(rms(&errs) < 0.25, "rms {:.3}", rms(&errs));
}

/// leveld, as configured by default, after the whole of `drive`.
fn fed(drive: &leveld::sim::Drive) -> Estimator {
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    for input in drive.merged() {
        match input {
            Input::Imu(x) => est.push_imu(x, &mut |_| {}),
            Input::Wheels(w) => est.push_wheels(w, &mut |_| {}),
        }
    }
    est
}

/// The pitch mode leveld learnt over a drive and the one simulated: (Hz, damping) each.
fn learnt_pitch_mode(name: &str, seed: u64, sets: &[&str]) -> ((f64, f64), (f64, f64)) {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let mut s = DriveSpec::parse_with(&shipped(name), &sets).unwrap();
    s.seed = seed;
    let case = s.cases().remove(0);
    let drive = simulate(&case.scenario);
    let m = fed(&drive)
        .pitch_mode()
        .expect("a drive of many stops shows its mode");
    let v = &case.scenario.vehicle;
    (
        (m.freq_hz(), m.damping_ratio()),
        (v.pitch_freq_hz, v.pitch_damping),
    )
}

/// The swing after each stop shows the body's pitch mode, on a sound suspension and on
/// worn dampers alike, with every sensor error, door shock and IMU gap of the family:
/// its frequency within 3 % and its damping within 12 % (measured: 0.2-2.0 % and
/// 1-6 %), and worn dampers (damping 0.12-0.18) read apart from sound ones (0.2-0.4).
#[test]
fn the_swing_after_the_stops_shows_the_bodys_pitch_mode_and_worn_dampers() {
    let worn = [
        "realistic.pitch_freq_hz=[0.9,1.0]",
        "realistic.pitch_damping=[0.12,0.18]",
    ];
    for (name, seed, sets) in [
        ("urban", 101, &[][..]),
        ("hilly", 205, &[][..]),
        ("urban", 102, &worn[..]),
        ("bumpy", 406, &worn[..]),
    ] {
        let ((hz, zeta), (sim_hz, sim_zeta)) = learnt_pitch_mode(name, seed, sets);
        eprintln!("{name} {seed}: {hz:.3} Hz {zeta:.3} for {sim_hz:.3} Hz {sim_zeta:.3}");
        assert!(
            (hz / sim_hz - 1.0).abs() < 0.03,
            "{name} {seed}: {hz} Hz for {sim_hz}"
        );
        assert!(
            (zeta / sim_zeta - 1.0).abs() < 0.12,
            "{name} {seed}: damping {zeta} for {sim_zeta}"
        );
        assert_eq!(zeta < 0.19, !sets.is_empty(), "{name} {seed}: {zeta}");
    }
}

/// The body's dive per m/s^2 of braking is learnt from the deceleration windows against
/// the pitch at rest where the walk left the reference. That is the first settled
/// sample, a turning point of the swing after the stop, on the same side of the rest
/// pitch at every stop: counted from there, the dive on stop-and-go (short brakes, the
/// swing largest against the dive) came out 0.83-0.93 of the simulated one with no
/// sensor error at all. Counted from the swing's centre, 0.93-1.00 (mean 0.96).
/// Bounds: every drive within 8 %, the mean within 5 %.
#[test]
fn the_dive_under_braking_is_counted_from_the_centre_of_the_swing_after_the_stop() {
    let quiet = [
        "sensors.acc_noise_ug_rthz=0",
        "sensors.gyro_noise_dps_rthz=0",
        "realistic.acc_bias_max_mps2=0",
        "realistic.gyro_bias_max_dps=0",
        "sensors.acc_bias_walk_mps2_rts=0",
        "sensors.gyro_bias_walk_dps_rts=0",
        "sensors.imu_drop_prob=0",
        "sensors.imu_jitter_ms=[0.0,0.0]",
        "realistic.road_roughness_1e6_m3=0.0",
        "realistic.vibration_mps2=0.0",
        "realistic.door_shock_share=0.0",
        "realistic.imu_gap_share=0.0",
    ]
    .map(String::from);
    let mut ratios = Vec::new();
    for seed in 301..305 {
        let mut s = DriveSpec::parse_with(&shipped("stop-and-go"), &quiet).unwrap();
        s.seed = seed;
        for case in s.cases() {
            let est = fed(&simulate(&case.scenario));
            ratios.push(est.pitch_per_force_deg() / case.scenario.vehicle.pitch_per_accel_deg);
        }
    }
    let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
    eprintln!("learnt over simulated dive: {ratios:.3?}, mean {mean:.3}");
    assert!(
        ratios.iter().all(|r| (r - 1.0).abs() < 0.08),
        "{ratios:.3?}"
    );
    assert!((mean - 1.0).abs() < 0.05, "mean {mean:.3}");
}

#[test]
fn the_stops_teach_no_accelerometer_bias_the_sensors_do_not_have() {
    // With a perfect IMU (no noise, bias or drift) every x bias the stops learn is the
    // body's own motion read as one: the rocking left in a stop's reference, a door
    // shock, a load ramping in. A settled reference of one second on stop-and-go 304 5P
    // took in six samples of a door shock as the stillness ended, 0.1 m/s^2 short of
    // gravity; at a stop 3 deg off the others' pitch that became an x bias of
    // -0.17 m/s^2 (1 deg on the end-of-line reference). Measured over these drives,
    // largest learnt bias after any stop: 0.007 m/s^2 (before: 0.17, and 0.052,
    // 0.042 and 0.018 on three other drives). The bound is 0.06 deg of reference.
    let perfect = [
        "sensors.acc_noise_ug_rthz=0",
        "sensors.acc_bias_walk_mps2_rts=0",
        "sensors.gyro_noise_dps_rthz=0",
        "sensors.gyro_bias_walk_dps_rts=0",
        "realistic.acc_bias_max_mps2=0",
        "realistic.gyro_bias_max_dps=0",
    ]
    .map(String::from);
    let mut cases = Vec::new();
    for (name, loads) in [("stop-and-go", ["1P", "5P"].as_slice()), ("bumpy", &["5P"])] {
        let mut s = DriveSpec::parse_with(&shipped(name), &perfect).unwrap();
        let base = s.seed;
        for k in 0..4 {
            s.seed = base + k;
            cases.extend(
                s.cases()
                    .into_iter()
                    .filter(|c| loads.contains(&c.load.as_str())),
            );
        }
    }
    let worst: Vec<(u64, String, f64)> = std::thread::scope(|sc| {
        let hs: Vec<_> = cases
            .iter()
            .map(|c| {
                sc.spawn(move || {
                    let drive = simulate(&c.scenario);
                    let learnt = drive_events(&drive)
                        .iter()
                        .filter_map(|e| match e {
                            Event::WindowsRebiased {
                                acc_bias_x_mps2, ..
                            } => Some(acc_bias_x_mps2.abs()),
                            _ => None,
                        })
                        .collect::<Vec<_>>();
                    assert!(learnt.len() >= 3, "seed {} {}: {learnt:?}", c.seed, c.load);
                    (
                        c.seed,
                        c.load.clone(),
                        learnt.iter().fold(0.0, |m, b| b.max(m)),
                    )
                })
            })
            .collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    });
    eprintln!("{worst:?}");
    let bad: Vec<_> = worst.iter().filter(|w| !(w.2 < 0.01)).collect();
    assert!(bad.is_empty(), "learnt x bias above 0.01 m/s^2: {bad:?}");
}

/// Drivers ease off the brake over the last second before rest: the car comes to rest
/// from a walking pace, below the wheels' dead zone, braking at 0.2-0.5 m/s^2, which
/// the IMU alone can take for rest a moment early. The attitude the standstill's motion
/// tracker starts from was taken over the last half-second and held that braking: the
/// tracker then saw the car pick up speed at rest, ended the standstill within a second
/// and never let another begin while the wheels read zero, so the stop was lost and the
/// load that came in at it too (urban, 4 seeds: 2 of 4 loads before drive-off, mean
/// error while VALID 0.154 deg against 0.044 with the stops braked to the end).
#[test]
fn a_stop_eased_to_rest_below_the_wheels_dead_zone_keeps_its_standstill_and_load() {
    let r = RealisticSpec {
        soft_stop_share: 1.0,
        ..brisk()
    };
    let (mut loads, mut applied, mut lost) = (0, 0, Vec::new());
    for seed in 51..59 {
        let mut s = spec(seed, 8, r.clone());
        s.load_change_at_stop = Some(4);
        let case = &s.cases()[1];
        let c = check(case, &valid);
        loads += c.load_changes;
        applied += c.load_applied;
        let drive = simulate(&case.scenario);
        let ev = drive_events(&drive);
        let plan = case.plan.as_ref().unwrap();
        for &(t_stop, t_go, kind, _) in &plan.stops[1..] {
            if kind != StopKind::Full {
                continue;
            }
            // The longest standstill within the stop.
            let mut begun = None;
            let mut held = 0.0f64;
            for e in &ev {
                match *e {
                    Event::StandstillStarted { t_s, .. } if t_s > t_stop && t_s < t_go => {
                        begun = Some(t_s)
                    }
                    Event::StandstillEnded { t_s, .. } => {
                        if let Some(t0) = begun.take() {
                            held = held.max(t_s - t0);
                        }
                    }
                    _ => {}
                }
            }
            // The drive ends at rest: its last standstill is still open.
            if let Some(t0) = begun {
                held = held.max(t_go - t0);
            }
            eprintln!(
                "seed {seed} stop at {t_stop:.1}: held {:.1} s of {:.1}",
                held,
                t_go - t_stop
            );
            if held < 0.5 * (t_go - t_stop) {
                lost.push((seed, t_stop));
            }
        }
    }
    eprintln!("{applied} of {loads} loads applied before drive-off; lost {lost:?}");
    assert!(
        lost.is_empty(),
        "stops without a standstill over half their length: {lost:?}"
    );
    assert_eq!(loads, 8);
    assert!(
        applied >= 7,
        "{applied} of {loads} loads applied before drive-off"
    );
}

/// A car that crawls to rest (0.05-0.12 m/s^2 over its last 2-4 s, below the wheels'
/// dead zone) is still rolling when the IMU turns quiet: the standstill begun then ends
/// as the car rolls on, and none follows while the wheels read zero. The walk begun at
/// that false drive-off covered its 3 m on drift while the car stood, and its window
/// was accepted: 4 of these 8 drives' 108 windows were 1.6-4.4 deg off. A real walk of
/// 3 m from rest ends faster than any wheel sensor's dead zone, so one that ends with
/// the wheels never having read a speed is refused.
#[test]
fn a_walk_the_wheels_never_saw_move_gives_no_window() {
    let r = RealisticSpec {
        soft_stop_share: 1.0,
        soft_stop_mps2: [0.05, 0.12],
        soft_stop_s: [2.0, 4.0],
        ..brisk()
    };
    let (mut windows, mut far) = (0, Vec::new());
    for seed in 51..55 {
        for load in 0..2 {
            let s = spec(seed, 8, r.clone());
            let drive = simulate(&s.cases()[load].scenario);
            for e in drive_events(&drive) {
                if let Event::WindowAccepted { window: w, .. } = e {
                    windows += 1;
                    let err = w.road_to_body_deg - drive.truth_at(w.t_s).load_pitch_deg;
                    // Single windows here are 0.2-0.5 deg rms: 1.5 deg is beyond noise.
                    if err.abs() > 1.5 {
                        far.push((seed, load, w.t_s, err));
                    }
                }
            }
        }
    }
    eprintln!("{} of {windows} windows beyond 1.5 deg", far.len());
    assert!(windows >= 40, "{windows} windows");
    assert!(far.is_empty(), "windows beyond 1.5 deg: {far:.2?}");
}
