//! Inter-process transport between the camera process and the tracker, on
//! iceoryx2 shared memory (DESIGN.md "IPC").
//!
//! Owns the message types ([`Frame`], [`PoseMsg`]), the services and their
//! quality of service ([`services`]), and the ports each side uses
//! ([`FramePublisher`], [`FrameSubscriber`], [`PosePublisher`],
//! [`PoseSubscriber`]). Takes in frames built in place by a camera source and
//! poses from the tracker; gives out views into shared memory, never copies.
//! Subscribers block on an iceoryx2 event listener, not a sleep loop, and
//! poll briefly around a periodic camera's predicted arrival.
//! Each process calls [`services::create_node`] first, which removes the
//! resources of crashed processes. Each data service admits one publisher;
//! `/dev/shm` space is checked before a publisher starts; a service whose
//! shared memory was deleted is recreated, and the frame subscriber
//! re-attaches to it ([`FrameSubscriber::reattach_if_orphaned`]).

pub mod config;
pub mod frame;
pub mod frame_transport;
pub mod pose;
pub mod pose_transport;
pub mod services;

pub use config::IpcConfig;
pub use frame::{
    Frame, FrameError, FrameHeader, FrameSlot, FrameView, PixelFormat, FRAME_CAPACITY_BYTES,
    FRAME_MAX_HEIGHT, FRAME_MAX_WIDTH, NO_DATASET_STAMP,
};
pub use frame_transport::{
    ArrivalPredictor, FrameEvent, FramePublisher, FrameSubscriber, PublishError, PublisherStats,
    ReceivedFrame, RunEnd, SubscriberStats,
};
pub use pose::{PoseMsg, TrackingState};
pub use pose_transport::{PosePublisher, PoseSubscriber};
pub use services::{create_node, load_iceoryx_config};

use std::path::PathBuf;

/// Errors of the transport.
#[derive(Debug, thiserror::Error)]
pub enum IpcError {
    /// The iceoryx2 configuration file could not be used.
    #[error("iceoryx2 config {path}: {reason}")]
    Config {
        /// The file.
        path: PathBuf,
        /// What was wrong.
        reason: String,
    },
    /// A service's one publisher slot is taken: another camera (or tracker)
    /// runs on the same iceoryx2 prefix.
    #[error("iceoryx2 service `{service}` already has its publisher: {holder}; only one may publish on a service, so stop that process first (or give this one another iceoryx2 prefix)")]
    PublisherTaken {
        /// The service.
        service: &'static str,
        /// Who holds it: node name, pid and executable.
        holder: String,
    },
    /// `/dev/shm` has less free space than a publisher's data segment needs.
    #[error("{} has {free_bytes} bytes free but the data segment of iceoryx2 service `{service}` needs {needed_bytes} bytes; free space there (old segments of crashed runs?) or enlarge it", dir.display())]
    ShmFull {
        /// The shared-memory folder.
        dir: PathBuf,
        /// The service whose publisher needs the space.
        service: String,
        /// Bytes the segment needs.
        needed_bytes: u64,
        /// Bytes free.
        free_bytes: u64,
    },
    /// The shared-memory folder could not be examined.
    #[error("cannot check the free space of {}: {reason}", dir.display())]
    SharedMemory {
        /// The folder.
        dir: PathBuf,
        /// What failed.
        reason: String,
    },
    /// An iceoryx2 operation failed.
    #[error("iceoryx2 {op} on `{name}` failed: {reason}")]
    Iceoryx {
        /// The operation, e.g. `create publisher`.
        op: &'static str,
        /// The service or node it applied to.
        name: String,
        /// iceoryx2's error.
        reason: String,
    },
}

impl IpcError {
    pub(crate) fn iceoryx(op: &'static str, name: &'static str, e: impl std::fmt::Debug) -> Self {
        Self::Iceoryx {
            op,
            name: name.to_string(),
            reason: format!("{e:?}"),
        }
    }
}
