use super::*;

fn small() -> BuildingSpec {
    BuildingSpec {
        rooms: 5,
        cell_m: 0.25,
        texture_px_per_m: 16.0,
        ..BuildingSpec::default()
    }
}

#[test]
fn default_spec_is_valid_and_bad_ones_are_named() {
    BuildingSpec::default().validate().expect("valid");
    let err = BuildingSpec {
        rooms: 0,
        ..BuildingSpec::default()
    }
    .validate()
    .expect_err("no rooms");
    assert_eq!(err.field, "rooms");
    let err = BuildingSpec {
        door_height_m: 2.95,
        ..BuildingSpec::default()
    }
    .validate()
    .expect_err("door as high as the ceiling");
    assert_eq!(err.field, "door_height_m");
}

#[test]
fn same_seed_same_building_and_rooms_repeat_designs() {
    let a = build_building(&small(), 3);
    let b = build_building(&small(), 3);
    assert_eq!(a.map, b.map);
    assert_eq!(a.truth, b.truth);
    let c = build_building(&small(), 4);
    assert_ne!(a.map.positions, c.map.positions);
    let plan = a.plan.as_ref().expect("plan");
    assert_eq!(plan.rooms.len(), 5);
    assert!(plan.designs.len() <= 6);
    // Occluders are in the truth only.
    assert!(a.truth.triangle_count() >= a.map.triangle_count());
    assert_eq!(a.map.textures.len() + 1, a.truth.textures.len());
    a.map.validate().expect("valid map");
    a.truth.validate().expect("valid truth");
}

#[test]
fn identical_rooms_are_the_same_from_inside() {
    // Ten rooms of two designs: rooms of one design on either side of the
    // corridor have the same surfaces and furniture in their own frames.
    let spec = BuildingSpec {
        rooms: 10,
        designs: 2,
        identical_rooms: true,
        ..small()
    };
    let plan = FloorPlan::generate(&spec, 5);
    let same: Vec<&PlacedRoom> = plan.rooms.iter().filter(|r| r.design == 0).collect();
    assert!(same.len() >= 4);
    assert!(same.iter().any(|r| r.turned) && same.iter().any(|r| !r.turned));
    let design = &plan.designs[0];
    let scene = build_building(&spec, 5);
    // Each furniture box of the design appears once per room of it.
    for b in &design.furnishing.furniture {
        let copies = scene
            .furniture
            .iter()
            .filter(|w| (w.half_size_m == b.half_size_m) && (w.height_m == b.height_m))
            .count();
        assert!(copies >= same.len(), "{copies} copies of a box");
    }
}

#[test]
fn look_alike_rooms_share_the_shell_and_differ_in_furniture() {
    let spec = BuildingSpec {
        rooms: 10,
        designs: 2,
        ..small()
    };
    let plan = FloorPlan::generate(&spec, 5);
    assert_eq!(plan.furnishings.len(), plan.rooms.len());
    let same: Vec<usize> = (0..plan.rooms.len())
        .filter(|&i| plan.rooms[i].design == 0)
        .collect();
    assert!(same.len() >= 4);
    for (k, &i) in same.iter().enumerate() {
        assert_eq!(plan.rooms[i].size_m, plan.designs[0].size_m);
        assert!(!plan.furnishings[i].furniture.is_empty(), "room {i} empty");
        for &j in &same[k + 1..] {
            assert_ne!(
                plan.furnishings[i], plan.furnishings[j],
                "rooms {i} and {j} furnished alike"
            );
        }
    }
    // Every room's boxes keep off its tour: the scene's free-space test
    // (which includes the furniture) passes along each room's route.
    let scene = build_building(&spec, 5);
    let n_boxes: usize = plan.furnishings.iter().map(|f| f.furniture.len()).sum();
    assert_eq!(scene.furniture.len(), n_boxes);
    for route in plan.routes() {
        for p in std::iter::once(route.inside_m).chain(route.loop_m) {
            assert!(scene.is_free([p[0], p[1], 1.4], 0.3), "{p:?}");
        }
    }
    // The shells are still the same: the map differs from the identical
    // rooms' only in furniture.
    let twins = build_building(
        &BuildingSpec {
            identical_rooms: true,
            ..spec
        },
        5,
    );
    assert_ne!(scene.map.positions, twins.map.positions);
}

#[test]
fn free_space_has_the_rooms_corridor_and_doors_and_not_the_walls() {
    let scene = build_building(&small(), 1);
    let plan = scene.plan.as_ref().expect("plan");
    let margin = 0.3;
    let [cx0, cy0] = plan.corridor_min_m;
    let [cx1, cy1] = plan.corridor_max_m;
    let mid_y = 0.5 * (cy0 + cy1);
    assert!(scene.is_free([0.5 * (cx0 + cx1), mid_y, 1.4], margin));
    // Floor, ceiling and the corridor's end walls are not free.
    assert!(!scene.is_free([0.5 * (cx0 + cx1), mid_y, 0.1], margin));
    assert!(!scene.is_free([0.5 * (cx0 + cx1), mid_y, 2.9], margin));
    assert!(!scene.is_free([cx0 + 0.1, mid_y, 1.4], margin));
    for route in plan.routes() {
        for p in [route.corridor_m, route.door_m, route.inside_m]
            .into_iter()
            .chain(route.loop_m)
        {
            assert!(scene.is_free([p[0], p[1], 1.4], margin), "{p:?}");
        }
        // Beside the door, in the wall between room and corridor.
        let d = route.door_m;
        let beside = if (d[0] - cx0) > 1.5 { -1.3 } else { 1.3 };
        assert!(!scene.is_free([d[0] + beside, d[1], 1.4], margin));
        // Above the door.
        assert!(!scene.is_free([d[0], d[1], 2.2], margin));
    }
}

#[test]
fn whole_floor_has_the_size_the_issue_asks() {
    // The plan only (cheap): 22 rooms, over 500 m2.
    let plan = FloorPlan::generate(&BuildingSpec::default(), 1);
    assert_eq!(plan.rooms.len(), 22);
    assert!(plan.floor_area_m2() >= 500.0, "{} m2", plan.floor_area_m2());
    let sizes: std::collections::BTreeSet<(u64, u64)> = plan
        .rooms
        .iter()
        .map(|r| (r.size_m[0].to_bits(), r.size_m[1].to_bits()))
        .collect();
    assert!(sizes.len() >= 3, "varied sizes: {sizes:?}");
}

#[test]
fn the_floors_surfaces_face_where_they_are_seen_from() {
    use crate::synth::scene::tests::{pixels_changed_by_back_face_cull, MOST_CRACK_PIXELS};
    let scene = build_building(&small(), 3);
    let plan = scene.plan.as_ref().expect("plan");
    let positions: Vec<[f64; 3]> = plan
        .routes()
        .iter()
        .flat_map(|r| [r.corridor_m, r.door_m, r.inside_m])
        .map(|p| [p[0], p[1], 1.4])
        .collect();
    assert!(positions.len() >= 10);
    for (mesh, what) in [(&scene.map, "map"), (&scene.truth, "truth")] {
        let changed = pixels_changed_by_back_face_cull(mesh, &positions);
        assert!(
            changed.iter().all(|&n| n <= MOST_CRACK_PIXELS),
            "{what}: pixels changed per view {changed:?}"
        );
    }
}
