//! The built-in garments: openings, fit on the canonical body, triangle quality, the warp,
//! deterministic builds and rejected imports. Built at the 3k-vertex resolution to keep CI
//! short; the same code builds the 10k ones.

use std::sync::OnceLock;

use glam::Vec3;
use sim::body::asset::{BodyModel, default_assets_dir};
use sim::body::pose::Pose;
use sim::cloth::BodyCollider;
use sim::garment::{self, GarmentError, Template, cut, def::BUILT_IN};
use sim::mesh::{TriMesh, remesh};

const RESOLUTION: usize = 3_000;

fn model() -> &'static BodyModel {
    static M: OnceLock<BodyModel> = OnceLock::new();
    M.get_or_init(|| BodyModel::load_default().unwrap())
}

/// The four garments built once (not from the cache: the build itself is under test).
fn built() -> &'static Vec<Template> {
    static T: OnceLock<Vec<Template>> = OnceLock::new();
    T.get_or_init(|| {
        let canonical = model().shape(&Default::default()).unwrap();
        let lib = garment::Library::new(&default_assets_dir());
        BUILT_IN
            .iter()
            .map(|(name, _)| lib.build(name, RESOLUTION, &canonical).unwrap())
            .collect()
    })
}

#[test]
fn every_garment_has_its_openings() {
    for t in built() {
        let loops = cut::directed_boundary_loops(&t.mesh);
        let expected = if t.meta.name == "jeans" { 3 } else { 4 };
        assert_eq!(
            loops.len(),
            expected,
            "{}: {} openings",
            t.meta.name,
            loops.len()
        );
        // And nothing else is open or torn: every edge has one or two triangles.
        sim::cloth::model::validate_mesh(&t.mesh).unwrap();
    }
}

#[test]
fn the_dress_flares_to_its_hem() {
    // The skirt's `flare` widens it towards the hem, away from the legs: the hem, the
    // lowest opening, goes round the dress about 1.6 m (1.19 m without the flare), the
    // widest of its openings by far.
    let t = built().iter().find(|t| t.meta.name == "dress").unwrap();
    let loops = remesh::boundary_loops(&t.mesh);
    let x = |v: u32| t.mesh.vertices[v as usize];
    let length = |l: &Vec<u32>| -> f32 {
        (0..l.len())
            .map(|k| x(l[k]).distance(x(l[(k + 1) % l.len()])))
            .sum()
    };
    let mean_y = |l: &Vec<u32>| l.iter().map(|&v| x(v).y).sum::<f32>() / l.len() as f32;
    let hem = loops
        .iter()
        .min_by(|a, b| mean_y(a).total_cmp(&mean_y(b)))
        .unwrap();
    let hem_length = length(hem);
    eprintln!("dress hem {hem_length} m round");
    assert!((1.5..1.8).contains(&hem_length), "hem {hem_length} m round");
}

#[test]
fn the_top_opening_is_the_neckline_or_the_waistband() {
    for t in built() {
        let top = t.top_opening();
        let y = |l: &[u32]| {
            l.iter()
                .map(|&v| t.mesh.vertices[v as usize].y)
                .sum::<f32>()
                / l.len() as f32
        };
        let sorted = |l: &[u32]| {
            let mut v = l.to_vec();
            v.sort_unstable();
            v
        };
        // One of the garment's openings, and the highest: the neckline of a top lies above
        // its sleeves and hem, the jeans' waistband far above their hems.
        let loops = remesh::boundary_loops(&t.mesh);
        assert!(loops.iter().any(|l| sorted(l) == sorted(&top)));
        let others: Vec<f32> = loops
            .iter()
            .filter(|l| sorted(l) != sorted(&top))
            .map(|l| y(l))
            .collect();
        let gap = if t.meta.name == "jeans" { 0.5 } else { 0.05 };
        assert!(
            others.iter().all(|&o| o + gap < y(&top)),
            "{}: top opening at {} m, others at {others:?}",
            t.meta.name,
            y(&top)
        );
        // No drop when the drape is the warp; the garment 30 cm lower drops 0.3 m.
        let lower: Vec<Vec3> = t.mesh.vertices.iter().map(|p| *p - Vec3::Y * 0.3).collect();
        assert_eq!(
            sim::cloth::drape::top_drop(&top, &t.mesh.vertices, &t.mesh.vertices),
            0.0
        );
        let d = sim::cloth::drape::top_drop(&top, &t.mesh.vertices, &lower);
        assert!((d - 0.3).abs() < 1e-5, "{d}");
    }
}

/// Vertices inside the body at any depth, as the simulator's verification counts them.
fn inside_count(body: &BodyCollider, vertices: &[Vec3]) -> usize {
    sim::cloth::drape::penetration(body, vertices).count
}

#[test]
fn garments_rest_outside_the_canonical_body() {
    let canonical = model().shape(&Default::default()).unwrap();
    let body = BodyCollider::new(&canonical.vertices, &model().triangles, 0.01);
    for t in built() {
        let inside = inside_count(&body, &t.mesh.vertices);
        assert_eq!(
            inside, 0,
            "{}: {inside} vertices inside the body",
            t.meta.name
        );
        assert_eq!(
            t.meta.build["relaxed"], true,
            "{}: relaxation did not converge",
            t.meta.name
        );
    }
}

#[test]
fn triangles_are_well_shaped_and_the_resolution_is_as_asked() {
    for t in built() {
        let a = remesh::angle_stats(&t.mesh);
        assert_eq!(a.degenerate, 0, "{}", t.meta.name);
        assert!(a.share_below_20 <= 0.01, "{}: {:?}", t.meta.name, a);
        let n = t.len() as f32;
        assert!(
            (n - RESOLUTION as f32).abs() < 0.15 * RESOLUTION as f32,
            "{}: {n} vertices for {RESOLUTION}",
            t.meta.name
        );
    }
}

/// The default resolution, the paper's size, built too: about 10k vertices, at most 1% of
/// triangles under 20 degrees, no degenerate face, every opening, nothing inside the body.
#[test]
fn the_10k_garments_are_well_shaped_open_and_outside_the_body() {
    let canonical = model().shape(&Default::default()).unwrap();
    let body = BodyCollider::new(&canonical.vertices, &model().triangles, 0.01);
    let lib = garment::Library::new(&default_assets_dir());
    for (name, _) in BUILT_IN {
        let t = lib.build(name, 10_000, &canonical).unwrap();
        let a = remesh::angle_stats(&t.mesh);
        assert_eq!(a.degenerate, 0, "{name}");
        assert!(a.share_below_20 <= 0.01, "{name}: {a:?}");
        let n = t.len() as f32;
        assert!(
            (n - 10_000.0).abs() < 1_500.0,
            "{name}: {n} vertices for 10k"
        );
        let loops = cut::directed_boundary_loops(&t.mesh).len();
        assert_eq!(loops, if name == "jeans" { 3 } else { 4 }, "{name}");
        let inside = inside_count(&body, &t.mesh.vertices);
        assert_eq!(inside, 0, "{name}: {inside} vertices inside the body");
    }
}

#[test]
fn the_warp_onto_the_canonical_body_at_rest_is_the_template() {
    let canonical = model().shape(&Default::default()).unwrap();
    let rest = canonical.pose(&Pose::rest(model().skeleton.len()));
    for t in built() {
        let w = t.warp(&canonical, &canonical, &rest);
        let worst = w
            .iter()
            .zip(&t.mesh.vertices)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "{}: moved {worst} m", t.meta.name);
    }
}

#[test]
fn the_reshape_by_shape_targets_equals_smoothing_the_bodys_moves() {
    // The reshape sums each shape target's smoothed move instead of smoothing the body's
    // moves: the same up to float rounding, for bodies far from the canonical one, and for
    // a body that no shape parameters make (its vertices edited), which it smooths itself.
    let canonical = model().shape(&Default::default()).unwrap();
    let bodies = [
        sim::body::ShapeParams {
            gender: 1.0,
            weight: 1.0,
            height: 0.9,
            ..Default::default()
        },
        sim::body::ShapeParams {
            gender: 0.0,
            age: 0.9,
            muscle: 0.1,
            proportions: 0.2,
            ..Default::default()
        },
    ];
    for t in built() {
        for (i, params) in bodies.iter().enumerate() {
            let mut shaped = model().shape(params).unwrap();
            if i == 1 {
                // Legs 2 cm longer than its parameters make them.
                for p in shaped.vertices.iter_mut().filter(|p| p.y < 0.8) {
                    p.y -= 0.025 * (0.8 - p.y);
                }
            }
            let want = t.reshape_by_smoothing(&canonical, &shaped);
            let got = t.reshape(&canonical, &shaped);
            let moved = want
                .iter()
                .zip(&t.mesh.vertices)
                .map(|(a, b)| a.distance(*b))
                .fold(0.0f32, f32::max);
            let worst = want
                .iter()
                .zip(&got)
                .map(|(a, b)| a.distance(*b))
                .fold(0.0f32, f32::max);
            assert!(moved > 0.02, "{} body {i}: moved {moved} m", t.meta.name);
            assert!(
                worst < 2e-6,
                "{} body {i}: {worst} m from smoothing the moves",
                t.meta.name
            );
        }
    }
}

#[test]
fn the_warp_follows_shape_and_pose() {
    // A taller body: the jeans' hems go down with the ankles.
    let canonical = model().shape(&Default::default()).unwrap();
    let tall = model()
        .shape(&sim::body::ShapeParams {
            height: 0.62,
            ..Default::default()
        })
        .unwrap();
    let jeans = built().iter().find(|t| t.meta.name == "jeans").unwrap();
    let rest = tall.pose(&Pose::rest(model().skeleton.len()));
    let w = jeans.warp(&canonical, &tall, &rest);
    let low = |x: &[Vec3]| x.iter().map(|p| p.y).fold(f32::MAX, f32::min);
    let body_low = |x: &[Vec3]| x.iter().map(|p| p.y).fold(f32::MAX, f32::min);
    let dropped = low(&jeans.mesh.vertices) - low(&w);
    let body_dropped = body_low(&canonical.vertices) - body_low(&tall.vertices);
    assert!(
        (dropped - body_dropped).abs() < 0.02,
        "hem moved {dropped} m, soles {body_dropped} m"
    );
}

#[test]
fn the_skirt_follows_the_hips_only() {
    let dress = built().iter().find(|t| t.meta.name == "dress").unwrap();
    let sk = &model().skeleton;
    let legs: Vec<u16> = ["LeftUpLeg", "RightUpLeg", "LeftLeg", "RightLeg"]
        .iter()
        .map(|n| sk.index(n).unwrap() as u16)
        .collect();
    // Below mid-thigh only the hips move the skirt.
    let knee_y = -0.2;
    for (p, (b, w)) in dress
        .mesh
        .vertices
        .iter()
        .zip(dress.skin.bones.iter().zip(&dress.skin.weights))
    {
        if p.y < knee_y {
            for k in 0..4 {
                assert!(
                    w[k] < 1e-3 || !legs.contains(&b[k]),
                    "a skirt vertex at {p} follows a leg with weight {}",
                    w[k]
                );
            }
        }
    }
}

#[test]
fn building_twice_gives_the_same_template() {
    let canonical = model().shape(&Default::default()).unwrap();
    let lib = garment::Library::new(&default_assets_dir());
    let again = lib.build("tshirt", RESOLUTION, &canonical).unwrap();
    let first = built().iter().find(|t| t.meta.name == "tshirt").unwrap();
    assert_eq!(again.mesh, first.mesh);
    assert_eq!(again.skin, first.skin);
    assert_eq!(again.bindings, first.bindings);
}

#[test]
fn templates_round_trip_through_their_file() {
    let t = &built()[0];
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.safetensors");
    std::fs::write(&path, t.encode()).unwrap();
    let back = Template::load(&path, model().triangles.len(), model().skeleton.len()).unwrap();
    assert_eq!(back.mesh, t.mesh);
    assert_eq!(back.skin, t.skin);
    assert_eq!(back.bindings, t.bindings);
    // (serde_json parses floats to the nearest few ulps, so the build figures are compared
    // by their fields.)
    assert_eq!(
        (&back.meta.name, &back.meta.key),
        (&t.meta.name, &t.meta.key)
    );
    assert_eq!(back.meta.build["vertices"], t.meta.build["vertices"]);
    // The jeans' own friction survives the file too.
    let jeans = built().iter().find(|t| t.meta.name == "jeans").unwrap();
    let path_jeans = dir.path().join("jeans.safetensors");
    std::fs::write(&path_jeans, jeans.encode()).unwrap();
    let back = Template::load(&path_jeans, model().triangles.len(), model().skeleton.len());
    assert_eq!(back.unwrap().meta.friction, Some(0.8));
    // A truncated file is refused with a reason.
    std::fs::write(&path, &t.encode()[..100]).unwrap();
    let err = Template::load(&path, model().triangles.len(), model().skeleton.len()).unwrap_err();
    assert!(matches!(err, GarmentError::Corrupt { .. }), "{err}");
}

fn import(mesh: TriMesh) -> Result<Template, GarmentError> {
    let canonical = model().shape(&Default::default()).unwrap();
    garment::import_mesh(mesh, "mine", std::path::Path::new("mine.obj"), &canonical)
}

#[test]
fn a_good_user_garment_is_imported_and_skinned() {
    // The built T-shirt, as a user would bring it.
    let t = &built()[0];
    let imported = import(t.mesh.clone()).unwrap();
    assert_eq!(imported.len(), t.len());
    assert_eq!(imported.meta.origin, "imported");
    // Sleeve ends follow the arms.
    let sk = &model().skeleton;
    let left_arm = sk.index("LeftArm").unwrap() as u16;
    let sleeve = imported
        .mesh
        .vertices
        .iter()
        .position(|p| p.x > 0.25)
        .expect("a sleeve vertex");
    assert!(imported.skin.bones[sleeve].contains(&left_arm));
}

#[test]
fn bad_user_garments_are_rejected_with_a_reason() {
    let t = &built()[0];
    let reason = |r: Result<Template, GarmentError>| match r {
        Err(GarmentError::Rejected { reason, .. }) => reason,
        other => panic!("expected a rejection, got {:?}", other.map(|t| t.len())),
    };
    // Centimetres instead of metres.
    let mut big = t.mesh.clone();
    big.vertices.iter_mut().for_each(|p| *p *= 100.0);
    assert!(reason(import(big)).contains("across"));
    // Shrunk into the body.
    let mut small = t.mesh.clone();
    let c = small.vertices.iter().copied().sum::<Vec3>() / small.vertices.len() as f32;
    small
        .vertices
        .iter_mut()
        .for_each(|p| *p = c + (*p - c) * 0.8);
    let r = reason(import(small));
    assert!(r.contains("inside"), "{r}");
    // One vertex deep inside the torso (over the 5 cm a distance query searches), and one
    // pushed through it to behind the back, its edges across the torso, both ends outside.
    let body = BodyCollider::new(
        &model().shape(&Default::default()).unwrap().vertices,
        &model().triangles,
        0.01,
    );
    let front = (0..t.mesh.vertices.len())
        .filter(|&i| t.mesh.vertices[i].x.abs() < 0.03)
        .max_by(|&a, &b| t.mesh.vertices[a].z.total_cmp(&t.mesh.vertices[b].z))
        .expect("a vertex at the front's midline");
    let mut deep = t.mesh.clone();
    let mut p = deep.vertices[front];
    while !(body.inside(p) && body.signed_distance(p, 0.05).is_none()) {
        p.z -= 0.01;
        assert!(
            p.z > -1.0,
            "no point deeper than 5 cm behind the front vertex"
        );
    }
    deep.vertices[front] = p;
    let r = reason(import(deep));
    assert!(r.contains("1 vertices lie inside"), "{r}");
    let mut across = t.mesh.clone();
    while body.inside(p) || body.signed_distance(p, 0.05).is_some_and(|d| d < 0.02) {
        p.z -= 0.01;
    }
    across.vertices[front] = p;
    let r = reason(import(across));
    assert!(r.contains("edges pass through the canonical body"), "{r}");
    // Far from the body.
    let mut away = t.mesh.clone();
    away.vertices.iter_mut().for_each(|p| p.z += 1.0);
    assert!(reason(import(away)).contains("around the body"));
    // Non-manifold: one edge shared by three faces.
    let mut bad = t.mesh.clone();
    let shared = |a: u32, b: u32| {
        bad.triangles
            .iter()
            .filter(|t| t.contains(&a) && t.contains(&b))
            .count()
    };
    let [a, b, _] = *bad
        .triangles
        .iter()
        .find(|t| shared(t[0], t[1]) == 2)
        .expect("an interior edge");
    let extra = bad.vertices[a as usize] + Vec3::new(0.0, 0.0, 0.05);
    bad.vertices.push(extra);
    bad.triangles.push([a, b, bad.vertices.len() as u32 - 1]);
    assert!(reason(import(bad)).contains("non-manifold"));
}

/// Garments by name: unknown names list what exists.
#[test]
fn unknown_garments_are_named_in_the_error() {
    let lib = garment::Library::new(&default_assets_dir());
    let err = lib.get("kilt", 3000, model(), &mut |_| {}).unwrap_err();
    assert!(
        err.to_string().contains("tshirt, sweater, dress, jeans"),
        "{err}"
    );
}

#[test]
fn a_graded_size_is_the_garment_made_for_its_reference_body() {
    let tshirt = built().iter().find(|t| t.meta.name == "tshirt").unwrap();
    let def = garment::built_in("tshirt").unwrap();
    let grading = def.grading.as_ref().expect("the T-shirt is graded");
    let xl = grading
        .sizes
        .iter()
        .find(|s| s.name == "men-XL-tall")
        .unwrap();
    let t = garment::grade(tshirt, &def, xl, model()).unwrap();
    // Same vertices, faces, skinning: every size feeds the same network.
    assert_eq!(t.mesh.triangles, tshirt.mesh.triangles);
    assert_eq!(t.skin, tshirt.skin);
    assert_eq!(t.reference(), xl.shape);
    assert_eq!(t.meta.build["relaxed"], true);
    // Outside its reference body, and bigger than the base: a longer hem and a wider chest.
    let reference = model().shape(&xl.shape).unwrap();
    let body = BodyCollider::new(&reference.vertices, &model().triangles, 0.01);
    let inside = t
        .mesh
        .vertices
        .iter()
        .filter(|p| body.signed_distance(**p, 0.05).is_some_and(|d| d < 0.0) || body.inside(**p))
        .count();
    assert_eq!(inside, 0);
    let length = |x: &[Vec3]| -> f32 {
        t.mesh
            .triangles
            .iter()
            .flat_map(|f| (0..3).map(move |k| (f[k], f[(k + 1) % 3])))
            .map(|(a, b)| x[a as usize].distance(x[b as usize]))
            .sum()
    };
    let grown = length(&t.mesh.vertices) / length(&tshirt.mesh.vertices);
    assert!((1.05..1.4).contains(&grown), "edge lengths x{grown}");
    // The warp from the reference body onto itself at rest is the size's template.
    let rest = reference.pose(&Pose::rest(model().skeleton.len()));
    let w = t.warp(&reference, &reference, &rest);
    let worst = w
        .iter()
        .zip(&t.mesh.vertices)
        .map(|(a, b)| a.distance(*b))
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-5, "moved {worst} m");
}

#[test]
fn grading_to_the_canonical_body_gives_back_the_base_template() {
    // Grading must not loosen a garment by itself: pushed out to the build's clearance and
    // relaxed under gravity again, the jeans graded to the canonical body came out with a
    // 4.4% longer waistband and slid down the body where the base size holds.
    let jeans = built().iter().find(|t| t.meta.name == "jeans").unwrap();
    let def = garment::built_in("jeans").unwrap();
    let same = garment::def::SizeDef {
        name: "again".into(),
        shape: Default::default(),
    };
    let t = garment::grade(jeans, &def, &same, model()).unwrap();
    let top = jeans.top_opening();
    let perimeter = |x: &[Vec3]| -> f32 {
        (0..top.len())
            .map(|i| x[top[i] as usize].distance(x[top[(i + 1) % top.len()] as usize]))
            .sum()
    };
    let ratio = perimeter(&t.mesh.vertices) / perimeter(&jeans.mesh.vertices);
    assert!((ratio - 1.0).abs() < 0.005, "waistband x{ratio}");
    let moved = t
        .mesh
        .vertices
        .iter()
        .zip(&jeans.mesh.vertices)
        .map(|(a, b)| a.distance(*b))
        .sum::<f32>()
        / t.len() as f32;
    assert!(moved < 0.002, "moved {moved} m on average");
}

#[test]
fn a_body_wears_the_size_its_measurements_pick() {
    let lib = garment::Library::new(&default_assets_dir());
    let chart = lib.size_chart("tshirt", model()).unwrap().unwrap();
    assert_eq!(chart.by, ["chest", "waist", "hips", "height"]);
    let pick =
        |shape: sim::body::ShapeParams| chart.pick(&model().shape(&shape).unwrap()).unwrap().0;
    assert_eq!(pick(Default::default()), "M");
    // The largest body of the default shape range (corner 57) and the smallest (corner 2).
    let largest = sim::body::ShapeParams {
        gender: 1.0,
        weight: 0.75,
        height: 0.62,
        proportions: 0.7,
        muscle: 0.25,
        ..Default::default()
    };
    assert_eq!(pick(largest), "men-XXL-tall");
    let smallest = sim::body::ShapeParams {
        gender: 0.0,
        age: 0.8,
        weight: 0.25,
        height: 0.35,
        proportions: 0.3,
        muscle: 0.25,
        ..Default::default()
    };
    assert_eq!(pick(smallest), "women-S");
    // A garment that is not graded has no chart; a size it lacks is named in the error.
    assert!(garment::built_in("tshirt").unwrap().size_names().len() > 1);
    let e = lib
        .get_size("tshirt", RESOLUTION, "XXXL", model(), &mut |_| {})
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("no size \"XXXL\"") && e.contains("men-XL-tall"),
        "{e}"
    );
}

#[test]
fn bad_gradings_are_rejected() {
    let base = BUILT_IN[0].1;
    for (extra, want) in [
        (
            "[grading]\nby = [\"bust\"]\nsizes = [{ name = \"L\", shape = { weight = 0.7 } }]\n",
            "measurements are",
        ),
        ("[grading]\nby = [\"chest\"]\nsizes = []\n", "at least one"),
        (
            "[grading]\nby = [\"chest\"]\nsizes = [{ name = \"M\", shape = { weight = 0.7 } }]\n",
            "repeated",
        ),
        (
            "[grading]\nby = [\"chest\"]\nsizes = [{ name = \"L\", shape = { weight = 1.7 } }]\n",
            "size L",
        ),
    ] {
        let text = match base.find("[grading]") {
            Some(i) => format!("{}{extra}", &base[..i]),
            None => format!("{base}\n{extra}"),
        };
        let e = garment::GarmentDef::from_toml(&text, "t.toml").unwrap_err();
        assert!(e.contains(want), "{extra}: {e}");
    }
}

#[test]
fn bad_materials_are_rejected() {
    let base = BUILT_IN[0].1;
    for (extra, want) in [
        ("[material]\nfriction = -0.1\n", "from 0 to 2"),
        ("[material]\nfriction = nan\n", "from 0 to 2"),
        ("[material]\nfriction = 3.0\n", "from 0 to 2"),
        ("[material]\nstiffness = 1.0\n", "unknown field"),
        ("[simulation]\nsubsteps = 0\n", "from 1 to 1000"),
        ("[simulation]\nsubsteps = 1001\n", "from 1 to 1000"),
        ("[simulation]\nsweeps = 3\n", "unknown field"),
        (
            "[skinning]\nsplit = { bones = [\"LeftUpLeg\", \"RightUpLeg\"], reach = 0.001 }\n",
            "reach must be from 0.005 to 0.5",
        ),
        (
            "[skinning]\nsplit = { bones = [\"LeftUpLeg\", \"RightUpLeg\"], reach = nan }\n",
            "reach must be from 0.005 to 0.5",
        ),
        (
            "[skinning]\nsplit = { bones = [\"LeftUpLeg\", \"LeftUpLeg\"], reach = 0.1 }\n",
            "two different bones",
        ),
        (
            "[skinning]\nsplit = { bones = [\"LeftUpLeg\"], reach = 0.1 }\n",
            "expected an array of length 2",
        ),
        ("[skinning]\nrounds = 8\n", "unknown field"),
        (
            "[material]\nbelow_band = { width = 0.08, friction = 0.1 }\n",
            "needs the band's own `friction`",
        ),
        (
            "[material]\nfriction = 0.8\nbelow_band = { width = 0.0, friction = 0.1 }\n",
            "width must be over 0",
        ),
        (
            "[material]\nfriction = 0.8\nbelow_band = { width = 0.08, friction = 2.5 }\n",
            "below_band friction must be from 0 to 2",
        ),
        (
            "[material]\nfriction = 0.8\nbelow_band = { width = 0.08 }\n",
            "missing field `friction`",
        ),
    ] {
        let e = garment::GarmentDef::from_toml(&format!("{base}\n{extra}"), "t.toml").unwrap_err();
        assert!(e.contains(want), "{extra}: {e}");
    }
    let ok = garment::GarmentDef::from_toml(&format!("{base}\n[material]\nfriction = 0.8\n"), "t")
        .unwrap();
    assert_eq!(ok.friction(), Some(0.8));
    assert_eq!(ok.below_band(), None);
    let banded = garment::GarmentDef::from_toml(
        &format!(
            "{base}\n[material]\nfriction = 0.8\nbelow_band = {{ width = 0.05, friction = 0.2 }}\n"
        ),
        "t",
    )
    .unwrap();
    let band = banded.below_band().unwrap();
    assert_eq!((band.width, band.friction), (0.05, 0.2));
    // Within 5 cm of an opening vertex: the band's friction; beyond: the band's below.
    let v = [
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::new(0.0, 0.96, 0.0),
        Vec3::new(0.02, 0.96, 0.0),
        Vec3::new(0.0, 0.9, 0.0),
    ];
    assert_eq!(band.friction_map(&v, &[0], 0.8), vec![0.8, 0.8, 0.8, 0.2]);
    assert_eq!(band.friction_map(&v, &[3], 0.8), vec![0.2, 0.2, 0.2, 0.8]);
}

#[test]
fn the_jeans_bring_their_own_substeps_and_crease_contacts_to_the_simulator() {
    // The jeans drape at 30 substeps throughout and with crease contacts (their
    // `[simulation]`), the tops at the config's substeps and without; a config whose
    // shear-and-bend rate cannot divide the jeans' 30 is refused, and a config that sets
    // crease contacts sets them for every garment.
    let config = sim::cloth::SimConfig::default();
    assert_eq!(config.crease_contacts, None);
    for t in built() {
        let cloth = t.cloth(&config).unwrap();
        let c = cloth.drape_config(&config).unwrap();
        for set in [false, true] {
            let forced = sim::cloth::SimConfig {
                crease_contacts: Some(set),
                ..Default::default()
            };
            let c = t.cloth(&forced).unwrap().drape_config(&forced).unwrap();
            assert_eq!(c.crease_contacts, Some(set), "{}", t.meta.name);
        }
        if t.meta.name == "jeans" {
            assert_eq!(t.meta.substeps, Some(30));
            assert!(t.meta.crease_contacts);
            assert_eq!((c.substeps, c.settle_substeps), (30, 30));
            assert_eq!(c.crease_contacts, Some(true));
            assert!(
                t.stepping(&config)
                    .contains("the garment's own crease contacts")
            );
            let odd = sim::cloth::SimConfig {
                substeps: 8,
                settle_substeps: 8,
                shear_bend_substeps: Some(4),
                ..Default::default()
            };
            assert!(odd.validate().is_ok());
            let e = t.cloth(&odd).unwrap_err().to_string();
            assert!(e.contains("own 30 substeps"), "{e}");
        } else {
            assert_eq!(t.meta.substeps, None, "{}", t.meta.name);
            assert!(!t.meta.crease_contacts, "{}", t.meta.name);
            let off = sim::cloth::SimConfig {
                crease_contacts: Some(false),
                ..config.clone()
            };
            assert_eq!(c, off, "{}", t.meta.name);
            assert!(!t.stepping(&config).contains("crease"), "{}", t.meta.name);
        }
    }
}

#[test]
fn the_jeans_bring_their_own_friction_to_the_simulator() {
    let config = sim::cloth::SimConfig::default();
    for t in built() {
        let mu = t.cloth(&config).unwrap().friction;
        let cloth = t.cloth(&config).unwrap();
        if t.meta.name == "jeans" {
            assert_eq!(t.meta.friction, Some(0.8));
            assert_eq!(mu, 0.8, "the jeans' cloth");
            // The waistband grips, the legs slide: 0.8 within 8 cm of the waist opening,
            // 0.1 below.
            let band = t.meta.below_band.expect("the jeans' band");
            assert_eq!((band.width, band.friction), (0.08, 0.1));
            assert_eq!(cloth.friction_map.len(), t.len());
            let top = t.top_opening();
            let y_top = top
                .iter()
                .map(|&i| t.mesh.vertices[i as usize].y)
                .fold(f32::MIN, f32::max);
            for (i, (p, f)) in t.mesh.vertices.iter().zip(&cloth.friction_map).enumerate() {
                if top.contains(&(i as u32)) {
                    assert_eq!(*f, 0.8, "waist vertex {i}");
                }
                // The band is no wider than its width: 20 cm below the waist is leg.
                if p.y < y_top - 0.2 {
                    assert_eq!(*f, 0.1, "vertex {i}, {} m below the waist", y_top - p.y);
                }
            }
            let gripping = cloth.friction_map.iter().filter(|&&f| f == 0.8).count();
            let share = gripping as f32 / t.len() as f32;
            assert!(
                (0.02..0.15).contains(&share),
                "band: {share} of the vertices"
            );
        } else {
            assert_eq!(t.meta.friction, None, "{}", t.meta.name);
            assert_eq!(t.meta.below_band, None, "{}", t.meta.name);
            assert!(cloth.friction_map.is_empty(), "{}", t.meta.name);
            assert_eq!(mu, config.friction, "{}'s cloth", t.meta.name);
        }
    }
}

/// The share of the two thighs' weights that goes to the left one, per vertex (None where
/// the vertex follows neither).
fn left_shares(t: &Template, left: u16, right: u16) -> Vec<Option<f32>> {
    (0..t.mesh.vertices.len())
        .map(|v| {
            let w = |bone: u16| -> f32 {
                (0..4)
                    .filter(|&k| t.skin.bones[v][k] == bone)
                    .map(|k| t.skin.weights[v][k])
                    .sum()
            };
            let (l, r) = (w(left), w(right));
            (l + r > 0.05).then(|| l / (l + r))
        })
        .collect()
}

#[test]
fn the_jeans_thighs_share_the_crotch_over_their_reach() {
    // The jeans' `[skinning] split` against the same definition without it: the same cloth
    // and bindings; more vertices follow both thighs (a left share from 10 to 90%), and the
    // vertices that follow neither thigh keep their weights.
    let canonical = model().shape(&Default::default()).unwrap();
    let jeans = built().iter().find(|t| t.meta.name == "jeans").unwrap();
    let text = BUILT_IN.iter().find(|(n, _)| *n == "jeans").unwrap().1;
    let def = garment::GarmentDef::from_toml(text, "jeans").unwrap();
    let split = def.split().unwrap();
    assert_eq!((split.bones[0].as_str(), split.reach), ("LeftUpLeg", 0.18));
    assert_eq!(
        garment::skin::smoothing_rounds(&jeans.mesh, split.reach),
        88
    );
    let line = "split = { bones = [\"LeftUpLeg\", \"RightUpLeg\"], reach = 0.18 }\n";
    let plain_text = text.replace(line, "");
    assert_ne!(plain_text, text);
    let plain_def = garment::GarmentDef::from_toml(&plain_text, "jeans without it").unwrap();
    assert_eq!(plain_def.split(), None);
    let helpers = default_assets_dir().join(garment::HELPERS_FILE);
    let build = |def: &garment::GarmentDef| {
        garment::build_template(def, &helpers, &canonical, RESOLUTION, String::new())
    };
    let plain = build(&plain_def).unwrap();
    assert_eq!(plain.mesh, jeans.mesh);
    assert_eq!(plain.bindings, jeans.bindings);
    // A bone the body does not have is named.
    let typo =
        garment::GarmentDef::from_toml(&text.replace("RightUpLeg", "RightUpLag"), "t").unwrap();
    let e = build(&typo).unwrap_err().to_string();
    assert!(
        e.contains("skinning split: no bone named RightUpLag"),
        "{e}"
    );
    let sk = &model().skeleton;
    let (l, r) = (
        sk.index("LeftUpLeg").unwrap() as u16,
        sk.index("RightUpLeg").unwrap() as u16,
    );
    let (with, without) = (left_shares(jeans, l, r), left_shares(&plain, l, r));
    let both = |s: &[Option<f32>]| {
        s.iter()
            .filter(|x| x.is_some_and(|x| (0.1..0.9).contains(&x)))
            .count()
    };
    // 291 against 83 (3k).
    let (b1, b0) = (both(&with), both(&without));
    assert!(
        b1 > 3 * b0,
        "vertices following both thighs: {b1} with the split, {b0} without"
    );
    let mut untouched = 0;
    for v in 0..jeans.mesh.vertices.len() {
        let weight = |t: &Template, bone: u16| -> f32 {
            (0..4)
                .filter(|&k| t.skin.bones[v][k] == bone)
                .map(|k| t.skin.weights[v][k])
                .sum()
        };
        let thighs = |t: &Template| weight(t, l) + weight(t, r);
        if thighs(&plain) < 1e-4 && thighs(jeans) < 1e-4 {
            untouched += 1;
            for &bone in plain.skin.bones[v].iter().chain(&jeans.skin.bones[v]) {
                let d = (weight(&plain, bone) - weight(jeans, bone)).abs();
                assert!(d < 1e-4, "vertex {v}, bone {bone}: {d}");
            }
        }
    }
    // The lower legs, at least.
    assert!(untouched > jeans.mesh.vertices.len() / 4, "{untouched}");
}
