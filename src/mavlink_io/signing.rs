//! MAVLink 2 message signing (<https://mavlink.io/en/guide/message_signing.html>),
//! on the `mavlink` crate's `mav2-message-signing` support.
//!
//! Owns the secret key (read from the file `[mavlink] signing_key` names),
//! the outgoing signature timestamp and the incoming streams' timestamps
//! (replay protection), in the crate's [`SigningData`]. Takes each outgoing
//! message and gives out a signed MAVLink 2 frame (SHA-256 over key, header,
//! payload, CRC, link id and the 48-bit timestamp in 10 us since
//! 2015-01-01, first 6 bytes); takes each incoming raw frame and says
//! whether to use it: a bad signature (or a replayed timestamp) never,
//! an unsigned frame (or MAVLink 1) only while `signing_required` is off.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;

use mavlink::dialects::common::MavMessage;
use mavlink::{
    MAVLinkMessageRaw, MAVLinkV2MessageRaw, MavHeader, Message, SigningConfig, SigningData,
};

use super::stats::{bump, Counters};

/// Bytes of a MAVLink 2 signing key.
pub const KEY_BYTES: usize = 32;

/// A signing key file that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum SigningKeyError {
    /// The file cannot be read (missing, no permission).
    #[error("cannot read MAVLink signing key {path}: {source}")]
    Read {
        /// The key file.
        path: PathBuf,
        /// The I/O error.
        source: io::Error,
    },
    /// The file does not hold exactly 32 bytes.
    #[error("MAVLink signing key {path}: expected exactly {KEY_BYTES} bytes (the raw secret, e.g. `head -c 32 /dev/urandom`), found {found}")]
    Size {
        /// The key file.
        path: PathBuf,
        /// Its size in bytes.
        found: usize,
    },
}

/// Reads a 32-byte key; warns when the file is readable by others.
pub fn load_key(path: &Path) -> Result<[u8; KEY_BYTES], SigningKeyError> {
    let bytes = fs::read(path).map_err(|source| SigningKeyError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let key: [u8; KEY_BYTES] = bytes
        .as_slice()
        .try_into()
        .map_err(|_| SigningKeyError::Size {
            path: path.to_path_buf(),
            found: bytes.len(),
        })?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        if let Ok(meta) = fs::metadata(path) {
            let mode = meta.permissions().mode();
            if mode & 0o004 != 0 {
                tracing::warn!(path = %path.display(), mode = format!("{:o}", mode & 0o777),
                    "MAVLink signing key is world-readable: chmod 600 it");
            }
        }
    }
    Ok(key)
}

/// What to do with an incoming frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Check {
    /// Use it (a good signature, or unsigned while signing is optional).
    Accept,
    /// Unsigned (or MAVLink 1) while signing is required: dropped.
    Unsigned,
    /// Signed, but the signature or its timestamp is wrong: dropped.
    BadSignature,
}

/// The link's signing state.
pub struct Signing {
    data: SigningData,
    required: bool,
}

impl Signing {
    /// Signs outgoing frames with `key` on `link_id`; `required`: drop
    /// unsigned incoming frames.
    pub fn new(key: [u8; KEY_BYTES], link_id: u8, required: bool) -> Self {
        Self {
            data: SigningData::from_config(SigningConfig::new(key, link_id, true, !required)),
            required,
        }
    }

    /// Serializes `message` into `frame`, signed. No allocation.
    pub fn sign(&self, header: MavHeader, message: &MavMessage, frame: &mut MAVLinkV2MessageRaw) {
        frame.serialize_message_for_signing(header, message);
        self.data.sign_message(frame);
    }

    /// Checks an incoming frame.
    pub fn check(&self, frame: &MAVLinkMessageRaw) -> Check {
        let MAVLinkMessageRaw::V2(v2) = frame else {
            return if self.required {
                Check::Unsigned
            } else {
                Check::Accept
            };
        };
        let signed = v2.incompatibility_flags() & mavlink::consts::v2::IFLAG_SIGNED != 0;
        match (signed, self.data.verify_signature(v2)) {
            (true, true) | (false, true) => Check::Accept,
            (true, false) => Check::BadSignature,
            (false, false) => Check::Unsigned,
        }
    }
}

/// Whether to use an incoming raw frame: always without signing; with
/// signing, by [`Signing::check`], counting (and warning at the 1st, 2nd,
/// 4th ... of) what is dropped.
pub(crate) fn admit(
    signing: Option<&Signing>,
    counters: &Counters,
    frame: &MAVLinkMessageRaw,
) -> bool {
    let Some(signing) = signing else {
        return true;
    };
    let (counter, what) = match signing.check(frame) {
        Check::Accept => return true,
        Check::Unsigned => (
            &counters.signing_rejected_unsigned,
            "unsigned (signing_required)",
        ),
        Check::BadSignature => (
            &counters.signing_rejected_bad,
            "bad signature or replayed timestamp",
        ),
    };
    bump(counter);
    let n = counter.load(Ordering::Relaxed);
    if n.is_power_of_two() {
        tracing::warn!(
            system_id = frame.system_id(),
            component_id = frame.component_id(),
            message_id = frame.message_id(),
            dropped = n,
            "MAVLink frame dropped: {what}"
        );
    }
    false
}

/// Decodes a raw frame (already CRC-checked by the reader).
pub fn decode(frame: &MAVLinkMessageRaw) -> Option<(MavHeader, MavMessage)> {
    let header = MavHeader {
        sequence: frame.sequence(),
        system_id: frame.system_id(),
        component_id: frame.component_id(),
    };
    MavMessage::parse(frame.version(), frame.message_id(), frame.payload())
        .ok()
        .map(|m| (header, m))
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::TIMESYNC_DATA;

    fn timesync() -> MavMessage {
        MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 0,
            ts1: 0x0102_0304_0506_0708,
            target_system: 0,
            target_component: 0,
        })
    }

    /// The signature by the spec's definition, computed here with `sha2`
    /// independently of the crate: sha256(key + header + payload + crc +
    /// link_id + timestamp)[0..6].
    fn spec_signature(key: &[u8; 32], bytes: &[u8]) -> [u8; 6] {
        use sha2::{Digest, Sha256};
        let n = bytes.len();
        let mut h = Sha256::new();
        h.update(key);
        h.update(&bytes[..n - 6]); // STX, header, payload, CRC, link id, timestamp
        let digest = h.finalize();
        let mut out = [0u8; 6];
        out.copy_from_slice(&digest[..6]);
        out
    }

    #[test]
    fn known_answer_vector() {
        // A fixed frame: key 0x00..0x1f, link 7, timestamp 0x0000_1234_5678
        // (10 us units since 2015-01-01), TIMESYNC from 1/197 seq 5.
        let key: [u8; 32] = core::array::from_fn(|i| i as u8);
        let header = MavHeader {
            system_id: 1,
            component_id: 197,
            sequence: 5,
        };
        let mut frame = MAVLinkV2MessageRaw::new();
        frame.serialize_message_for_signing(header, &timesync());
        frame
            .signature_timestamp_bytes_mut()
            .copy_from_slice(&[0x78, 0x56, 0x34, 0x12, 0x00, 0x00]);
        *frame.signature_link_id_mut() = 7;
        let mut sig = [0u8; 6];
        frame.calculate_signature(&key, &mut sig);
        // The frame as it goes on the wire.
        frame.signature_value_mut().copy_from_slice(&sig);
        let bytes = frame.raw_bytes().to_vec();
        assert_eq!(bytes[0], 0xFD);
        assert_eq!(bytes[2], 0x01, "incompat flag: signed");
        assert_eq!(
            &bytes[bytes.len() - 13..bytes.len() - 6],
            &[7, 0x78, 0x56, 0x34, 0x12, 0, 0]
        );
        assert_eq!(sig, spec_signature(&key, &bytes));
        // The known answer: the same frame signed by pymavlink (an
        // independent implementation): `MAVLink(None, 1, 197)`, seq 5,
        // signing key bytes(range(32)), link_id 7, timestamp 0x12345678,
        // `MAVLink_timesync_message(0, 0x0102030405060708).pack(mav)`.
        assert_eq!(hex(&bytes), PYMAVLINK_FRAME);
    }

    const PYMAVLINK_FRAME: &str =
        "fd1001000501c56f0000000000000000000008070605040302014b7807785634120000dafce0eff494";

    fn hex(bytes: &[u8]) -> String {
        bytes.iter().map(|b| format!("{b:02x}")).collect()
    }

    #[test]
    fn signed_frames_verify_and_tampering_does_not() {
        let key = [42u8; 32];
        let tx = Signing::new(key, 0, true);
        let rx = Signing::new(key, 0, true);
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        };
        let mut frame = MAVLinkV2MessageRaw::new();
        tx.sign(header, &timesync(), &mut frame);
        assert_eq!(rx.check(&MAVLinkMessageRaw::V2(frame)), Check::Accept);
        // The same frame again: a replayed timestamp.
        assert_eq!(rx.check(&MAVLinkMessageRaw::V2(frame)), Check::BadSignature);
        // Another key.
        let other = Signing::new([1u8; 32], 0, true);
        let mut frame = MAVLinkV2MessageRaw::new();
        other.sign(header, &timesync(), &mut frame);
        assert_eq!(rx.check(&MAVLinkMessageRaw::V2(frame)), Check::BadSignature);
        // A signature byte changed in transit.
        let mut frame = MAVLinkV2MessageRaw::new();
        tx.sign(header, &timesync(), &mut frame);
        *frame.signature_value_mut().first_mut().unwrap() ^= 1;
        assert_eq!(rx.check(&MAVLinkMessageRaw::V2(frame)), Check::BadSignature);
        // Unsigned: dropped when required, used when optional.
        let mut plain = MAVLinkV2MessageRaw::new();
        plain.serialize_message(header, &timesync());
        assert_eq!(rx.check(&MAVLinkMessageRaw::V2(plain)), Check::Unsigned);
        let optional = Signing::new(key, 0, false);
        assert_eq!(optional.check(&MAVLinkMessageRaw::V2(plain)), Check::Accept);
        let (h, m) = decode(&MAVLinkMessageRaw::V2(plain)).unwrap();
        assert_eq!((h.system_id, h.component_id), (1, 1));
        assert_eq!(m, timesync());
        // MAVLink 1 is never signed.
        let mut v1 = mavlink::MAVLinkV1MessageRaw::new();
        v1.serialize_message(header, &timesync());
        assert_eq!(rx.check(&MAVLinkMessageRaw::V1(v1)), Check::Unsigned);
        assert_eq!(optional.check(&MAVLinkMessageRaw::V1(v1)), Check::Accept);
    }

    #[test]
    fn key_file_is_validated() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("none.key");
        let e = load_key(&missing).unwrap_err().to_string();
        assert!(e.contains("none.key"), "{e}");
        let short = dir.path().join("short.key");
        fs::write(&short, [1u8; 31]).unwrap();
        let e = load_key(&short).unwrap_err().to_string();
        assert!(
            e.contains("exactly 32 bytes") && e.contains("found 31"),
            "{e}"
        );
        let good = dir.path().join("good.key");
        fs::write(&good, [7u8; 32]).unwrap();
        assert_eq!(load_key(&good).unwrap(), [7u8; 32]);
    }
}
