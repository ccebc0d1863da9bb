//! Device traits and backends. Every blocking call takes a timeout.
//!
//! - [`can`]: the CAN bus trait with SocketCAN, in-process and cross-process backends.
//! - [`hand`]: the Barrett BH8-282 driver over any CAN bus.

pub mod can;
pub mod hand;
