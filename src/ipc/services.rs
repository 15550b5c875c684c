//! iceoryx2 nodes and service definitions: names, quality of service, and
//! start-up cleanup of what crashed processes left behind.
//!
//! Takes in the `[ipc]` section of the star config (the iceoryx2 config file);
//! gives out a [`Node`] and opened service port factories. Both sides open a
//! service through the same function here, so their QoS always match.
//!
//! Each data service admits one publisher ([`MAX_PUBLISHERS`]): a second
//! `star camera` or a second tracker on the same prefix is refused with an
//! error naming the process that holds the service ([`publisher_refused`]),
//! instead of two cameras interleaving frames. Before a publisher creates
//! its data segment, [`check_shm_space`] compares the free space of
//! `/dev/shm` with the segment's size, so a full `/dev/shm` is an error at
//! start naming the bytes needed, not a SIGBUS when a page is first touched.

use std::path::{Path, PathBuf};

use iceoryx2::identifiers::UniqueNodeId;
use iceoryx2::node::{Node, NodeState, NodeView};
use iceoryx2::port::publisher::PublisherCreateError;
use iceoryx2::prelude::{
    CallbackProgression, FileName, FilePath, MessagingPattern, NodeBuilder, NodeName,
    SemanticString, ServiceName,
};
use iceoryx2::service::builder::event::{EventOpenError, EventOpenOrCreateError};
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::ipc;
use iceoryx2::service::port_factory::{event, publish_subscribe};
use tracing::{info, warn};

use super::frame::Frame;
use super::pose::PoseMsg;
use super::IpcError;

/// Frames from the camera process.
pub const FRAME_SERVICE: &str = "star/camera/frames";
/// Event raised after every published frame (subscribers wait on it).
pub const FRAME_EVENT_SERVICE: &str = "star/camera/frames/ready";
/// Poses from the tracker.
pub const POSE_SERVICE: &str = "star/tracker/poses";
/// Event raised after every published pose.
pub const POSE_EVENT_SERVICE: &str = "star/tracker/poses/ready";

/// Publishers a data service admits: one camera, one tracker.
pub const MAX_PUBLISHERS: usize = 1;
/// Where iceoryx2 keeps its shared memory segments (POSIX shm on Linux).
pub const SHM_DIR: &str = "/dev/shm";
/// Frames the camera's publisher may loan at once.
pub const FRAME_MAX_LOANED: usize = 1;

/// Frame subscribers the service admits (tracker, recorder, viewer, spare).
pub const FRAME_MAX_SUBSCRIBERS: usize = 4;
/// Frames one subscriber may hold at once (current frame plus one).
pub const FRAME_MAX_BORROWED: usize = 2;
/// Pose subscribers the service admits.
pub const POSE_MAX_SUBSCRIBERS: usize = 8;
/// Poses buffered per subscriber before the oldest is overwritten.
pub const POSE_BUFFER: usize = 4;

/// Loads the iceoryx2 configuration from `path`. When `path` does not exist
/// the built-in defaults are used and a warning says so. `prefix`, when
/// given, replaces the resource prefix (isolates test runs).
pub fn load_iceoryx_config(
    path: &Path,
    prefix: Option<&str>,
) -> Result<iceoryx2::config::Config, IpcError> {
    let mut config = if path.exists() {
        let file =
            FilePath::new(path.as_os_str().as_encoded_bytes()).map_err(|e| IpcError::Config {
                path: path.to_owned(),
                reason: format!("not a valid iceoryx2 file path: {e:?}"),
            })?;
        iceoryx2::config::Config::from_file(&file).map_err(|e| IpcError::Config {
            path: path.to_owned(),
            reason: format!("{e:?}"),
        })?
    } else {
        warn!(path = %path.display(), "iceoryx2 config not found, using built-in defaults");
        iceoryx2::config::Config::default()
    };
    if let Some(prefix) = prefix {
        config.global.prefix = FileName::new(prefix.as_bytes()).map_err(|e| IpcError::Config {
            path: PathBuf::from(path),
            reason: format!("invalid prefix `{prefix}`: {e:?}"),
        })?;
    }
    Ok(config)
}

/// Creates this process's node named `name` and removes the resources of
/// dead nodes (a crashed camera or tracker) before anything opens a service.
pub fn create_node(
    name: &str,
    config: &iceoryx2::config::Config,
) -> Result<Node<ipc::Service>, IpcError> {
    let node_name = NodeName::new(name).map_err(|e| IpcError::Iceoryx {
        op: "node name",
        name: name.to_string(),
        reason: format!("{e:?}"),
    })?;
    let node = NodeBuilder::new()
        .name(&node_name)
        .config(config)
        .create::<ipc::Service>()
        .map_err(|e| IpcError::Iceoryx {
            op: "create node",
            name: name.to_string(),
            reason: e.to_string(),
        })?;
    let cleanup = node.try_cleanup_dead_nodes();
    if cleanup.cleanups > 0 || cleanup.failed_cleanups > 0 {
        info!(
            removed = cleanup.cleanups,
            failed = cleanup.failed_cleanups,
            "removed stale iceoryx2 resources of dead processes"
        );
    }
    Ok(node)
}

pub(crate) fn service_name(name: &'static str) -> Result<ServiceName, IpcError> {
    ServiceName::new(name).map_err(|e| IpcError::Iceoryx {
        op: "service name",
        name: name.to_string(),
        reason: format!("{e:?}"),
    })
}

fn iox_err(op: &'static str, name: &'static str) -> impl FnOnce(String) -> IpcError {
    move |reason| IpcError::Iceoryx {
        op,
        name: name.to_string(),
        reason,
    }
}

/// The frame service's settings, the one place they are written: opening
/// with other settings than the creator's fails.
fn frame_service_builder(
    node: &Node<ipc::Service>,
    name: &ServiceName,
) -> iceoryx2::service::builder::publish_subscribe::Builder<Frame, (), ipc::Service> {
    node.service_builder(name)
        .publish_subscribe::<Frame>()
        .enable_safe_overflow(true)
        .subscriber_max_buffer_size(1)
        .subscriber_max_borrowed_samples(FRAME_MAX_BORROWED)
        .history_size(0)
        .max_publishers(MAX_PUBLISHERS)
        .max_subscribers(FRAME_MAX_SUBSCRIBERS)
}

/// Opens (or creates) the frame service: one publisher, a buffer of one
/// frame per subscriber with safe overflow, so a slow consumer always finds
/// the newest frame and nothing queues up. A service whose shared memory
/// was deleted is removed and created anew ([`remove_orphaned`]).
pub fn open_frame_service(
    node: &Node<ipc::Service>,
) -> Result<publish_subscribe::PortFactory<ipc::Service, Frame, ()>, IpcError> {
    let name = service_name(FRAME_SERVICE)?;
    let open = || frame_service_builder(node, &name).open_or_create();
    match open() {
        Err(e) if pubsub_orphaned(&e) => {
            remove_orphaned(node, FRAME_SERVICE, MessagingPattern::PublishSubscribe);
            open()
        }
        other => other,
    }
    .map_err(|e| iox_err("open service", FRAME_SERVICE)(e.to_string()))
}

/// Opens (or creates) the pose service (recreated like the frame service
/// when its shared memory was deleted).
pub fn open_pose_service(
    node: &Node<ipc::Service>,
) -> Result<publish_subscribe::PortFactory<ipc::Service, PoseMsg, ()>, IpcError> {
    let name = service_name(POSE_SERVICE)?;
    let open = || {
        node.service_builder(&name)
            .publish_subscribe::<PoseMsg>()
            .enable_safe_overflow(true)
            .subscriber_max_buffer_size(POSE_BUFFER)
            .subscriber_max_borrowed_samples(2)
            .history_size(1)
            .max_publishers(MAX_PUBLISHERS)
            .max_subscribers(POSE_MAX_SUBSCRIBERS)
            .open_or_create()
    };
    match open() {
        Err(e) if pubsub_orphaned(&e) => {
            remove_orphaned(node, POSE_SERVICE, MessagingPattern::PublishSubscribe);
            open()
        }
        other => other,
    }
    .map_err(|e| iox_err("open service", POSE_SERVICE)(e.to_string()))
}

/// Opens the frame service only if it exists and is usable: `None` when it
/// does not exist or lost its shared memory and was not recreated yet. It
/// never creates the service, so a process that still holds ports of the
/// old one can call it (iceoryx2 refuses to register a service twice in one
/// node).
pub fn open_existing_frame_service(
    node: &Node<ipc::Service>,
) -> Result<Option<publish_subscribe::PortFactory<ipc::Service, Frame, ()>>, IpcError> {
    let opened = frame_service_builder(node, &service_name(FRAME_SERVICE)?).open();
    match opened {
        Ok(factory) => Ok(Some(factory)),
        Err(
            PublishSubscribeOpenError::DoesNotExist
            | PublishSubscribeOpenError::HangsInCreation
            | PublishSubscribeOpenError::ServiceInCorruptedState
            | PublishSubscribeOpenError::IsMarkedForDestruction,
        ) => Ok(None),
        Err(e) => Err(iox_err("open service", FRAME_SERVICE)(e.to_string())),
    }
}

/// [`open_existing_frame_service`] for an event service.
pub fn open_existing_event_service(
    node: &Node<ipc::Service>,
    name: &'static str,
) -> Result<Option<event::PortFactory<ipc::Service>>, IpcError> {
    let opened = event_service_builder(node, &service_name(name)?).open();
    match opened {
        Ok(factory) => Ok(Some(factory)),
        Err(
            EventOpenError::DoesNotExist
            | EventOpenError::HangsInCreation
            | EventOpenError::ServiceInCorruptedState
            | EventOpenError::IsMarkedForDestruction,
        ) => Ok(None),
        Err(e) => Err(iox_err("open event service", name)(e.to_string())),
    }
}

/// Whether opening failed because the service's shared state is gone: its
/// static description exists but its dynamic segment does not (files
/// deleted from `/dev/shm` while processes used it), so nobody can open it
/// again until it is removed.
fn pubsub_orphaned(e: &PublishSubscribeOpenOrCreateError) -> bool {
    matches!(
        e,
        PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
            PublishSubscribeOpenError::HangsInCreation
                | PublishSubscribeOpenError::ServiceInCorruptedState
        )
    )
}

/// [`pubsub_orphaned`] for an event service.
fn event_orphaned(e: &EventOpenOrCreateError) -> bool {
    matches!(
        e,
        EventOpenOrCreateError::EventOpenError(
            EventOpenError::HangsInCreation | EventOpenError::ServiceInCorruptedState
        )
    )
}

/// Removes what is left of a service whose shared memory was deleted, so
/// the next open creates it anew. Processes still attached keep their own
/// mappings of the old one (a running camera keeps publishing into it); the
/// frame subscriber notices that it was left behind and re-attaches
/// ([`crate::ipc::FrameSubscriber::reattach_if_orphaned`]). Only a node that
/// holds no ports of the service may call this (through the `open_*`
/// functions): iceoryx2 aborts when one node registers a service twice.
pub fn remove_orphaned(node: &Node<ipc::Service>, name: &'static str, pattern: MessagingPattern) {
    warn!(
        service = name,
        "iceoryx2 service lost its shared memory (files deleted from /dev/shm?); removing what is left so it is created anew"
    );
    let Ok(service) = service_name(name) else {
        return;
    };
    // SAFETY: nobody can open the service any more (its dynamic state is
    // gone); the processes still attached use their own mappings, which
    // removing the files does not unmap.
    if let Err(e) = unsafe { node.force_remove_service(&service, pattern) } {
        warn!(service = name, error = ?e, "cannot remove the orphaned iceoryx2 service");
    }
}

/// An event service's settings, the one place they are written.
fn event_service_builder(
    node: &Node<ipc::Service>,
    name: &ServiceName,
) -> iceoryx2::service::builder::event::Builder<ipc::Service> {
    node.service_builder(name)
        .event()
        .max_notifiers(4)
        .max_listeners(POSE_MAX_SUBSCRIBERS)
}

/// Opens (or creates) an event service used to wake subscribers (recreated
/// like the frame service when its shared memory was deleted).
pub fn open_event_service(
    node: &Node<ipc::Service>,
    name: &'static str,
) -> Result<event::PortFactory<ipc::Service>, IpcError> {
    let service = service_name(name)?;
    let open = || event_service_builder(node, &service).open_or_create();
    match open() {
        Err(e) if event_orphaned(&e) => {
            remove_orphaned(node, name, MessagingPattern::Event);
            open()
        }
        other => other,
    }
    .map_err(|e| iox_err("open event service", name)(e.to_string()))
}

/// Bytes of the data segment a publisher of `T` creates: iceoryx2 sizes it
/// for every sample that can be in flight at once (each subscriber's buffer
/// and borrowed samples, the history and the publisher's loans).
pub fn data_segment_bytes<T>(
    max_subscribers: usize,
    buffer: usize,
    borrowed: usize,
    history: usize,
    loaned: usize,
) -> u64 {
    let samples = max_subscribers * (buffer + borrowed) + history + loaned;
    samples as u64 * std::mem::size_of::<T>() as u64
}

/// The frame publisher's data segment, bytes.
pub fn frame_segment_bytes() -> u64 {
    data_segment_bytes::<Frame>(
        FRAME_MAX_SUBSCRIBERS,
        1,
        FRAME_MAX_BORROWED,
        0,
        FRAME_MAX_LOANED,
    )
}

/// The pose publisher's data segment, bytes (iceoryx2's default of 2 loans).
pub fn pose_segment_bytes() -> u64 {
    data_segment_bytes::<PoseMsg>(POSE_MAX_SUBSCRIBERS, POSE_BUFFER, 2, 1, 2)
}

/// Free bytes for an unprivileged writer on the file system holding `dir`.
pub fn free_bytes(dir: &Path) -> Result<u64, IpcError> {
    let failed = |reason: String| IpcError::SharedMemory {
        dir: dir.to_owned(),
        reason,
    };
    let path = std::ffi::CString::new(dir.as_os_str().as_encoded_bytes())
        .map_err(|_| failed("the path holds a NUL byte".into()))?;
    // SAFETY: a zeroed statvfs is a valid out-parameter; `path` is a valid
    // NUL-terminated string that outlives the call.
    let mut stat: libc::statvfs = unsafe { std::mem::zeroed() };
    if unsafe { libc::statvfs(path.as_ptr(), &mut stat) } != 0 {
        return Err(failed(format!(
            "statvfs: {}",
            std::io::Error::last_os_error()
        )));
    }
    Ok((stat.f_bavail as u64).saturating_mul(stat.f_frsize as u64))
}

/// Errors with [`IpcError::ShmFull`] when `dir` has less than
/// `needed_bytes` free for `service`'s data segment.
pub fn check_shm_space(dir: &Path, service: &str, needed_bytes: u64) -> Result<(), IpcError> {
    let free = free_bytes(dir)?;
    if free < needed_bytes {
        return Err(IpcError::ShmFull {
            dir: dir.to_owned(),
            service: service.to_string(),
            needed_bytes,
            free_bytes: free,
        });
    }
    Ok(())
}

/// The processes holding the publishers with these node ids, for an error:
/// `node `star-camera` (pid 1234)`, or the bare node id when the node's
/// details cannot be read.
pub fn describe_nodes(config: &iceoryx2::config::Config, ids: &[UniqueNodeId]) -> String {
    let mut found: Vec<String> = Vec::new();
    let listed = Node::<ipc::Service>::list(config, |state| {
        if let NodeState::Alive(view) = &state {
            if ids.contains(view.id()) {
                found.push(match view.details() {
                    Some(d) => format!(
                        "node `{}` (pid {}, {})",
                        d.name(),
                        d.process_id().value(),
                        d.executable()
                    ),
                    None => format!("node {}", view.id()),
                });
            }
        }
        CallbackProgression::Continue
    });
    if found.is_empty() || listed.is_err() {
        found.extend(ids.iter().map(|id| format!("node {id}")));
    }
    found.join(", ")
}

/// The error for a publisher that `service` refused: when the service's one
/// publisher slot is taken, names who holds it.
pub fn publisher_refused(
    node: &Node<ipc::Service>,
    service: &'static str,
    holders: &[UniqueNodeId],
    error: PublisherCreateError,
) -> IpcError {
    if error == PublisherCreateError::ExceedsMaxSupportedPublishers {
        return IpcError::PublisherTaken {
            service,
            holder: describe_nodes(node.config(), holders),
        };
    }
    IpcError::iceoryx("create publisher", service, error)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shm_space_check_names_the_bytes_needed() {
        let free = free_bytes(Path::new("/tmp")).expect("statvfs /tmp");
        check_shm_space(Path::new("/tmp"), "small", 1).expect("one byte fits");
        let err = check_shm_space(Path::new("/tmp"), "huge", free.saturating_add(1 << 40))
            .expect_err("more than free");
        let msg = err.to_string();
        assert!(msg.contains("huge") && msg.contains("/tmp"), "{msg}");
        assert!(
            msg.contains(&free.saturating_add(1 << 40).to_string()),
            "{msg}"
        );
        assert!(free_bytes(Path::new("/nonexistent/shm")).is_err());
    }

    #[test]
    fn frame_segment_is_every_frame_in_flight() {
        // 4 subscribers x (1 buffered + 2 borrowed) + 1 loaned.
        assert_eq!(
            frame_segment_bytes(),
            13 * std::mem::size_of::<Frame>() as u64
        );
    }

    #[test]
    fn shipped_iceoryx_config_parses_and_missing_file_falls_back() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/iceoryx2.toml");
        let config = load_iceoryx_config(&path, Some("startest_cfg_")).expect("shipped config");
        assert_eq!(config.global.prefix.as_bytes(), b"startest_cfg_");
        let default =
            load_iceoryx_config(Path::new("/nonexistent/iceoryx2.toml"), None).expect("defaults");
        assert_eq!(
            default.global.prefix,
            iceoryx2::config::Config::default().global.prefix
        );
    }

    #[test]
    fn bad_prefix_is_an_error_naming_it() {
        let err = load_iceoryx_config(Path::new("/nonexistent"), Some("a/b"))
            .expect_err("slash is not a file name");
        assert!(err.to_string().contains("a/b"), "{err}");
    }
}
