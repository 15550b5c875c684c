//! Parsing of camera source URIs (`v4l2:/dev/video0`, `aravis:ID`,
//! `replay:DIR`, `pattern:WxH`, `sim:LINK[?scene=DIR&origin=LAT,LON,ALT]`).

use std::fmt;
use std::path::PathBuf;

use super::CameraError;
use crate::mavlink_io::LinkAddress;

/// The forms every parse error lists.
const FORMS: &str = "expected `v4l2:/dev/videoN`, `aravis:ID`, `replay:DIR`, `pattern:WxH` or \
     `sim:LINK[?scene=DIR&origin=LAT,LON,ALT]`";

/// The vehicle-simulator camera (`sim:`): where the simulated vehicle's
/// true pose comes from and which synthetic scene it flies in. Opened by
/// `synth::sim_camera`, which needs the config's transforms and intrinsics.
#[derive(Debug, Clone, PartialEq)]
pub struct SimUri {
    /// The MAVLink connection to the simulator, in `mavlink.connection`'s
    /// syntax (`tcpout:HOST:PORT`, `udpout:`, `udpin:`, `serial:`).
    pub link: String,
    /// The `star synth` dataset folder whose scene the camera sees; `None`:
    /// the folder that holds the configured `map.mesh` (`DIR/map/map.obj`).
    pub scene: Option<PathBuf>,
    /// The geodetic point that is local NED `(0, 0, 0)`; `None`: the
    /// vehicle's position in the first state the simulator sends.
    pub origin: Option<GeoPoint>,
}

/// A WGS-84 position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GeoPoint {
    /// Latitude, degrees, -90..=90.
    pub lat_deg: f64,
    /// Longitude, degrees, -180..=180.
    pub lon_deg: f64,
    /// Altitude above mean sea level, meters.
    pub alt_m: f64,
}

/// A parsed camera source.
#[derive(Debug, Clone, PartialEq)]
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
    /// A camera rendered at a simulated vehicle's true pose (SITL).
    Sim(SimUri),
}

impl SourceUri {
    /// Parses `text`; the error names the URI and the accepted forms.
    pub fn parse(text: &str) -> Result<Self, CameraError> {
        let invalid = |reason: &str| CameraError::InvalidUri {
            uri: text.to_string(),
            reason: reason.to_string(),
        };
        let Some((scheme, rest)) = text.split_once(':') else {
            return Err(invalid(FORMS));
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
            "sim" => SimUri::parse(rest).map(Self::Sim).map_err(|r| invalid(&r)),
            _ => Err(invalid(&format!("unknown scheme `{scheme}`; {FORMS}"))),
        }
    }
}

impl SimUri {
    /// Parses what follows `sim:`; the error says what is wrong.
    fn parse(rest: &str) -> Result<Self, String> {
        let (link, query) = match rest.split_once('?') {
            Some((link, query)) => (link, Some(query)),
            None => (rest, None),
        };
        if link.is_empty() {
            return Err("expected the simulator's MAVLink connection after `sim:`, \
                 e.g. sim:tcpout:127.0.0.1:5763 (SITL's SERIAL2)"
                .into());
        }
        if let Some(hostport) = link.strip_prefix("tcp:") {
            return Err(format!(
                "`tcp:` is not a star connection; use `tcpout:{hostport}` \
                 (the syntax of mavlink.connection)"
            ));
        }
        LinkAddress::parse(link).map_err(|e| e.to_string())?;
        let mut uri = SimUri {
            link: link.to_string(),
            scene: None,
            origin: None,
        };
        for pair in query.into_iter().flat_map(|q| q.split('&')) {
            let (key, value) = pair
                .split_once('=')
                .ok_or_else(|| format!("`{pair}` is not KEY=VALUE (keys: scene, origin)"))?;
            match key {
                "scene" if uri.scene.is_some() => return Err("`scene` given twice".into()),
                "scene" if value.is_empty() => {
                    return Err("`scene=` needs a `star synth` dataset folder".into())
                }
                "scene" => uri.scene = Some(PathBuf::from(value)),
                "origin" if uri.origin.is_some() => return Err("`origin` given twice".into()),
                "origin" => uri.origin = Some(GeoPoint::parse(value)?),
                other => return Err(format!("unknown key `{other}`; keys: scene, origin")),
            }
        }
        Ok(uri)
    }
}

impl GeoPoint {
    /// Parses `LAT,LON,ALT` (degrees, degrees, meters above sea level).
    fn parse(text: &str) -> Result<Self, String> {
        let bad = |why: &str| {
            format!("origin `{text}`: {why}; expected LAT,LON,ALT in degrees, degrees, meters")
        };
        let values: Vec<f64> = text
            .split(',')
            .map(|v| v.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect::<Option<_>>()
            .ok_or_else(|| bad("not three finite numbers"))?;
        let [lat_deg, lon_deg, alt_m] = values[..] else {
            return Err(bad("not three numbers"));
        };
        if !(-90.0..=90.0).contains(&lat_deg) || !(-180.0..=180.0).contains(&lon_deg) {
            return Err(bad(
                "latitude must be within +-90 and longitude within +-180",
            ));
        }
        if !(-1_000.0..=20_000.0).contains(&alt_m) {
            return Err(bad("altitude must be within -1000..=20000 m"));
        }
        Ok(Self {
            lat_deg,
            lon_deg,
            alt_m,
        })
    }
}

impl fmt::Display for SimUri {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "sim:{}", self.link)?;
        let mut sep = '?';
        if let Some(scene) = &self.scene {
            write!(f, "{sep}scene={}", scene.display())?;
            sep = '&';
        }
        if let Some(o) = &self.origin {
            write!(f, "{sep}origin={},{},{}", o.lat_deg, o.lon_deg, o.alt_m)?;
        }
        Ok(())
    }
}

impl fmt::Display for SourceUri {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SourceUri::V4l2(p) => write!(f, "v4l2:{}", p.display()),
            SourceUri::Aravis(id) => write!(f, "aravis:{id}"),
            SourceUri::Replay(p) => write!(f, "replay:{}", p.display()),
            SourceUri::Pattern { width, height } => write!(f, "pattern:{width}x{height}"),
            SourceUri::Sim(sim) => sim.fmt(f),
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
            "sim:tcpout:127.0.0.1:5763",
            "sim:tcpout:127.0.0.1:5763?scene=/data/room",
            "sim:udpin:0.0.0.0:14550?scene=/data/room&origin=-35.363261,149.16523,584.09",
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

    #[test]
    fn parses_the_sim_source_and_its_keys() {
        let uri = SourceUri::parse("sim:tcpout:127.0.0.1:5763?origin=-35.5,149.25,584&scene=/d/r")
            .expect("sim");
        assert_eq!(
            uri,
            SourceUri::Sim(SimUri {
                link: "tcpout:127.0.0.1:5763".into(),
                scene: Some(PathBuf::from("/d/r")),
                origin: Some(GeoPoint {
                    lat_deg: -35.5,
                    lon_deg: 149.25,
                    alt_m: 584.0
                }),
            })
        );
    }

    #[test]
    fn rejects_bad_sim_sources_saying_why() {
        for (text, why) in [
            ("sim:", "MAVLink connection"),
            ("sim:?scene=/d", "MAVLink connection"),
            ("sim:tcp:127.0.0.1:5763", "use `tcpout:127.0.0.1:5763`"),
            ("sim:tcpout:127.0.0.1", "no `:PORT`"),
            ("sim:bogus:1:2", "unknown scheme"),
            ("sim:tcpout:h:1?scene", "not KEY=VALUE"),
            ("sim:tcpout:h:1?scene=", "dataset folder"),
            ("sim:tcpout:h:1?scene=/a&scene=/b", "given twice"),
            ("sim:tcpout:h:1?map=/a", "unknown key `map`"),
            ("sim:tcpout:h:1?origin=1,2", "not three numbers"),
            ("sim:tcpout:h:1?origin=1,2,x", "not three finite numbers"),
            ("sim:tcpout:h:1?origin=91,2,3", "within +-90"),
            ("sim:tcpout:h:1?origin=1,2,1e9", "altitude"),
            ("sim:tcpout:h:1?origin=NaN,2,3", "finite"),
        ] {
            let err = SourceUri::parse(text).expect_err(text).to_string();
            assert!(err.contains(text) && err.contains(why), "{text}: {err}");
        }
    }
}
