//! Replays through the configured pipeline: the real Kona capture, a simulated drive
//! with truth, and bad input.

use leveld::can::candump::{Line, parse_line};
use leveld::can::codec::Status;
use leveld::daemon::pipeline::Pipeline;
use leveld::daemon::replay::{ReplayOptions, Summary, replay};
use leveld::sim::canlog::{InputEncoder, write_candump};
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn pipeline() -> Pipeline {
    let (cfg, db, _) = leveld::daemon::load(Some(&root().join("config/leveld.toml"))).unwrap();
    Pipeline::new(&cfg, &db).unwrap()
}

fn run(log: &[u8], opts: &ReplayOptions) -> (Summary, Vec<u8>, Vec<u8>, Pipeline) {
    let mut p = pipeline();
    let (mut events, mut frames) = (Vec::new(), Vec::new());
    let s = replay(&mut p, &mut &log[..], opts, &mut events, Some(&mut frames)).unwrap();
    (s, events, frames, p)
}

fn kona() -> Vec<u8> {
    std::fs::read(root().join("tests/data/kona-ev-2019-ccan-power-cycle.log")).unwrap()
}

#[test]
fn kona_wheel_speeds_decode_clean_and_standstill_is_seen() {
    let opts = ReplayOptions {
        interface: Some("can1".into()),
        json: true,
        ..Default::default()
    };
    let (s, events, _, _) = run(&kona(), &opts);
    assert_eq!(s.lines, 39_546);
    assert_eq!(s.malformed_lines, 0);
    let w = s.messages["WHL_SPD11"];
    assert_eq!(
        (
            w.frames,
            w.checksum_errors,
            w.counter_errors,
            w.dlc_errors,
            w.timeouts
        ),
        (542, 0, 0, 0, 0)
    );
    // Everything else on can1 is ignored without error.
    assert_eq!(s.ignored_frames, s.frames - 542);
    let ev = String::from_utf8(events).unwrap();
    assert!(
        ev.contains("\"event\":\"wheels_stopped\""),
        "standstill must be detected from the wheels"
    );
    assert_eq!(s.estimates_accepted, 0, "the car never moves");
    assert!(s.final_state.road_to_body_pitch_deg.is_none());
    // The capture has no IMU: that is input loss, not a silent NO_ESTIMATE.
    assert_eq!(s.final_state.status, Status::HoldInputLost);
}

#[test]
fn kona_with_every_interface_takes_the_wheel_message_from_one_bus() {
    // Without --interface every bus is read. The gateway mirrors the ESC frames onto
    // can0; the copies are counted as mirrored, not decoded twice.
    let (s, _, _, _) = run(&kona(), &ReplayOptions::default());
    let w = s.messages["WHL_SPD11"];
    assert_eq!(
        (
            w.frames,
            w.checksum_errors,
            w.counter_errors,
            w.dlc_errors,
            w.mirrored
        ),
        (542, 0, 0, 0, 542)
    );
    assert_eq!(s.malformed_lines, 0);
}

#[test]
fn a_corrupted_wheel_frame_is_counted_not_used() {
    let text = String::from_utf8(kona()).unwrap();
    let mut done = false;
    let patched: String = text
        .lines()
        .map(|l| {
            if !done && l.contains("can1 386#") {
                done = true;
                let (head, data) = l.split_once('#').unwrap();
                let b0 = u8::from_str_radix(&data[..2], 16).unwrap() ^ 0x01;
                format!("{head}#{b0:02X}{}\n", &data[2..])
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    let opts = ReplayOptions {
        interface: Some("can1".into()),
        ..Default::default()
    };
    let (s, _, _, _) = run(patched.as_bytes(), &opts);
    let w = s.messages["WHL_SPD11"];
    assert_eq!((w.frames, w.checksum_errors, w.counter_errors), (542, 1, 0));
}

#[test]
fn malformed_lines_are_counted_with_line_numbers_and_fatal_only_when_strict() {
    let log = "(1.000000) can1 386#0000C00000400000\ngarbage\n(1.020000) can1 386#00\n(1.x) can1 386#00\n";
    let (s, _, _, _) = run(log.as_bytes(), &ReplayOptions::default());
    assert_eq!(s.malformed_lines, 2);
    assert_eq!(s.malformed_examples, vec![2, 4]);
    assert_eq!(s.messages["WHL_SPD11"].dlc_errors, 1);
    let strict = ReplayOptions {
        strict: true,
        ..Default::default()
    };
    let mut p = pipeline();
    let err = replay(&mut p, &mut log.as_bytes(), &strict, &mut Vec::new(), None).unwrap_err();
    assert!(format!("{err:#}").contains("line 2"), "{err:#}");
}

/// A simulated multi-stop drive written through the DBC, with its truth.
fn simulated(preset: &str, seed: u64) -> (Vec<u8>, leveld::sim::Drive, f64) {
    let sc = leveld::sim::presets::preset(preset, seed).unwrap();
    let drive = leveld::sim::simulate(&sc);
    let db = leveld::can::dbc::Database::load(&root().join("dbc/leveld.dbc")).unwrap();
    let mut enc = InputEncoder::new(&db).unwrap();
    let mut log = Vec::new();
    let t0 = 1000.0;
    write_candump(&drive, &mut enc, "vcan0", t0, &mut log).unwrap();
    (log, drive, t0)
}

#[test]
fn simulated_drive_leveling_output_matches_truth_once_valid() {
    let (log, drive, t0) = simulated("multi-stop", 7);
    let (s, _, frames, p) = run(&log, &ReplayOptions::default());
    assert_eq!(s.malformed_lines, 0);
    for m in s.messages.values() {
        assert_eq!(
            (
                m.checksum_errors,
                m.counter_errors,
                m.dlc_errors,
                m.timeouts
            ),
            (0, 0, 0, 0),
            "{m:?}"
        );
    }
    assert!(s.estimates_accepted >= 10, "{s:?}");
    // The summary says what was learnt of the suspension: this body's dive per m/s^2
    // of braking and its squat pulling away (alike here), to within a tenth.
    let vehicle = leveld::sim::presets::preset("multi-stop", 7)
        .unwrap()
        .vehicle;
    let sim_k = vehicle.pitch_per_accel_deg;
    let susp = s.final_state.suspension;
    eprintln!("{susp:?} for {vehicle:?}");
    assert!(
        (susp.pitch_per_braking_deg_per_mps2 - sim_k).abs() < 0.1 * sim_k,
        "{susp:?} for a body of {sim_k} deg per m/s^2"
    );
    assert!(
        (susp.pitch_per_drive_deg_per_mps2 - sim_k).abs() < 0.1 * sim_k,
        "{susp:?} for a body of {sim_k} deg per m/s^2"
    );
    // And the body's pitch mode from its swing after the stops.
    let (hz, zeta) = (
        susp.pitch_mode_hz.expect("learnt"),
        susp.pitch_mode_damping.expect("learnt"),
    );
    assert!(
        (hz / vehicle.pitch_freq_hz - 1.0).abs() < 0.02,
        "{susp:?} for {vehicle:?}"
    );
    assert!(
        (zeta / vehicle.pitch_damping - 1.0).abs() < 0.15,
        "{susp:?} for {vehicle:?}"
    );
    let out = p.output().clone();
    let mut seen_valid = 0;
    let mut statuses = Vec::new();
    let mut last_t = None;
    for line in String::from_utf8(frames).unwrap().lines() {
        let Ok(Line::Frame(f)) = parse_line(line) else {
            panic!("bad output line {line}")
        };
        assert_eq!(f.id, 0x3E8);
        if let Some(t) = last_t {
            assert!(f.t_s >= t, "output in time order");
        }
        last_t = Some(f.t_s);
        let d: [u8; 8] = f.payload().try_into().unwrap();
        let lv = out.decode(&d);
        assert!(lv.crc_ok);
        let st = Status::from_raw(lv.status).unwrap();
        if statuses.last() != Some(&st) {
            statuses.push(st);
        }
        if st == Status::Valid {
            seen_valid += 1;
            let truth = drive.truth_at(f.t_s - t0).load_pitch_deg;
            assert!(
                (lv.road_to_body_deg - truth).abs() < 0.2,
                "at {}: {} vs truth {truth}",
                f.t_s,
                lv.road_to_body_deg
            );
            // LevelCorrection is -(pitch - reference) with the default reference 0.
            assert!((lv.level_correction_deg + lv.road_to_body_deg).abs() <= 0.011);
        }
    }
    assert!(seen_valid > 100, "VALID must be reached and held");
    assert_eq!(
        statuses,
        vec![Status::NoEstimate, Status::Converging, Status::Valid],
        "{statuses:?}"
    );
}

#[test]
fn output_counter_steps_mod_16_at_10_hz() {
    let (log, _, _) = simulated("multi-stop", 3);
    let (_, _, frames, p) = run(&log, &ReplayOptions::default());
    let out = p.output().clone();
    let mut prev: Option<(f64, u64)> = None;
    let mut periodic = 0usize;
    let mut n = 0usize;
    for line in String::from_utf8(frames).unwrap().lines() {
        let Ok(Line::Frame(f)) = parse_line(line) else {
            panic!()
        };
        let lv = out.decode(&f.payload().try_into().unwrap());
        if let Some((t, c)) = prev {
            assert_eq!(lv.counter, (c + 1) % 16);
            let dt = f.t_s - t;
            assert!(dt <= 0.1 + 1e-6, "gap {dt}");
            if (dt - 0.1).abs() < 1e-6 {
                periodic += 1;
            }
        }
        prev = Some((f.t_s, lv.counter));
        n += 1;
    }
    // All but the on-change frames keep the 100 ms grid.
    assert!(periodic as f64 > 0.97 * n as f64, "{periodic} of {n}");
}

#[test]
fn replay_is_deterministic() {
    let (log, _, _) = simulated("load-change", 2);
    let a = run(
        &log,
        &ReplayOptions {
            json: true,
            ..Default::default()
        },
    );
    let b = run(
        &log,
        &ReplayOptions {
            json: true,
            ..Default::default()
        },
    );
    assert_eq!(a.1, b.1);
    assert_eq!(a.2, b.2);
    assert!(!a.2.is_empty());
}

#[test]
fn config_dbc_path_is_relative_to_the_config_file() {
    let (cfg, _, _) =
        leveld::daemon::load(Some(Path::new(&root().join("config/leveld.toml")))).unwrap();
    assert!(
        cfg.can.dbc.ends_with("config/../dbc/leveld.dbc"),
        "{:?}",
        cfg.can.dbc
    );
}

/// Run python3 with cantools; the test command installs it.
fn python(script: &str, args: &[&str]) -> String {
    let out = std::process::Command::new("python3")
        .arg("-c")
        .arg(script)
        .args(args)
        .output()
        .expect("python3 must be installed (tools/test-all.sh installs it)");
    assert!(
        out.status.success(),
        "python failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn reference_dbc_loads_in_cantools_strict_without_warnings() {
    let dbc = root().join("dbc/leveld.dbc");
    let out = python(
        "import sys, warnings, cantools\nwarnings.simplefilter('error')\ndb = cantools.database.load_file(sys.argv[1], strict=True)\nprint(sorted((m.name, m.frame_id, m.cycle_time) for m in db.messages))",
        &[dbc.to_str().unwrap()],
    );
    assert_eq!(
        out.trim(),
        "[('IMU_ACC', 992, 10), ('IMU_GYR', 993, 10), ('LEVELING', 1000, 100), ('WHL_SPD11', 902, 20)]"
    );
}

#[test]
fn cantools_decodes_the_output_log_as_leveld_does() {
    let (log, _, _) = simulated("multi-stop", 11);
    let (_, _, frames, p) = run(&log, &ReplayOptions::default());
    let dir = std::env::temp_dir().join(format!("leveld-cantools-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("out.log");
    std::fs::write(&path, &frames).unwrap();
    let script = r#"
import sys, cantools, json
db = cantools.database.load_file(sys.argv[1], strict=True)
m = db.get_message_by_name('LEVELING')
for line in open(sys.argv[2]):
    data = bytes.fromhex(line.split('#')[1].strip())
    d = m.decode(data, decode_choices=False)
    print(json.dumps([d[k] for k in ('RoadToBodyPitch', 'LevelCorrection', 'RoadSlope', 'EstimateCount', 'Status', 'Counter', 'CRC')]))
"#;
    let out = python(
        script,
        &[
            root().join("dbc/leveld.dbc").to_str().unwrap(),
            path.to_str().unwrap(),
        ],
    );
    let theirs: Vec<Vec<f64>> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let ours: Vec<Vec<f64>> = String::from_utf8(frames)
        .unwrap()
        .lines()
        .map(|l| {
            let Ok(Line::Frame(f)) = parse_line(l) else {
                panic!()
            };
            let v = p.output().decode(&f.payload().try_into().unwrap());
            vec![
                v.road_to_body_deg,
                v.level_correction_deg,
                v.road_slope_deg,
                v.estimate_count as f64,
                v.status as f64,
                v.counter as f64,
                v.crc as f64,
            ]
        })
        .collect();
    assert_eq!(theirs.len(), ours.len());
    assert!(ours.len() > 1000);
    for (a, b) in theirs.iter().zip(&ours) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() < 1e-9, "{a:?} vs {b:?}");
        }
    }
}

#[test]
fn simulate_drive_writes_a_benchmark_scenario_and_names_its_load_cases() {
    let dir = std::env::temp_dir().join(format!("leveld-simdrive-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("sg.log");
    let sim = |load: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_leveld"))
            .current_dir(root())
            .args([
                "simulate",
                "drive",
                "--scenario",
                "scenarios/realistic/stop-and-go.toml",
            ])
            .args(["--load", load, "--interface", "can0", "-o"])
            .arg(&log)
            .output()
            .unwrap()
    };
    let ok = sim("5P");
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    let text = std::fs::read_to_string(&log).unwrap();
    // The three configured inputs are all in the log.
    for id in [" can0 386#", " can0 3E0#", " can0 3E1#"] {
        assert!(text.contains(id), "no {id} frames");
    }
    let bad = sim("7P");
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.contains("no load case `7P`") && err.contains("1P, 5P"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
