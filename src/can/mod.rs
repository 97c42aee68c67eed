//! CAN side: DBC-driven codecs, message checks and candump log I/O.

pub mod candump;
pub mod checks;
pub mod codec;
pub mod dbc;
pub mod signal;

/// Error-frame class bits and controller status bytes (linux/can/error.h).
pub const CAN_ERR_CRTL: u32 = 0x0000_0004;
pub const CAN_ERR_BUSOFF: u32 = 0x0000_0040;
pub const CAN_ERR_RESTARTED: u32 = 0x0000_0100;
pub const CAN_ERR_CRTL_RX_PASSIVE: u8 = 0x10;
pub const CAN_ERR_CRTL_TX_PASSIVE: u8 = 0x20;
