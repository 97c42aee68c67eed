//! The pipeline clock: frame timestamps turned into a time that only moves forward.
//!
//! Frame timestamps come from a log or from the kernel. A log may hold a line stamped
//! far in the future or the past (an edited or spliced file, a logger whose clock was
//! set while it ran); a live ECU without a real-time clock may step its wall clock
//! when GNSS or NTP arrives. Such a step would freeze the estimator (every later frame
//! looks old) or make it catch up hours of output at once. So a timestamp that goes
//! back by more than `BACK_TOL_S`, or forward by more than the configured gap, counts
//! as a clock step: the pipeline time continues from where it was, shifted by the
//! step, and the caller restarts what spans time (timeouts, an open standstill).

use std::time::{Instant, SystemTime, UNIX_EPOCH};

/// Frames of different interfaces may arrive slightly out of order: a timestamp this
/// much behind the newest is taken as the newest, not as a step, s.
pub const BACK_TOL_S: f64 = 0.5;

/// Outcome of mapping one timestamp.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Mapped {
    /// Pipeline time, s.
    Time(f64),
    /// The clock stepped by `step_s` (frame time minus expected); pipeline time `t_s`.
    Step { t_s: f64, step_s: f64 },
    /// Not a usable timestamp (NaN or infinite).
    Invalid,
}

#[derive(Debug, Clone, Copy)]
pub struct FrameClock {
    /// Pipeline time minus frame time, s.
    offset_s: f64,
    /// Newest pipeline time handed out, s.
    last_s: Option<f64>,
    max_gap_s: f64,
    /// Steps seen.
    pub steps: u64,
}

impl FrameClock {
    /// `max_gap_s`: the longest forward jump taken as time that passed.
    pub fn new(max_gap_s: f64) -> Self {
        Self {
            offset_s: 0.0,
            last_s: None,
            max_gap_s,
            steps: 0,
        }
    }

    pub fn map(&mut self, frame_t_s: f64) -> Mapped {
        if !frame_t_s.is_finite() {
            return Mapped::Invalid;
        }
        let Some(last) = self.last_s else {
            self.last_s = Some(frame_t_s);
            return Mapped::Time(frame_t_s);
        };
        let t = frame_t_s + self.offset_s;
        let d = t - last;
        if d >= 0.0 && d <= self.max_gap_s {
            self.last_s = Some(t);
            return Mapped::Time(t);
        }
        if (-BACK_TOL_S..0.0).contains(&d) {
            return Mapped::Time(last);
        }
        // A step: continue from the newest time.
        self.offset_s = last - frame_t_s;
        self.steps += 1;
        Mapped::Step {
            t_s: last,
            step_s: d,
        }
    }

    /// Newest pipeline time, if any frame was seen.
    pub fn now_s(&self) -> Option<f64> {
        self.last_s
    }
}

/// A jump of the wall clock against the monotonic clock larger than this between two
/// reads is a step, not a slew, s.
const MAX_WALL_STEP_S: f64 = 0.5;

/// Pipeline time of a live run. Frames carry the kernel's receive time, a wall-clock
/// time, so that a candump recording of the same frames replays to the same output. The
/// wall clock may be stepped at any moment (GNSS or NTP after boot, a user), so the
/// offset between the wall clock and CLOCK_MONOTONIC is read with every frame and
/// tick: a slow slew is followed, and a jump of more than `MAX_WALL_STEP_S` is a step,
/// taken out of every later stamp and tick. A step of the wall clock therefore changes
/// neither the output period nor the estimate.
pub struct MonoClock {
    start: Instant,
    /// Wall clock minus monotonic clock as last read, s.
    wall_minus_mono_s: f64,
    /// Sum of the wall-clock steps taken out, s.
    offset_s: f64,
    pub steps: u64,
}

fn wall_s(t: SystemTime) -> f64 {
    match t.duration_since(UNIX_EPOCH) {
        Ok(d) => d.as_secs_f64(),
        Err(e) => -e.duration().as_secs_f64(),
    }
}

/// A kernel receive stamp in seconds, cut to whole microseconds as candump writes it:
/// a drive recorded with candump replays with the very times the daemon saw, and so
/// to the same output. Exact: the microseconds since the epoch fit an f64's mantissa,
/// and one division rounds them as parsing the log line does.
fn frame_stamp_s(t: SystemTime) -> f64 {
    match t.duration_since(UNIX_EPOCH) {
        Ok(d) => {
            let us = d
                .as_secs()
                .saturating_mul(1_000_000)
                .saturating_add(u64::from(d.subsec_micros()));
            us as f64 / 1e6
        }
        Err(e) => -e.duration().as_secs_f64(),
    }
}

impl Default for MonoClock {
    fn default() -> Self {
        Self::new()
    }
}

impl MonoClock {
    pub fn new() -> Self {
        let start = Instant::now();
        Self {
            start,
            wall_minus_mono_s: wall_s(SystemTime::now()),
            offset_s: 0.0,
            steps: 0,
        }
    }

    /// Read both clocks; take a jump of their difference out as a step. Returns the
    /// monotonic time, s.
    fn sample(&mut self) -> f64 {
        let mono = self.start.elapsed().as_secs_f64();
        let d = wall_s(SystemTime::now()) - mono;
        let jump = d - self.wall_minus_mono_s;
        if jump.abs() > MAX_WALL_STEP_S {
            self.offset_s -= jump;
            self.steps += 1;
            tracing::warn!(
                step_s = jump,
                "the wall clock stepped; leveld keeps its own time"
            );
        }
        self.wall_minus_mono_s = d;
        mono
    }

    /// Now, in pipeline time.
    pub fn now_s(&mut self) -> f64 {
        let mono = self.sample();
        mono + self.wall_minus_mono_s + self.offset_s
    }

    /// Pipeline time of a frame stamped `stamp` by the kernel.
    pub fn frame_s(&mut self, stamp: SystemTime) -> f64 {
        self.sample();
        frame_stamp_s(stamp) + self.offset_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn a_kernel_stamp_is_the_time_its_candump_line_parses_to() {
        for (secs, ns) in [
            (1_733_330_000u64, 123_456_789u32),
            (1_733_330_000, 999_999_999),
            (1_733_330_001, 1_000),
            (4_102_444_800, 500),
            (12, 345_678_901),
        ] {
            let stamp = UNIX_EPOCH + Duration::new(secs, ns);
            let line = format!("({secs}.{:06}) can0 3E0#00", ns / 1000);
            let crate::can::candump::Line::Frame(f) =
                crate::can::candump::parse_line(&line).unwrap()
            else {
                panic!("{line}");
            };
            assert_eq!(frame_stamp_s(stamp).to_bits(), f.t_s.to_bits(), "{line}");
        }
    }

    #[test]
    fn steady_time_passes_through() {
        let mut c = FrameClock::new(5.0);
        assert_eq!(c.map(10.0), Mapped::Time(10.0));
        assert_eq!(c.map(10.01), Mapped::Time(10.01));
        assert_eq!(c.map(13.0), Mapped::Time(13.0));
        assert_eq!(c.steps, 0);
    }

    #[test]
    fn small_reordering_is_held_not_stepped() {
        let mut c = FrameClock::new(5.0);
        c.map(10.0);
        assert_eq!(c.map(9.8), Mapped::Time(10.0));
        assert_eq!(c.steps, 0);
    }

    #[test]
    fn one_stray_timestamp_costs_two_steps_and_time_goes_on() {
        let mut c = FrameClock::new(5.0);
        c.map(1.0);
        c.map(1.01);
        assert!(matches!(c.map(9.02), Mapped::Step { t_s, .. } if t_s == 1.01));
        // Back to the true clock: another step, then normal time from there.
        assert!(matches!(c.map(1.03), Mapped::Step { t_s, .. } if t_s == 1.01));
        assert!(matches!(c.map(1.04), Mapped::Time(t) if (t - 1.02).abs() < 1e-9));
        assert_eq!(c.steps, 2);
    }

    #[test]
    fn huge_and_invalid_timestamps_do_not_move_time() {
        let mut c = FrameClock::new(5.0);
        c.map(1.0);
        assert!(matches!(c.map(1125899906842624.0), Mapped::Step { t_s, .. } if t_s == 1.0));
        assert_eq!(c.map(f64::NAN), Mapped::Invalid);
        assert_eq!(c.map(f64::INFINITY), Mapped::Invalid);
        assert!(matches!(c.map(1125899906842624.01), Mapped::Time(t) if (t - 1.01).abs() < 0.1));
    }
}
