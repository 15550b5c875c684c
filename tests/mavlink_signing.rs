//! MAVLink 2 signing on a live link (`udpout:` to a Rust peer holding the
//! same key): what star sends is signed and verifies with the key; with
//! `signing_required`, an unsigned TIMESYNC request and one signed with
//! another key are dropped (counted) and not answered, a correctly signed one
//! is answered.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mavlink::dialects::common::{MavMessage, TIMESYNC_DATA};
use mavlink::{
    MAVLinkMessageRaw, MAVLinkV2MessageRaw, MavHeader, MavlinkReader, SigningConfig, SigningData,
};
use star::mavlink_io::{MavlinkConfig, MavlinkLink};

const KEY: [u8; 32] = [9; 32];

fn request(ts1: i64) -> MavMessage {
    MavMessage::TIMESYNC(TIMESYNC_DATA {
        tc1: 0,
        ts1,
        target_system: 0,
        target_component: 0,
    })
}

/// Raw frames received over `window`.
fn drain(peer: &UdpSocket, window: Duration) -> Vec<MAVLinkMessageRaw> {
    let mut out = Vec::new();
    let end = Instant::now() + window;
    let mut buf = [0u8; 600];
    while Instant::now() < end {
        if let Ok((n, _)) = peer.recv_from(&mut buf) {
            let mut reader = MavlinkReader::new(&buf[..n]);
            while let Ok(raw) = reader.read_any_raw_message::<MavMessage>() {
                out.push(raw);
            }
        }
    }
    out
}

fn answered(frames: &[MAVLinkMessageRaw], ts1: i64) -> bool {
    frames.iter().any(|raw| {
        matches!(
            mavlink::Message::parse(raw.version(), raw.message_id(), raw.payload()),
            Ok(MavMessage::TIMESYNC(d)) if d.tc1 != 0 && d.ts1 == ts1
        )
    })
}

#[test]
fn signed_link_signs_and_drops_unsigned_and_foreign_signatures() {
    let dir = tempfile::tempdir().unwrap();
    let key_file = dir.path().join("mavlink.key");
    std::fs::write(&key_file, KEY).unwrap();
    let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
    peer.set_read_timeout(Some(Duration::from_millis(50)))
        .unwrap();
    let config = MavlinkConfig {
        connection: format!("udpout:{}", peer.local_addr().unwrap()),
        signing_key: Some(key_file),
        signing_required: true,
        ..MavlinkConfig::default()
    };
    let link = MavlinkLink::spawn(&config, Arc::new(AtomicBool::new(false))).unwrap();

    // What star sends (HEARTBEAT, TIMESYNC requests) is signed with the key.
    let verifier = SigningData::from_config(SigningConfig::new(KEY, 0, false, false));
    let frames = drain(&peer, Duration::from_millis(600));
    assert!(!frames.is_empty(), "nothing from star");
    let mut star_addr: Option<SocketAddr> = None;
    for raw in &frames {
        let MAVLinkMessageRaw::V2(v2) = raw else {
            panic!("a MAVLink 1 frame");
        };
        assert!(
            verifier.verify_signature(v2),
            "a frame star sent does not verify"
        );
    }
    let mut buf = [0u8; 600];
    while star_addr.is_none() {
        star_addr = peer.recv_from(&mut buf).ok().map(|(_, a)| a);
    }
    let star_addr = star_addr.unwrap();
    let header = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };

    // Unsigned: dropped.
    let mut plain = MAVLinkV2MessageRaw::new();
    plain.serialize_message(header, &request(111));
    peer.send_to(plain.raw_bytes(), star_addr).unwrap();
    // Signed with another key: dropped.
    let foreign = SigningData::from_config(SigningConfig::new([1; 32], 0, true, false));
    let mut forged = MAVLinkV2MessageRaw::new();
    forged.serialize_message_for_signing(header, &request(222));
    foreign.sign_message(&mut forged);
    peer.send_to(forged.raw_bytes(), star_addr).unwrap();
    // Signed with the key: answered.
    let ours = SigningData::from_config(SigningConfig::new(KEY, 0, true, false));
    let mut good = MAVLinkV2MessageRaw::new();
    good.serialize_message_for_signing(header, &request(333));
    ours.sign_message(&mut good);
    peer.send_to(good.raw_bytes(), star_addr).unwrap();

    let frames = drain(&peer, Duration::from_millis(500));
    let stats = link.stats();
    println!("{stats:?}");
    assert!(
        answered(&frames, 333),
        "the signed request was not answered"
    );
    assert!(!answered(&frames, 111), "an unsigned request was answered");
    assert!(!answered(&frames, 222), "a forged request was answered");
    assert_eq!(stats.signing_rejected_unsigned, 1, "{stats:?}");
    assert_eq!(stats.signing_rejected_bad, 1, "{stats:?}");
    assert!(link.shutdown());
}
