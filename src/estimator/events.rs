//! What the estimator reports: the estimate, accepted windows and events.

use super::window::RejectReason;
use serde::{Deserialize, Serialize};

/// Which operating condition of Fig. 7 a window used.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Condition {
    /// Integrated forward from the end of a stop.
    AccelAfterStop,
    /// Integrated backward from the start of a stop.
    DecelBeforeStop,
}

/// Current road-to-body pitch estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    /// Road-to-body (road-to-IMU) pitch, deg, positive nose-up.
    pub road_to_body_deg: f64,
    /// Standard error of `road_to_body_deg`, deg.
    pub std_err_deg: f64,
    /// Windows accepted under the current load.
    pub windows: u64,
    /// Effective number of windows behind the value (a load-change prior counts too).
    pub weight: f64,
}

/// One accepted slope window.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct WindowReport {
    pub t_s: f64,
    /// Middle of the stop's reference the window's pitch was measured against, s: the
    /// body held `road_to_body_deg` then. Equal to `t_s` but for a deceleration window
    /// whose stop settled only after a load came in, whose value is the new load's.
    pub reference_s: f64,
    pub condition: Condition,
    /// IMU pitch at the stop from gravity (eq. 9), deg.
    pub imu_pitch_deg: f64,
    /// Road slope along body x over the window (eq. 14), deg, positive rising ahead;
    /// with a quiet accelerometer, of the line between the contact points the body
    /// stood on at rest (`axle_chord`).
    pub road_slope_deg: f64,
    /// imu_pitch - road_slope (eq. 16), less the pitch the body had at rest on that
    /// slope beyond its pitch on level ground as fitted when the window came
    /// (`correct_grade_pitch`), deg.
    pub road_to_body_deg: f64,
    pub distance_m: f64,
    pub duration_s: f64,
    /// Time of the walk's first sample, s (the latest one for a deceleration window).
    pub start_s: f64,
    pub chord_deviation_m: f64,
}

/// What the estimator observed and why.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    /// The wheels have read zero for `zero_speed_time_s` (no IMU needed for this).
    WheelsStopped {
        t_s: f64,
    },
    /// The wheels read a speed again.
    WheelsMoving {
        t_s: f64,
    },
    /// Wheels stopped and the IMU still: the standstill reference is being taken.
    StandstillStarted {
        t_s: f64,
        imu_pitch_deg: f64,
    },
    StandstillEnded {
        t_s: f64,
        duration_s: f64,
    },
    WindowAccepted {
        window: WindowReport,
        estimate: Estimate,
    },
    WindowRejected {
        t_s: f64,
        condition: Condition,
        reason: RejectReason,
    },
    /// A pitch step at the first standstill after a restart or wheel-speed outage:
    /// the load may have changed, or the car moved unseen. The next accepted window
    /// decides; until then nothing changes.
    LoadChangeSuspected {
        t_s: f64,
        delta_deg: f64,
    },
    /// A step in standstill IMU pitch: the load changed while the road could not.
    LoadChanged {
        t_s: f64,
        delta_deg: f64,
        estimate: Option<Estimate>,
    },
    /// `shift_windows` windows in a row sat beyond `shift_deg` on one side of the
    /// estimate: the pitch moved unseen, and the average restarted from them.
    PitchShifted {
        t_s: f64,
        delta_deg: f64,
        estimate: Option<Estimate>,
    },
    /// The stops' estimate of the accelerometer's x bias changed, and every window in
    /// the average is now read with it (`rebias_windows`): the estimate moved by
    /// `delta_deg` without a window of its own.
    WindowsRebiased {
        t_s: f64,
        acc_bias_x_mps2: f64,
        delta_deg: f64,
        estimate: Option<Estimate>,
    },
    /// The first wheel speed after a drive-off disagreed with the speed the IMU
    /// integrated from the standstill: the car never was at rest (a rolling stop under
    /// the wheel sensors' dead zone) or the reference was wrong. The deceleration
    /// window taken from that standstill is taken back out of the estimate.
    WindowWithdrawn {
        t_s: f64,
        /// The withdrawn window's value, deg (its grade's pitch taken out with the
        /// share fitted when it is withdrawn).
        road_to_body_deg: f64,
        imu_mps: f64,
        wheel_mps: f64,
        estimate: Option<Estimate>,
    },
    /// An input sample was dropped (non-finite value or time going backwards).
    SampleDropped {
        t_s: f64,
        reason: DropReason,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DropReason {
    NonFinite,
    TimeNotIncreasing,
}
