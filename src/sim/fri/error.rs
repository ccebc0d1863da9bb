//! What can go wrong configuring or running the FRI simulator.

use std::net::SocketAddr;

/// Errors of configuring or running the simulator.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A configuration value is out of range.
    #[error("FRI simulator: {field} = {value}: {problem}")]
    BadConfig {
        /// The field.
        field: String,
        /// The offending value, as text.
        value: String,
        /// What is wrong with it.
        problem: &'static str,
    },
    /// A socket operation failed.
    #[error("FRI simulator: {op} {addr}: {source}")]
    Io {
        /// What was being done.
        op: &'static str,
        /// The address involved.
        addr: SocketAddr,
        /// The I/O error.
        source: std::io::Error,
    },
}
