//! The simulated world: scenes of a table and object meshes, a depth camera that
//! renders them with a Kinect-like error model, and devices that speak the real
//! protocols (FRI robot, CAN pucks), so the cell runs and is tested without hardware.

pub mod audit;
pub mod camera;
pub mod fri;
pub mod fri_link;
pub mod lab;
pub mod observer;
pub mod physics;
pub mod puck;
pub mod scene;
pub mod world;
