//! Device drivers behind traits. Every blocking call takes a timeout, and each
//! driver's documentation says what "stop" does to the hardware.
//!
//! - [`can`]: the CAN bus trait with SocketCAN, in-process and cross-process backends.
//! - [`hand`]: the Barrett BH8-282 driver over any CAN bus.
//! - [`fri`]: the KUKA LBR4+ over FRI 1.x (UDP).
//! - [`kinect`]: the Kinect v1 camera through libfreenect (driver behind the
//!   `kinect` feature), its depth model and fakenect recordings.
//! - [`realtime`]: real-time priority for the threads that answer a device's cycle.

pub mod can;
pub mod fri;
pub mod hand;
pub mod kinect;
pub mod realtime;
