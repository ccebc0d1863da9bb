//! graspcell: a controller for a table-top grasping cell.
//!
//! A KUKA LBR4+ arm with a Barrett BH8-282 hand and a fixed RGB-D camera grasp a
//! novel object of a known category for a task, by the method of Nikandrova & Kyrki
//! (2015): one depth snapshot, registration against every model of the category, and
//! the hand pose that maximises expected stability and task compatibility over all of
//! them, subject to reachability and the table. See `ARCHITECTURE.md` in the repository
//! for the processes, their messages and the module layers; each module below owns
//! one concept.

pub mod calib;
pub mod category;
pub mod cell;
pub mod cli;
pub mod clock;
pub mod cloud;
pub mod config;
pub mod eval;
pub mod execute;
pub mod fsio;
pub mod geometry;
pub mod hash;
pub mod hw;
pub mod ipc;
pub mod logging;
pub mod mesh;
pub mod plan;
pub mod ply;
pub mod quality;
pub mod register;
pub mod robot;
pub mod serve;
pub mod sim;
pub mod stats;
pub mod sys;
pub mod trajectory;
pub mod trial;
pub mod untrusted;
