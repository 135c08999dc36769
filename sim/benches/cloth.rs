//! Micro-benchmarks of the simulator's hot loops on the 10k-particle tube and the default
//! body: one constraint sweep, one BVH refit, contact queries, one full frame.
//!
//! `cargo bench -p sim --bench cloth`

use std::hint::black_box;
use std::sync::OnceLock;

use sim::body::{BodyModel, ShapeParams};
use sim::cloth::{BodyCollider, ClothModel, SimConfig, Solver};
use sim::mesh::TriMesh;

fn main() {
    divan::main();
}

struct Scene {
    model: BodyModel,
    tube: TriMesh,
    body: Vec<glam::Vec3>,
    posed: Vec<glam::Vec3>,
}

fn scene() -> &'static Scene {
    static S: OnceLock<Scene> = OnceLock::new();
    S.get_or_init(|| {
        let model = BodyModel::load_default().unwrap();
        let body = model.shape(&ShapeParams::default()).unwrap();
        let tube = sim::cloth::scene::torso_tube(&body, 128, 78, 0.015);
        let posed = body.pose(&model.t_pose).vertices;
        let vertices = body.vertices.clone();
        Scene {
            model,
            tube,
            body: vertices,
            posed,
        }
    })
}

/// One frame (10 substeps) of the tube on the static body: detection, sweeps, collision; on
/// one thread, and on two (inside a pool of two threads, as in a drape: detection on both,
/// each sweep's two halves at once).
#[divan::bench(args = [1, 2], sample_count = 20)]
fn frame_10k_tube(bencher: divan::Bencher, threads: usize) {
    let s = scene();
    let config = SimConfig::default();
    let cloth = ClothModel::new(&s.tube, &config, &[]).unwrap();
    let body = BodyCollider::new(&s.body, &s.model.triangles, config.margin);
    let mut solver = Solver::new(&cloth, &config, s.tube.vertices.clone());
    solver.parallel = threads > 1;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    bencher.bench_local(|| pool.install(|| solver.frame(black_box(&body))));
}

/// One sweep over the tube's 69,862 distance constraints, on one thread (the two halves
/// one after the other, then the constraints joining them).
#[divan::bench(sample_count = 50)]
fn constraint_sweep_10k_tube(bencher: divan::Bencher) {
    let s = scene();
    let config = SimConfig::default();
    let cloth = ClothModel::new(&s.tube, &config, &[]).unwrap();
    let mut solver = Solver::new(&cloth, &config, s.tube.vertices.clone());
    bencher.bench_local(|| solver.solve_distance());
}

/// Building the cloth: constraints, classification and colouring of 10,112 particles.
#[divan::bench(sample_count = 10)]
fn cook_10k_tube() -> ClothModel {
    ClothModel::new(&scene().tube, &SimConfig::default(), &[]).unwrap()
}

/// Moving the body to new positions: pseudo-normals and a refit of the BVH's swept boxes
/// over 26,756 triangles; on one thread, and on two (as in a drape with `parallel`).
#[divan::bench(args = [1, 2], sample_count = 50)]
fn body_advance_and_refit(bencher: divan::Bencher, threads: usize) {
    let s = scene();
    let mut body = BodyCollider::new(&s.body, &s.model.triangles, 0.01);
    body.set_parallel(threads > 1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let mut flip = false;
    bencher.bench_local(|| {
        flip = !flip;
        pool.install(|| body.advance(if flip { &s.posed } else { &s.body }));
    });
}

/// 10,112 contact queries (the tube's particles against the body): divide the time by
/// 10,112 for one query.
#[divan::bench(sample_count = 20)]
fn contact_queries_10k(bencher: divan::Bencher) {
    let s = scene();
    let body = BodyCollider::new(&s.body, &s.model.triangles, 0.01);
    bencher.bench(|| {
        s.tube
            .vertices
            .iter()
            .filter(|p| body.contact(**p, 0.003).is_some())
            .count()
    });
}
