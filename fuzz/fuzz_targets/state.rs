//! Any bytes as a state file or a calibration file: refused with a reason, or restored
//! into an estimator (which may refuse it too) without panicking.
#![no_main]
use leveld::daemon::{calibration, state};
use leveld::estimator::{Estimator, EstimatorConfig};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(st) = state::parse(data) {
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        let _ = est.restore(&st.estimator);
        let _ = est.estimate();
    }
    if let Ok(c) = calibration::parse(data) {
        assert!(c.reference_pitch_deg.is_finite() && c.reference_pitch_deg.abs() <= 10.0);
    }
});
