//! The simulated world: device emulators that stand in for the hardware.

pub mod puck;
