#!/usr/bin/env bash
# Regenerate docs/accuracy.md from docs/accuracy.tmpl.md with the figures of the code
# in this tree (about 15 minutes on 2 idle cores).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q
bin=target/release/leveld
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

run() { echo "+ leveld $*" >&2; "$bin" "$@"; }
run simulate paper-grid --format summary > "$tmp/grid"
run bench accuracy --plots docs > "$tmp/base1"
run bench accuracy --seeds 8 > "$tmp/base8"
run bench accuracy --scenarios scenarios/realistic/*.toml --seeds 8 > "$tmp/real8"
run bench accuracy --ablation > "$tmp/abl"
# An INS-grade IMU: 30 ug/sqrt(Hz), 0.003 deg/s/sqrt(Hz), slow bias drift.
ins=(sensors.acc_noise_ug_rthz=30 sensors.acc_bias_walk_mps2_rts=0.0001
    sensors.gyro_noise_dps_rthz=0.003 sensors.gyro_bias_walk_dps_rts=0.0005)
# The realistic drives with one thing about the car or its sensors changed.
sens() {
    local name=$1 file=$2; shift 2
    local sets=(--set "name=\"$name\"")
    for s in "$@"; do sets+=(--set "$s"); done
    run bench accuracy --scenarios "scenarios/realistic/$file.toml" --seeds 4 "${sets[@]}"
}
{
    sens "urban, as shipped" urban
    sens "urban, smooth road (no unevenness)" urban realistic.road_roughness_1e6_m3=0.0
    sens "urban, IMU at 50 Hz" urban sensors.imu_rate_hz=50
    sens "urban, IMU at 200 Hz" urban sensors.imu_rate_hz=200
    sens "urban, accelerometer 500 ug/rtHz" urban sensors.acc_noise_ug_rthz=500
    sens "urban, accelerometer 1000 ug/rtHz" urban sensors.acc_noise_ug_rthz=1000
    sens "stop-and-go, accelerometer 1000 ug/rtHz" stop-and-go sensors.acc_noise_ug_rthz=1000
    sens "urban, INS-grade IMU (30 ug/rtHz, gyro 0.003 deg/s/rtHz)" urban \
        "${ins[@]}"
    sens "stop-and-go, INS-grade IMU (30 ug/rtHz, gyro 0.003 deg/s/rtHz)" stop-and-go \
        "${ins[@]}"
    sens "urban, 5 % of IMU frames lost" urban sensors.imu_drop_prob=0.05
    sens "urban, soft suspension" urban "realistic.pitch_freq_hz=[1.0, 1.1]" \
        "realistic.pitch_damping=[0.15, 0.25]" "realistic.pitch_per_accel_deg=[0.3, 0.45]"
    sens "urban, gyro 0.03 deg/s/rtHz" urban sensors.gyro_noise_dps_rthz=0.03
    sens "stop-and-go, gyro 0.03 deg/s/rtHz" stop-and-go sensors.gyro_noise_dps_rthz=0.03
    sens "urban, gyro 0.05 deg/s/rtHz" urban sensors.gyro_noise_dps_rthz=0.05
    sens "urban, IMU 1.5 m ahead, left, high" urban "realistic.lever_arm_m=[1.5, -0.6, 0.7]"
    sens "urban, gentle braking (0.4-0.8 m/s^2)" urban "brake_mps2=[0.4, 0.8]"
    sens "stop-and-go, gentle braking (0.4-0.8 m/s^2)" stop-and-go "brake_mps2=[0.4, 0.8]"
    sens "urban, wheels zero below 3 km/h" urban sensors.wheel_zero_below_kmh=3.0
    sens "stop-and-go, wheels zero below 3 km/h" stop-and-go sensors.wheel_zero_below_kmh=3.0
    sens "urban, wheel speeds 0.15 s old" urban sensors.wheel_delay_s=0.15
    sens "stop-and-go, wheel speeds 0.15 s old" stop-and-go sensors.wheel_delay_s=0.15
    sens "urban, wheel speeds at 10 Hz" urban sensors.wheel_rate_hz=10
    sens "urban, 0.2-0.4 deg door shock and an IMU gap at every stop" urban \
        realistic.door_shock_share=1.0 "realistic.door_shock_deg=[0.2, 0.4]" \
        realistic.imu_gap_share=1.0
    sens "urban, drive-offs and rolling stops' pull-aways at 0.15-0.3 m/s^2" urban \
        "realistic.gentle_accel_mps2=[0.15, 0.3]"
    sens "stop-and-go, drive-offs and rolling stops' pull-aways at 0.15-0.3 m/s^2" stop-and-go \
        "realistic.gentle_accel_mps2=[0.15, 0.3]"
    sens "urban, lanes falling 2.5 % to the right" urban realistic.cross_slope_pct=2.5
    sens "urban, accelerometer z axis leaning 0.29 deg towards x, uncalibrated" urban \
        "sensors.acc_axes=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.005, 0.0, 1.0]]"
    sens "urban, body pitching 0.4-0.5 deg per m/s^2 (a soft SUV)" urban \
        "realistic.pitch_per_accel_deg=[0.4, 0.5]"
    sens "stop-and-go, body pitching 0.4-0.5 deg per m/s^2 (a soft SUV)" stop-and-go \
        "realistic.pitch_per_accel_deg=[0.4, 0.5]"
    sens "hilly, a body that squats half as much as it dives" hilly \
        "realistic.squat_share=[0.5, 0.5]"
    sens "hilly, INS-grade IMU, a body that squats half as much as it dives" hilly \
        "${ins[@]}" \
        "realistic.squat_share=[0.5, 0.5]"
    sens "urban, INS-grade IMU, a body that squats half as much as it dives" urban \
        "${ins[@]}" \
        "realistic.squat_share=[0.5, 0.5]"
    sens "urban, stiff suspension (pitch 1.6-1.9 Hz, damping 0.3-0.5, 0.08-0.15 deg per m/s^2)" \
        urban "realistic.pitch_freq_hz=[1.6, 1.9]" "realistic.pitch_damping=[0.3, 0.5]" \
        "realistic.pitch_per_accel_deg=[0.08, 0.15]"
    sens "bumpy, worn dampers (pitch 0.9-1.0 Hz, damping 0.12-0.18)" bumpy \
        "realistic.pitch_freq_hz=[0.9, 1.0]" "realistic.pitch_damping=[0.12, 0.18]"
    sens "urban, loads put in over 0.3 s through the suspension" urban \
        realistic.load_ramp_s=0.3 realistic.load_through_suspension=true
    sens "hilly, loads put in over 0.3 s through the suspension" hilly \
        realistic.load_ramp_s=0.3 realistic.load_through_suspension=true
    sens "urban, body rising 2 mm per m/s^2 of force as it pitches" urban \
        "realistic.heave_per_accel_mm=[2.0, 2.0]"
    sens "urban, body sinking 2 mm per m/s^2 of force as it pitches" urban \
        "realistic.heave_per_accel_mm=[-2.0, -2.0]"
    sens "urban, INS-grade IMU, body rising 2 mm per m/s^2 of force" urban \
        "${ins[@]}" \
        "realistic.heave_per_accel_mm=[2.0, 2.0]"
    sens "hilly, a body that stands level on every grade (no pitch from the grade's pull)" hilly \
        realistic.pitch_from_grade=false
    sens "urban, every drive-off gentle (0.3-0.6 m/s^2)" urban realistic.gentle_start_share=1.0
    sens "hilly, every drive-off gentle (0.3-0.6 m/s^2)" hilly realistic.gentle_start_share=1.0
    sens "stop-and-go, every drive-off gentle (0.3-0.6 m/s^2)" stop-and-go \
        realistic.gentle_start_share=1.0
    sens "urban, INS-grade IMU and every drive-off gentle" urban \
        "${ins[@]}" \
        realistic.gentle_start_share=1.0
    sens "urban, engine idling (0.2 m/s^2 rms at 25 Hz)" urban realistic.idle_vibration_mps2=0.2
    sens "stop-and-go, engine idling (0.2 m/s^2 rms at 25 Hz)" stop-and-go \
        realistic.idle_vibration_mps2=0.2
    sens "urban, INS-grade IMU and an idling engine (0.2 m/s^2 at 25 Hz)" urban \
        "${ins[@]}" \
        realistic.idle_vibration_mps2=0.2
    sens "stop-and-go, INS-grade IMU and an idling engine (0.2 m/s^2 at 25 Hz)" stop-and-go \
        "${ins[@]}" \
        realistic.idle_vibration_mps2=0.2
    sens "urban, INS-grade IMU and an idling engine, no IMU frame lost" urban \
        "${ins[@]}" \
        realistic.idle_vibration_mps2=0.2 sensors.imu_drop_prob=0
    sens "stop-and-go, a noise-free IMU (biases kept, no drift)" stop-and-go \
        sensors.acc_noise_ug_rthz=0 sensors.acc_bias_walk_mps2_rts=0 \
        sensors.gyro_noise_dps_rthz=0 sensors.gyro_bias_walk_dps_rts=0
    sens "urban, every stop eased (0.2-0.5 m/s^2 over its last 0.6-1.2 s)" urban \
        realistic.soft_stop_share=1.0
    sens "stop-and-go, every stop eased (0.2-0.5 m/s^2 over its last 0.6-1.2 s)" stop-and-go \
        realistic.soft_stop_share=1.0
    sens "urban, INS-grade IMU and every stop eased" urban \
        "${ins[@]}" \
        realistic.soft_stop_share=1.0
    sens "urban, every stop a crawl to rest (0.05-0.12 m/s^2 over its last 2-4 s)" urban \
        realistic.soft_stop_share=1.0 "realistic.soft_stop_mps2=[0.05, 0.12]" \
        "realistic.soft_stop_s=[2.0, 4.0]"
    sens "urban, IMU at the car's centre (an INS), configured at the headlamp" urban \
        "realistic.lever_arm_m=[0.0, 0.0, 0.4]"
    sens "hilly, axles 2.4 m apart (configured 2.7)" hilly realistic.wheelbase_m=2.4
    sens "urban, axles 3.1 m apart (configured 2.7)" urban realistic.wheelbase_m=3.1
} > "$tmp/sens"
run bench accuracy --ablation --scenarios scenarios/realistic/*.toml --seeds 4 > "$tmp/ablreal"

python3 - "$tmp" <<'PY'
import sys, pathlib
tmp = pathlib.Path(sys.argv[1])

def tables(name):
    """Markdown tables of a command's output, in order."""
    out, cur = [], []
    lines = (tmp / name).read_text().splitlines()
    for i, line in enumerate(lines):
        # A header row (the separator follows it) starts a table even without a blank
        # line before it: one command's output runs into the next one's.
        header = i + 1 < len(lines) and lines[i + 1].startswith("| ---")
        if header and cur:
            out.append("\n".join(cur)); cur = []
        if line.startswith("|"):
            cur.append(line)
        elif cur:
            out.append("\n".join(cur)); cur = []
    if cur:
        out.append("\n".join(cur))
    return out

real = tables("real8")
sens = tables("sens")
# leveld's row of every accuracy table, then every stop table's rows, under one header.
def rows(ts, keep, row=lambda l: True):
    head, body = None, []
    for t in ts:
        lines = t.splitlines()
        if keep(lines[0]):
            head = head or lines[:2]
            body += [l for l in lines[2:] if row(l)]
    return "\n".join(head + body)
sens_acc = rows(sens, lambda h: "| method |" in h, lambda l: "| leveld |" in l)
sens_stops = rows(sens, lambda h: "gentle drive-offs with a window" in h)
abl = tables("abl")
ablreal = tables("ablreal")
text = pathlib.Path("docs/accuracy.tmpl.md").read_text()
fill = {
    "{{GRID}}": "\n\n".join(tables("grid")),
    "{{BASE1}}": tables("base1")[0],
    "{{BASE8}}": tables("base8")[0],
    "{{REAL8}}": real[0],
    "{{REAL8STOPS}}": "\n\n".join(real[1:]),
    "{{SENS}}": sens_acc + "\n\n" + sens_stops,
    "{{ABLATION}}": "## 4. What each part is worth\n\n"
        "`leveld bench accuracy --ablation` switches one part off at a time "
        "(`paper-like`: all of them off, with eq. 17). On the drive suite, one seed:\n\n"
        + abl[0]
        + "\n\nOn the realistic family, four seeds (`--ablation --scenarios "
        "scenarios/realistic/*.toml --seeds 4`):\n\n" + ablreal[0],
}
for k, v in fill.items():
    text = text.replace(k, v)
pathlib.Path("docs/accuracy.md").write_text(text)
PY
echo "docs/accuracy.md written" >&2
