//! The simulated world: devices that speak the real protocols, so the cell runs and
//! is tested without hardware.

pub mod fri;
