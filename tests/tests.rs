//! Integration and hardware-in-loop tests, built as one binary (one link step).

mod ipc;
