//! Body model benchmark: asset load, shaping, posing (FK + LBS) and DQS of the whole body.
//!
//! `cargo bench -p sim --bench body` prints the median and spread of each step.

use std::hint::black_box;
use std::sync::OnceLock;

use sim::body::skinning::dqs;
use sim::body::{BodyModel, ShapeParams};

fn main() {
    divan::main();
}

fn model() -> &'static BodyModel {
    static M: OnceLock<BodyModel> = OnceLock::new();
    M.get_or_init(|| BodyModel::load_default().unwrap())
}

fn shape() -> ShapeParams {
    ShapeParams {
        gender: 0.8,
        age: 0.6,
        muscle: 0.7,
        weight: 0.4,
        height: 0.55,
        proportions: 0.6,
        ..Default::default()
    }
}

/// Read, gunzip, parse and validate `assets/body/body.safetensors.gz` (2.6 MB).
#[divan::bench(sample_count = 20)]
fn load_asset() -> BodyModel {
    BodyModel::load_default().unwrap()
}

/// Apply the macro targets and rebuild joints and bone frames.
#[divan::bench(sample_count = 50)]
fn shape_body(bencher: divan::Bencher) {
    let m = model();
    bencher.bench(|| m.shape(black_box(&shape())).unwrap().vertices.len());
}

/// Shape, then forward kinematics and LBS of all 13,380 vertices into the T-pose.
#[divan::bench(sample_count = 50)]
fn shaped_and_posed_body(bencher: divan::Bencher) {
    let m = model();
    bencher.bench(|| {
        m.shape(black_box(&shape()))
            .unwrap()
            .pose(&m.t_pose)
            .vertices
            .len()
    });
}

/// Forward kinematics and LBS only, body already shaped.
#[divan::bench(sample_count = 100)]
fn pose_lbs(bencher: divan::Bencher) {
    let m = model();
    let body = m.shape(&shape()).unwrap();
    bencher.bench(|| body.pose(black_box(&m.t_pose)).vertices.len());
}

/// Dual quaternion skinning of all 13,380 body vertices (the garment warp's kernel).
#[divan::bench(sample_count = 100)]
fn dqs_body(bencher: divan::Bencher) {
    let m = model();
    let body = m.shape(&shape()).unwrap();
    let posed = body.pose(&m.t_pose);
    bencher.bench(|| dqs(black_box(&body.vertices), &m.skin, &posed.skinning).len());
}
