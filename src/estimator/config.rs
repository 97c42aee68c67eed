//! Estimator parameters. Every field carries its unit in its name.

use serde::{Deserialize, Serialize};

/// How accepted windows are combined into the road-to-body estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Averaging {
    /// The running mean of eq. 17 of Kim et al. (2023).
    Mean,
    /// Huber M-estimate with a MAD scale: windows far from the bulk, by the spread their
    /// own weight predicts, get less weight.
    Huber,
}

/// Tuning of the static leveling estimator.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EstimatorConfig {
    /// The accelerometer's own calibration, applied to every sample as f = M f_raw
    /// (rows: x, y, z; identity: none). leveld measures the road as the angle between
    /// the force at rest and the force under acceleration, both read by the same three
    /// axes, so a z axis that leans towards x by e rad reads e of every acceleration
    /// as vertical and biases every window by e: a 0.5 % coupling is 0.29 deg. A
    /// rotation of the whole triad on its package or mount is harmless (the gravity
    /// reference takes it out); the axes' lean against each other is not, and only a
    /// per-unit calibration of the IMU (a tumble test by its maker) can give M.
    pub acc_matrix: [[f64; 3]; 3],
    /// Wheel speeds at or below this read as zero, km/h.
    pub zero_speed_kmh: f64,
    /// Wheels must read zero this long before a standstill is declared, s.
    pub zero_speed_time_s: f64,
    /// The IMU must also be still this long before a standstill is declared, s.
    pub still_time_s: f64,
    /// Length of the sliding window of the IMU stillness test, s.
    pub still_window_s: f64,
    /// Stillness: largest per-axis accelerometer standard deviation in the window, m/s^2.
    pub still_acc_std_mps2: f64,
    /// Stillness: largest norm of the window-mean gyro rate minus the bias, deg/s.
    pub still_gyro_dps: f64,
    /// Stillness: largest per-axis gyro standard deviation in the window, deg/s.
    pub still_gyro_std_dps: f64,
    /// Settled: the window-mean rate is within this of the bias. Only settled samples
    /// feed the bias filter (eq. 7) and the gravity reference, so body rocking after a
    /// stop and slow rotations (loading, doors) leak into neither, deg/s.
    pub bias_gate_dps: f64,
    /// The gyro noise density `still_gyro_std_dps`, `still_gyro_dps` and
    /// `bias_gate_dps` are sized for, deg/s/sqrt(Hz). A gyro learnt at rest to be
    /// noisier widens them in proportion (`scale_gyro_gates`).
    pub gyro_noise_dps_rthz: f64,
    /// Widen the gyro gates with the noise learnt at rest. Off, a gyro noisier than
    /// `gyro_noise_dps_rthz` fails the stillness and bias gates more and more often:
    /// at five times that noise hardly a sample counts as settled.
    pub scale_gyro_gates: bool,
    /// The accelerometer noise density `still_acc_std_mps2`, `rest_acc_tol_mps2` and
    /// `drive_off_speed_mps` hold for, ug/sqrt(Hz): past it, noise alone starts to fail them. An
    /// accelerometer learnt at rest to be noisier (or an engine vibrating at idle)
    /// widens them in proportion (`scale_acc_gates`).
    pub acc_noise_ug_rthz: f64,
    /// Widen the accelerometer gates with the noise learnt at rest. Off, at three times
    /// `acc_noise_ug_rthz` no standstill is found.
    pub scale_acc_gates: bool,
    /// Random walk of the accelerometer bias along gravity (temperature drift), m/s^2
    /// per sqrt(s). Sets how long the standstill gravity magnitude is averaged.
    pub gravity_walk_mps2_rts: f64,
    /// Settled samples needed before the deceleration window is evaluated, s.
    pub settle_time_s: f64,
    /// A window walk starts where the mean specific force over 0.05 s (at least 5
    /// samples) last matched the standstill mean within this, per axis, m/s^2. Constant
    /// braking has no variance, so this, not the stillness test, finds the moment the
    /// car came to rest.
    pub rest_acc_tol_mps2: f64,
    /// While the wheels read zero, a standstill ends when the IMU sees the car pick up
    /// this much speed since it was last surely at rest (a drive-off or creep inside the
    /// wheel sensors' dead zone), m/s.
    pub drive_off_speed_mps: f64,
    /// Time constant of the gyro-bias low-pass filter of eq. 7, s. Its coefficient
    /// alpha is the IMU's sample interval over this (0.01 per sample at 100 Hz), so the
    /// bias follows the same span of settled samples at any IMU rate.
    pub gyro_bias_time_constant_s: f64,
    /// Horizontal travel of one slope window, T_d of eq. 15, m. The paper uses 2 m. With
    /// the velocity-free slope a longer window no longer integrates a start velocity
    /// for longer, and the errors that do not grow with its duration (the reference,
    /// the body's heave at its ends) shrink with its length; the accelerometer noise
    /// over a drive-off at constant acceleration falls only as the length^(-1/4).
    pub window_distance_m: f64,
    /// The straightness check continues this far past the window, m.
    pub chord_check_extra_m: f64,
    /// A window whose corrected trajectory leaves its end-to-end chord by more than this is rejected, m.
    pub max_chord_deviation_m: f64,
    /// The short fallback's limit on its deviation from its chord (below) does not go
    /// below this many standard deviations of what the accelerometer's noise (learnt
    /// at rest) alone leaves on a walk of its duration, up to `max_chord_deviation_m`
    /// times `short_window_share` (a bend that tilts its shorter chord as much as the
    /// whole window's limit tilts its own); 0 keeps the bend limit alone. That limit,
    /// 3 mm, is below the noise of a slow walk and refused straight roads at random:
    /// the half-window a speed bump ahead leaves lasts 2-3 s after a gentle drive-off,
    /// over which 300 ug/sqrt(Hz) alone reaches 2-6 mm.
    pub chord_noise_sigmas: f64,
    /// Take the window's slope from weights t (T - t) on its acceleration, which vanish
    /// at both ends, instead of the chord to its end point (eq. 14). The chord carries
    /// any velocity the IMU had where the walk began times the window's duration: a
    /// body still rocking from the stop or a door, a drive-off found a little late.
    /// The weighted form does not see that velocity, and its noise is a little lower.
    pub velocity_free_slope: bool,
    /// The velocity-free slope is used on a path that leaves its chord by at most this,
    /// m; a more bent one keeps the chord's slope. The fit reads a grade change inside
    /// the window partly as a start velocity: on drives that stop where the grade
    /// changes, windows bent by 6-12 mm came out 0.8 deg rms with it and 0.4 with the
    /// chord, while below 6 mm it was the better of the two.
    pub velocity_free_max_chord_m: f64,
    /// With an accelerometer quieter than this (the noise learnt at rest), the chord's
    /// slope is used on every path, ug/sqrt(Hz); 0 keeps the velocity-free slope for
    /// any accelerometer. The start velocity the chord carries comes mostly from the
    /// noise integrated over the rest before the walk; with little of it the chord,
    /// which reads the road nearer the car and takes no grade change for a start
    /// velocity, is the better slope. Windows of the realistic family (8 seeds), rms
    /// velocity-free against chord: 0.196 / 0.175 deg with an INS-grade unit (30
    /// ug/sqrt(Hz), gyro 0.003 deg/s/sqrt(Hz), little drift), 0.261 / 0.254 at 100
    /// ug/sqrt(Hz), 0.280 / 0.275 at 200, 0.309 / 0.308 at 300, where the drive suite
    /// still favours the velocity-free slope (p95 0.182 against 0.215 deg on urban).
    pub chord_below_acc_noise_ug_rthz: f64,
    /// A window whose path bends (a speed bump just ahead, a grade change) or turns
    /// beyond its first part falls back to that part: this share of
    /// `window_distance_m`, checked over its own length against the chord limits times
    /// the square of the share (a bend of one curvature leaves a path of half the length
    /// a quarter as far from its chord), and weighted as the shorter window it is. 0
    /// turns the fallback off. Creeps and rolling stops that never cover the whole
    /// distance still give no window.
    pub short_window_share: f64,
    /// Distance between the axles, m, and where along it the body pitches, as a share
    /// of it from the rear axle (0.5: midway). With a quiet accelerometer
    /// (`chord_below_acc_noise_ug_rthz`) a window measures the road between the
    /// contact points the body stood on at rest, from its walk one wheelbase out
    /// (`axle_chord`). A wheelbase 10 % off keeps most of what that gives.
    pub wheelbase_m: f64,
    pub pitch_centre_share: f64,
    /// With a quiet accelerometer, measure a window's slope between the axles' contact
    /// points at rest instead of over the window (`estimator/fusion.rs`,
    /// `axle_slope_rad`). Realistic family with an INS-grade unit (8 seeds):
    /// single-window p95 0.25-0.33 -> 0.22-0.33 deg. At 300 ug/sqrt(Hz) the
    /// velocity-free slope over the window stays: on the paths bent enough to take the
    /// chord there, the axles' chord moved the drives within the spread between seeds,
    /// a little worse on fresh seeds.
    pub axle_chord: bool,
    /// Windows with a yaw rate above this are rejected as turning, deg/s.
    pub max_yaw_rate_dps: f64,
    /// Windows with a lateral acceleration above this are rejected as turning, m/s^2.
    pub max_lateral_acc_mps2: f64,
    /// A window that has not covered its distance after this long is abandoned, s.
    pub max_window_time_s: f64,
    /// A gap between IMU samples longer than this breaks a window, s.
    pub max_imu_gap_s: f64,
    /// A wheel-speed frame may carry a speed this old, s: the ESC derives it from tooth
    /// periods and filters it, and a gateway may hold it. The checks that compare the
    /// wheels with the IMU's speed accept any speed the IMU had over that span.
    pub max_wheel_speed_age_s: f64,
    /// Position of the IMU relative to the body pitch centre in body axes (x fwd, y left, z up), m.
    /// Body pitch under acceleration swings the IMU about that centre; the window removes it.
    pub lever_arm_m: [f64; 3],
    /// Refine `lever_arm_m` along x and z from the body rocking seen after each stop.
    pub learn_lever_arm: bool,
    /// Learn the body's pitch mode (frequency and damping) from the swing after each
    /// stop, count the dive under braking from the pitch the body swings about, and
    /// report the mode with the rest of the suspension (`estimator/mode.rs`).
    pub learn_pitch_mode: bool,
    /// Remove the horizontal accelerometer bias that the standstill gravity magnitude
    /// reveals over stops at different pitch (`estimator/gravity.rs`) from every window
    /// and its reference. The paper's cancellation of a bias between reference and
    /// window holds only while the body keeps its reference attitude; a body that
    /// dives 0.3 deg per m/s^2 while braking turns a 0.3 m/s^2 bias into a vertical
    /// 1.6 mm/s^2 per m/s^2 of deceleration: about 0.09 deg on every window.
    pub correct_acc_bias: bool,
    /// Read every window in the average with the bias the stops know now, not the one
    /// known when it was measured (`Averager::set_acc_bias_x`): the stops learn the x
    /// bias over many stops at different grades, and until then each window is off by
    /// the body's pitch per m/s^2 of force (and as much again through its grade's
    /// pull) times what is not yet known, the same in every window of a car. It uses
    /// the pitch per m/s^2 learnt from braking (`correct_grade_pitch`).
    pub rebias_windows: bool,
    /// With `rebias_windows`, each window follows the bias by what its own walk says
    /// (`WindowGeometry::slope_per_bias_x`: the gyro's turn from rest, weighed as the
    /// slope weighs the path) instead of the body's mean pitch per m/s^2 learnt from
    /// braking. The body's pitch builds up and rocks through a window, and a drive-off
    /// walks less of it than the braking pitch says; a window over a change of grade
    /// turns the bias by the road's pitch as well.
    pub rebias_by_walk: bool,
    /// Learn the body's squat per m/s^2 pulling away from the acceleration windows,
    /// apart from its dive under braking, for the pitch the force gives the body where
    /// an acceleration window's walk is one wheelbase out (`axle_chord`). Off, a body
    /// is taken to squat as it dives.
    pub learn_squat: bool,
    /// A window whose slope is taken between the axles (`axle_chord`) took the pitch
    /// the force gave the body there with the dive and squat learnt by then; the average
    /// reads each such window with the ones learnt since (`average::PitchTerms`). Off,
    /// a window keeps what it was measured with, and the first stops' windows, taken
    /// before the squat is learnt, keep its error.
    pub follow_learnt_pitch: bool,
    /// How far the accelerometer's horizontal bias may be off zero before any stop has
    /// shown it (1 sigma), m/s^2: 0.2 for an untrimmed MEMS part (20-30 mg), a few
    /// hundredths for one trimmed at its maker (its data sheet's offset after
    /// calibration). The stops weigh what they show against it; the end-of-line
    /// reference takes the bias out as they learnt it (`level_reference_deg`), so a prior
    /// far wider than the part's bias lets the stops' noise into the reference.
    pub acc_bias_prior_mps2: f64,
    /// IMU history kept for the deceleration window (integrated backwards from the stop), s.
    pub history_s: f64,
    /// A step in standstill IMU pitch above this is taken as a load change, deg.
    pub load_change_deg: f64,
    /// Length of the blocks in which the standstill pitch is compared for load changes, s.
    pub load_block_s: f64,
    /// After a load change, the shifted previous estimate counts as at most this many windows.
    pub load_prior_windows: f64,
    /// `shift_windows` accepted windows in a row, each this far from the estimate on the
    /// same side, restart the average from them: the pitch changed unseen (a load change
    /// during a stop too short to confirm it, or while nothing watched). Their weighted
    /// mean must also stand four standard errors off, judged by the spread of windows
    /// before the run, so that a run of noisy or gentle windows is not taken for one. deg.
    pub shift_deg: f64,
    /// See `shift_deg`; 0 disables the check.
    pub shift_windows: usize,
    /// Weigh each window by its predicted error (long, slow windows integrate more
    /// accelerometer noise) instead of equally.
    pub weight_windows: bool,
    /// Scale the part of that error which is the accelerometer's noise by the noise
    /// learnt at rest (the model was fitted at 300 ug/sqrt(Hz)): with a quiet
    /// accelerometer slow windows weigh nearly as much as brisk ones, and windows of
    /// stops too short to settle less (`estimator/fusion.rs`, `short_stop_share`).
    pub noise_scaled_weights: bool,
    /// Follow the body's pitch at rest with the gyro, so that a load still ramping in
    /// shows in the estimate before the settled blocks confirm it and is applied at
    /// drive-off.
    pub live_standstill_pitch: bool,
    /// The deceleration and acceleration windows of a stop shorter than 8 s enter the
    /// average as one entry. Both start from the same standstill reference, and an
    /// error in it (a door shock on a short stop) moves them in opposite directions.
    pub pair_stop_windows: bool,
    /// A stop too short for the body to settle (a stop sign, a queue) gives an
    /// acceleration window: the drive-off is found on the rocking body, and the
    /// reference is the rest samples turned by the gyro into the body frame at the
    /// drive-off. Off: such stops give no window.
    pub short_stop_windows: bool,
    /// Weight of a window from a stop too short to settle, as a share of a settled
    /// window of the same length, for an accelerometer of 300 ug/sqrt(Hz): the rest
    /// samples still carry the heave of the body, and the window starts with the body's
    /// unknown vertical speed. Over 64 realistic drives (8 seeds of each scenario and
    /// load) the forward windows of such stops were 0.62 deg rms off, those of settled
    /// stops 0.33: (0.33 / 0.62)^2. With `noise_scaled_weights` the share follows the
    /// noise learnt at rest, smaller for a quieter accelerometer.
    pub short_stop_weight: f64,
    /// The motion tracker that ends a standstill in the wheels' dead zone stands on the
    /// mean force turned by the gyro into the body frame at its own sample, not on the
    /// raw mean, which lags a body still rocking by its rate times half the window.
    pub derotated_motion_anchor: bool,
    /// A settled block teaches the gyro bias (eq. 7) only if it began at least 1 s after
    /// the car came to rest and its mean rate is within `bias_gate_dps` of the bias: the
    /// body's swing back from its dive passes the per-window gate with rates of one
    /// sign, and a bias taught by it misses that much of every turn the gyro carries
    /// (load steps from the gyro with ideal sensors: rms error 0.047 deg with every
    /// block teaching, 0.031 without those). Off, every block that joins the stop's
    /// reference teaches at once.
    pub still_blocks_teach_bias: bool,
    /// A settled sample whose lever-arm acceleration, as the gyro shows it, exceeds this
    /// stays out of the gravity reference (the stop's mean force and the gravity
    /// magnitude), m/s^2. The lever-arm model is smoothed over 11 gyro samples and leaves
    /// part of a door shock's 5-8 Hz swing in the force; a shock's tail passes the
    /// stillness test. 0.05 is about five times what a gyro noise of 0.01 deg/s/sqrt(Hz)
    /// shows at a 2 m arm. A block of quiet samples with fewer than a quarter of them
    /// below the gate keeps them all, and so does the gravity filter while fewer than a
    /// quarter of its recent samples are below it (a gyro noisier than the gate is
    /// sized for must not leave a stop without reference).
    pub rest_swing_gate_mps2: f64,
    /// A stop's reference does not begin with a block of settled samples during which
    /// the body's angular acceleration, as the gyro shows it, went above this, deg/s^2
    /// (in the first 4 s of the stop, after which any block may; widened like the rate
    /// gates for a noisier gyro). A lightly damped body (0.9-1.0 Hz, damping 0.12-0.18)
    /// still swings a tenth of a degree 2 s after a stop; at each turning point its
    /// rate crosses zero and the samples there pass the rate gates, while the body
    /// stands that far from its rest pitch with (2 pi f)^2 A of angular acceleration
    /// (3.6 deg/s^2 for 0.1 deg at 0.95 Hz). A reference begun there made the body's
    /// return to rest look like a load change, which the gyro confirmed: 10 false load
    /// changes of 0.13-0.48 deg on the family's 64 drives with such a body. Blocks of a
    /// body at rest reach 1.2 deg/s^2 (median) and 2.1 (99th percentile) at 0.01
    /// deg/s/sqrt(Hz), from the gyro's noise through the lever-arm smoothing.
    pub reference_swing_gate_dps2: f64,
    /// Take out of each window the pitch the body has at rest on its grade
    /// (`estimator/grade.rs`): the brakes hold gravity's share along the road and the
    /// body dives or squats under it as under braking. Its pitch per m/s^2 is learnt
    /// from the deceleration windows, and the share of it the body shows at rest from
    /// stops at different grades (1 until they tell).
    pub correct_grade_pitch: bool,
    /// How windows are combined.
    pub averaging: Averaging,
    /// Number of most recent windows the average keeps.
    pub average_capacity: usize,
    /// Prior for the spread of single windows before enough have been seen, deg.
    pub window_sigma_prior_deg: f64,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            acc_matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            zero_speed_kmh: 0.1,
            zero_speed_time_s: 1.0,
            still_time_s: 0.5,
            still_window_s: 0.2,
            still_acc_std_mps2: 0.15,
            still_gyro_dps: 1.0,
            still_gyro_std_dps: 0.5,
            bias_gate_dps: 0.1,
            gyro_noise_dps_rthz: 0.01,
            scale_gyro_gates: true,
            acc_noise_ug_rthz: 500.0,
            scale_acc_gates: true,
            rest_acc_tol_mps2: 0.1,
            settle_time_s: 3.0,
            drive_off_speed_mps: 0.06,
            gravity_walk_mps2_rts: 0.0005,
            gyro_bias_time_constant_s: 1.0,
            window_distance_m: 3.0,
            chord_check_extra_m: 1.0,
            max_chord_deviation_m: 0.012,
            chord_noise_sigmas: 3.0,
            velocity_free_slope: true,
            velocity_free_max_chord_m: 0.006,
            chord_below_acc_noise_ug_rthz: 150.0,
            short_window_share: 0.5,
            wheelbase_m: 2.7,
            pitch_centre_share: 0.5,
            axle_chord: true,
            max_yaw_rate_dps: 3.0,
            max_lateral_acc_mps2: 0.5,
            max_window_time_s: 15.0,
            max_imu_gap_s: 0.1,
            max_wheel_speed_age_s: 0.15,
            lever_arm_m: [2.0, 0.0, 0.3],
            learn_lever_arm: true,
            learn_pitch_mode: true,
            correct_acc_bias: true,
            rebias_windows: true,
            rebias_by_walk: true,
            follow_learnt_pitch: true,
            learn_squat: true,
            acc_bias_prior_mps2: 0.2,
            history_s: 30.0,
            load_change_deg: 0.2,
            load_block_s: 0.5,
            load_prior_windows: 4.0,
            shift_deg: 0.4,
            shift_windows: 3,
            weight_windows: true,
            noise_scaled_weights: true,
            live_standstill_pitch: true,
            pair_stop_windows: true,
            short_stop_windows: true,
            short_stop_weight: 0.28,
            derotated_motion_anchor: true,
            still_blocks_teach_bias: true,
            rest_swing_gate_mps2: 0.05,
            reference_swing_gate_dps2: 2.5,
            correct_grade_pitch: true,
            averaging: Averaging::Huber,
            average_capacity: 64,
            window_sigma_prior_deg: 0.2,
        }
    }
}

/// A parameter is out of its valid range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("estimator parameter `{field}` = {value} is invalid: {hint}")]
pub struct ConfigError {
    pub field: &'static str,
    pub value: f64,
    pub hint: &'static str,
}

/// Names of the entries of `acc_matrix` in errors.
const ACC_MATRIX_FIELDS: [[&str; 3]; 3] = [
    ["acc_matrix[0][0]", "acc_matrix[0][1]", "acc_matrix[0][2]"],
    ["acc_matrix[1][0]", "acc_matrix[1][1]", "acc_matrix[1][2]"],
    ["acc_matrix[2][0]", "acc_matrix[2][1]", "acc_matrix[2][2]"],
];

impl EstimatorConfig {
    /// Check every parameter; the error names the field and the valid range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let pos = |field: &'static str, value: f64| {
            if value.is_finite() && value > 0.0 {
                Ok(())
            } else {
                Err(ConfigError {
                    field,
                    value,
                    hint: "set a finite value greater than 0",
                })
            }
        };
        let nonneg = |field: &'static str, value: f64| {
            if value.is_finite() && value >= 0.0 {
                Ok(())
            } else {
                Err(ConfigError {
                    field,
                    value,
                    hint: "set a finite value of 0 or more",
                })
            }
        };
        let within = |field: &'static str,
                      value: f64,
                      range: std::ops::RangeInclusive<f64>,
                      hint: &'static str| {
            if value.is_finite() && range.contains(&value) {
                Ok(())
            } else {
                Err(ConfigError { field, value, hint })
            }
        };
        // Durations size buffers (seconds times the sample rate): bounded above too.
        let secs = |field: &'static str, value: f64, max_s: f64| {
            if value.is_finite() && value > 0.0 && value <= max_s {
                Ok(())
            } else {
                Err(ConfigError {
                    field,
                    value,
                    hint: match max_s {
                        m if m <= 5.0 => "choose a duration above 0 and at most 5 s",
                        m if m <= 10.0 => "choose a duration above 0 and at most 10 s",
                        _ => "choose a duration above 0 and at most 60 s",
                    },
                })
            }
        };
        secs("still_window_s", self.still_window_s, 10.0)?;
        secs("still_time_s", self.still_time_s, 60.0)?;
        secs("settle_time_s", self.settle_time_s, 60.0)?;
        secs("load_block_s", self.load_block_s, 60.0)?;
        secs("max_imu_gap_s", self.max_imu_gap_s, 5.0)?;
        within(
            "max_wheel_speed_age_s",
            self.max_wheel_speed_age_s,
            0.0..=1.0,
            "choose 0..1 s: how old a wheel speed can be when its frame is sent",
        )?;
        if self.zero_speed_time_s > 60.0 {
            return Err(ConfigError {
                field: "zero_speed_time_s",
                value: self.zero_speed_time_s,
                hint: "choose 0..60 s",
            });
        }
        nonneg("zero_speed_kmh", self.zero_speed_kmh)?;
        nonneg("zero_speed_time_s", self.zero_speed_time_s)?;
        pos("still_time_s", self.still_time_s)?;
        pos("still_window_s", self.still_window_s)?;
        pos("still_acc_std_mps2", self.still_acc_std_mps2)?;
        pos("still_gyro_dps", self.still_gyro_dps)?;
        pos("still_gyro_std_dps", self.still_gyro_std_dps)?;
        pos("rest_swing_gate_mps2", self.rest_swing_gate_mps2)?;
        pos("reference_swing_gate_dps2", self.reference_swing_gate_dps2)?;
        pos("bias_gate_dps", self.bias_gate_dps)?;
        pos("gyro_noise_dps_rthz", self.gyro_noise_dps_rthz)?;
        pos("acc_noise_ug_rthz", self.acc_noise_ug_rthz)?;
        within(
            "chord_below_acc_noise_ug_rthz",
            self.chord_below_acc_noise_ug_rthz,
            0.0..=10_000.0,
            "choose 0..10000 ug/sqrt(Hz); 0 keeps the velocity-free slope for any accelerometer",
        )?;
        within(
            "wheelbase_m",
            self.wheelbase_m,
            1.5..=6.0,
            "the distance between the axles, 1.5..6 m (a passenger car: 2.4-3.1)",
        )?;
        within(
            "pitch_centre_share",
            self.pitch_centre_share,
            0.0..=1.0,
            "where the body pitches along the wheelbase, as a share from the rear axle: 0..1 (0.5 when unknown)",
        )?;
        pos("rest_acc_tol_mps2", self.rest_acc_tol_mps2)?;
        pos("settle_time_s", self.settle_time_s)?;
        pos("drive_off_speed_mps", self.drive_off_speed_mps)?;
        pos("gravity_walk_mps2_rts", self.gravity_walk_mps2_rts)?;
        if self.history_s < self.max_window_time_s + 2.0 {
            return Err(ConfigError {
                field: "history_s",
                value: self.history_s,
                hint: "keep at least max_window_time_s + 2 s of history for the deceleration window",
            });
        }
        if !(self.short_stop_weight > 0.0 && self.short_stop_weight <= 1.0) {
            return Err(ConfigError {
                field: "short_stop_weight",
                value: self.short_stop_weight,
                hint: "choose a share in (0, 1] of a settled window's weight; 0.28 is measured",
            });
        }
        if !(self.gyro_bias_time_constant_s >= 0.01 && self.gyro_bias_time_constant_s <= 1e4) {
            return Err(ConfigError {
                field: "gyro_bias_time_constant_s",
                value: self.gyro_bias_time_constant_s,
                hint: "choose 0.01 to 10000 s; 1 s is the paper's alpha of 0.01 at 100 Hz",
            });
        }
        pos("window_distance_m", self.window_distance_m)?;
        pos("max_chord_deviation_m", self.max_chord_deviation_m)?;
        pos("velocity_free_max_chord_m", self.velocity_free_max_chord_m)?;
        within(
            "chord_noise_sigmas",
            self.chord_noise_sigmas,
            0.0..=10.0,
            "choose 0 (the configured limits alone) to 10; 3 is the default",
        )?;
        within(
            "chord_check_extra_m",
            self.chord_check_extra_m,
            0.0..=5.0,
            "choose 0..5 m",
        )?;
        if !(self.short_window_share.is_finite() && (0.0..1.0).contains(&self.short_window_share)) {
            return Err(ConfigError {
                field: "short_window_share",
                value: self.short_window_share,
                hint: "choose 0 (no fallback) up to below 1; 0.5 keeps the first half",
            });
        }
        pos("max_yaw_rate_dps", self.max_yaw_rate_dps)?;
        pos("max_lateral_acc_mps2", self.max_lateral_acc_mps2)?;
        pos("max_window_time_s", self.max_window_time_s)?;
        pos("max_imu_gap_s", self.max_imu_gap_s)?;
        for (i, v) in self.lever_arm_m.iter().enumerate() {
            if !v.is_finite() || v.abs() > 10.0 {
                return Err(ConfigError {
                    field: ["lever_arm_m[0]", "lever_arm_m[1]", "lever_arm_m[2]"][i],
                    value: *v,
                    hint: "give the IMU offset from the pitch centre in metres, within +-10 m",
                });
            }
        }
        if !(self.history_s.is_finite() && (2.0..=120.0).contains(&self.history_s)) {
            return Err(ConfigError {
                field: "history_s",
                value: self.history_s,
                hint: "keep between 2 and 120 s of IMU history",
            });
        }
        pos("load_change_deg", self.load_change_deg)?;
        pos("load_block_s", self.load_block_s)?;
        nonneg("load_prior_windows", self.load_prior_windows)?;
        pos("shift_deg", self.shift_deg)?;
        if self.shift_windows == 1 || self.shift_windows > 64 {
            return Err(ConfigError {
                field: "shift_windows",
                value: self.shift_windows as f64,
                hint: "use 0 (off) or 2 to 64 windows",
            });
        }
        if self.average_capacity < 2 || self.average_capacity > 4096 {
            return Err(ConfigError {
                field: "average_capacity",
                value: self.average_capacity as f64,
                hint: "keep between 2 and 4096 windows",
            });
        }
        pos("window_sigma_prior_deg", self.window_sigma_prior_deg)?;
        if !(self.acc_bias_prior_mps2 >= 0.001 && self.acc_bias_prior_mps2 <= 2.0) {
            return Err(ConfigError {
                field: "acc_bias_prior_mps2",
                value: self.acc_bias_prior_mps2,
                hint: "give the accelerometer's offset, 0.001-2 m/s^2 (0.2 for an untrimmed MEMS part)",
            });
        }
        for (i, row) in self.acc_matrix.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                let ok = if i == j {
                    (0.9..=1.1).contains(v)
                } else {
                    v.abs() <= 0.05
                };
                if !ok {
                    return Err(ConfigError {
                        field: ACC_MATRIX_FIELDS[i][j],
                        value: *v,
                        hint: "give the accelerometer's calibration near identity: 0.9-1.1 on the diagonal, within +-0.05 off it",
                    });
                }
            }
        }
        Ok(())
    }
}
