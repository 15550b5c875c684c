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

/// A UDP autopilot stand-in on its own thread: answers the link's TIMESYNC
/// requests as `answer(since_start, request_index, ts1)` says (`None`: stay
/// silent) and records each VISION_POSITION_ESTIMATE as (arrival on
/// CLOCK_MONOTONIC, usec).
struct Peer {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<Vec<(u64, u64)>>>,
}

type Answer = fn(Duration, usize, i64) -> Option<i64>;

impl Peer {
    fn start(peer: UdpSocket, answer: Answer) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let thread = std::thread::spawn(move || {
            peer.set_read_timeout(Some(Duration::from_millis(20)))
                .unwrap();
            let start = Instant::now();
            let mut poses = Vec::new();
            let mut requests = 0;
            let mut buf = [0u8; 512];
            let header = MavHeader {
                system_id: 1,
                component_id: 1,
                sequence: 0,
            };
            while !stop2.load(Ordering::Relaxed) {
                let Ok((n, from)) = peer.recv_from(&mut buf) else {
                    continue;
                };
                let arrival = monotonic_now_ns();
                let mut reader = MavlinkReader::new(&buf[..n]);
                let Ok((_, msg)) = reader.read_message::<MavMessage>(MavlinkVersion::V2) else {
                    continue;
                };
                match msg {
                    MavMessage::VISION_POSITION_ESTIMATE(d) => poses.push((arrival, d.usec)),
                    MavMessage::TIMESYNC(d) if d.tc1 == 0 => {
                        let k = requests;
                        requests += 1;
                        if let Some(tc1) = answer(start.elapsed(), k, d.ts1) {
                            let mut frame = mavlink::MAVLinkV2MessageRaw::new();
                            let reply = MavMessage::TIMESYNC(TIMESYNC_DATA {
                                tc1,
                                ts1: d.ts1,
                                target_system: 1,
                                target_component: 197,
                            });
                            frame.serialize_message(header, &reply);
                            peer.send_to(frame.raw_bytes(), from).unwrap();
                        }
                    }
                    _ => {}
                }
            }
            poses
        });
        Self {
            stop,
            thread: Some(thread),
        }
    }

    fn finish(mut self) -> Vec<(u64, u64)> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.take().unwrap().join().unwrap()
    }
}

/// The stand-in's clock runs this far ahead of ours.
const PEER_OFFSET_NS: i64 = 5_000_000_000;

/// Publishes for `duration` at 200 Hz, then stops the link; returns its stats.
fn run_link(config: &MavlinkConfig, duration: Duration) -> star::mavlink_io::LinkStats {
    let link = Arc::new(MavlinkLink::spawn(config, Arc::new(AtomicBool::new(false))).unwrap());
    let stop = Arc::new(AtomicBool::new(false));
    let pub_thread = publisher(link.clone(), stop.clone());
    std::thread::sleep(duration);
    stop.store(true, Ordering::Relaxed);
    pub_thread.join().unwrap();
    let stats = link.stats();
    let link = Arc::try_unwrap(link).ok().expect("publisher finished");
    assert!(link.shutdown());
    stats
}

/// Latency of each pose in the given clock: arrival + `offset` - usec, ms.
fn latencies_ms(poses: &[(u64, u64)], offset_ns: i64) -> Vec<f64> {
    poses
        .iter()
        .map(|&(arrival, usec)| (arrival as i64 + offset_ns - usec as i64 * 1000) as f64 * 1e-6)
        .collect()
}

fn check_spacing(poses: &[(u64, u64)], min_us: u64) {
    for w in poses.windows(2) {
        assert!(
            w[1].1 >= w[0].1 + min_us,
            "usec {} then {}: under {min_us} us apart",
            w[0].1,
            w[1].1
        );
    }
}

#[test]
fn first_pose_waits_for_timesync_and_is_in_the_autopilot_clock() {
    let (peer, config) = udp_peer();
    // Silent for the first 300 ms, then answers in its clock.
    let peer = Peer::start(peer, |since, _, _| {
        (since > Duration::from_millis(300)).then(|| monotonic_now_ns() as i64 + PEER_OFFSET_NS)
    });
    let stats = run_link(&config, Duration::from_millis(1500));
    let poses = peer.finish();
    assert!(poses.len() > 20, "{} poses: {stats:?}", poses.len());
    assert!(stats.poses_dropped_clock > 0, "{stats:?}");
    assert!(!stats.monotonic_clock, "{stats:?}");
    assert!(stats.timesync_offset_ns.is_some(), "{stats:?}");
    // Every pose, the first included, is in the stand-in's clock: captured
    // shortly before it arrived there (in CLOCK_MONOTONIC it would look 5 s
    // in the future).
    for (k, lat) in latencies_ms(&poses, PEER_OFFSET_NS).into_iter().enumerate() {
        assert!((-5.0..150.0).contains(&lat), "pose {k}: latency {lat} ms");
    }
    check_spacing(&poses, 10_000);
}

#[test]
fn silent_autopilot_gets_our_clock_from_the_first_pose_and_no_switch() {
    let (peer, mut config) = udp_peer();
    config.timesync_wait_ms = 300;
    // Silent for 800 ms (past the wait), then answers in its clock.
    let peer = Peer::start(peer, |since, _, _| {
        (since > Duration::from_millis(800)).then(|| monotonic_now_ns() as i64 + PEER_OFFSET_NS)
    });
    let start = monotonic_now_ns();
    let stats = run_link(&config, Duration::from_millis(2000));
    let poses = peer.finish();
    assert!(poses.len() > 20, "{} poses: {stats:?}", poses.len());
    let first_ms = (poses[0].0 - start) as f64 * 1e-6;
    assert!(first_ms >= 290.0, "first pose {first_ms} ms after start");
    assert!(stats.poses_dropped_clock > 0, "{stats:?}");
    assert!(
        stats.timesync_samples > 0,
        "answers came and were used for the estimate: {stats:?}"
    );
    assert!(stats.monotonic_clock, "{stats:?}");
    assert_eq!(stats.timesync_offset_ns, None, "{stats:?}");
    // All in CLOCK_MONOTONIC, also after the answers came.
    for (k, lat) in latencies_ms(&poses, 0).into_iter().enumerate() {
        assert!((-5.0..150.0).contains(&lat), "pose {k}: latency {lat} ms");
    }
    check_spacing(&poses, 10_000);
}

#[test]
fn hostile_timesync_replies_do_not_move_usec() {
    let (peer, mut config) = udp_peer();
    config.timesync_wait_ms = 1000;
    // Every other reply is hostile: tc1 = 2^62, -2^62 or 1.
    let peer = Peer::start(peer, |_, k, _| {
        Some(match k % 6 {
            1 => 1 << 62,
            3 => -(1 << 62),
            5 => 1,
            _ => monotonic_now_ns() as i64 + PEER_OFFSET_NS,
        })
    });
    let stats = run_link(&config, Duration::from_millis(3000));
    let poses = peer.finish();
    assert!(poses.len() > 50, "{} poses: {stats:?}", poses.len());
    assert!(stats.timesync_rejected >= 2, "{stats:?}");
    assert_eq!(stats.timesync_resyncs, 0, "{stats:?}");
    for (k, lat) in latencies_ms(&poses, PEER_OFFSET_NS).into_iter().enumerate() {
        assert!((-5.0..150.0).contains(&lat), "pose {k}: latency {lat} ms");
    }
    check_spacing(&poses, 10_000);
}

/// ArduPilot flags only the first sample of a new `reset_counter` as a
/// reset; a pose right behind it made EKF3 drop it and lose the reset
/// (hil_tests/test_sitl_blackout.py). The pose after a reset waits at least
/// one rate interval (20 ms at 50 Hz) of wall time, also when the tracker
/// hands over the next one at once.
#[test]
fn the_pose_after_a_reset_waits_one_interval() {
    let (peer, mut config) = udp_peer();
    config.timesync = false;
    let shutdown = Arc::new(AtomicBool::new(false));
    let link = MavlinkLink::spawn(&config, shutdown).unwrap();
    wait_for("link up", || link.stats().heartbeat_sent >= 1);
    let receiver = std::thread::spawn(move || {
        let mut arrivals = Vec::new();
        let end = Instant::now() + Duration::from_secs(3);
        let mut buf = [0u8; 512];
        while Instant::now() < end {
            if let Ok((n, _)) = peer.recv_from(&mut buf) {
                let t = Instant::now();
                let mut reader = MavlinkReader::new(&buf[..n]);
                if let Ok((_, MavMessage::VISION_POSITION_ESTIMATE(d))) =
                    reader.read_message::<MavMessage>(MavlinkVersion::V2)
                {
                    arrivals.push((t, d.reset_counter));
                }
            }
        }
        arrivals
    });
    let mut tracker_counter = 0u8;
    for k in 0..60u64 {
        if k % 20 == 10 {
            // A relocalization: the tracker's counter changes, and the next
            // frame (captured one interval later, as the autopilot's
            // minimum spacing wants) follows as soon as the link has taken
            // this one.
            tracker_counter += 1;
            let mut reset = sample(monotonic_now_ns(), true);
            reset.reset_counter = tracker_counter;
            let sent = link.stats().vision_position_estimate_sent;
            link.publish(reset);
            wait_for("the reset pose sent", || {
                link.stats().vision_position_estimate_sent > sent
            });
            let mut next = sample(reset.capture_ns + 20_000_000, true);
            next.reset_counter = tracker_counter;
            link.publish(next);
        } else {
            let mut s = sample(monotonic_now_ns(), true);
            s.reset_counter = tracker_counter;
            link.publish(s);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let arrivals = receiver.join().unwrap();
    let resets: Vec<usize> = (1..arrivals.len())
        .filter(|&i| arrivals[i].1 != arrivals[i - 1].1)
        .collect();
    assert_eq!(resets.len(), 3, "three resets: {arrivals:?}");
    for i in resets {
        let (t_reset, _) = arrivals[i];
        let (t_next, _) = arrivals
            .get(i + 1)
            .copied()
            .expect("a pose after the reset");
        let gap = t_next - t_reset;
        println!("pose after reset {}: {gap:?} later", arrivals[i].1);
        assert!(
            gap >= Duration::from_millis(19),
            "the pose after a reset came {gap:?} later"
        );
    }
    assert!(link.shutdown());
}
