//! Replay of the real Kona EV capture through the reference DBC.

use leveld::can::dbc::Database;
use leveld::daemon::gateway::{Gateway, InputCodecs};
use leveld::daemon::replay::{ReplayOptions, replay};
use leveld::estimator::EstimatorConfig;
use std::path::Path;

fn gateway() -> Gateway {
    let db = Database::load(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("dbc/leveld.dbc")
            .as_path(),
    )
    .unwrap();
    Gateway::new(
        InputCodecs::reference(&db).unwrap(),
        EstimatorConfig::default(),
    )
    .unwrap()
}

fn kona() -> std::io::BufReader<std::fs::File> {
    let p =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/kona-ev-2019-ccan-power-cycle.log");
    std::io::BufReader::new(std::fs::File::open(p).unwrap())
}

#[test]
fn kona_wheel_speeds_decode_with_valid_checksums_and_counters() {
    let mut gw = gateway();
    let opts = ReplayOptions {
        interface: Some("can1".into()),
        ..Default::default()
    };
    let mut out = Vec::new();
    let s = replay(&mut gw, &mut kona(), &opts, &mut out).unwrap();
    assert_eq!(s.lines, 39_546);
    assert_eq!(s.malformed_lines, 0);
    let w = s.messages["WHL_SPD11"];
    assert_eq!(
        (w.frames, w.checksum_errors, w.counter_errors, w.dlc_errors),
        (542, 0, 0, 0)
    );
    // Everything else on can1 is ignored without error.
    assert_eq!(s.ignored_frames, s.frames - 542);
    assert_eq!(s.estimates_accepted, 0, "the car never moves");
    assert!(s.final_state.road_to_body_pitch_deg.is_none());
}

#[test]
fn a_corrupted_wheel_frame_is_counted_not_used() {
    // Flip one speed bit of one frame: the checksum must catch it.
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/kona-ev-2019-ccan-power-cycle.log"),
    )
    .unwrap();
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
    let mut gw = gateway();
    let opts = ReplayOptions {
        interface: Some("can1".into()),
        ..Default::default()
    };
    let s = replay(&mut gw, &mut patched.as_bytes(), &opts, &mut Vec::new()).unwrap();
    let w = s.messages["WHL_SPD11"];
    assert_eq!((w.frames, w.checksum_errors), (542, 1));
}

#[test]
fn malformed_lines_are_counted_with_line_numbers_and_fatal_only_when_strict() {
    let log = "(1.000000) can1 386#0000C00000400000\ngarbage\n(1.020000) can1 386#00\n(1.x) can1 386#00\n";
    let mut gw = gateway();
    let s = replay(
        &mut gw,
        &mut log.as_bytes(),
        &ReplayOptions::default(),
        &mut Vec::new(),
    )
    .unwrap();
    assert_eq!(s.malformed_lines, 2);
    assert_eq!(s.malformed_examples, vec![2, 4]);
    assert_eq!(s.messages["WHL_SPD11"].dlc_errors, 1);
    let strict = ReplayOptions {
        strict: true,
        ..Default::default()
    };
    let err = replay(
        &mut gateway(),
        &mut log.as_bytes(),
        &strict,
        &mut Vec::new(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("line 2"), "{err}");
}
