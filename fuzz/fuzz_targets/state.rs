//! Any bytes as a state file: refused with a reason, or restored into an estimator
//! (which may refuse it too) without panicking.
#![no_main]
use leveld::daemon::state::parse;
use leveld::estimator::{Estimator, EstimatorConfig};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(st) = parse(data) {
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        let _ = est.restore(&st.estimator);
        let _ = est.estimate();
    }
});
