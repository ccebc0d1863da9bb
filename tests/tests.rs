//! Integration and hardware-in-loop tests, built as one binary (one link step).

mod shipped_files;
mod trial;
mod calib;
mod camera;
mod objects;
mod fri;
mod can;
mod quality;
mod ipc;
