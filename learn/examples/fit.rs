//! How fast a config fits: trains on the first `SAMPLES` training samples for `STEPS` Adam
//! steps (batches of the config's size, cycling) and prints the training and held-out
//! (val + test) Edist every `EVERY` steps, with the config's learning rate (and its decay,
//! `learning_rate_end`). A diagnostic for model and loss changes.
//!
//! `cargo run --release -p learn --example fit -- CONFIG DATASET_DIR SAMPLES STEPS [EVERY]`

use std::time::Instant;

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::Device;
use dataset::config::Split;
use dataset::reader::Dataset;
use learn::config::TrainConfig;
use learn::data::Prepared;
use learn::model::GarNet;
use learn::train::{Setup, evaluate};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 5 {
        eprintln!("usage: fit CONFIG DATASET_DIR SAMPLES STEPS [EVERY]");
        std::process::exit(2);
    }
    let config = TrainConfig::load(a[1].as_ref()).expect("config");
    let data = Dataset::open(a[2].as_ref()).expect("dataset");
    let samples: usize = a[3].parse().expect("SAMPLES");
    let steps: usize = a[4].parse().expect("STEPS");
    let every: usize = a.get(5).map_or(25, |s| s.parse().expect("EVERY"));
    let device = Device::default().autodiff();
    device.seed(config.seed);
    let setup = Setup::new(&config, &data, &device);
    let mut rows = Vec::new();
    for s in data
        .manifest
        .shards
        .iter()
        .filter(|s| s.split == Split::Train)
    {
        rows.extend(data.read_shard(&s.file).expect("shard"));
        if rows.len() >= samples {
            break;
        }
    }
    rows.truncate(samples);
    let prepared: Vec<Prepared> = rows.iter().map(|r| setup.pre.prepare_row(r)).collect();
    let mut model = GarNet::new(&config.model, setup.params, &device);
    let mut optim = AdamConfig::new()
        .with_epsilon(config.adam_epsilon as f32)
        .init();
    let b = config.batch_size.min(prepared.len());
    let t0 = Instant::now();
    let report = |step: usize, model: &GarNet, t: &learn::train::Terms| {
        let held = [Split::Val, Split::Test].map(|s| {
            evaluate(&setup, &model.valid(), &data, s)
                .expect("evaluate")
                .map_or(f64::NAN, |(t, _)| t.edist_cm)
        });
        println!(
            "step {step:5}  train Edist {:.3} cm (vert {:.3e} pen {:.3e} norm {:.3e} bend {:.3e})  val {:.3} test {:.3} cm  {:.0} s",
            t.edist_cm,
            t.vert,
            t.pen,
            t.norm,
            t.bend,
            held[0],
            held[1],
            t0.elapsed().as_secs_f64()
        );
    };
    for step in 0..=steps {
        let start = (step * b) % prepared.len();
        let refs: Vec<&Prepared> = (0..b)
            .map(|i| &prepared[(start + i) % prepared.len()])
            .collect();
        let (loss, terms) = setup.losses(&model, &refs);
        if step % every == 0 {
            report(step, &model, &terms);
        }
        if step == steps {
            break;
        }
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        model = optim.step(config.rate_at(step as u64, steps as u64), model, grads);
    }
}
