//! iceoryx2 nodes and service definitions: names, quality of service, and
//! start-up cleanup of what crashed processes left behind.
//!
//! Takes in the `[ipc]` section of the star config (the iceoryx2 config file);
//! gives out a [`Node`] and opened service port factories. Both sides open a
//! service through the same function here, so their QoS always match.

use std::path::{Path, PathBuf};

use iceoryx2::node::Node;
use iceoryx2::prelude::{FileName, FilePath, NodeBuilder, NodeName, SemanticString, ServiceName};
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

/// Opens (or creates) the frame service: one publisher, a buffer of one
/// frame per subscriber with safe overflow, so a slow consumer always finds
/// the newest frame and nothing queues up.
pub fn open_frame_service(
    node: &Node<ipc::Service>,
) -> Result<publish_subscribe::PortFactory<ipc::Service, Frame, ()>, IpcError> {
    node.service_builder(&service_name(FRAME_SERVICE)?)
        .publish_subscribe::<Frame>()
        .enable_safe_overflow(true)
        .subscriber_max_buffer_size(1)
        .subscriber_max_borrowed_samples(FRAME_MAX_BORROWED)
        .history_size(0)
        .max_publishers(2)
        .max_subscribers(FRAME_MAX_SUBSCRIBERS)
        .open_or_create()
        .map_err(|e| iox_err("open service", FRAME_SERVICE)(e.to_string()))
}

/// Opens (or creates) the pose service.
pub fn open_pose_service(
    node: &Node<ipc::Service>,
) -> Result<publish_subscribe::PortFactory<ipc::Service, PoseMsg, ()>, IpcError> {
    node.service_builder(&service_name(POSE_SERVICE)?)
        .publish_subscribe::<PoseMsg>()
        .enable_safe_overflow(true)
        .subscriber_max_buffer_size(POSE_BUFFER)
        .subscriber_max_borrowed_samples(2)
        .history_size(1)
        .max_publishers(2)
        .max_subscribers(POSE_MAX_SUBSCRIBERS)
        .open_or_create()
        .map_err(|e| iox_err("open service", POSE_SERVICE)(e.to_string()))
}

/// Opens (or creates) an event service used to wake subscribers.
pub fn open_event_service(
    node: &Node<ipc::Service>,
    name: &'static str,
) -> Result<event::PortFactory<ipc::Service>, IpcError> {
    node.service_builder(&service_name(name)?)
        .event()
        .max_notifiers(4)
        .max_listeners(POSE_MAX_SUBSCRIBERS)
        .open_or_create()
        .map_err(|e| iox_err("open event service", name)(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

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
