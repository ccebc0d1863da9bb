//! Kinematics, reachability and collision of the LBR4+ with the BH8-282.
