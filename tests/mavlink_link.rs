//! The link's behavior with a Rust-side peer: reconnecting over TCP without a
//! burst of stale poses, dropping stale and lost samples, TIMESYNC answers,
//! and shutdown through the shared flag.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::net::{TcpListener, TcpStream, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use mavlink::dialects::common::{MavMessage, TIMESYNC_DATA};
use mavlink::{MavHeader, MavlinkReader, MavlinkVersion};
use star::clock::monotonic_now_ns;
use star::geometry::Pose;
use star::mavlink_io::{MavlinkConfig, MavlinkHandle, MavlinkLink, PoseSample};

fn sample(capture_ns: u64, tracking: bool) -> PoseSample {
    PoseSample {
        capture_ns,
        world_from_camera: Pose::identity(),
        covariance_6x6: [[0.0; 6]; 6],
        reset_counter: 0,
        quality_percent: 50,
        tracking,
    }
}

/// Polls `cond` for up to 5 s.
fn wait_for(what: &str, mut cond: impl FnMut() -> bool) {
    let end = Instant::now() + Duration::from_secs(5);
    while !cond() {
        assert!(Instant::now() < end, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn accept(listener: &TcpListener) -> TcpStream {
    let mut stream = None;
    wait_for("a TCP connection", || {
        stream = listener.accept().ok().map(|(s, _)| s);
        stream.is_some()
    });
    let stream = stream.unwrap();
    stream.set_nonblocking(false).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    stream
}

/// Reads messages until a pose arrives; returns its `usec`.
fn next_pose_usec(reader: &mut MavlinkReader<TcpStream>) -> u64 {
    loop {
        let (header, msg) = reader
            .read_message::<MavMessage>(MavlinkVersion::V2)
            .expect("a MAVLink 2 message");
        assert_eq!((header.system_id, header.component_id), (1, 197));
        if let MavMessage::VISION_POSITION_ESTIMATE(d) = msg {
            return d.usec;
        }
    }
}

/// Publishes fresh tracked samples at ~200 Hz until `stop`.
fn publisher(link: Arc<MavlinkHandle>, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        while !stop.load(Ordering::Relaxed) {
            link.publish(sample(monotonic_now_ns(), true));
            std::thread::sleep(Duration::from_millis(5));
        }
    })
}

#[test]
fn tcp_link_reconnects_and_sends_only_fresh_poses() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    listener.set_nonblocking(true).unwrap();
    let config = MavlinkConfig {
        connection: format!("tcpout:{}", listener.local_addr().unwrap()),
        timesync: false,
        ..MavlinkConfig::default()
    };
    let link = Arc::new(MavlinkLink::spawn(&config, Arc::new(AtomicBool::new(false))).unwrap());
    let stop = Arc::new(AtomicBool::new(false));
    let pub_thread = publisher(link.clone(), stop.clone());

    let first = accept(&listener);
    let mut reader = MavlinkReader::new(first.try_clone().unwrap());
    for _ in 0..5 {
        next_pose_usec(&mut reader);
    }
    // The autopilot side goes away; the link notices and reconnects.
    first.shutdown(std::net::Shutdown::Both).unwrap();
    drop(reader);
    drop(first);
    let second = accept(&listener);
    let mut reader = MavlinkReader::new(second);
    // The first pose after the outage is fresh (within max_pose_age_ms of now).
    let usec = next_pose_usec(&mut reader);
    let age_ms = (monotonic_now_ns() / 1000).saturating_sub(usec) as f64 / 1000.0;
    assert!(
        age_ms <= f64::from(config.max_pose_age_ms) + 50.0,
        "first pose after reconnect is {age_ms} ms old"
    );
    next_pose_usec(&mut reader);

    stop.store(true, Ordering::Relaxed);
    pub_thread.join().unwrap();
    let stats = link.stats();
    assert!(stats.connects >= 2, "{stats:?}");
    assert!(stats.link_errors >= 1, "{stats:?}");
    assert!(stats.link_up, "{stats:?}");
    let link = Arc::try_unwrap(link).ok().expect("publisher finished");
    assert!(link.shutdown());
}

fn udp_peer() -> (UdpSocket, MavlinkConfig) {
    let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
    peer.set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let config = MavlinkConfig {
        connection: format!("udpout:{}", peer.local_addr().unwrap()),
        ..MavlinkConfig::default()
    };
    (peer, config)
}

/// Receives datagrams until `window` passes; decodes them.
fn drain(peer: &UdpSocket, window: Duration) -> Vec<(MavHeader, MavMessage)> {
    let mut out = Vec::new();
    let end = Instant::now() + window;
    let mut buf = [0u8; 512];
    while Instant::now() < end {
        if let Ok((n, _)) = peer.recv_from(&mut buf) {
            let mut reader = MavlinkReader::new(&buf[..n]);
            out.push(
                reader
                    .read_message::<MavMessage>(MavlinkVersion::V2)
                    .unwrap(),
            );
        }
    }
    out
}

#[test]
fn stale_lost_and_invalid_samples_are_not_sent_and_timesync_is_answered() {
    let (peer, config) = udp_peer();
    let shutdown = Arc::new(AtomicBool::new(false));
    let link = MavlinkLink::spawn(&config, shutdown.clone()).unwrap();
    wait_for("link up", || link.stats().heartbeat_sent >= 1);
    // One second old: stale.
    link.publish(sample(monotonic_now_ns() - 1_000_000_000, true));
    wait_for("stale drop", || link.stats().poses_dropped_stale == 1);
    link.publish(sample(monotonic_now_ns(), false));
    wait_for("lost drop", || link.stats().poses_dropped_lost == 1);
    // A NaN pose from a broken tracker is not sent either.
    let mut nan = sample(monotonic_now_ns(), true);
    nan.world_from_camera.translation.vector.x = f64::NAN;
    link.publish(nan);
    wait_for("invalid drop", || link.stats().poses_dropped_invalid == 1);
    let got = drain(&peer, Duration::from_millis(100));
    assert!(got
        .iter()
        .all(|(_, m)| !matches!(m, MavMessage::VISION_POSITION_ESTIMATE(_))));
    // Learn the link's address from what it sent, then ask for the time.
    let mut buf = [0u8; 512];
    let mut link_addr = None;
    wait_for("a heartbeat", || {
        link_addr = peer.recv_from(&mut buf).ok().map(|(_, a)| a);
        link_addr.is_some()
    });
    let link_addr = link_addr.unwrap();
    let header = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    let mut frame = mavlink::MAVLinkV2MessageRaw::new();
    let request = MavMessage::TIMESYNC(TIMESYNC_DATA {
        tc1: 0,
        ts1: 123_456_789,
        target_system: 0,
        target_component: 0,
    });
    frame.serialize_message(header, &request);
    peer.send_to(frame.raw_bytes(), link_addr).unwrap();
    let got = drain(&peer, Duration::from_millis(300));
    let reply = got
        .iter()
        .find_map(|(_, m)| match m {
            MavMessage::TIMESYNC(d) if d.tc1 != 0 => Some(d.clone()),
            _ => None,
        })
        .expect("TIMESYNC answered");
    assert_eq!(
        (reply.ts1, reply.target_system, reply.target_component),
        (123_456_789, 1, 1)
    );
    // The shared shutdown flag stops the threads.
    shutdown.store(true, Ordering::Relaxed);
    assert!(link.shutdown());
}
