//! Hostile input and hostile clocks: each reproducer of a defect found by mutating
//! logs, configs and timestamps, kept as a regression test.

use leveld::can::codec::Status;
use leveld::daemon::config::Config;
use leveld::daemon::pipeline::Pipeline;
use leveld::daemon::replay::{ReplayOptions, Summary, replay};
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn pipeline() -> Pipeline {
    let (cfg, db, _) = leveld::daemon::load(Some(&root().join("config/leveld.toml"))).unwrap();
    Pipeline::new(&cfg, &db).unwrap()
}

fn run(log: &[u8]) -> (Summary, String, usize) {
    let mut p = pipeline();
    let (mut events, mut frames) = (Vec::new(), Vec::new());
    let opts = ReplayOptions::default();
    let s = replay(&mut p, &mut &log[..], &opts, &mut events, Some(&mut frames)).unwrap();
    let n = frames.iter().filter(|&&b| b == b'\n').count();
    (s, String::from_utf8(events).unwrap(), n)
}

fn drive() -> Vec<u8> {
    std::fs::read(root().join("data/sim-multi-stop.log")).unwrap()
}

/// Replace the timestamp of line `n` (1-based) with `t`.
fn restamp(log: &[u8], n: usize, t: &str) -> Vec<u8> {
    let text = String::from_utf8(log.to_vec()).unwrap();
    let mut out = String::new();
    for (i, l) in text.lines().enumerate() {
        if i + 1 == n {
            let close = l.find(')').unwrap();
            out.push_str(&format!("({t}{}", &l[close..]));
        } else {
            out.push_str(l);
        }
        out.push('\n');
    }
    out.into_bytes()
}

#[test]
fn a_timestamp_of_2_pow_50_neither_hangs_nor_floods() {
    let (s, _, frames) = run(b"(1.0) can0 3E0#00\n(1125899906842624.0) can0 3E0#00\n");
    assert_eq!(s.lines, 2);
    assert_eq!(s.malformed_lines, 1, "a timestamp past 1e11 s is refused");
    assert!(frames <= 2, "{frames} LEVELING frames");
}

#[test]
fn a_huge_jump_that_parses_is_a_counted_clock_step() {
    let log = b"(1.0) can0 3E0#00\n(99999999999.0) can0 3E0#00\n(1.1) can0 3E0#00\n";
    let (s, events, frames) = run(log);
    assert_eq!(s.clock_steps, 2, "there and back");
    assert!(events.contains("clock step"), "{events}");
    assert!(frames <= 3, "{frames} LEVELING frames");
}

#[test]
fn one_stray_timestamp_does_not_freeze_the_clock() {
    let clean = run(&drive());
    let (first_input, wheel_line) = {
        // Line 101 of the drive, and the first wheel-speed line after it.
        let text = String::from_utf8(drive()).unwrap();
        let w = text
            .lines()
            .enumerate()
            .skip(101)
            .find(|(_, l)| l.contains(" 386#"))
            .unwrap()
            .0
            + 1;
        (101, w)
    };
    for n in [first_input, wheel_line] {
        let log = drive();
        let line = String::from_utf8(log.clone())
            .unwrap()
            .lines()
            .nth(n - 1)
            .unwrap()
            .to_string();
        let t: f64 = line[1..line.find(')').unwrap()].parse().unwrap();
        let (s, _, frames) = run(&restamp(&log, n, &format!("{:.6}", t + 8.0)));
        assert_eq!(s.clock_steps, 2, "line {n}: one step out, one back");
        assert_eq!(s.malformed_lines, 0);
        // The output goes on at 10 Hz; the estimate is what the clean log gives.
        assert!(
            frames as f64 >= 0.99 * clean.2 as f64,
            "line {n}: {frames} LEVELING frames, {} without the stray stamp",
            clean.2
        );
        let (a, b) = (
            s.final_state.road_to_body_pitch_deg.unwrap(),
            clean.0.final_state.road_to_body_pitch_deg.unwrap(),
        );
        assert!((a - b).abs() < 0.05, "line {n}: {a} vs {b}");
        assert!(
            s.estimates_accepted + 2 >= clean.0.estimates_accepted,
            "line {n}: {} windows vs {}",
            s.estimates_accepted,
            clean.0.estimates_accepted
        );
        assert_eq!(s.final_state.status, clean.0.final_state.status);
    }
}

#[test]
fn invalid_utf8_and_overlong_lines_are_counted_malformed_lines() {
    let mut log = b"(1.0) can0 3E0#D5\xff\n".to_vec();
    log.extend(std::iter::repeat_n(b'A', 5_000_000));
    log.extend_from_slice(b"\n(1.1) can0 3E0#00\n");
    let (s, _, _) = run(&log);
    assert_eq!((s.lines, s.malformed_lines), (3, 2));
    assert_eq!(s.malformed_examples, vec![1, 2]);
    assert_eq!(s.frames, 1);
}

#[test]
fn many_interfaces_are_looked_up_in_constant_time() {
    let mut log = String::new();
    for i in 0..40_000 {
        log.push_str(&format!("({}.{:06}) c{i} 3E0#00\n", 1 + i / 1000, i % 1000));
    }
    let t = std::time::Instant::now();
    let (s, _, _) = run(log.as_bytes());
    assert_eq!(s.frames, 40_000);
    // Quadratic lookup took 11 s here; a hash map takes milliseconds. The bound is
    // generous for slow machines and still far below quadratic.
    assert!(t.elapsed().as_secs_f64() < 3.0, "{:?}", t.elapsed());
}

#[test]
fn a_bus_off_error_frame_in_a_log_gives_fault_until_restart() {
    let mut log = String::from_utf8(drive()).unwrap();
    let lines: Vec<&str> = log.lines().collect();
    let cut = lines.len() / 2;
    let t: f64 = lines[cut][1..lines[cut].find(')').unwrap()]
        .parse()
        .unwrap();
    let mut out = String::new();
    for (i, l) in lines.iter().enumerate() {
        out.push_str(l);
        out.push('\n');
        if i == cut {
            out.push_str(&format!("({:.6}) can0 20000040#0000000000000000\n", t));
        }
    }
    log = out;
    let mut p = pipeline();
    let (mut events, mut frames) = (Vec::new(), Vec::new());
    let opts = ReplayOptions {
        strict: true,
        ..Default::default()
    };
    let s = replay(
        &mut p,
        &mut log.as_bytes(),
        &opts,
        &mut events,
        Some(&mut frames),
    )
    .unwrap();
    assert_eq!(s.malformed_lines, 0, "candump -e lines are frames");
    assert_eq!(s.final_state.status, Status::Fault);
    assert!(String::from_utf8(events).unwrap().contains("bus off"));
    // ... and a controller restart clears it.
    let mut p2 = pipeline();
    let restarted = format!("{log}({:.6}) can0 20000100#0000000000000000\n", t + 1e3);
    let (mut e2, mut f2) = (Vec::new(), Vec::new());
    let s2 = replay(
        &mut p2,
        &mut restarted.as_bytes(),
        &opts,
        &mut e2,
        Some(&mut f2),
    )
    .unwrap();
    assert_ne!(s2.final_state.status, Status::Fault);
}

fn config_error(edit: &dyn Fn(&str) -> String) -> String {
    let text = std::fs::read_to_string(root().join("config/leveld.toml")).unwrap();
    let path = root().join("config/leveld.toml");
    match Config::parse(&path, &edit(&text)) {
        Ok(_) => String::new(),
        Err(e) => e.to_string(),
    }
}

fn set(text: &str, section: &str, line: &str) -> String {
    let head = format!("[{section}]\n");
    match text.find(&head) {
        Some(i) => {
            let at = i + head.len();
            format!("{}{line}\n{}", &text[..at], &text[at..])
        }
        None => format!("{text}\n{head}{line}\n"),
    }
}

#[test]
fn check_config_refuses_values_that_break_the_daemon() {
    let cases: &[(&str, &str, &str)] = &[
        ("estimator", "still_window_s = 1e6", "still_window_s"),
        ("estimator", "still_window_s = 1e15", "still_window_s"),
        ("estimator", "still_window_s = 1e300", "still_window_s"),
        (
            "leveling",
            "valid_max_std_err_deg = nan",
            "valid_max_std_err_deg",
        ),
        (
            "leveling",
            "valid_max_std_err_deg = -1.0",
            "valid_max_std_err_deg",
        ),
        ("leveling", "valid_min_windows = inf", "valid_min_windows"),
        ("leveling", "valid_min_windows = -3.0", "valid_min_windows"),
        ("leveling", "max_clock_step_s = 0.0", "max_clock_step_s"),
        (
            "estimator",
            "acc_matrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.3, 0.0, 1.0]]",
            "acc_matrix[2][0]",
        ),
        (
            "estimator",
            "acc_matrix = [[1.0, 0.0, 0.0], [0.0, nan, 0.0], [0.0, 0.0, 1.0]]",
            "acc_matrix[1][1]",
        ),
    ];
    for (section, line, field) in cases {
        let e = config_error(&|t| set(t, section, line));
        assert!(e.contains(field), "{line}: {e:?}");
    }
    // The shipped file sets the vehicle's geometry; a wheelbase or pitch centre that no
    // car has is refused by name.
    for (from, to, field) in [
        ("wheelbase_m = 2.7", "wheelbase_m = 0.0", "wheelbase_m"),
        ("wheelbase_m = 2.7", "wheelbase_m = nan", "wheelbase_m"),
        (
            "pitch_centre_share = 0.5",
            "pitch_centre_share = 1.5",
            "pitch_centre_share",
        ),
    ] {
        assert!(
            std::fs::read_to_string(root().join("config/leveld.toml"))
                .unwrap()
                .contains(from)
        );
        let e = config_error(&|t| t.replacen(from, to, 1));
        assert!(e.contains(field), "{to}: {e:?}");
    }
    for kind in ["none", "hyundai_whl_spd"] {
        let e = config_error(&|t| {
            let (head, out) = t.split_at(t.find("[output]").unwrap());
            let out = out.replacen(
                "checksum_kind = \"crc8_sae_j1850\"",
                &format!("checksum_kind = \"{kind}\""),
                1,
            );
            format!("{head}{out}")
        });
        assert!(e.contains("output.checksum_kind"), "{kind}: {e:?}");
    }
    for (from, to, field) in [
        ("path = \"", "path = \"\" #", "state.path"),
        (
            "output_interface = \"",
            "output_interface = \"\" #",
            "can.output_interface",
        ),
        (
            "output_interface = \"",
            "output_interface = \"abcdefghijklmnopqrstuvwxyzabcdefghijklmn\" #",
            "can.output_interface",
        ),
    ] {
        let e = config_error(&|t| t.replacen(from, to, 1));
        assert!(e.contains(field), "{to}: {e:?}");
    }
}

#[test]
fn calibration_needs_a_real_standstill_duration() {
    for d in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let e = leveld::daemon::calibrate::check_duration(d).unwrap_err();
        assert!(e.to_string().contains("--duration"), "{e}");
    }
    assert!(leveld::daemon::calibrate::check_duration(30.0).is_ok());
    let _ = Path::new(".");
}

#[test]
fn dbc_files_in_windows_1252_or_with_a_bom_load() {
    use leveld::can::dbc::Database;
    let text = std::fs::read(root().join("dbc/leveld.dbc")).unwrap();
    let dir = std::env::temp_dir().join(format!("leveld-dbc-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut latin = text.clone();
    latin.extend_from_slice(b"\nCM_ \"Au\xdfentemperatur in \xb0C \x96 gepr\xfcft\";\n");
    let mut bom = b"\xEF\xBB\xBF".to_vec();
    bom.extend_from_slice(&text);
    for (name, bytes) in [("latin.dbc", latin), ("bom.dbc", bom)] {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        let db = Database::load(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(db.message("WHL_SPD11").is_ok(), "{name}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Issue reproducers: DBC files that loaded and then decoded the wrong bits, or
/// overflowed in debug builds. Each is refused with the message and what is allowed.
#[test]
fn dbc_defects_in_the_messages_leveld_reads_are_refused_with_the_line() {
    use leveld::can::dbc::Database;
    let dbc = std::fs::read_to_string(root().join("dbc/leveld.dbc")).unwrap();
    let cfg = Config::parse(
        &root().join("config/leveld.toml"),
        &std::fs::read_to_string(root().join("config/leveld.toml")).unwrap(),
    )
    .unwrap();
    let refused = |text: String| -> String {
        match Database::parse(Path::new("edited.dbc"), &text) {
            Err(e) => format!("parse: {e}"),
            Ok(db) => match Pipeline::new(&cfg, &db) {
                Ok(_) => String::new(),
                Err(e) => format!("{e:#}"),
            },
        }
    };
    let cases: &[(&str, &str, &str)] = &[
        // 66438 = 0x10386: the parser keeps 16 bits and read it as WHL_SPD11's 0x386.
        (
            "BO_ 902 WHL_SPD11:",
            "BO_ 66438 WHL_SPD11:",
            "line 16: message `WHL_SPD11` has ID 66438",
        ),
        ("BO_ 992 IMU_ACC:", "BO_ 2100 IMU_ACC:", "at most 0x7FF"),
        (
            "BO_ 993 IMU_GYR:",
            "BO_ 992 IMU_GYR:",
            "as has `IMU_GYR` on line 33",
        ),
        (
            " SG_ WHL_SPD_FL : 0|14@1+",
            " SG_ WHL_SPD_FL : 0|65@1+",
            "1 to 64",
        ),
        (
            " SG_ WHL_SPD_FL : 0|14@1+",
            " SG_ WHL_SPD_FL : 0|0@1+",
            "1 to 64",
        ),
        (
            " SG_ IMU_AccX : 0|16@1-",
            " SG_ IMU_AccX : 70000|16@1-",
            "past any frame",
        ),
        (
            " SG_ IMU_AccX : 0|16@1-",
            " SG_ IMU_AccX : 60|16@1-",
            "does not fit",
        ),
        (
            "(0.001,0) [-32.768|32.767] \"m/s^2\" LEVELD\n SG_ IMU_AccY",
            "(0,0) [-32.768|32.767] \"m/s^2\" LEVELD\n SG_ IMU_AccY",
            "factor 0",
        ),
        (
            " SG_ WHL_SPD_FR : 16|14@1+",
            " SG_ WHL_SPD_FR : 8|14@1+",
            "share bits",
        ),
        (
            " SG_ IMU_RateZ : 32|16@1-",
            " SG_ IMU_RateZ : 44|16@1-",
            "share bits",
        ),
        (
            " SG_ IMU_AccZ : 32|16@1-",
            " SG_ IMU_Mux M : 52|4@1+ (1,0) [0|15] \"\" LEVELD\n SG_ IMU_AccZ m1 : 32|16@1-",
            "multiplexed",
        ),
        (" SG_ CRC : 56|8@1+", " SG_ CRC : 52|8@1+", "byte 7"),
        ("BO_ 1000 LEVELING: 8", "BO_ 1000 LEVELING: 6", "8-byte"),
    ];
    assert_eq!(refused(dbc.clone()), "", "the reference DBC loads");
    for (from, to, expect) in cases {
        assert!(dbc.contains(from), "{from}");
        let e = refused(dbc.replacen(from, to, 1));
        assert!(e.contains(expect), "{to}: {e:?}");
    }
    // One signal in two roles (config side).
    let mut twice = cfg.clone();
    twice.wheels.signals[1] = twice.wheels.signals[0].clone();
    let db = Database::parse(Path::new("leveld.dbc"), &dbc).unwrap();
    let e = format!("{:#}", Pipeline::new(&twice, &db).unwrap_err());
    assert!(e.contains("two roles"), "{e}");
}
