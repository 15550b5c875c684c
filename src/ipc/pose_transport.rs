//! Pose transport: the tracker's [`PosePublisher`] and the tools'
//! [`PoseSubscriber`].
//!
//! Takes in [`PoseMsg`] values from the tracker, gives out the newest poses
//! to any number of readers (logging, MAVLink bridge, tests). Poses are small,
//! so they are written into the loaned sample by value; the buffer keeps the
//! last few and overwrites the oldest.

use std::path::Path;

use iceoryx2::node::Node;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::{CallbackProgression, PortFactory};
use iceoryx2::service::ipc;

use super::pose::PoseMsg;
use super::services::{
    check_shm_space, open_event_service, open_pose_service, pose_segment_bytes, publisher_refused,
    POSE_BUFFER, POSE_EVENT_SERVICE, POSE_SERVICE, SHM_DIR,
};
use super::IpcError;

/// Publishes poses and wakes the pose listeners.
pub struct PosePublisher {
    publisher: Publisher<ipc::Service, PoseMsg, ()>,
    notifier: Notifier<ipc::Service>,
}

impl PosePublisher {
    /// Opens the pose and pose-event services on `node` and creates the ports.
    pub fn new(node: &Node<ipc::Service>) -> Result<Self, IpcError> {
        check_shm_space(Path::new(SHM_DIR), POSE_SERVICE, pose_segment_bytes())?;
        let service = open_pose_service(node)?;
        let publisher = service.publisher_builder().create().map_err(|e| {
            let mut holders = Vec::new();
            service.dynamic_config().list_publishers(|p| {
                holders.push(p.node_id);
                CallbackProgression::Continue
            });
            publisher_refused(node, POSE_SERVICE, &holders, e)
        })?;
        let notifier = open_event_service(node, POSE_EVENT_SERVICE)?
            .notifier_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("create notifier", POSE_EVENT_SERVICE, e))?;
        Ok(Self {
            publisher,
            notifier,
        })
    }

    /// Sends one pose and notifies.
    pub fn publish(&self, pose: &PoseMsg) -> Result<(), IpcError> {
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| IpcError::iceoryx("loan", POSE_SERVICE, e))?;
        sample
            .write_payload(*pose)
            .send()
            .map_err(|e| IpcError::iceoryx("send", POSE_SERVICE, e))?;
        self.notifier
            .notify()
            .map_err(|e| IpcError::iceoryx("notify", POSE_EVENT_SERVICE, e))?;
        Ok(())
    }
}

/// Reads poses.
pub struct PoseSubscriber {
    subscriber: Subscriber<ipc::Service, PoseMsg, ()>,
    listener: Listener<ipc::Service>,
}

impl PoseSubscriber {
    /// Opens the pose and pose-event services on `node` and creates the ports.
    pub fn new(node: &Node<ipc::Service>) -> Result<Self, IpcError> {
        let subscriber = open_pose_service(node)?
            .subscriber_builder()
            .buffer_size(POSE_BUFFER)
            .create()
            .map_err(|e| IpcError::iceoryx("create subscriber", POSE_SERVICE, e))?;
        let listener = open_event_service(node, POSE_EVENT_SERVICE)?
            .listener_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("create listener", POSE_EVENT_SERVICE, e))?;
        Ok(Self {
            subscriber,
            listener,
        })
    }

    /// The pose event listener, to attach to a WaitSet.
    pub fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }

    /// Next buffered pose, oldest first; `None` when none is waiting.
    pub fn try_next(&self) -> Result<Option<PoseMsg>, IpcError> {
        self.listener
            .try_wait(|_| {})
            .map_err(|e| IpcError::iceoryx("wait", POSE_EVENT_SERVICE, e))?;
        let sample = self
            .subscriber
            .receive()
            .map_err(|e| IpcError::iceoryx("receive", POSE_SERVICE, e))?;
        Ok(sample.map(|s| *s.payload()))
    }

    /// Blocks up to `timeout` for the next pose.
    pub fn wait_next(&self, timeout: std::time::Duration) -> Result<Option<PoseMsg>, IpcError> {
        if let Some(p) = self.try_next()? {
            return Ok(Some(p));
        }
        self.listener
            .timed_wait(|_| {}, timeout)
            .map_err(|e| IpcError::iceoryx("wait", POSE_EVENT_SERVICE, e))?;
        self.try_next()
    }
}
