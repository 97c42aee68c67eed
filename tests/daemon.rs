//! Daemon behaviour without a bus: config and DBC errors, calibration, input loss,
//! garbage frames, the systemd hardening bar.

use leveld::can::candump::{Line, parse_line};
use leveld::can::codec::Status;
use leveld::daemon::config::Config;
use leveld::daemon::pipeline::Pipeline;
use leveld::daemon::sink::{Notice, Sink};
use leveld::estimator::Event;
use leveld::sim::canlog::{InputEncoder, write_candump};
use leveld::sim::{Road, Scenario, Sensors, SpeedProfile, Vehicle};
use std::path::PathBuf;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn reference_toml() -> String {
    std::fs::read_to_string(root().join("config/leveld.toml")).unwrap()
}

fn tmp(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("leveld-daemon-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Write a config next to a copy of the reference DBC and try to load it.
fn load_variant(
    tag: &str,
    toml: &str,
    dbc: Option<&str>,
) -> anyhow::Result<(
    Config,
    leveld::can::dbc::Database,
    leveld::daemon::ConfigSource,
)> {
    let d = tmp(tag);
    let dbc_text = dbc
        .map(str::to_string)
        .unwrap_or_else(|| std::fs::read_to_string(root().join("dbc/leveld.dbc")).unwrap());
    std::fs::write(d.join("leveld.dbc"), dbc_text).unwrap();
    let toml = toml.replace("dbc = \"../dbc/leveld.dbc\"", "dbc = \"leveld.dbc\"");
    std::fs::write(d.join("leveld.toml"), toml).unwrap();
    leveld::daemon::load(Some(&d.join("leveld.toml")))
}

fn err_of(r: anyhow::Result<impl std::fmt::Debug>) -> String {
    format!("{:#}", r.expect_err("must fail"))
}

#[test]
fn reference_config_and_dbc_load() {
    let (cfg, db, _) = load_variant("ok", &reference_toml(), None).unwrap();
    let p = Pipeline::new(&cfg, &db).unwrap();
    assert_eq!(
        p.input_ids(),
        [(0x386, false), (0x3E0, false), (0x3E1, false)]
    );
    // Timeouts default to 10 x GenMsgCycleTime.
    assert!((p.input_codec(0).timeout_s - 0.2).abs() < 1e-12);
    assert!((p.input_codec(1).timeout_s - 0.1).abs() < 1e-12);
}

#[test]
fn config_mistakes_name_the_file_and_field() {
    // Each mistake: a name for its directory, the config text, and what the error
    // must name (the file or field, and the range or fix where there is one).
    let mistakes: Vec<(&str, String, &[&str])> = vec![
        (
            "syntax",
            "this is = = not toml".to_string(),
            &["leveld.toml"],
        ),
        (
            "unknown",
            reference_toml().replace("[state]", "[state]\nbogus = 1"),
            &["bogus"],
        ),
        (
            "count",
            reference_toml().replace("\"IMU_AccX\", ", ""),
            &["acc.signals", "needs 3"],
        ),
        (
            "est",
            reference_toml() + "gyro_bias_time_constant_s = 0.0\n",
            &["gyro_bias_time_constant_s"],
        ),
        (
            "bias-prior",
            reference_toml().replace("acc_bias_prior_mps2 = 0.2", "acc_bias_prior_mps2 = 0.0"),
            &["acc_bias_prior_mps2", "offset"],
        ),
        (
            "renamed",
            reference_toml() + "gyro_bias_alpha = 0.01\n",
            &["estimator.gyro_bias_alpha", "`gyro_bias_time_constant_s`"],
        ),
        (
            "share",
            reference_toml() + "short_stop_weight = 0.0\n",
            &["short_stop_weight"],
        ),
        (
            "age",
            reference_toml().replace(
                "max_wheel_speed_age_s = 0.15",
                "max_wheel_speed_age_s = -0.1",
            ),
            &["max_wheel_speed_age_s", "0..1 s"],
        ),
        (
            "chord",
            reference_toml() + "chord_below_acc_noise_ug_rthz = -1.0\n",
            &["chord_below_acc_noise_ug_rthz", "0..10000"],
        ),
        (
            "half",
            reference_toml() + "short_window_share = 1.0\n",
            &["short_window_share", "below 1"],
        ),
        (
            "noise-floor",
            reference_toml() + "chord_noise_sigmas = nan\n",
            &["chord_noise_sigmas", "0 (the configured limits alone)"],
        ),
        (
            "gate",
            reference_toml() + "rest_swing_gate_mps2 = -0.05\n",
            &["rest_swing_gate_mps2", "greater than 0"],
        ),
        (
            "act",
            reference_toml().replace("actuator_min_deg = -3.0", "actuator_min_deg = 5.0"),
            &["leveling.actuator_min_deg"],
        ),
    ];
    for (tag, toml, names) in mistakes {
        let e = err_of(load_variant(tag, &toml, None));
        for name in names {
            assert!(e.contains(name), "{tag}: {name:?} not in {e}");
        }
    }
}

#[test]
fn dbc_mistakes_are_clear() {
    let (cfg, db, _) = load_variant(
        "sig",
        &reference_toml().replace("\"IMU_RateZ\"", "\"IMU_RateW\""),
        None,
    )
    .unwrap();
    let e = format!("{:#}", Pipeline::new(&cfg, &db).unwrap_err());
    assert!(
        e.contains("IMU_RateW") && e.contains("IMU_RateZ"),
        "must name the missing and the known signals: {e}"
    );
    let (cfg, db, _) = load_variant(
        "msg",
        &reference_toml().replace("message = \"LEVELING\"", "message = \"LEVELLING\""),
        None,
    )
    .unwrap();
    let e = format!("{:#}", Pipeline::new(&cfg, &db).unwrap_err());
    assert!(e.contains("LEVELLING"), "{e}");
    let e = err_of(load_variant(
        "dbcsyntax",
        &reference_toml(),
        Some("VERSION \"x\"\nBO_ 902 WHL_SPD11: 8 ESC\n SG_ broken"),
    ));
    assert!(
        e.contains("leveld.dbc") && e.contains("does not parse"),
        "{e}"
    );
}

#[derive(Default)]
struct Collect {
    events: Vec<Event>,
    notices: Vec<Notice>,
    frames: Vec<(f64, [u8; 8])>,
}

impl Sink for Collect {
    fn event(&mut self, e: &Event) {
        self.events.push(*e);
    }
    fn notice(&mut self, n: &Notice) {
        self.notices.push(*n);
    }
    fn frame(&mut self, t: f64, _: u32, _: bool, d: &[u8; 8]) {
        self.frames.push((t, *d));
    }
}

fn frames_of(sc: &Scenario) -> Vec<leveld::can::candump::LogFrame> {
    let db = leveld::can::dbc::Database::load(&root().join("dbc/leveld.dbc")).unwrap();
    let mut enc = InputEncoder::new(&db).unwrap();
    let mut log = Vec::new();
    write_candump(
        &leveld::sim::simulate(sc),
        &mut enc,
        "vcan0",
        100.0,
        &mut log,
    )
    .unwrap();
    String::from_utf8(log)
        .unwrap()
        .lines()
        .map(|l| match parse_line(l) {
            Ok(Line::Frame(f)) => f,
            _ => panic!(),
        })
        .collect()
}

fn pipeline() -> Pipeline {
    let (cfg, db, _) = leveld::daemon::load(Some(&root().join("config/leveld.toml"))).unwrap();
    Pipeline::new(&cfg, &db).unwrap()
}

fn level_stand(seconds: f64, pitch: f64) -> Scenario {
    Scenario {
        speed: SpeedProfile::default().hold(seconds),
        road: Road::default(),
        load_pitch_deg: pitch,
        load_changes: vec![],
        vehicle: Vehicle::default(),
        sensors: Sensors::default(),
        shocks: Vec::new(),
        imu_gaps: Vec::new(),
        seed: 4,
    }
}

#[test]
fn calibration_on_a_level_floor_reads_the_mounting_pitch() {
    let mut sc = level_stand(12.0, 0.6);
    // Rolled 0.5 deg on its mount, left side up.
    sc.vehicle.imu_mount_deg = [0.5, 0.0, 0.0];
    let mut log = Vec::new();
    for f in frames_of(&sc) {
        log.extend_from_slice(format!("{}\n", leveld::can::candump::CandumpLine(&f)).as_bytes());
    }
    let mut p = pipeline();
    let cal = leveld::daemon::calibrate::from_log(&mut p, &mut &log[..], None, 5.0).unwrap();
    // 5 s at 300 ug/sqrt(Hz): the mean is good to well under 0.01 deg.
    assert!((cal.reference_pitch_deg - 0.6).abs() < 0.01, "{cal:?}");
    assert!((cal.reference_roll_deg - 0.5).abs() < 0.01, "{cal:?}");
    let d = tmp("cal");
    let (cal_path, state_path) = (d.join("calibration.json"), d.join("state.json"));
    leveld::daemon::calibrate::store(&mut p, &cal_path, &state_path, &cal).unwrap();
    // The reference lives in the calibration file; the state file holds the seeded estimate.
    assert_eq!(
        leveld::daemon::calibration::load(&cal_path).reference_pitch_deg(),
        Some(cal.reference_pitch_deg)
    );
    assert_eq!(
        leveld::daemon::calibration::load(&cal_path).reference_roll_deg(),
        Some(cal.reference_roll_deg)
    );
    match leveld::daemon::state::load(&state_path) {
        leveld::daemon::state::Loaded::State(s) => {
            assert_eq!(s.reference_pitch_deg, None);
            let mut q = pipeline();
            q.restore(&s.estimator).unwrap();
            assert_eq!(
                q.estimate().map(|e| e.road_to_body_deg),
                Some(cal.reference_pitch_deg)
            );
        }
        other => panic!("{other:?}"),
    }
    // Too short a standstill is refused with a reason.
    let short = level_stand(3.0, 0.6);
    let mut log = Vec::new();
    for f in frames_of(&short) {
        log.extend_from_slice(format!("{}\n", leveld::can::candump::CandumpLine(&f)).as_bytes());
    }
    let e =
        leveld::daemon::calibrate::from_log(&mut pipeline(), &mut &log[..], None, 5.0).unwrap_err();
    assert!(e.to_string().contains("still for only"), "{e}");
    // An IMU rolled or pitched beyond 10 deg is no mounting on a level floor: the
    // calibration is refused before anything is stored.
    for (mount, what) in [([15.0, 0.0, 0.0], "roll"), ([0.0, -12.0, 0.0], "pitch")] {
        let mut sc = level_stand(12.0, 0.0);
        sc.vehicle.imu_mount_deg = mount;
        let mut log = Vec::new();
        for f in frames_of(&sc) {
            log.extend_from_slice(
                format!("{}\n", leveld::can::candump::CandumpLine(&f)).as_bytes(),
            );
        }
        let cal =
            leveld::daemon::calibrate::from_log(&mut pipeline(), &mut &log[..], None, 5.0).unwrap();
        let e = cal.check_plausible().unwrap_err().to_string();
        assert!(
            e.contains(&format!("measured {what}")) && e.contains("implausible"),
            "{e}"
        );
    }
}

#[test]
fn the_level_correction_is_taken_against_a_floor_pitch_freed_of_the_accelerometer_bias() {
    // A hilly drive whose accelerometer reads 0.27 m/s^2 along x: the floor's raw pitch
    // is 1.6 deg above the road-to-body pitch the windows find, and the correction sent
    // for the floor's load must stay near zero all the same.
    let text = std::fs::read_to_string(root().join("scenarios/realistic/hilly.toml")).unwrap();
    let mut spec = leveld::bench::suite::DriveSpec::parse(&text).unwrap();
    spec.seed = 1106;
    let case = spec.cases().into_iter().find(|c| c.load == "1P").unwrap();
    let sc = case.scenario;
    assert!(
        sc.sensors.acc_bias_mps2[0] > 0.25,
        "{:?}",
        sc.sensors.acc_bias_mps2
    );
    let (floor_pitch, floor_roll) = leveld::sim::floor_attitude_deg(&sc);
    let mut p = pipeline();
    p.set_calibration(&leveld::daemon::calibration::Calibration::Calibrated {
        reference_pitch_deg: floor_pitch,
        reference_roll_deg: Some(floor_roll),
        legacy: false,
    });
    p.seed_calibration(floor_pitch, 4.0);
    let mut sink = Collect::default();
    for f in &frames_of(&sc) {
        p.on_can_frame(f.t_s, f, &mut sink);
    }
    let (_, last) = sink.frames.last().unwrap();
    let out = p.output().decode(last);
    let truth = leveld::sim::simulate(&sc).truth_at(0.0).load_pitch_deg;
    assert!(floor_pitch - truth > 1.4, "{floor_pitch} {truth}");
    // Measured: -0.01 deg (against the raw floor pitch, +1.57); road-to-body -0.02 off.
    assert!(out.level_correction_deg.abs() < 0.1, "{out:?}");
    assert!(
        (out.road_to_body_deg - truth).abs() < 0.1,
        "{out:?} {truth}"
    );
}

fn multi_stop() -> Scenario {
    leveld::sim::presets::preset("multi-stop", 5).unwrap()
}

fn status_of(p: &Pipeline, d: &[u8; 8]) -> Status {
    Status::from_raw(p.output().decode(d).status).unwrap()
}

#[test]
fn imu_loss_holds_the_value_and_recovers() {
    let frames = frames_of(&multi_stop());
    let (t_cut, t_back) = (100.0 + 150.0, 100.0 + 160.0);
    let mut p = pipeline();
    let mut sink = Collect::default();
    for f in &frames {
        if f.id != 0x386 && f.t_s > t_cut && f.t_s < t_back {
            continue; // IMU frames stop for 10 s
        }
        p.on_can_frame(f.t_s, f, &mut sink);
    }
    let lost_at = sink.notices.iter().find_map(|n| match n {
        Notice::InputLost {
            t_s,
            message: "acc",
        } => Some(*t_s),
        _ => None,
    });
    let lost_at = lost_at.expect("IMU loss must be noticed");
    // Within the 100 ms timeout plus one output period.
    assert!(
        lost_at > t_cut && lost_at <= t_cut + 0.1 + 0.1 + 1e-6,
        "{lost_at}"
    );
    let before: Vec<_> = sink.frames.iter().filter(|(t, _)| *t < t_cut).collect();
    let during: Vec<_> = sink
        .frames
        .iter()
        .filter(|(t, _)| *t > lost_at + 0.05 && *t < t_back)
        .collect();
    let after: Vec<_> = sink
        .frames
        .iter()
        .filter(|(t, _)| *t > t_back + 1.0)
        .collect();
    assert!(!during.is_empty());
    let held = p
        .output()
        .decode(&before.last().unwrap().1)
        .road_to_body_deg;
    for (t, d) in &during {
        assert_eq!(status_of(&p, d), Status::HoldInputLost, "at {t}");
        assert_eq!(
            p.output().decode(d).road_to_body_deg,
            held,
            "the last value is held"
        );
    }
    assert!(
        after
            .iter()
            .all(|(_, d)| status_of(&p, d) != Status::HoldInputLost),
        "it must recover"
    );
    assert!(
        sink.notices
            .iter()
            .any(|n| matches!(n, Notice::InputRestored { message: "acc", .. }))
    );
}

#[test]
fn bad_crc_wrong_dlc_and_unknown_ids_are_counted_and_not_used() {
    let frames = frames_of(&multi_stop());
    let mut p = pipeline();
    let mut sink = Collect::default();
    let (mut bad_crc, mut bad_dlc, mut unknown) = (0, 0, 0);
    for (i, f) in frames.iter().enumerate() {
        let mut g = *f;
        if f.id == 0x3E0 && i % 50 == 0 {
            g.data[7] ^= 0x5A; // CRC no longer matches
            bad_crc += 1;
        }
        if f.id == 0x3E1 && i % 77 == 0 {
            g.len = 6;
            bad_dlc += 1;
        }
        p.on_can_frame(g.t_s, &g, &mut sink);
        if i % 10 == 0 {
            let junk = leveld::can::candump::LogFrame::new(
                f.t_s,
                "vcan0",
                0x123 + (i as u32 % 7),
                false,
                &[1, 2, 3],
            );
            p.on_can_frame(f.t_s, &junk, &mut sink);
            unknown += 1;
        }
    }
    let acc = p.stats(1);
    let gyr = p.stats(2);
    assert_eq!(acc.checksum_errors, bad_crc);
    assert_eq!(gyr.dlc_errors, bad_dlc);
    assert_eq!(p.counters().ignored_frames, unknown);
    // Isolated bad frames do not invalidate the message and the drive still converges.
    assert!(p.estimate().is_some());
    assert_eq!(p.status(), Status::Valid, "{:?}", p.estimate());
}

#[test]
fn consecutive_checksum_failures_invalidate_the_message() {
    let frames = frames_of(&multi_stop());
    let mut p = pipeline();
    let mut sink = Collect::default();
    for f in &frames {
        let mut g = *f;
        if f.id == 0x386 && f.t_s > 130.0 && f.t_s < 131.0 {
            g.data[0] ^= 1;
        }
        p.on_can_frame(g.t_s, &g, &mut sink);
        if f.t_s > 130.2 && f.t_s < 130.9 {
            assert_eq!(p.status(), Status::HoldInputLost);
        }
    }
    assert!(sink.notices.iter().any(|n| matches!(
        n,
        Notice::MessageInvalid {
            message: "wheels",
            reason: "checksum",
            ..
        }
    )));
    assert_ne!(p.status(), Status::HoldInputLost);
}

#[test]
fn systemd_unit_exposure_is_at_most_2() {
    let unit = root().join("systemd/leveld.service");
    let out = std::process::Command::new("systemd-analyze")
        .args(["security", "--offline=true", "--no-pager"])
        .arg(&unit)
        .output()
        .expect("systemd-analyze must be installed (tools/test-all.sh installs it)");
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text
        .lines()
        .find(|l| l.contains("Overall exposure level"))
        .unwrap_or_else(|| panic!("{text}"));
    let level: f64 = line
        .split(':')
        .nth(1)
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(level <= 2.0, "{line}");
}

#[test]
fn a_mirrored_bus_takes_over_when_the_source_goes_silent() {
    let frames = frames_of(&multi_stop());
    let mut p = pipeline();
    let mut sink = Collect::default();
    // Everything arrives on both interfaces; interface 0 goes silent after 60 s.
    for f in &frames {
        if f.t_s < 160.0 {
            p.on_can_frame_from(0, f.t_s, f, &mut sink);
        }
        p.on_can_frame_from(1, f.t_s + 0.0001, f, &mut sink);
    }
    let w = p.stats(0);
    assert!(w.mirrored > 2000, "{w:?}");
    assert_eq!(
        w.timeouts, 1,
        "one loss, then interface 1 takes over: {w:?}"
    );
    assert_eq!((w.checksum_errors, w.counter_errors), (0, 0), "{w:?}");
    assert_eq!(p.status(), Status::Valid, "{:?}", p.estimate());
}

#[test]
fn an_unusable_estimator_state_keeps_the_calibration_and_the_file() {
    let d = tmp("badest");
    let path = d.join("state.json");
    let mut st = leveld::daemon::state::PersistedState {
        format: leveld::daemon::state::PersistedState::FORMAT,
        estimator: pipeline().estimator_state(),
        reference_pitch_deg: Some(0.37),
    };
    st.estimator.format = 99; // written by another version
    leveld::daemon::state::save(&path, &st).unwrap();
    let mut p = pipeline();
    assert_eq!(
        leveld::daemon::live::restore(&mut p, &path),
        Some(0.37),
        "the EOL reference must survive"
    );
    assert!(!path.exists());
    let moved = d.join("state.json.corrupt-1");
    let kept: serde_json::Value = serde_json::from_slice(&std::fs::read(moved).unwrap()).unwrap();
    assert_eq!(
        kept["estimator"]["format"], 99,
        "the bad file is moved aside, not deleted"
    );
    assert!(p.estimate().is_none(), "fresh estimator");
}
