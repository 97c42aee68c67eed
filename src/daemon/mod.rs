//! The daemon side: the frame pipeline shared by live runs and replays.

pub mod gateway;
pub mod replay;
