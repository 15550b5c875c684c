//! Round trip and error cases of the database file.

use std::path::Path;

use nalgebra::{Translation3, UnitQuaternion};

use super::coarse::CoarsePoint;
use super::database::{RelocDatabase, RelocDbError, RelocEntry};
use super::descriptor::Descriptor;
use super::landmarks::{Landmark, LANDMARK_LEN};
use super::region::SearchRegion;
use super::search::{Ranked, SearchIndex, MAX_TOP_K};
use crate::geometry::{PinholeCamera, Pose};

fn camera() -> PinholeCamera {
    PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5)
}

fn db(n: usize) -> RelocDatabase {
    let entries = (0..n)
        .map(|i| RelocEntry {
            world_from_camera: Pose::from_parts(
                Translation3::new(i as f64 * 0.5, 1.0, 1.4),
                UnitQuaternion::from_euler_angles(0.1, -0.2, i as f64 * 0.3),
            ),
            descriptor: Descriptor([i as u64, !(i as u64), (i as u64) << 7, 0xdead_beef]),
            coarse_start: (3 * (i / 2) + (i % 2)) as u32,
            coarse_len: (i % 2) as u32 + 1,
        })
        .collect();
    // Entry i holds 1 or 2 points (i even or odd), stored back to back.
    let coarse_points = (0..(n / 2) * 3 + n % 2)
        .map(|k| CoarsePoint {
            x: (k % 40) as u8,
            y: (k % 32) as u8,
            gray: (k * 7 % 256) as u8,
            depth_mm: 500 + k as u16,
            grad_x: -(k as i16) * 3,
            grad_y: k as i16 * 5,
        })
        .collect();
    let (landmarks, vocabulary) = super::build::organize(
        (0..n)
            .map(|i| Landmark {
                world_m: [i as f32 * 0.25, -1.0, 1.5],
                descriptor: Descriptor([!(i as u64), i as u64, 7, 9]),
            })
            .collect(),
    );
    RelocDatabase {
        camera: camera(),
        map_fingerprint: 0x1234_5678_9abc_def0,
        entries,
        coarse_points,
        landmarks,
        vocabulary,
        path: "mem.rdb".into(),
    }
}

#[test]
fn round_trip_through_a_file() {
    let tmp = tempfile::tempdir().expect("tmp");
    let path = tmp.path().join("map.rdb");
    let a = db(25);
    a.write(&path).expect("write");
    let b = RelocDatabase::read(&path).expect("read");
    assert_eq!(b.path, path);
    assert_eq!(b.camera, a.camera);
    assert_eq!(b.map_fingerprint, a.map_fingerprint);
    assert_eq!(b.entries.len(), 25);
    assert_eq!(b.coarse_points, a.coarse_points);
    assert_eq!(b.landmarks, a.landmarks);
    for (i, (x, y)) in a.entries.iter().zip(&b.entries).enumerate() {
        assert_eq!(x.descriptor, y.descriptor);
        assert_eq!(b.coarse_points_of(i), a.coarse_points_of(i));
        assert_eq!(b.coarse_points_of(i).len(), i % 2 + 1);
        let d = x.world_from_camera.inverse() * y.world_from_camera;
        assert!(d.translation.vector.norm() < 1e-12 && d.rotation.angle() < 1e-9);
    }
    b.check_compatible(&camera(), a.map_fingerprint)
        .expect("compatible");
}

#[test]
fn corrupt_byte_is_a_checksum_error_naming_the_file() {
    let mut bytes = db(5).to_bytes();
    let at = bytes.len() - 40;
    bytes[at] ^= 0x10;
    let err = RelocDatabase::from_bytes(&bytes, Path::new("/data/x.rdb")).expect_err("corrupt");
    assert!(matches!(err, RelocDbError::Checksum { .. }), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains("/data/x.rdb") && msg.contains("corrupt"),
        "{msg}"
    );
}

#[test]
fn truncated_and_padded_files_are_length_errors() {
    let bytes = db(5).to_bytes();
    for cut in [bytes.len() - 1, bytes.len() - 88, 40, 13] {
        let err = RelocDatabase::from_bytes(&bytes[..cut], Path::new("t.rdb")).expect_err("cut");
        assert!(matches!(err, RelocDbError::Length { .. }), "{cut}: {err}");
        assert!(err.to_string().contains("t.rdb"));
    }
    let mut long = bytes.clone();
    long.push(0);
    let err = RelocDatabase::from_bytes(&long, Path::new("t.rdb")).expect_err("long");
    assert!(matches!(err, RelocDbError::Length { .. }), "{err}");
    let err = RelocDatabase::from_bytes(&[], Path::new("t.rdb")).expect_err("empty");
    assert!(matches!(err, RelocDbError::BadMagic { .. }), "{err}");
}

/// Bytes of the vocabulary at the end of the body.
fn vocabulary_len(d: &RelocDatabase) -> usize {
    (d.vocabulary.words.len() + d.vocabulary.leaves.len()) * (32 + 4)
}

/// Rewrites the checksum after an edit of the body.
fn reseal(bytes: &mut [u8]) {
    let end = bytes.len() - 8;
    let sum = super::file::checksum(&bytes[12..end]);
    bytes[end..].copy_from_slice(&sum.to_le_bytes());
}

#[test]
fn coarse_point_counts_that_disagree_are_invalid() {
    // Entry 0's coarse count sits after the header (12), camera (80),
    // fingerprint (8), the counts of entries, points, landmarks, words and
    // leaves (5 x 8), pose and descriptor (88).
    let at = 12 + 80 + 8 + 40 + 88;
    let mut bytes = db(4).to_bytes();
    assert_eq!(&bytes[at..at + 4], &1u32.to_le_bytes());
    bytes[at] = 2;
    reseal(&mut bytes);
    let err = RelocDatabase::from_bytes(&bytes, Path::new("c.rdb")).expect_err("count");
    assert!(matches!(err, RelocDbError::Invalid { .. }), "{err}");
    assert!(err.to_string().contains("coarse points"), "{err}");
    // A point with zero depth.
    let mut bytes = db(4).to_bytes();
    let first_point = bytes.len() - 8 - vocabulary_len(&db(4)) - 4 * LANDMARK_LEN - 6 * 10;
    bytes[first_point + 4] = 0;
    bytes[first_point + 5] = 0;
    reseal(&mut bytes);
    let err = RelocDatabase::from_bytes(&bytes, Path::new("c.rdb")).expect_err("depth");
    assert!(err.to_string().contains("coarse point 0"), "{err}");
}

#[test]
fn a_landmark_off_the_map_is_invalid() {
    // Landmark 1's y coordinate: the landmarks come before the vocabulary.
    let mut bytes = db(4).to_bytes();
    let at = bytes.len() - 8 - vocabulary_len(&db(4)) - 3 * LANDMARK_LEN + 4;
    assert_eq!(&bytes[at..at + 4], &(-1.0f32).to_le_bytes());
    bytes[at..at + 4].copy_from_slice(&f32::INFINITY.to_le_bytes());
    reseal(&mut bytes);
    let err = RelocDatabase::from_bytes(&bytes, Path::new("l.rdb")).expect_err("landmark");
    assert!(matches!(err, RelocDbError::Invalid { .. }), "{err}");
    assert!(err.to_string().contains("landmark 1"), "{err}");
}

#[test]
fn a_vocabulary_that_does_not_hold_the_landmarks_is_invalid() {
    // The last leaf's landmark count ends the body.
    let d = db(30);
    assert!(!d.vocabulary.is_empty());
    let mut bytes = d.to_bytes();
    let at = bytes.len() - 8 - 4;
    let n = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    bytes[at..at + 4].copy_from_slice(&(n + 1).to_le_bytes());
    reseal(&mut bytes);
    let err = RelocDatabase::from_bytes(&bytes, Path::new("v.rdb")).expect_err("vocabulary");
    assert!(matches!(err, RelocDbError::Invalid { .. }), "{err}");
    assert!(err.to_string().contains("vocabulary"), "{err}");
}

#[test]
fn a_mapped_file_cut_short_or_corrupt_is_refused_naming_it() {
    let tmp = tempfile::tempdir().expect("tmp");
    let path = tmp.path().join("cut.rdb");
    let bytes = db(6).to_bytes();
    std::fs::write(&path, &bytes[..bytes.len() - 3]).expect("write");
    let err = RelocDatabase::read(&path).expect_err("cut");
    assert!(matches!(err, RelocDbError::Length { .. }), "{err}");
    assert!(err.to_string().contains("cut.rdb"), "{err}");
    let mut bad = bytes.clone();
    bad[40] ^= 1;
    std::fs::write(&path, &bad).expect("write");
    let err = RelocDatabase::read(&path).expect_err("corrupt");
    assert!(matches!(err, RelocDbError::Checksum { .. }), "{err}");
    std::fs::write(&path, b"").expect("write");
    let err = RelocDatabase::read(&path).expect_err("empty");
    assert!(matches!(err, RelocDbError::BadMagic { .. }), "{err}");
    // A good file maps, and its coarse points read back from the map.
    std::fs::write(&path, &bytes).expect("write");
    let mapped = RelocDatabase::read(&path).expect("mapped");
    assert!(format!("{:?}", mapped.coarse_points).contains("mapped: true"));
    assert_eq!(mapped.coarse_points, db(6).coarse_points);
    assert_eq!(mapped.landmarks, db(6).landmarks);
    assert_eq!(mapped.vocabulary, db(6).vocabulary);
}

#[test]
fn bad_magic_and_version_are_named() {
    let mut bytes = db(2).to_bytes();
    bytes[0] = b'X';
    let err = RelocDatabase::from_bytes(&bytes, Path::new("m.rdb")).expect_err("magic");
    assert!(matches!(err, RelocDbError::BadMagic { .. }), "{err}");
    let mut bytes = db(2).to_bytes();
    bytes[8] = 99;
    let err = RelocDatabase::from_bytes(&bytes, Path::new("m.rdb")).expect_err("version");
    assert!(
        matches!(err, RelocDbError::Version { found: 99, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("version 99"));
}

#[test]
fn missing_file_is_an_io_error_naming_it() {
    let err = RelocDatabase::read(Path::new("/nonexistent/reloc.rdb")).expect_err("missing");
    assert!(err.to_string().contains("/nonexistent/reloc.rdb"), "{err}");
}

#[test]
fn other_map_or_other_camera_is_a_mismatch() {
    let d = db(3);
    let err = d.check_compatible(&camera(), 42).expect_err("other map");
    assert!(matches!(err, RelocDbError::MapMismatch { .. }), "{err}");
    assert!(err.to_string().contains("mem.rdb"));
    let other = PinholeCamera::new(640, 512, 400.0, 420.0, 319.5, 255.5);
    let err = d
        .check_compatible(&other, d.map_fingerprint)
        .expect_err("other camera");
    assert!(matches!(err, RelocDbError::CameraMismatch { .. }), "{err}");
    assert!(err.to_string().contains("fx 400"), "{err}");
}

#[test]
fn top_k_ranks_by_hamming_and_respects_the_radius() {
    let mut d = db(40);
    let query = Descriptor([0, 0, 0, 0]);
    for (i, e) in d.entries.iter_mut().enumerate() {
        // Entry i differs from the query in (i * 7) % 40 + 1 bits.
        let bits = (i * 7) % 40 + 1;
        let mut words = [0u64; 4];
        for b in 0..bits {
            words[b % 4] |= 1 << (b / 4);
        }
        e.descriptor = Descriptor(words);
    }
    let mut best = [Ranked::default(); MAX_TOP_K];
    let index = SearchIndex::new(&d);
    assert_eq!(index.len(), 40);
    let n = index.top_k(&[query], SearchRegion::Everywhere, 5, &mut best);
    assert_eq!(n, 5);
    let dists: Vec<u32> = best[..n].iter().map(|b| b.distance).collect();
    assert_eq!(dists, vec![1, 2, 3, 4, 5]);
    for b in &best[..n] {
        assert_eq!(
            query.hamming(&d.entries[b.index as usize].descriptor),
            b.distance
        );
    }
    // With a second query shift that matches entry 0 exactly, entry 0 comes first.
    let exact = d.entries[0].descriptor;
    let n = index.top_k(&[query, exact], SearchRegion::Everywhere, 3, &mut best);
    assert_eq!(
        (n, best[0].distance, best[0].index, best[0].shift),
        (3, 0, 0, 1)
    );
    // Entries lie at x = 0.5 i; within 1.1 m of x = 10 are i = 18..=22.
    let region = SearchRegion::Near {
        center_m: nalgebra::Vector3::new(10.0, 1.0, 1.4),
        radius_m: 1.1,
    };
    let n = index.top_k(&[query], region, 10, &mut best);
    assert_eq!(n, 5);
    let mut idx: Vec<u32> = best[..n].iter().map(|b| b.index).collect();
    assert!(best[..n].windows(2).all(|w| w[0].distance <= w[1].distance));
    idx.sort_unstable();
    assert_eq!(idx, vec![18, 19, 20, 21, 22]);
}
