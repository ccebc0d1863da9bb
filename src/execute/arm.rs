//! The arm as the executor sees it: the few operations it needs, behind a trait so
//! the safety layer wraps any implementation (the FRI driver on the cell; a
//! simulated link in tests).

use crate::hw::fri::{ForceGuard, FriDriver, FriError, FriStatus, JOINTS};
use crate::trajectory::Trajectory;

/// A joint-position-controlled arm that follows time-parametrised trajectories.
///
/// Calls do not block: the executor polls [`Arm::motion_outcome`] on its own clock,
/// so its watchdog decides how long to wait.
pub trait Arm {
    /// The link and the arm now (commanded and measured joints, command mode,
    /// late measurements).
    fn status(&self) -> FriStatus;
    /// Starts following `trajectory` (it must start at the commanded position);
    /// returns the motion's id.
    fn start_trajectory(&self, trajectory: Trajectory<JOINTS>) -> Result<u64, FriError>;
    /// Starts following `trajectory` guarded by `guard`: the arm stops (decelerates,
    /// then holds) when the estimated external TCP force exceeds the guard's
    /// threshold, and the motion ends with [`FriError::Contact`].
    fn start_guarded_trajectory(
        &self,
        trajectory: Trajectory<JOINTS>,
        guard: ForceGuard,
    ) -> Result<u64, FriError>;
    /// How motion `id` ended, or `None` while it runs.
    fn motion_outcome(&self, id: u64) -> Option<Result<(), FriError>>;
    /// Ends any motion: decelerate within the trajectory's limits, then hold.
    fn stop(&self);
}

impl Arm for FriDriver {
    fn status(&self) -> FriStatus {
        FriDriver::status(self)
    }

    fn start_trajectory(&self, trajectory: Trajectory<JOINTS>) -> Result<u64, FriError> {
        FriDriver::start_trajectory(self, trajectory)
    }

    fn start_guarded_trajectory(
        &self,
        trajectory: Trajectory<JOINTS>,
        guard: ForceGuard,
    ) -> Result<u64, FriError> {
        FriDriver::start_guarded_trajectory(self, trajectory, guard)
    }

    fn motion_outcome(&self, id: u64) -> Option<Result<(), FriError>> {
        FriDriver::motion_outcome(self, id)
    }

    fn stop(&self) {
        FriDriver::stop(self)
    }
}

impl<A: Arm + ?Sized> Arm for &A {
    fn status(&self) -> FriStatus {
        (**self).status()
    }

    fn start_trajectory(&self, trajectory: Trajectory<JOINTS>) -> Result<u64, FriError> {
        (**self).start_trajectory(trajectory)
    }

    fn start_guarded_trajectory(
        &self,
        trajectory: Trajectory<JOINTS>,
        guard: ForceGuard,
    ) -> Result<u64, FriError> {
        (**self).start_guarded_trajectory(trajectory, guard)
    }

    fn motion_outcome(&self, id: u64) -> Option<Result<(), FriError>> {
        (**self).motion_outcome(id)
    }

    fn stop(&self) {
        (**self).stop()
    }
}
