//! Every service name of the cell, in one place.
//!
//! A name is `graspcell/<instance>/<topic path>` for the data (publish-subscribe)
//! service of a topic and the same with `/wake` appended for the event service that
//! wakes its subscribers. Node names are `graspcell/<instance>/<stage>`. The instance
//! name keeps cells (and tests) on one machine apart. No other module writes a
//! service name.

use super::IpcError;
use iceoryx2::prelude::{NodeName, ServiceName};

/// Longest instance name (keeps every service name far below iceoryx2's 255 bytes).
pub const MAX_INSTANCE_LEN: usize = 64;

/// Longest stage name.
pub const MAX_STAGE_LEN: usize = 32;

/// Root of every name of the cell.
const ROOT: &str = "graspcell";

/// Suffix of the event service that wakes a topic's subscribers.
const WAKE_SUFFIX: &str = "wake";

/// A topic of the cell: one publish-subscribe service plus one wake-up event service.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Topic {
    /// Operator -> camera (and everyone): start a trial (category, task, method).
    TrialRequest,
    /// Camera -> perception: the depth snapshot as a point cloud.
    Cloud,
    /// Perception -> planner: registration of every category model.
    Fits,
    /// Planner -> executor: the grasp to execute.
    GraspPlan,
    /// Executor -> log: phase and errors of the execution.
    ExecutionStatus,
    /// Executor -> anyone: arm and hand joint angles.
    JointStates,
    /// Log -> operator: the graded outcome of a trial.
    TrialResult,
    /// Diagnostics: a copy of each received cloud sent back (tests, `cell bench ipc`).
    CloudEcho,
    /// Diagnostics: acknowledgement of a received cloud (tests, `cell bench ipc`).
    CloudAck,
    /// Camera -> log: each snapshot's gravity check, or why there is none.
    CameraStatus,
}

impl Topic {
    /// Every topic.
    pub const ALL: [Topic; 10] = [
        Topic::TrialRequest,
        Topic::Cloud,
        Topic::Fits,
        Topic::GraspPlan,
        Topic::ExecutionStatus,
        Topic::JointStates,
        Topic::TrialResult,
        Topic::CloudEcho,
        Topic::CloudAck,
        Topic::CameraStatus,
    ];

    /// The topic's path below the instance (`<publishing stage>/<what>`).
    pub fn path(self) -> &'static str {
        match self {
            Topic::TrialRequest => "operator/trial_request",
            Topic::Cloud => "camera/cloud",
            Topic::Fits => "perceive/fits",
            Topic::GraspPlan => "plan/grasp_plan",
            Topic::ExecutionStatus => "execute/status",
            Topic::JointStates => "execute/joint_states",
            Topic::TrialResult => "log/trial_result",
            Topic::CloudEcho => "diagnostics/cloud_echo",
            Topic::CloudAck => "diagnostics/cloud_ack",
            Topic::CameraStatus => "camera/status",
        }
    }
}

/// The topics that carry point clouds (a header and a slice of points).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CloudTopic {
    /// The camera's snapshot.
    Camera,
    /// Diagnostics: clouds sent back by an echo peer.
    Echo,
}

impl CloudTopic {
    /// The topic of this cloud stream.
    pub fn topic(self) -> Topic {
        match self {
            CloudTopic::Camera => Topic::Cloud,
            CloudTopic::Echo => Topic::CloudEcho,
        }
    }
}

/// The service and node names of one cell instance.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Services {
    instance: String,
}

impl Services {
    /// Names for the cell instance `instance`: 1 to 64 ASCII letters, digits, `_`,
    /// `-` or `.`.
    pub fn new(instance: &str) -> Result<Services, IpcError> {
        check_identifier(instance, MAX_INSTANCE_LEN).map_err(|reason| {
            IpcError::InvalidInstance {
                instance: instance.to_string(),
                reason,
            }
        })?;
        Ok(Services {
            instance: instance.to_string(),
        })
    }

    /// The instance name.
    pub fn instance(&self) -> &str {
        &self.instance
    }

    /// Name of the publish-subscribe service of `topic`, as text.
    pub fn data_name(&self, topic: Topic) -> String {
        format!("{ROOT}/{}/{}", self.instance, topic.path())
    }

    /// Name of the event service that wakes the subscribers of `topic`, as text.
    pub fn wake_name(&self, topic: Topic) -> String {
        format!("{}/{WAKE_SUFFIX}", self.data_name(topic))
    }

    /// The iceoryx2 name of the publish-subscribe service of `topic`.
    pub fn data(&self, topic: Topic) -> Result<ServiceName, IpcError> {
        service_name(&self.data_name(topic))
    }

    /// The iceoryx2 name of the wake-up event service of `topic`.
    pub fn wake(&self, topic: Topic) -> Result<ServiceName, IpcError> {
        service_name(&self.wake_name(topic))
    }

    /// Name of the node of stage `stage` (`camera`, `perceive`, ...), as text.
    pub fn node_name_text(&self, stage: &str) -> Result<String, IpcError> {
        check_identifier(stage, MAX_STAGE_LEN).map_err(|reason| IpcError::InvalidStage {
            stage: stage.to_string(),
            reason,
        })?;
        Ok(format!("{ROOT}/{}/{stage}", self.instance))
    }

    /// The iceoryx2 node name of stage `stage`.
    pub fn node_name(&self, stage: &str) -> Result<NodeName, IpcError> {
        let text = self.node_name_text(stage)?;
        NodeName::new(&text).map_err(|e| IpcError::iceoryx("node name", text, e))
    }
}

fn service_name(text: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(text).map_err(|e| IpcError::iceoryx("service name", text, e))
}

fn check_identifier(text: &str, max: usize) -> Result<(), &'static str> {
    if text.is_empty() {
        return Err("empty");
    }
    if text.len() > max {
        return Err("too long");
    }
    if !text
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'))
    {
        return Err("only ASCII letters, digits, '_', '-' and '.' are allowed");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    #[test]
    fn names_follow_the_scheme() {
        let s = Services::new("cell-1").unwrap();
        assert_eq!(s.data_name(Topic::Cloud), "graspcell/cell-1/camera/cloud");
        assert_eq!(
            s.wake_name(Topic::Cloud),
            "graspcell/cell-1/camera/cloud/wake"
        );
        assert_eq!(
            s.node_name_text("perceive").unwrap(),
            "graspcell/cell-1/perceive"
        );
        assert_eq!(
            s.data(Topic::TrialResult).unwrap().as_str(),
            "graspcell/cell-1/log/trial_result"
        );
    }

    #[test]
    fn all_names_are_distinct_and_valid_for_the_longest_instance() {
        let s = Services::new(&"x".repeat(MAX_INSTANCE_LEN)).unwrap();
        let mut seen = HashSet::new();
        for topic in Topic::ALL {
            assert!(seen.insert(s.data(topic).unwrap().as_str().to_string()));
            assert!(seen.insert(s.wake(topic).unwrap().as_str().to_string()));
        }
        assert_eq!(seen.len(), 2 * Topic::ALL.len());
        s.node_name(&"y".repeat(MAX_STAGE_LEN)).unwrap();
    }

    #[test]
    fn bad_instances_and_stages_are_rejected() {
        for bad in ["", "a/b", "a b", "ä", &"x".repeat(MAX_INSTANCE_LEN + 1)] {
            let err = Services::new(bad).unwrap_err();
            assert!(matches!(err, IpcError::InvalidInstance { .. }), "{bad:?}");
        }
        let s = Services::new("c").unwrap();
        assert!(matches!(
            s.node_name("cam/era"),
            Err(IpcError::InvalidStage { .. })
        ));
    }
}
