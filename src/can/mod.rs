//! CAN side: DBC-driven codecs, message checks and candump log I/O.

pub mod candump;
pub mod checks;
pub mod dbc;
pub mod signal;
