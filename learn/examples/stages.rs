//! Where a GarNet-Local training step spends its time: forward + backward of each stage on
//! random inputs with a real garment's mesh graph.
//!
//! `cargo run --release -p learn --example stages -- DATASET_DIR [BATCH]`

use std::time::Instant;

use burn::module::Module;
use burn::tensor::{Device, Distribution, Tensor};
use learn::config::ModelConfig;
use learn::loss::{self, LossTopology};
use learn::model::{Aggregation, FeaStConv, Graph, Mlp};
use learn::topology::Topology;

fn time(name: &str, reps: usize, mut f: impl FnMut()) {
    f();
    let t = Instant::now();
    for _ in 0..reps {
        f();
    }
    println!(
        "{name:<34} {:8.1} ms",
        t.elapsed().as_secs_f64() * 1e3 / reps as f64
    );
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dir = std::path::PathBuf::from(args.get(1).expect("usage: stages DATASET_DIR [BATCH]"));
    let b: usize = args.get(2).map_or(8, |s| s.parse().expect("batch"));
    let data = dataset::reader::Dataset::open(&dir).expect("dataset");
    let st = &data.statics;
    let topo = Topology::new(st.garment_vertices.len(), &st.garment_triangles);
    let n = topo.vertices;
    let c = ModelConfig::default();
    let device = Device::default().autodiff();
    let g = Graph::new(&topo, &device);
    let lt = LossTopology::new(&topo, &device);
    let w = c.conv_width;
    println!(
        "batch {b}, {n} vertices, {} FeaStNet edges in {} slots per vertex, conv width {w}, {} heads",
        topo.vertices + topo.rings.iter().map(Vec::len).sum::<usize>(),
        topo.slots,
        c.conv_heads
    );
    let conv = FeaStConv::new(w + 3, w, c.conv_heads, false, &device);
    let x = Tensor::<3>::random([b, n, w + 3], Distribution::Default, &device).require_grad();
    let rows = g.rows(b, &device);
    let fused = g.aggregation(b, &device); // the build's: fused on the CPU backends
    let tensors = Aggregation::Tensors(rows.clone());
    time("FeaStConv forward", 3, || {
        let _ = conv.forward(x.clone(), &g, &fused);
    });
    time("FeaStConv forward+backward", 3, || {
        let _ = conv.forward(x.clone(), &g, &fused).sum().backward();
    });
    time("FeaStConv forward (burn's tensor ops)", 3, || {
        let _ = conv.forward(x.clone(), &g, &tensors);
    });
    time("FeaStConv fwd+bwd (burn's tensor ops)", 3, || {
        let _ = conv.forward(x.clone(), &g, &tensors).sum().backward();
    });
    let h = Tensor::<3>::random([b, n, w], Distribution::Default, &device).require_grad();
    time("gather [B*N*K, C] forward+backward", 3, || {
        let _ = h
            .clone()
            .reshape([b * n, w])
            .select(0, rows.clone())
            .sum()
            .backward();
    });
    time("pointwise Linear C->4C fwd+bwd", 3, || {
        let l = burn::nn::LinearConfig::new(w, 4 * w).init(&device);
        let _ = l.forward(h.clone()).sum().backward();
    });
    let body = Mlp::new(6, &[64, 128, 256], 0.1, false, &device);
    let p =
        Tensor::<3>::random([b, c.body_points, 6], Distribution::Default, &device).require_grad();
    time("body MLP 6-64-128-256 fwd+bwd", 3, || {
        let _ = body.forward(p.clone()).sum().backward();
    });
    let pred = Tensor::<3>::random([b, n, 3], Distribution::Default, &device).require_grad();
    let tgt = Tensor::<3>::random([b, n, 3], Distribution::Default, &device);
    time("L_norm fwd+bwd", 3, || {
        let _ = loss::normal_loss(pred.clone(), tgt.clone(), &lt).backward();
    });
    time("L_bend fwd+bwd", 3, || {
        let _ = loss::bending_loss(pred.clone(), tgt.clone(), &lt).backward();
    });
    time("L_vert fwd+bwd", 3, || {
        let _ = loss::vertex_loss(pred.clone(), tgt.clone()).backward();
    });
    let _ = body.num_params();
}
