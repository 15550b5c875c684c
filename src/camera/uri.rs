//! Parsing of camera source URIs (`v4l2:/dev/video0`, `aravis:ID`,
//! `replay:DIR`, `pattern:WxH`).

use std::fmt;
use std::path::PathBuf;

use super::CameraError;

/// A parsed camera source.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SourceUri {
    /// A V4L2 capture device.
    V4l2(PathBuf),
    /// An Aravis camera id; empty selects the first camera, `fake` the
    /// built-in fake camera.
    Aravis(String),
    /// A dataset folder in the TUM layout.
    Replay(PathBuf),
    /// A moving test pattern of the given size.
    Pattern {
        /// Width, pixels.
        width: u32,
        /// Height, pixels.
        height: u32,
    },
}

impl SourceUri {
    /// Parses `text`; the error names the URI and the accepted forms.
    pub fn parse(text: &str) -> Result<Self, CameraError> {
        let invalid = |reason: &str| CameraError::InvalidUri {
            uri: text.to_string(),
            reason: reason.to_string(),
        };
        let Some((scheme, rest)) = text.split_once(':') else {
            return Err(invalid(
                "expected `v4l2:/dev/videoN`, `aravis:ID`, `replay:DIR` or `pattern:WxH`",
            ));
        };
        match scheme {
            "v4l2" if rest.starts_with('/') => Ok(Self::V4l2(PathBuf::from(rest))),
            "v4l2" => Err(invalid(
                "expected an absolute device path, e.g. v4l2:/dev/video0",
            )),
            "aravis" => Ok(Self::Aravis(rest.to_string())),
            "replay" if !rest.is_empty() => Ok(Self::Replay(PathBuf::from(rest))),
            "replay" => Err(invalid("expected a dataset folder, e.g. replay:/data/seq1")),
            "pattern" => {
                let (w, h) = rest.split_once('x').ok_or_else(|| {
                    invalid("expected pattern:WIDTHxHEIGHT, e.g. pattern:640x512")
                })?;
                let parse = |s: &str| s.parse::<u32>().ok().filter(|v| *v > 0);
                match (parse(w), parse(h)) {
                    (Some(width), Some(height)) => Ok(Self::Pattern { width, height }),
                    _ => Err(invalid(
                        "expected positive integers in pattern:WIDTHxHEIGHT",
                    )),
                }
            }
            _ => Err(invalid(
                "unknown scheme; expected v4l2:, aravis:, replay: or pattern:",
            )),
        }
    }
}

impl fmt::Display for SourceUri {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SourceUri::V4l2(p) => write!(f, "v4l2:{}", p.display()),
            SourceUri::Aravis(id) => write!(f, "aravis:{id}"),
            SourceUri::Replay(p) => write!(f, "replay:{}", p.display()),
            SourceUri::Pattern { width, height } => write!(f, "pattern:{width}x{height}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_scheme_and_round_trips() {
        for text in [
            "v4l2:/dev/video3",
            "aravis:Fake_1",
            "aravis:",
            "replay:/data/seq",
            "pattern:640x512",
        ] {
            let uri = SourceUri::parse(text).expect(text);
            assert_eq!(uri.to_string(), text);
        }
        assert_eq!(
            SourceUri::parse("pattern:8x4").expect("pattern"),
            SourceUri::Pattern {
                width: 8,
                height: 4
            }
        );
    }

    #[test]
    fn rejects_malformed_uris_with_the_uri_in_the_message() {
        for text in [
            "video0",
            "v4l2:video0",
            "replay:",
            "pattern:0x4",
            "pattern:8",
            "usb:1",
        ] {
            let err = SourceUri::parse(text).expect_err(text);
            assert!(err.to_string().contains(text), "{err}");
        }
    }
}
