//! Where `--rerun` sends the live view: `save:FILE.rrd` (a recording file
//! for the Rerun viewer) or `connect:ADDR` (a running viewer, gRPC). Parsed
//! in every build, so a build without the `rerun` feature can say so
//! instead of refusing the option.

use std::path::PathBuf;

/// The default port of a Rerun viewer's gRPC proxy.
pub const DEFAULT_VIEWER_PORT: u16 = 9876;

/// A parsed `--rerun` value.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RerunTarget {
    /// Write a `.rrd` recording to this file.
    Save(PathBuf),
    /// Stream to a viewer at this URL (`rerun+http://HOST:PORT/proxy`).
    Connect(String),
}

/// A `--rerun` value that is neither form.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("--rerun `{0}`: expected save:FILE.rrd or connect:HOST:PORT (a Rerun viewer, e.g. connect:127.0.0.1:9876)")]
pub struct RerunTargetError(pub String);

impl RerunTarget {
    /// Parses `save:FILE` or `connect:ADDR` (`HOST:PORT`, `HOST` for the
    /// default port, or a full `rerun+http://.../proxy` URL).
    pub fn parse(text: &str) -> Result<Self, RerunTargetError> {
        let bad = || RerunTargetError(text.to_string());
        if let Some(file) = text.strip_prefix("save:") {
            if file.is_empty() {
                return Err(bad());
            }
            return Ok(Self::Save(PathBuf::from(file)));
        }
        let Some(addr) = text.strip_prefix("connect:") else {
            return Err(bad());
        };
        if addr.starts_with("rerun+http://") || addr.starts_with("rerun+https://") {
            return Ok(Self::Connect(addr.to_string()));
        }
        if addr.is_empty() || addr.contains('/') || addr.contains(char::is_whitespace) {
            return Err(bad());
        }
        let host_port = if addr
            .rsplit_once(':')
            .is_some_and(|(_, port)| port.parse::<u16>().is_ok())
        {
            addr.to_string()
        } else {
            format!("{addr}:{DEFAULT_VIEWER_PORT}")
        };
        Ok(Self::Connect(format!("rerun+http://{host_port}/proxy")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn save_and_connect_parse_and_others_are_refused() {
        assert_eq!(
            RerunTarget::parse("save:x.rrd"),
            Ok(RerunTarget::Save("x.rrd".into()))
        );
        assert_eq!(
            RerunTarget::parse("connect:10.0.0.2:9000"),
            Ok(RerunTarget::Connect(
                "rerun+http://10.0.0.2:9000/proxy".into()
            ))
        );
        assert_eq!(
            RerunTarget::parse("connect:laptop"),
            Ok(RerunTarget::Connect(
                "rerun+http://laptop:9876/proxy".into()
            ))
        );
        for bad in ["x.rrd", "save:", "connect:", "udp:1.2.3.4", "connect:a b"] {
            assert!(RerunTarget::parse(bad).is_err(), "{bad}");
        }
    }
}
