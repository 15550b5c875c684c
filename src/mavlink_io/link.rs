//! The MAVLink transport: parses a connection string and opens a MAVLink 2
//! connection (common dialect) with short read timeouts, so the threads that
//! use it can notice a shutdown.
//!
//! Takes a connection string (`udpout:`, `udpin:`, `tcpout:`, `serial:`),
//! gives out a [`Link`]: `send` and a `recv` that returns `Ok(None)` on a read
//! timeout. Reconnecting is the sender thread's job (see `sender.rs`); a
//! [`LinkError::Broken`] tells it to.
//!
//! `udpout`, `tcpout` and `serial` use the `mavlink` crate's connections;
//! `udpin` is our own socket locked to one autopilot (`udpin.rs`). With
//! MAVLink 2 signing (`signing.rs`) every frame is serialized and signed
//! here and sent raw, and every incoming frame is read raw, checked (drops
//! counted) and then decoded; a signed serial link reads the port itself,
//! since the crate's raw serial read never returns on a timeout.

use std::fmt;
use std::io::{self, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use mavlink::dialects::common::MavMessage;
use mavlink::error::MessageReadError;
use mavlink::{
    Connectable, Connection, MAVLinkMessageRaw, MAVLinkV2MessageRaw, MavConnection, MavHeader,
    MavlinkReader, MavlinkVersion, SerialConfig, TcpConfig, UdpConfig, UdpMode,
};

use super::signing::{self, Signing};
use super::stats::Counters;
use super::udpin::{PeerPolicy, UdpIn};

/// How long a blocking receive waits before it returns `Ok(None)`.
pub const READ_TIMEOUT: Duration = Duration::from_millis(100);
/// How long a TCP connect or write may take before it counts as a failure.
const TCP_TIMEOUT: Duration = Duration::from_millis(1000);

/// A bad connection string.
#[derive(Debug, thiserror::Error)]
#[error("invalid MAVLink connection `{connection}`: {reason}; expected udpout:HOST:PORT, udpin:ADDR:PORT, tcpout:HOST:PORT or serial:PORT:BAUD")]
pub struct AddressError {
    /// The string as given.
    pub connection: String,
    /// What is wrong with it.
    pub reason: String,
}

/// Errors of an open link.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The link could not be opened.
    #[error("cannot open MAVLink link {address}: {source}")]
    Open {
        /// The connection string.
        address: String,
        /// The I/O error.
        source: io::Error,
    },
    /// The link failed while in use (peer closed, device gone, write failed);
    /// it must be reopened.
    #[error("MAVLink link {address} broke: {reason}")]
    Broken {
        /// The connection string.
        address: String,
        /// What failed.
        reason: String,
    },
}

/// A parsed connection string.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkAddress {
    /// `udpout:HOST:PORT`: send to HOST:PORT from an ephemeral port; replies come back to it.
    UdpOut(String),
    /// `udpin:ADDR:PORT`: listen on ADDR:PORT; send to the autopilot it
    /// locked to (`udpin.rs`).
    UdpIn(String),
    /// `tcpout:HOST:PORT`: a TCP client.
    TcpOut(String),
    /// `serial:PORT:BAUD`, e.g. `serial:/dev/ttyACM0:921600`.
    Serial {
        /// Device path.
        port: String,
        /// Baud rate.
        baud: u32,
    },
}

impl fmt::Display for LinkAddress {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::UdpOut(a) => write!(f, "udpout:{a}"),
            Self::UdpIn(a) => write!(f, "udpin:{a}"),
            Self::TcpOut(a) => write!(f, "tcpout:{a}"),
            Self::Serial { port, baud } => write!(f, "serial:{port}:{baud}"),
        }
    }
}

fn host_port(connection: &str, rest: &str) -> Result<String, AddressError> {
    let bad = |reason: String| AddressError {
        connection: connection.to_string(),
        reason,
    };
    let (host, port) = rest
        .rsplit_once(':')
        .ok_or_else(|| bad(format!("`{rest}` has no `:PORT`")))?;
    if host.is_empty() {
        return Err(bad("empty host".into()));
    }
    port.parse::<u16>()
        .map_err(|_| bad(format!("port `{port}` is not a number 0..=65535")))?;
    Ok(rest.to_string())
}

impl LinkAddress {
    /// Parses `udpout:`, `udpin:`, `tcpout:` or `serial:` strings.
    pub fn parse(connection: &str) -> Result<Self, AddressError> {
        let bad = |reason: String| AddressError {
            connection: connection.to_string(),
            reason,
        };
        let (scheme, rest) = connection
            .split_once(':')
            .ok_or_else(|| bad("no scheme".into()))?;
        match scheme {
            "udpout" => Ok(Self::UdpOut(host_port(connection, rest)?)),
            "udpin" => Ok(Self::UdpIn(host_port(connection, rest)?)),
            "tcpout" => Ok(Self::TcpOut(host_port(connection, rest)?)),
            "serial" => {
                let (port, baud) = rest
                    .rsplit_once(':')
                    .ok_or_else(|| bad("serial needs PORT:BAUD".into()))?;
                if port.is_empty() {
                    return Err(bad("empty serial port".into()));
                }
                let baud = baud
                    .parse::<u32>()
                    .ok()
                    .filter(|b| *b > 0)
                    .ok_or_else(|| bad(format!("baud `{baud}` is not a positive number")))?;
                Ok(Self::Serial {
                    port: port.to_string(),
                    baud,
                })
            }
            other => Err(bad(format!("unknown scheme `{other}`"))),
        }
    }
}

/// The transport behind a [`Link`].
enum Transport {
    /// rust-mavlink's connection (`udpout`, `tcpout`, `serial`).
    Crate(Connection<MavMessage>),
    /// Our own `udpin` socket, locked to one autopilot (`udpin.rs`).
    UdpIn(UdpIn),
    /// A serial port read frame by frame as raw frames (signing on: the
    /// crate's `recv_raw` on serial never returns on a read timeout).
    SerialRaw(SerialRaw),
}

/// A serial port with our own reader and writer.
struct SerialRaw {
    reader: Mutex<MavlinkReader<Box<dyn serialport::SerialPort>>>,
    writer: Mutex<Box<dyn serialport::SerialPort>>,
}

impl SerialRaw {
    fn open(port: &str, baud: u32) -> io::Result<Self> {
        let read_port = serialport::new(port, baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None)
            .timeout(READ_TIMEOUT)
            .open()
            .map_err(io::Error::from)?;
        let write_port = read_port.try_clone().map_err(io::Error::from)?;
        Ok(Self {
            reader: Mutex::new(MavlinkReader::new(read_port)),
            writer: Mutex::new(write_port),
        })
    }
}

/// An open MAVLink 2 connection.
pub struct Link {
    transport: Transport,
    address: LinkAddress,
    /// MAVLink 2 signing of what we send and check of what we receive.
    signing: Option<Arc<Signing>>,
    counters: Arc<Counters>,
    /// Our sequence numbers while signing (the crate's send is bypassed).
    sequence: AtomicU8,
}

impl Link {
    /// Opens `address` with the default `udpin` peer policy.
    pub fn open(address: &LinkAddress) -> Result<Self, LinkError> {
        Self::open_with(address, &PeerPolicy::default(), Arc::default(), None)
    }

    /// Opens `address`. UDP binds immediately (it never fails for a reachable
    /// local address), TCP connects with a 1 s timeout, serial opens the
    /// device. `udpin` locks to an autopilot by `policy`; drops count into
    /// `counters`; `signing` signs and checks frames.
    pub(crate) fn open_with(
        address: &LinkAddress,
        policy: &PeerPolicy,
        counters: Arc<Counters>,
        signing: Option<Arc<Signing>>,
    ) -> Result<Self, LinkError> {
        let open_error = |source: io::Error| LinkError::Open {
            address: address.to_string(),
            source,
        };
        let mut connection: Connection<MavMessage> = match address {
            LinkAddress::UdpOut(a) => UdpConfig::new(a.clone(), UdpMode::Udpout)
                .read_timeout(READ_TIMEOUT)
                .connect::<MavMessage>(),
            LinkAddress::UdpIn(a) => {
                let udpin = UdpIn::bind(
                    a,
                    policy.clone(),
                    READ_TIMEOUT,
                    counters.clone(),
                    signing.clone(),
                )
                .map_err(open_error)?;
                return Ok(Self {
                    transport: Transport::UdpIn(udpin),
                    address: address.clone(),
                    signing,
                    counters,
                    sequence: AtomicU8::new(0),
                });
            }
            LinkAddress::TcpOut(a) => {
                tcp_connect(a).and_then(|s| TcpConfig::from_stream(s)?.connect())
            }
            LinkAddress::Serial { port, baud } if signing.is_some() => {
                let serial = SerialRaw::open(port, *baud).map_err(open_error)?;
                return Ok(Self {
                    transport: Transport::SerialRaw(serial),
                    address: address.clone(),
                    signing,
                    counters,
                    sequence: AtomicU8::new(0),
                });
            }
            LinkAddress::Serial { port, baud } => SerialConfig::new(port.clone(), *baud)
                .timeout(READ_TIMEOUT)
                .connect::<MavMessage>(),
        }
        .map_err(open_error)?;
        connection.set_protocol_version(MavlinkVersion::V2);
        // Autopilots may talk MAVLink 1 until they hear MAVLink 2.
        connection.set_allow_recv_any_version(true);
        Ok(Self {
            transport: Transport::Crate(connection),
            address: address.clone(),
            signing,
            counters,
            sequence: AtomicU8::new(0),
        })
    }

    /// How many times the peer was locked: 0 until a `udpin` link hears an
    /// autopilot, 1 for the other transports (their peer is fixed). A
    /// change means a new autopilot, hence a new stream.
    pub fn peer_epoch(&self) -> u64 {
        match &self.transport {
            Transport::Crate(_) | Transport::SerialRaw(_) => 1,
            Transport::UdpIn(u) => u.peer_epoch(),
        }
    }

    /// The address this link was opened with.
    pub fn address(&self) -> &LinkAddress {
        &self.address
    }

    /// Sends one message. `Ok(false)` when there is nobody to send to yet
    /// (`udpin` before the first packet arrives).
    pub fn send(&self, header: &MavHeader, message: &MavMessage) -> Result<bool, LinkError> {
        if let Some(signing) = &self.signing {
            let header = MavHeader {
                sequence: self.sequence.fetch_add(1, Ordering::Relaxed),
                ..*header
            };
            let mut frame = MAVLinkV2MessageRaw::new();
            signing.sign(header, message, &mut frame);
            return match &self.transport {
                Transport::Crate(connection) => connection
                    .send_raw(&MAVLinkMessageRaw::V2(frame))
                    .map(|n| n > 0)
                    .map_err(|e| self.broken(e.to_string())),
                Transport::UdpIn(udpin) => udpin
                    .send_frame(frame.raw_bytes())
                    .map_err(|e| self.broken(e.to_string())),
                Transport::SerialRaw(serial) => serial
                    .writer
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .write_all(frame.raw_bytes())
                    .map(|()| true)
                    .map_err(|e| self.broken(e.to_string())),
            };
        }
        match &self.transport {
            Transport::Crate(connection) => match connection.send(header, message) {
                Ok(n) => Ok(n > 0),
                Err(e) => Err(self.broken(e.to_string())),
            },
            Transport::UdpIn(udpin) => udpin
                .send(header, message)
                .map_err(|e| self.broken(e.to_string())),
            // Only opened with signing, which returned above.
            Transport::SerialRaw(_) => Ok(false),
        }
    }

    /// Waits up to [`READ_TIMEOUT`] for one message. `Ok(None)` on timeout or
    /// on a frame that did not decode (bad CRC frames are skipped by the reader).
    pub fn recv(&self) -> Result<Option<(MavHeader, MavMessage)>, LinkError> {
        // The serial transport's blocking `recv` retries timeouts forever;
        // its `try_recv` waits for the port timeout instead.
        let result = match (&self.transport, &self.address) {
            (Transport::UdpIn(udpin), _) => udpin.recv().map_err(MessageReadError::Io),
            (Transport::SerialRaw(serial), _) => serial
                .reader
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .read_any_raw_message::<MavMessage>()
                .map(|raw| {
                    signing::admit(self.signing.as_deref(), &self.counters, &raw)
                        .then(|| signing::decode(&raw))
                        .flatten()
                }),
            // Signing: raw frames, checked here (counted), then decoded.
            (Transport::Crate(connection), _) if self.signing.is_some() => {
                connection.recv_raw().map(|raw| {
                    signing::admit(self.signing.as_deref(), &self.counters, &raw)
                        .then(|| signing::decode(&raw))
                        .flatten()
                })
            }
            (Transport::Crate(connection), LinkAddress::Serial { .. }) => {
                connection.try_recv().map(Some)
            }
            (Transport::Crate(connection), _) => connection.recv().map(Some),
        };
        match result {
            Ok(m) => Ok(m),
            Err(MessageReadError::Io(e)) => match e.kind() {
                io::ErrorKind::WouldBlock
                | io::ErrorKind::TimedOut
                | io::ErrorKind::Interrupted => Ok(None),
                _ => Err(self.broken(e.to_string())),
            },
            Err(MessageReadError::Parse(e)) => {
                tracing::debug!(error = %e, "undecodable MAVLink message skipped");
                Ok(None)
            }
        }
    }

    fn broken(&self, reason: String) -> LinkError {
        LinkError::Broken {
            address: self.address.to_string(),
            reason,
        }
    }
}

fn tcp_connect(address: &str) -> io::Result<TcpStream> {
    let mut last = io::Error::new(io::ErrorKind::NotFound, "address resolved to nothing");
    for addr in address.to_socket_addrs()? {
        match TcpStream::connect_timeout(&addr, TCP_TIMEOUT) {
            Ok(stream) => {
                stream.set_read_timeout(Some(READ_TIMEOUT))?;
                stream.set_write_timeout(Some(TCP_TIMEOUT))?;
                stream.set_nodelay(true)?;
                return Ok(stream);
            }
            Err(e) => last = e,
        }
    }
    Err(last)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_four_schemes() {
        assert_eq!(
            LinkAddress::parse("udpout:127.0.0.1:14550").unwrap(),
            LinkAddress::UdpOut("127.0.0.1:14550".into())
        );
        assert_eq!(
            LinkAddress::parse("udpin:0.0.0.0:14540").unwrap(),
            LinkAddress::UdpIn("0.0.0.0:14540".into())
        );
        assert_eq!(
            LinkAddress::parse("tcpout:localhost:5760").unwrap(),
            LinkAddress::TcpOut("localhost:5760".into())
        );
        assert_eq!(
            LinkAddress::parse("serial:/dev/ttyACM0:921600").unwrap(),
            LinkAddress::Serial {
                port: "/dev/ttyACM0".into(),
                baud: 921_600
            }
        );
        let a = LinkAddress::parse("serial:/dev/ttyACM0:921600").unwrap();
        assert_eq!(a.to_string(), "serial:/dev/ttyACM0:921600");
    }

    #[test]
    fn rejects_bad_strings_with_reason() {
        for (s, needle) in [
            ("udp:1.2.3.4:5", "unknown scheme `udp`"),
            ("udpout:1.2.3.4", "no `:PORT`"),
            ("udpout:1.2.3.4:99999", "port `99999`"),
            ("serial:/dev/ttyACM0", "PORT:BAUD"),
            ("serial:/dev/ttyACM0:fast", "baud `fast`"),
            ("tcpout::5760", "empty host"),
            ("", "no scheme"),
        ] {
            let e = LinkAddress::parse(s).expect_err(s).to_string();
            assert!(e.contains(needle), "{s}: {e}");
        }
    }

    #[test]
    fn tcp_refused_is_an_open_error() {
        // Bind then drop to get a port that nobody listens on.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let address = LinkAddress::TcpOut(format!("127.0.0.1:{port}"));
        let Err(err) = Link::open(&address) else {
            panic!("connect to a closed port succeeded");
        };
        assert!(matches!(err, LinkError::Open { .. }), "{err}");
    }

    #[test]
    fn udp_roundtrip_is_mavlink2() {
        let peer = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        peer.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        let address = LinkAddress::UdpOut(peer.local_addr().unwrap().to_string());
        let link = Link::open(&address).unwrap();
        let header = MavHeader {
            system_id: 7,
            component_id: 197,
            sequence: 0,
        };
        let msg = MavMessage::TIMESYNC(mavlink::dialects::common::TIMESYNC_DATA {
            tc1: 0,
            ts1: 42,
            target_system: 0,
            target_component: 0,
        });
        assert!(link.send(&header, &msg).unwrap());
        let mut buf = [0u8; 300];
        let (n, _) = peer.recv_from(&mut buf).unwrap();
        assert!(n > 12);
        assert_eq!(buf[0], 0xFD, "MAVLink 2 magic");
        assert_eq!(buf[5], 7, "system id");
        assert_eq!(buf[6], 197, "component id");
        // Nothing comes back: recv times out as Ok(None).
        assert!(link.recv().unwrap().is_none());
    }
}
