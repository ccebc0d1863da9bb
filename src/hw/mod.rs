//! Device drivers behind traits: every blocking call takes a timeout, and each
//! driver's documentation says what "stop" does to the hardware.

pub mod fri;
