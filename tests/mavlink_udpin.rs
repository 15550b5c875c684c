//! Issue 24: a `udpin:` link cannot be hijacked. A fake autopilot (a UDP
//! socket sending ArduPilot HEARTBEATs) locks the link; a foreign socket
//! then sends 20 random bytes and valid autopilot HEARTBEATs of another
//! system id: the poses keep reaching the autopilot at the 50 Hz cap and
//! none reach the foreign socket. Only after the autopilot has been silent
//! for `peer_silence_s` does the other sender get the link, with a warning
//! in the log.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::Write;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mavlink::dialects::common::{
    MavAutopilot, MavMessage, MavModeFlag, MavState, MavType, HEARTBEAT_DATA,
};
use mavlink::{MavHeader, MavlinkReader};
use star::clock::monotonic_now_ns;
use star::geometry::Pose;
use star::mavlink_io::{MavlinkConfig, MavlinkHandle, MavlinkLink, PoseSample};

const SILENCE_S: f64 = 1.0;

/// Where the link's log goes, to look for the warning.
#[derive(Clone, Default)]
struct LogBuffer(Arc<Mutex<Vec<u8>>>);

impl Write for LogBuffer {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        std::io::stderr().write_all(buf)?;
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl LogBuffer {
    fn text(&self) -> String {
        String::from_utf8_lossy(&self.0.lock().unwrap()).into_owned()
    }
}

fn heartbeat_frame(system_id: u32) -> Vec<u8> {
    let mut bytes = Vec::new();
    mavlink::write_v2_msg(
        &mut bytes,
        MavHeader {
            system_id,
            component_id: 1,
            sequence: 0,
        },
        &MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 0,
            mavtype: MavType::MAV_TYPE_QUADROTOR,
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            base_mode: MavModeFlag::empty(),
            system_status: MavState::MAV_STATE_STANDBY,
            mavlink_version: 3,
        }),
    )
    .unwrap();
    bytes
}

/// 20 fixed pseudo-random bytes that start like a MAVLink 2 frame.
fn garbage() -> [u8; 20] {
    let mut x: u32 = 0x2545_F491;
    let mut out = [0u8; 20];
    for b in &mut out {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        *b = x as u8;
    }
    out[0] = 0xFD;
    out
}

/// One end of the test: a socket that records the VISION_POSITION_ESTIMATEs
/// and the datagrams it receives, and sends HEARTBEATs while `beating`.
struct Peer {
    socket: UdpSocket,
    poses: Arc<Mutex<Vec<Instant>>>,
    datagrams: Arc<Mutex<Vec<Instant>>>,
    beating: Arc<AtomicBool>,
    last_beat: Arc<Mutex<Option<Instant>>>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

impl Peer {
    fn new(system_id: u32, link: SocketAddr) -> Self {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(50)))
            .unwrap();
        let mut peer = Self {
            socket,
            poses: Arc::default(),
            datagrams: Arc::default(),
            beating: Arc::default(),
            last_beat: Arc::default(),
            stop: Arc::default(),
            threads: Vec::new(),
        };
        let (socket, poses, datagrams, stop) = (
            peer.socket.try_clone().unwrap(),
            peer.poses.clone(),
            peer.datagrams.clone(),
            peer.stop.clone(),
        );
        peer.threads.push(std::thread::spawn(move || {
            let mut buf = [0u8; 2048];
            while !stop.load(Ordering::Relaxed) {
                let Ok((n, _)) = socket.recv_from(&mut buf) else {
                    continue;
                };
                let t = Instant::now();
                datagrams.lock().unwrap().push(t);
                let mut reader = MavlinkReader::new(&buf[..n]);
                while let Ok((_, m)) = reader.read_any_message::<MavMessage>() {
                    if matches!(m, MavMessage::VISION_POSITION_ESTIMATE(_)) {
                        poses.lock().unwrap().push(t);
                    }
                }
            }
        }));
        let (socket, beating, last_beat, stop) = (
            peer.socket.try_clone().unwrap(),
            peer.beating.clone(),
            peer.last_beat.clone(),
            peer.stop.clone(),
        );
        let frame = heartbeat_frame(system_id);
        peer.threads.push(std::thread::spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                if beating.load(Ordering::Relaxed) {
                    socket.send_to(&frame, link).unwrap();
                    *last_beat.lock().unwrap() = Some(Instant::now());
                }
                std::thread::sleep(Duration::from_millis(100));
            }
        }));
        peer
    }

    fn poses_in(&self, from: Instant, to: Instant) -> usize {
        let poses = self.poses.lock().unwrap();
        poses.iter().filter(|&&t| t >= from && t < to).count()
    }

    fn datagrams_since(&self, from: Instant) -> usize {
        let d = self.datagrams.lock().unwrap();
        d.iter().filter(|&&t| t >= from).count()
    }

    fn first_pose_after(&self, from: Instant) -> Option<Instant> {
        let poses = self.poses.lock().unwrap();
        poses.iter().copied().find(|&t| t >= from)
    }

    fn close(mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            t.join().unwrap();
        }
    }
}

/// Publishes fresh tracked samples at 100 Hz (the link caps them at 50).
fn publisher(link: Arc<MavlinkHandle>, stop: Arc<AtomicBool>) -> JoinHandle<()> {
    std::thread::spawn(move || {
        while !stop.load(Ordering::Relaxed) {
            link.publish(PoseSample {
                capture_ns: monotonic_now_ns(),
                world_from_camera: Pose::identity(),
                covariance_6x6: [[0.0; 6]; 6],
                reset_counter: 0,
                quality_percent: 50,
                tracking: true,
            });
            std::thread::sleep(Duration::from_millis(10));
        }
    })
}

fn wait_until(what: &str, timeout: Duration, mut cond: impl FnMut() -> bool) -> Instant {
    let end = Instant::now() + timeout;
    loop {
        if cond() {
            return Instant::now();
        }
        assert!(Instant::now() < end, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Poses per second over `window` from now.
fn rate_hz(peer: &Peer, window: Duration) -> f64 {
    let from = Instant::now();
    std::thread::sleep(window);
    peer.poses_in(from, from + window) as f64 / window.as_secs_f64()
}

#[test]
fn udpin_locks_to_the_autopilot_and_ignores_foreign_senders() {
    let log = LogBuffer::default();
    let writer = log.clone();
    let subscriber = tracing_subscriber::fmt()
        .with_writer(move || writer.clone())
        .with_ansi(false)
        .with_max_level(tracing::Level::INFO)
        .finish();
    tracing::subscriber::set_global_default(subscriber).unwrap();

    let port = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let link_addr = SocketAddr::from(([127, 0, 0, 1], port));
    let config = MavlinkConfig {
        connection: format!("udpin:{link_addr}"),
        // The fake autopilot does not answer TIMESYNC.
        timesync: false,
        peer_silence_s: SILENCE_S,
        ..MavlinkConfig::default()
    };
    let shutdown = Arc::new(AtomicBool::new(false));
    let link = Arc::new(MavlinkLink::spawn(&config, shutdown).unwrap());
    let stop = Arc::new(AtomicBool::new(false));
    let publishing = publisher(link.clone(), stop.clone());
    let autopilot = Peer::new(1, link_addr);
    let foreign = Peer::new(2, link_addr);

    // Before any autopilot: garbage locks nothing and gets nothing.
    std::thread::sleep(Duration::from_millis(300));
    foreign.socket.send_to(&garbage(), link_addr).unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let stats = link.stats();
    assert_eq!(stats.udpin_peer_locks, 0, "{stats:?}");
    assert_eq!(stats.vision_position_estimate_sent, 0, "{stats:?}");
    assert!(stats.udpin_foreign_datagrams >= 1, "{stats:?}");
    assert!(stats.poses_dropped_link > 0, "poses wait: {stats:?}");
    assert_eq!(
        foreign.datagrams_since(Instant::now() - Duration::from_secs(60)),
        0
    );

    // The autopilot speaks: it gets the poses at the cap.
    autopilot.beating.store(true, Ordering::Relaxed);
    let locked = Instant::now();
    wait_until("poses at the autopilot", Duration::from_secs(3), || {
        autopilot.first_pose_after(locked).is_some()
    });
    let before = rate_hz(&autopilot, Duration::from_secs(2));

    // The foreign sender: 20 random bytes, then valid autopilot HEARTBEATs
    // of system 2 every 100 ms.
    let attack = Instant::now();
    foreign.socket.send_to(&garbage(), link_addr).unwrap();
    foreign.beating.store(true, Ordering::Relaxed);
    let during = rate_hz(&autopilot, Duration::from_secs(2));
    let stats = link.stats();
    println!(
        "autopilot: {before:.1} Hz before, {during:.1} Hz while a foreign sender sends garbage \
         and HEARTBEATs; foreign datagrams received: {}; {stats:?}",
        foreign.datagrams_since(attack)
    );
    assert_eq!(
        foreign.datagrams_since(attack),
        0,
        "the foreign sender got something"
    );
    for hz in [before, during] {
        assert!((40.0..=52.0).contains(&hz), "pose rate {hz:.1} Hz, not ~50");
    }
    assert_eq!(stats.udpin_peer_locks, 1, "{stats:?}");
    assert!(stats.udpin_foreign_datagrams >= 15, "{stats:?}");
    assert!(!log.text().contains("peer changed"));

    // The autopilot goes silent; after SILENCE_S the other one gets the link.
    autopilot.beating.store(false, Ordering::Relaxed);
    std::thread::sleep(Duration::from_millis(150)); // a beat in flight
    let last_beat = autopilot.last_beat.lock().unwrap().expect("it beat");
    let switched = wait_until("poses at the new peer", Duration::from_secs(5), || {
        foreign.first_pose_after(attack).is_some()
    });
    let first_new = foreign.first_pose_after(attack).unwrap();
    let silent_s = (first_new - last_beat).as_secs_f64();
    // Nothing to the old peer once the new one has poses (100 ms for
    // datagrams already in flight).
    std::thread::sleep(Duration::from_millis(100));
    let grace = switched + Duration::from_millis(100);
    let after = rate_hz(&foreign, Duration::from_secs(1));
    let stats = link.stats();
    let old_after = autopilot.datagrams_since(grace);
    println!(
        "switch after {silent_s:.2} s of autopilot silence (peer_silence_s {SILENCE_S}); new peer \
         {after:.1} Hz; old peer datagrams after the switch: {old_after}; {stats:?}"
    );
    assert!(
        silent_s >= SILENCE_S,
        "switched after {silent_s:.2} s of silence"
    );
    assert!(silent_s < SILENCE_S + 1.5, "switched late: {silent_s:.2} s");
    assert_eq!(old_after, 0, "the old peer still gets datagrams");
    assert!((40.0..=52.0).contains(&after), "new peer at {after:.1} Hz");
    assert_eq!(stats.udpin_peer_locks, 2, "{stats:?}");
    let text = log.text();
    let warned = text
        .lines()
        .any(|l| l.contains("WARN") && l.contains("peer changed"));
    assert!(warned, "no warning of the peer change in:\n{text}");

    stop.store(true, Ordering::Relaxed);
    publishing.join().unwrap();
    autopilot.close();
    foreign.close();
    let link = Arc::try_unwrap(link).ok().expect("publisher finished");
    assert!(link.shutdown());
}
