//! A process of the cell on iceoryx2: its node, typed ports and its peers' liveness.
//!
//! Every publisher here pairs a publish-subscribe port with a notifier on the topic's
//! wake-up event service, and every subscriber pairs its port with a listener, so a
//! receiver blocks (with a timeout) instead of spinning. Service settings (queue
//! depths, maximum ports, slice sizes) are fixed here for every process alike, since
//! iceoryx2 only opens a service whose settings are compatible.

use super::domain::Domain;
use super::payloads::{CloudHeader, Message, Point, MAX_CLOUD_POINTS};
use super::services::{CloudTopic, Topic};
use super::IpcError;
use iceoryx2::node::{NodeState, NodeView};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::sample_mut::SampleMut;
use iceoryx2::service::port_factory::event::PortFactory as EventService;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubService;
use std::marker::PhantomData;
use std::time::{Duration, Instant};

type Ipc = ipc::Service;

/// How long [`Stage::start`] waits for another process that is cleaning a dead node.
pub const CLEANUP_TIMEOUT: Duration = Duration::from_millis(500);

/// Queue depth of every subscriber (newer samples replace the oldest when full).
const SUBSCRIBER_BUFFER: usize = 2;
/// Samples a subscriber may hold at once.
const SUBSCRIBER_BORROWED: usize = 2;
/// Most publishers of a message topic.
const MESSAGE_MAX_PUBLISHERS: usize = 4;
/// Most subscribers of a message topic (every stage plus the log and tools).
const MESSAGE_MAX_SUBSCRIBERS: usize = 8;
/// Most publishers of a cloud topic (a restarted camera while the dead one is not yet
/// cleaned counts twice).
const CLOUD_MAX_PUBLISHERS: usize = 2;
/// Most subscribers of a cloud topic; each costs shared memory for 4 full clouds.
const CLOUD_MAX_SUBSCRIBERS: usize = 4;

/// How many processes on the other side of a port are alive or dead.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Peers {
    /// Ports whose node's process is alive.
    pub alive: usize,
    /// Ports whose node's process died without cleaning up (not yet cleaned).
    pub dead: usize,
}

/// The state of a stage's node as seen from another process.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StageStatus {
    /// No node of that stage exists.
    Missing,
    /// A node of that stage is alive.
    Alive,
    /// Only dead nodes of that stage exist (its process died; not yet cleaned).
    Dead,
}

/// One process of the cell: an iceoryx2 node named after the stage.
#[derive(Debug)]
pub struct Stage {
    domain: Domain,
    name: String,
    node: Node<Ipc>,
    cleaned_at_start: u64,
}

impl Stage {
    /// Creates the node of stage `stage` (e.g. `camera`) in `domain` and removes the
    /// stale resources of every dead node of the domain (a process that was killed).
    pub fn start(domain: &Domain, stage: &str) -> Result<Stage, IpcError> {
        let node_name = domain.services().node_name(stage)?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .config(domain.config())
            .create::<Ipc>()
            .map_err(|e| IpcError::iceoryx("create node", node_name.as_str(), e))?;
        let cleaned = node.blocking_cleanup_dead_nodes(CLEANUP_TIMEOUT);
        if cleaned.cleanups > 0 {
            tracing::info!(
                stage,
                dead_nodes = cleaned.cleanups,
                "cleaned stale resources of dead nodes"
            );
        }
        if cleaned.failed_cleanups > 0 {
            tracing::warn!(
                stage,
                failed = cleaned.failed_cleanups,
                "could not clean every dead node"
            );
        }
        Ok(Stage {
            domain: domain.clone(),
            name: stage.to_string(),
            node,
            cleaned_at_start: cleaned.cleanups,
        })
    }

    /// The stage name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The domain the stage lives in.
    pub fn domain(&self) -> &Domain {
        &self.domain
    }

    /// The iceoryx2 node (for what this module does not wrap).
    pub fn node(&self) -> &Node<Ipc> {
        &self.node
    }

    /// Number of dead nodes whose resources [`Stage::start`] removed.
    pub fn dead_nodes_cleaned_at_start(&self) -> u64 {
        self.cleaned_at_start
    }

    /// Removes the stale resources of dead nodes now; returns how many were removed.
    pub fn cleanup_dead_nodes(&self) -> u64 {
        self.node.try_cleanup_dead_nodes().cleanups
    }

    /// Whether stage `stage` of this cell instance has a living node.
    pub fn stage_status(&self, stage: &str) -> Result<StageStatus, IpcError> {
        let wanted = self.domain.services().node_name_text(stage)?;
        let mut status = StageStatus::Missing;
        Node::<Ipc>::list(self.domain.config(), |state| {
            let named = |view: &dyn NodeView| {
                view.details()
                    .as_ref()
                    .is_some_and(|d| d.name().as_str() == wanted)
            };
            match &state {
                NodeState::Alive(view) if named(view) => {
                    status = StageStatus::Alive;
                    return CallbackProgression::Stop;
                }
                NodeState::Dead(view) if named(view) => status = StageStatus::Dead,
                _ => {}
            }
            CallbackProgression::Continue
        })
        .map_err(|e| IpcError::iceoryx("list nodes", wanted.clone(), e))?;
        Ok(status)
    }

    /// A publisher of message type `M` on its topic.
    pub fn publisher<M: Message>(&self) -> Result<MessagePublisher<M>, IpcError> {
        let target = self.domain.services().data_name(M::TOPIC);
        let service = self.message_service::<M>()?;
        let publisher = service
            .publisher_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("create publisher", &target, e))?;
        Ok(MessagePublisher {
            notifier: self.notifier(M::TOPIC)?,
            service,
            publisher,
            target,
            config: self.domain.config().clone(),
        })
    }

    /// A subscriber of message type `M` on its topic.
    pub fn subscriber<M: Message>(&self) -> Result<MessageSubscriber<M>, IpcError> {
        let target = self.domain.services().data_name(M::TOPIC);
        let service = self.message_service::<M>()?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(SUBSCRIBER_BUFFER)
            .create()
            .map_err(|e| IpcError::iceoryx("create subscriber", &target, e))?;
        Ok(MessageSubscriber {
            listener: self.listener(M::TOPIC)?,
            service,
            subscriber,
            target,
            config: self.domain.config().clone(),
            _message: PhantomData,
        })
    }

    /// A publisher of point clouds of up to [`MAX_CLOUD_POINTS`] points on `topic`.
    pub fn cloud_publisher(&self, topic: CloudTopic) -> Result<CloudPublisher, IpcError> {
        let target = self.domain.services().data_name(topic.topic());
        let service = self.cloud_service(topic)?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(MAX_CLOUD_POINTS)
            // Static: a subscriber maps the whole segment when it connects, so a cloud
            // outlives a publisher that exits right after sending it (a growable
            // segment is mapped on first receipt, and such a cloud would be lost).
            .allocation_strategy(AllocationStrategy::Static)
            .create()
            .map_err(|e| IpcError::iceoryx("create publisher", &target, e))?;
        Ok(CloudPublisher {
            notifier: self.notifier(topic.topic())?,
            service,
            publisher,
            target,
            config: self.domain.config().clone(),
        })
    }

    /// A subscriber of point clouds on `topic`.
    pub fn cloud_subscriber(&self, topic: CloudTopic) -> Result<CloudSubscriber, IpcError> {
        let target = self.domain.services().data_name(topic.topic());
        let service = self.cloud_service(topic)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(SUBSCRIBER_BUFFER)
            .create()
            .map_err(|e| IpcError::iceoryx("create subscriber", &target, e))?;
        Ok(CloudSubscriber {
            listener: self.listener(topic.topic())?,
            service,
            subscriber,
            target,
            config: self.domain.config().clone(),
        })
    }

    fn message_service<M: Message>(&self) -> Result<PubSubService<Ipc, M, ()>, IpcError> {
        let name = self.domain.services().data(M::TOPIC)?;
        self.node
            .service_builder(&name)
            .publish_subscribe::<M>()
            .max_publishers(MESSAGE_MAX_PUBLISHERS)
            .max_subscribers(MESSAGE_MAX_SUBSCRIBERS)
            .subscriber_max_buffer_size(SUBSCRIBER_BUFFER)
            .subscriber_max_borrowed_samples(SUBSCRIBER_BORROWED)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(|e| IpcError::iceoryx("open or create service", name.as_str(), e))
    }

    fn cloud_service(
        &self,
        topic: CloudTopic,
    ) -> Result<PubSubService<Ipc, [Point], CloudHeader>, IpcError> {
        let name = self.domain.services().data(topic.topic())?;
        self.node
            .service_builder(&name)
            .publish_subscribe::<[Point]>()
            .user_header::<CloudHeader>()
            .max_publishers(CLOUD_MAX_PUBLISHERS)
            .max_subscribers(CLOUD_MAX_SUBSCRIBERS)
            .subscriber_max_buffer_size(SUBSCRIBER_BUFFER)
            .subscriber_max_borrowed_samples(SUBSCRIBER_BORROWED)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(|e| IpcError::iceoryx("open or create service", name.as_str(), e))
    }

    fn wake_service(&self, topic: Topic) -> Result<EventService<Ipc>, IpcError> {
        let name = self.domain.services().wake(topic)?;
        self.node
            .service_builder(&name)
            .event()
            .open_or_create()
            .map_err(|e| IpcError::iceoryx("open or create event service", name.as_str(), e))
    }

    fn notifier(&self, topic: Topic) -> Result<Notifier<Ipc>, IpcError> {
        self.wake_service(topic)?
            .notifier_builder()
            .create()
            .map_err(|e| {
                IpcError::iceoryx(
                    "create notifier",
                    self.domain.services().wake_name(topic),
                    e,
                )
            })
    }

    fn listener(&self, topic: Topic) -> Result<Listener<Ipc>, IpcError> {
        self.wake_service(topic)?
            .listener_builder()
            .create()
            .map_err(|e| {
                IpcError::iceoryx(
                    "create listener",
                    self.domain.services().wake_name(topic),
                    e,
                )
            })
    }
}

/// Calls `check` every millisecond until it returns true or `timeout` passes;
/// returns whether it did. For waiting on another process to come up.
pub fn poll_until(
    timeout: Duration,
    mut check: impl FnMut() -> Result<bool, IpcError>,
) -> Result<bool, IpcError> {
    let deadline = Instant::now() + timeout;
    loop {
        if check()? {
            return Ok(true);
        }
        if Instant::now() >= deadline {
            return Ok(false);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// A receiver that can be woken: gives access to its topic's wake-up listener.
pub trait Wakeable {
    /// The listener of the topic's wake-up event service (e.g. to attach to an
    /// iceoryx2 `WaitSet`).
    fn wake_listener(&self) -> &Listener<Ipc>;
}

/// Blocks until any of `receivers` is woken or `timeout` passes; returns whether one
/// was woken. It consumes the wake-ups, so call `try_receive` on every receiver
/// afterwards until each is empty (a stage that listens to several topics loops:
/// drain all, then wait).
pub fn wait_any(receivers: &[&dyn Wakeable], timeout: Duration) -> Result<bool, IpcError> {
    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(|e| IpcError::iceoryx("create wait set", "wait_any", e))?;
    let guards = receivers
        .iter()
        .map(|r| waitset.attach_notification(r.wake_listener()))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| IpcError::iceoryx("attach to wait set", "wait_any", e))?;
    let mut woken = false;
    waitset
        .wait_and_process_once_with_timeout(
            |_| {
                woken = true;
                CallbackProgression::Continue
            },
            timeout,
        )
        .map_err(|e| IpcError::iceoryx("wait", "wait_any", e))?;
    drop(guards);
    for receiver in receivers {
        receiver
            .wake_listener()
            .try_wait(|_| {})
            .map_err(|e| IpcError::iceoryx("consume wake-ups", "wait_any", e))?;
    }
    Ok(woken)
}

/// Tries `try_once`, then blocks on `listener` until the next wake-up, until a value
/// arrives or `timeout` passes (then `None`).
fn receive_with_timeout<T>(
    listener: &Listener<Ipc>,
    target: &str,
    timeout: Duration,
    mut try_once: impl FnMut() -> Result<Option<T>, IpcError>,
) -> Result<Option<T>, IpcError> {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(value) = try_once()? {
            return Ok(Some(value));
        }
        let now = Instant::now();
        if now >= deadline {
            return Ok(None);
        }
        listener
            .timed_wait(|_| {}, deadline - now)
            .map_err(|e| IpcError::iceoryx("wait for wake-up", target, e))?;
    }
}

fn wake(notifier: &Notifier<Ipc>, target: &str) -> Result<(), IpcError> {
    notifier
        .notify()
        .map(|_| ())
        .map_err(|e| IpcError::iceoryx("notify", target, e))
}

/// Counts living and dead processes among the nodes of `nodes`.
fn classify_nodes(
    config: &iceoryx2::config::Config,
    target: &str,
    nodes: Vec<iceoryx2::identifiers::UniqueNodeId>,
) -> Result<Peers, IpcError> {
    let mut peers = Peers::default();
    for id in nodes {
        match Node::<Ipc>::state_of(config, id)
            .map_err(|e| IpcError::iceoryx("node state", target, e))?
        {
            Some(NodeState::Alive(_)) => peers.alive += 1,
            // Dead, gone while its port is still registered, or unreadable.
            _ => peers.dead += 1,
        }
    }
    Ok(peers)
}

/// The ports of a service whose nodes [`port_peers`] classifies.
#[derive(Clone, Copy)]
enum Ports {
    Publishers,
    Subscribers,
}

fn port_peers<P: std::fmt::Debug + ?Sized + iceoryx2::prelude::IceoryxSend, H>(
    service: &PubSubService<Ipc, P, H>,
    config: &iceoryx2::config::Config,
    target: &str,
    ports: Ports,
) -> Result<Peers, IpcError>
where
    H: std::fmt::Debug + ZeroCopySend,
{
    let mut nodes = Vec::new();
    let dynamic = service.dynamic_config();
    match ports {
        Ports::Publishers => dynamic.list_publishers(|d| {
            nodes.push(d.node_id);
            CallbackProgression::Continue
        }),
        Ports::Subscribers => dynamic.list_subscribers(|d| {
            nodes.push(d.node_id);
            CallbackProgression::Continue
        }),
    }
    classify_nodes(config, target, nodes)
}

/// Publishes messages of type `M` and wakes their subscribers.
///
/// Keep a publisher until its subscribers have its messages: a subscriber maps a
/// publisher's memory when it first receives after the publisher appeared, so what
/// a publisher sent and then dropped before that is lost (a one-shot sender such as
/// an operator command waits for the answer before it exits).
#[derive(Debug)]
pub struct MessagePublisher<M: Message> {
    service: PubSubService<Ipc, M, ()>,
    publisher: Publisher<Ipc, M, ()>,
    notifier: Notifier<Ipc>,
    target: String,
    config: iceoryx2::config::Config,
}

impl<M: Message> MessagePublisher<M> {
    /// Sends a copy of `message`; returns the number of subscribers it reached.
    pub fn send(&self, message: &M) -> Result<usize, IpcError> {
        let reached = self
            .publisher
            .send_copy(*message)
            .map_err(|e| IpcError::iceoryx("send", &self.target, e))?;
        wake(&self.notifier, &self.target)?;
        Ok(reached)
    }

    /// Living and dead subscribers of the topic.
    pub fn subscriber_peers(&self) -> Result<Peers, IpcError> {
        port_peers(
            &self.service,
            &self.config,
            &self.target,
            Ports::Subscribers,
        )
    }
}

/// Receives messages of type `M`.
#[derive(Debug)]
pub struct MessageSubscriber<M: Message> {
    service: PubSubService<Ipc, M, ()>,
    subscriber: Subscriber<Ipc, M, ()>,
    listener: Listener<Ipc>,
    target: String,
    config: iceoryx2::config::Config,
    _message: PhantomData<M>,
}

impl<M: Message> MessageSubscriber<M> {
    /// The oldest queued message, if any, without blocking.
    pub fn try_receive(&self) -> Result<Option<M>, IpcError> {
        self.subscriber
            .receive()
            .map(|sample| sample.map(|s| *s.payload()))
            .map_err(|e| IpcError::iceoryx("receive", &self.target, e))
    }

    /// The oldest queued message, blocking up to `timeout` for one (`None` if none).
    pub fn receive_timeout(&self, timeout: Duration) -> Result<Option<M>, IpcError> {
        receive_with_timeout(&self.listener, &self.target, timeout, || self.try_receive())
    }

    /// Living and dead publishers of the topic.
    pub fn publisher_peers(&self) -> Result<Peers, IpcError> {
        port_peers(&self.service, &self.config, &self.target, Ports::Publishers)
    }
}

impl<M: Message> Wakeable for MessageSubscriber<M> {
    fn wake_listener(&self) -> &Listener<Ipc> {
        &self.listener
    }
}

/// Publishes point clouds (a [`CloudHeader`] and up to [`MAX_CLOUD_POINTS`] points)
/// written directly into shared memory, and wakes their subscribers. As for
/// [`MessagePublisher`], keep it until its subscribers have what it sent.
#[derive(Debug)]
pub struct CloudPublisher {
    service: PubSubService<Ipc, [Point], CloudHeader>,
    publisher: Publisher<Ipc, [Point], CloudHeader>,
    notifier: Notifier<Ipc>,
    target: String,
    config: iceoryx2::config::Config,
}

impl CloudPublisher {
    fn check_len(&self, header: &CloudHeader, len: usize) -> Result<(), IpcError> {
        if header.len() != len || len > MAX_CLOUD_POINTS {
            return Err(IpcError::CloudShape {
                width: header.width,
                height: header.height,
                points: len,
                max: MAX_CLOUD_POINTS,
            });
        }
        Ok(())
    }

    /// A cloud in shared memory with `header` and the points copied from `points`.
    pub fn loan_copy(
        &self,
        header: CloudHeader,
        points: &[Point],
    ) -> Result<CloudLoan<'_>, IpcError> {
        self.check_len(&header, points.len())?;
        let mut sample = self
            .publisher
            .loan_slice_uninit(points.len())
            .map_err(|e| IpcError::iceoryx("loan", &self.target, e))?;
        *sample.user_header_mut() = header;
        Ok(CloudLoan {
            sample: sample.write_from_slice(points),
            publisher: self,
        })
    }

    /// A cloud in shared memory with `header` and `header.len()` points made by
    /// `point(i)` in place (e.g. a renderer writing pixel `i`), without a copy.
    pub fn loan_with(
        &self,
        header: CloudHeader,
        point: impl FnMut(usize) -> Point,
    ) -> Result<CloudLoan<'_>, IpcError> {
        let len = header.len();
        self.check_len(&header, len)?;
        let mut sample = self
            .publisher
            .loan_slice_uninit(len)
            .map_err(|e| IpcError::iceoryx("loan", &self.target, e))?;
        *sample.user_header_mut() = header;
        Ok(CloudLoan {
            sample: sample.write_from_fn(point),
            publisher: self,
        })
    }

    /// Sends a copy of `points` with `header`; returns the subscribers reached.
    pub fn send_copy(&self, header: CloudHeader, points: &[Point]) -> Result<usize, IpcError> {
        self.loan_copy(header, points)?.send()
    }

    /// Living and dead subscribers of the topic.
    pub fn subscriber_peers(&self) -> Result<Peers, IpcError> {
        port_peers(
            &self.service,
            &self.config,
            &self.target,
            Ports::Subscribers,
        )
    }
}

/// A cloud being written in shared memory; [`CloudLoan::send`] publishes it.
#[derive(Debug)]
pub struct CloudLoan<'a> {
    sample: SampleMut<Ipc, [Point], CloudHeader>,
    publisher: &'a CloudPublisher,
}

impl CloudLoan<'_> {
    /// The header.
    pub fn header(&self) -> &CloudHeader {
        self.sample.user_header()
    }

    /// The header, to change (e.g. the stamp just before sending).
    pub fn header_mut(&mut self) -> &mut CloudHeader {
        self.sample.user_header_mut()
    }

    /// The points.
    pub fn points(&self) -> &[Point] {
        self.sample.payload()
    }

    /// The points, to write in place.
    pub fn points_mut(&mut self) -> &mut [Point] {
        self.sample.payload_mut()
    }

    /// Validates the header against the points, publishes the cloud (no copy) and
    /// wakes the subscribers; returns the number of subscribers reached.
    pub fn send(self) -> Result<usize, IpcError> {
        self.header().validate(self.points().len())?;
        let target = &self.publisher.target;
        let reached = self
            .sample
            .send()
            .map_err(|e| IpcError::iceoryx("send", target, e))?;
        wake(&self.publisher.notifier, target)?;
        Ok(reached)
    }
}

/// Receives point clouds as references into shared memory.
#[derive(Debug)]
pub struct CloudSubscriber {
    service: PubSubService<Ipc, [Point], CloudHeader>,
    subscriber: Subscriber<Ipc, [Point], CloudHeader>,
    listener: Listener<Ipc>,
    target: String,
    config: iceoryx2::config::Config,
}

impl CloudSubscriber {
    /// The oldest queued cloud, if any, without blocking.
    pub fn try_receive(&self) -> Result<Option<CloudSample>, IpcError> {
        self.subscriber
            .receive()
            .map(|sample| sample.map(|sample| CloudSample { sample }))
            .map_err(|e| IpcError::iceoryx("receive", &self.target, e))
    }

    /// The oldest queued cloud, blocking up to `timeout` for one (`None` if none).
    pub fn receive_timeout(&self, timeout: Duration) -> Result<Option<CloudSample>, IpcError> {
        receive_with_timeout(&self.listener, &self.target, timeout, || self.try_receive())
    }

    /// Living and dead publishers of the topic.
    pub fn publisher_peers(&self) -> Result<Peers, IpcError> {
        port_peers(&self.service, &self.config, &self.target, Ports::Publishers)
    }
}

impl Wakeable for CloudSubscriber {
    fn wake_listener(&self) -> &Listener<Ipc> {
        &self.listener
    }
}

/// A received cloud, read in place in shared memory; dropping it returns the memory.
#[derive(Debug)]
pub struct CloudSample {
    sample: Sample<Ipc, [Point], CloudHeader>,
}

impl CloudSample {
    /// The header.
    pub fn header(&self) -> &CloudHeader {
        self.sample.user_header()
    }

    /// The points (row-major for an organised cloud).
    pub fn points(&self) -> &[Point] {
        self.sample.payload()
    }

    /// Checks the header against the points ([`CloudHeader::validate`]).
    pub fn validate(&self) -> Result<(), IpcError> {
        self.header().validate(self.points().len())
    }

    /// A copy as a [`crate::cloud::PointCloud`] in the header's frame (organisation
    /// kept; missing returns stay NaN).
    pub fn to_cloud(&self) -> crate::cloud::PointCloud {
        let header = self.header();
        crate::cloud::PointCloud {
            points: self.points().iter().map(|&p| p.into()).collect(),
            normals: None,
            width: header.width,
            height: header.height,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose;
    use crate::ipc::payloads::{Frame, Intrinsics, TrialRequest};

    const WAIT: Duration = Duration::from_secs(10);

    fn header(trial_id: u64, width: u32, height: u32) -> CloudHeader {
        let intrinsics = Intrinsics {
            fx: 500.0,
            fy: 500.0,
            cx: 320.0,
            cy: 240.0,
        };
        CloudHeader::new(
            trial_id,
            1,
            width,
            height,
            intrinsics,
            Frame::CameraOptical,
            &Pose::identity(),
        )
    }

    #[test]
    fn messages_and_clouds_between_two_nodes_then_no_files_left() {
        let domain = Domain::temporary("stage-unit").unwrap();
        {
            let a = Stage::start(&domain, "a").unwrap();
            let b = Stage::start(&domain, "b").unwrap();
            let sub = b.subscriber::<TrialRequest>().unwrap();
            let publ = a.publisher::<TrialRequest>().unwrap();
            let req = TrialRequest::new(42, 7, "mug", "top", "laplace").unwrap();
            assert_eq!(publ.send(&req).unwrap(), 1);
            let got = sub.receive_timeout(WAIT).unwrap().unwrap();
            assert_eq!(got, req);
            assert_eq!(got.task().unwrap(), "top");
            assert!(sub.try_receive().unwrap().is_none());
            assert_eq!(sub.publisher_peers().unwrap(), Peers { alive: 1, dead: 0 });
            assert_eq!(
                publ.subscriber_peers().unwrap(),
                Peers { alive: 1, dead: 0 }
            );
            assert_eq!(b.stage_status("a").unwrap(), StageStatus::Alive);
            assert_eq!(b.stage_status("nobody").unwrap(), StageStatus::Missing);

            let cloud_sub = b.cloud_subscriber(CloudTopic::Camera).unwrap();
            let cloud_pub = a.cloud_publisher(CloudTopic::Camera).unwrap();
            let loan = cloud_pub
                .loan_with(header(3, 4, 2), |i| Point::new(i as f32, -(i as f32), 0.5))
                .unwrap();
            assert_eq!(loan.send().unwrap(), 1);
            let points: Vec<Point> = (0..6)
                .map(|i| Point::new(0.0, i as f32, f32::NAN))
                .collect();
            cloud_pub.send_copy(header(4, 6, 1), &points).unwrap();
            let first = cloud_sub.receive_timeout(WAIT).unwrap().unwrap();
            first.validate().unwrap();
            assert_eq!(first.header().trial_id, 3);
            assert_eq!(first.points()[7], Point::new(7.0, -7.0, 0.5));
            let second = cloud_sub.receive_timeout(WAIT).unwrap().unwrap();
            assert_eq!(second.header().width, 6);
            assert_eq!(second.points()[5].y, 5.0);
            assert!(second.points()[5].z.is_nan());

            // A shape that does not match the points is refused before loaning.
            assert!(matches!(
                cloud_pub.send_copy(header(5, 3, 3), &points),
                Err(IpcError::CloudShape { points: 6, .. })
            ));
            // A header made inconsistent after loaning is refused at send.
            let mut loan = cloud_pub.loan_copy(header(6, 6, 1), &points).unwrap();
            loan.header_mut().height = 2;
            assert!(loan.send().is_err());
            assert!(cloud_sub.try_receive().unwrap().is_none());
        }
        assert_eq!(domain.alive_nodes().unwrap(), 0);
        assert_eq!(
            domain.leftover_files().unwrap(),
            Vec::<std::path::PathBuf>::new()
        );
        assert_eq!(domain.files().unwrap().len(), 1, "only the node counter");
        domain.remove().unwrap();
        assert!(domain.files().unwrap().is_empty());
        assert!(!domain.root().exists());
    }

    #[test]
    fn wait_any_wakes_on_any_topic() {
        use crate::ipc::payloads::CloudAck;
        let domain = Domain::temporary("stage-wait-any").unwrap();
        {
            let a = Stage::start(&domain, "a").unwrap();
            let requests = a.subscriber::<TrialRequest>().unwrap();
            let acks = a.subscriber::<CloudAck>().unwrap();
            let clouds = a.cloud_subscriber(CloudTopic::Camera).unwrap();
            let all: [&dyn Wakeable; 3] = [&requests, &acks, &clouds];
            assert!(!wait_any(&all, Duration::from_millis(5)).unwrap());

            let b = Stage::start(&domain, "b").unwrap();
            let ack = CloudAck {
                trial_id: 9,
                ..CloudAck::default()
            };
            let publisher = b.publisher::<CloudAck>().unwrap();
            publisher.send(&ack).unwrap();
            assert!(wait_any(&all, WAIT).unwrap());
            assert!(requests.try_receive().unwrap().is_none());
            assert_eq!(acks.try_receive().unwrap(), Some(ack));
            // The wake-up was consumed: nothing wakes the set now.
            assert!(!wait_any(&all, Duration::from_millis(5)).unwrap());
        }
        domain.remove().unwrap();
    }

    #[test]
    fn receive_times_out_without_a_message() {
        let domain = Domain::temporary("stage-timeout").unwrap();
        {
            let a = Stage::start(&domain, "a").unwrap();
            let sub = a.subscriber::<TrialRequest>().unwrap();
            assert!(sub
                .receive_timeout(Duration::from_millis(5))
                .unwrap()
                .is_none());
            assert_eq!(sub.publisher_peers().unwrap(), Peers::default());
            assert!(matches!(
                domain.remove(),
                Err(IpcError::DomainInUse { alive: 1, .. })
            ));
        }
        domain.remove().unwrap();
    }
}
