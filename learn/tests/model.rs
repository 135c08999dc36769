//! Shapes of every block and variant, the FeaStNet convolution against its formula, the
//! losses against hand-computed values, finite gradients, checkpoint round trips.

use burn::module::Module;
use burn::tensor::{Device, Distribution, Int, Tensor, TensorData};
use learn::config::{ModelConfig, Variant};
use learn::loss::{self, LossTopology};
use learn::model::{FeaStConv, GarNet, Graph, Input};
use learn::topology::Topology;

/// A w x h grid of unit-spaced vertices, two triangles per cell.
fn grid(w: usize, h: usize) -> (Vec<[f32; 3]>, Topology) {
    let mut v = Vec::new();
    for y in 0..h {
        for x in 0..w {
            v.push([x as f32 * 0.01, y as f32 * 0.01, 0.0]);
        }
    }
    let mut t = Vec::new();
    for y in 0..h - 1 {
        for x in 0..w - 1 {
            let i = (y * w + x) as u32;
            t.push([i, i + 1, i + w as u32 + 1]);
            t.push([i, i + w as u32 + 1, i + w as u32]);
        }
    }
    let topo = Topology::new(v.len(), &t);
    (v, topo)
}

fn small_config(variant: Variant) -> ModelConfig {
    ModelConfig {
        variant,
        body_points: 60,
        body_mlp1: vec![8, 8],
        body_mlp2: vec![16, 24],
        stn_mlp: vec![8, 16],
        stn_head: vec![8],
        garment_mlp: vec![8, 12],
        conv_width: 10,
        conv_heads: 3,
        conv_blocks: 2,
        fusion: vec![16, 8],
        local_downsample: 10,
        local_pool_k: 4,
        local_k: 3,
        ..ModelConfig::default()
    }
}

fn random_input(c: &ModelConfig, b: usize, n: usize, params: usize, device: &Device) -> Input {
    let p = c.body_points;
    let pd = c.local_points();
    let idx = |len: usize, rows: usize| -> Tensor<1, Int> {
        let v: Vec<i64> = (0..len).map(|i| ((i * 7919) % rows) as i64).collect();
        Tensor::from_data(TensorData::new(v, [len]), device)
    };
    Input {
        body: Tensor::random([b, p, 6], Distribution::Default, device),
        params: Tensor::random([b, params], Distribution::Default, device),
        warped: Tensor::random([b, n, 3], Distribution::Default, device),
        pool_index: idx(b * pd * c.local_pool_k, b * p),
        local_index: idx(b * n * c.local_k, b * pd),
        offsets: c
            .body_offsets
            .then(|| Tensor::random([b, n, 7], Distribution::Default, device)),
    }
}

#[test]
fn every_variant_outputs_one_translation_per_vertex() {
    let device = Device::default();
    let (_, topo) = grid(6, 5);
    let g = Graph::new(&topo, &device);
    let with_offsets = [Variant::Naive, Variant::Global, Variant::Local]
        .map(|v| (v, true))
        .into_iter();
    for (variant, body_offsets) in Variant::ALL
        .map(|v| (v, false))
        .into_iter()
        .chain(with_offsets)
    {
        let c = ModelConfig {
            body_offsets,
            ..small_config(variant)
        };
        c.validate().unwrap();
        let net = GarNet::new(&c, 13, &device);
        let input = random_input(&c, 2, topo.vertices, 13, &device);
        let out = net.forward(&input, &g);
        assert_eq!(out.dims(), [2, 30, 3], "{variant:?} {body_offsets}");
        if body_offsets {
            // The 7 offsets widen the garment MLP's first layer by 7 inputs.
            let plain = GarNet::new(&small_config(variant), 13, &device);
            assert_eq!(
                net.num_params() - plain.num_params(),
                7 * c.garment_mlp[0],
                "{variant:?}"
            );
            let n = topo.vertices;
            let flops = |c: &ModelConfig| learn::model::forward_flops(c, 13, n, 7);
            let extra = flops(&c) - flops(&small_config(variant));
            assert_eq!(
                extra,
                2.0 * (n * 7 * c.garment_mlp[0]) as f64,
                "{variant:?}"
            );
        }
        // The last layer starts at zero: an untrained network returns M (the DQS warp).
        let max = out.abs().max().into_scalar::<f32>();
        assert_eq!(max, 0.0, "{variant:?}");
    }
}

#[test]
fn feastconv_matches_its_formula() {
    let device = Device::default();
    let (_, topo) = grid(4, 3);
    let g = Graph::new(&topo, &device);
    let (cin, cout, m) = (5, 4, 3);
    let conv = FeaStConv::new(cin, cout, m, false, &device);
    let x = Tensor::<3>::random([1, topo.vertices, cin], Distribution::Default, &device);
    let y = conv
        .forward(x.clone(), &g, &g.aggregation(1, &device))
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    // Parameters as plain numbers.
    let mut params = Vec::new();
    struct Grab<'a>(&'a mut Vec<Vec<f32>>);
    impl burn::module::ModuleVisitor for Grab<'_> {
        fn visit_float<const D: usize>(&mut self, p: &burn::module::Param<Tensor<D>>) {
            self.0
                .push(p.val().into_data().try_to_vec::<f32>().unwrap());
        }
    }
    conv.visit(&mut Grab(&mut params));
    // Order of fields: lin.weight [M*Cin, Cout], u.weight [Cin, M], c [M], bias [Cout].
    let (w, u, c, b) = (&params[0], &params[1], &params[2], &params[3]);
    let xs = x.into_data().try_to_vec::<f32>().unwrap();
    let xv = |i: usize, k: usize| xs[i * cin + k];
    let rings = &topo.rings;
    for i in 0..topo.vertices {
        let mut nb = vec![i];
        nb.extend(rings[i].iter().map(|&j| j as usize));
        for o in 0..cout {
            let mut acc = 0.0f64;
            for &j in &nb {
                let logits: Vec<f64> = (0..m)
                    .map(|h| {
                        c[h] as f64
                            + (0..cin)
                                .map(|k| u[k * m + h] as f64 * (xv(j, k) - xv(i, k)) as f64)
                                .sum::<f64>()
                    })
                    .collect();
                let mx = logits.iter().cloned().fold(f64::MIN, f64::max);
                let z: f64 = logits.iter().map(|l| (l - mx).exp()).sum();
                for h in 0..m {
                    let q = (logits[h] - mx).exp() / z;
                    let wx: f64 = (0..cin)
                        .map(|k| w[(h * cin + k) * cout + o] as f64 * xv(j, k) as f64)
                        .sum();
                    acc += q * wx;
                }
            }
            let expect = acc / nb.len() as f64 + b[o] as f64;
            let got = y[i * cout + o] as f64;
            assert!(
                (got - expect).abs() < 1e-4,
                "vertex {i} out {o}: {got} vs {expect}"
            );
        }
    }
}

fn tensor(v: &[[f32; 3]], device: &Device) -> Tensor<3> {
    let flat: Vec<f32> = v.iter().flatten().copied().collect();
    Tensor::from_data(TensorData::new(flat, [1, v.len(), 3]), device)
}

fn value(t: Tensor<1>) -> f64 {
    t.into_scalar::<f32>() as f64
}

#[test]
fn losses_are_zero_for_identical_meshes_and_match_hand_values() {
    let device = Device::default();
    let (v, topo) = grid(3, 3);
    let lt = LossTopology::new(&topo, &device);
    let g = tensor(&v, &device);
    assert!(value(loss::vertex_loss(g.clone(), g.clone())).abs() < 1e-12);
    assert!(value(loss::normal_loss(g.clone(), g.clone(), &lt)).abs() < 1e-9);
    assert!(value(loss::bending_loss(g.clone(), g.clone(), &lt)).abs() < 1e-6);
    assert!(value(loss::uniform_curvature_loss(g.clone(), g.clone(), &lt)).abs() < 1e-12);
    // Lift the centre vertex by h: its Laplacian moves by -h in z; each of its six
    // neighbours' by h over its own ring's size (the corners 0 and 8 on the diagonal have
    // 3 neighbours, the edge midpoints 1, 3, 5, 7 have 4; 2 and 6 are not neighbours).
    // L_UMC = (h^2 + 2 (h/3)^2 + 4 (h/4)^2) / 9 = 53 h^2 / 324.
    assert_eq!(topo.rings[4], [0, 1, 3, 5, 7, 8]);
    assert_eq!(topo.rings[0].len(), 3);
    assert_eq!(topo.rings[1].len(), 4);
    let h = 0.01;
    let mut lifted = v.clone();
    lifted[4][2] += h;
    let got = value(loss::uniform_curvature_loss(
        tensor(&lifted, &device),
        g.clone(),
        &lt,
    ));
    let want = 53.0 * (h as f64).powi(2) / 324.0;
    assert!((got - want).abs() < 1e-4 * want, "{got} vs {want}");
    // Shift every vertex by 3 mm in z: L_vert = 9e-6 m^2; normals and distances unchanged.
    let shifted: Vec<[f32; 3]> = v.iter().map(|p| [p[0], p[1], p[2] + 0.003]).collect();
    let p = tensor(&shifted, &device);
    assert!((value(loss::vertex_loss(p.clone(), g.clone())) - 9e-6).abs() < 1e-9);
    assert!(value(loss::normal_loss(p.clone(), g.clone(), &lt)).abs() < 1e-9);
    assert!(value(loss::bending_loss(p, g.clone(), &lt)).abs() < 1e-6);
    // Scale the grid by 2: every two-ring distance doubles, so L_bend is their mean length.
    let scaled: Vec<[f32; 3]> = v.iter().map(|p| [2.0 * p[0], 2.0 * p[1], 0.0]).collect();
    let mut mean = 0.0;
    for [i, k] in &topo.bend_pairs {
        let (a, b) = (v[*i as usize], v[*k as usize]);
        mean += ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt() as f64;
    }
    mean /= topo.bend_pairs.len() as f64;
    let got = value(loss::bending_loss(tensor(&scaled, &device), g.clone(), &lt));
    assert!((got - mean).abs() < 1e-6, "{got} vs {mean}");
    // Mirror z of a tilted mesh: a face normal (a, b, c) becomes (a, b, -c) ... instead
    // rotate the grid 90 degrees about x: every normal turns by 90 degrees, dot 0, L_norm 1.
    let rotated: Vec<[f32; 3]> = v.iter().map(|p| [p[0], 0.0, p[1]]).collect();
    let got = value(loss::normal_loss(tensor(&rotated, &device), g, &lt));
    assert!((got - 1.0).abs() < 1e-6, "{got}");
}

/// Four points of one neighbourhood, shared by all four vertices: rows `[N * K]`.
fn cross_neighbourhood(a: f32, b: f32, device: &Device) -> (Tensor<3>, Tensor<1, Int>) {
    let x = tensor(
        &[[a, 0.0, 0.0], [-a, 0.0, 0.0], [0.0, b, 0.0], [0.0, -b, 0.0]],
        device,
    );
    let rows: Vec<i64> = (0..4).flat_map(|_| 0..4).collect();
    (x, Tensor::from_data(TensorData::new(rows, [16]), device))
}

#[test]
fn rayleigh_quotients_bound_the_covariance_and_l_rq_matches_hand_values() {
    let device = Device::default();
    // Points (+-a, 0, 0), (0, +-b, 0): mean 0, Sigma = diag(a^2 / 2, b^2 / 2, 0), tr = the
    // mean squared norm (a^2 + b^2) / 2. RQ of (a, 0, 0) is a^4 / 2 / (a^2 + 1e-3 tr).
    let (a, b) = (0.02f64, 0.01f64);
    let (x, rows) = cross_neighbourhood(a as f32, b as f32, &device);
    let (lo, hi) = loss::rayleigh_bounds(x.clone(), rows.clone(), 4);
    let tr = (a * a + b * b) / 2.0;
    let want_hi = a.powi(4) / 2.0 / (a * a + 1e-3 * tr);
    let want_lo = b.powi(4) / 2.0 / (b * b + 1e-3 * tr);
    let (lo, hi) = (
        lo.into_data().try_to_vec::<f32>().unwrap(),
        hi.into_data().try_to_vec::<f32>().unwrap(),
    );
    for (l, h) in lo.iter().zip(&hi) {
        assert!(
            (*l as f64 - want_lo).abs() < 1e-3 * want_lo,
            "{l} vs {want_lo}"
        );
        assert!(
            (*h as f64 - want_hi).abs() < 1e-3 * want_hi,
            "{h} vs {want_hi}"
        );
    }
    assert!(value(loss::rayleigh_loss(x.clone(), x.clone(), rows.clone(), 4)).abs() < 1e-20);
    // Doubling the points multiplies every quotient by 4: L_RQ = (3 lo)^2 + (3 hi)^2.
    let got = value(loss::rayleigh_loss(x.clone() * 2.0, x, rows, 4));
    let want = 9.0 * (want_lo * want_lo + want_hi * want_hi);
    assert!((got - want).abs() < 1e-3 * want, "{got} vs {want}");
}

/// A regular octahedron of radius r: 6 vertices, 8 equilateral faces, outward winding.
fn octahedron(r: f32) -> (Vec<[f32; 3]>, Topology) {
    let v = vec![
        [r, 0.0, 0.0],
        [-r, 0.0, 0.0],
        [0.0, r, 0.0],
        [0.0, -r, 0.0],
        [0.0, 0.0, r],
        [0.0, 0.0, -r],
    ];
    let t = vec![
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ];
    (v, Topology::new(6, &t))
}

#[test]
fn mean_curvature_normal_and_l_mc_match_hand_values() {
    let device = Device::default();
    // Octahedron vertex: four 60-degree corners opposite each edge, weight 2 cot 60 per
    // edge, sum of (x_j - x_i) = -4 r n; Voronoi area 4 * r^2 / (2 sqrt 3). So
    // kappa = -(8 r / sqrt 3) n / (4 r^2 / sqrt 3) = -(2 / r) n: 40 / m at r = 5 cm.
    let (v, topo) = octahedron(0.05);
    let lt = LossTopology::new(&topo, &device);
    let x = tensor(&v, &device);
    let k = loss::mean_curvature_normal(x.clone(), &lt)
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    for (i, p) in v.iter().enumerate() {
        for c in 0..3 {
            let want = -40.0 * p[c] / 0.05;
            assert!(
                (k[3 * i + c] - want).abs() < 1e-3,
                "vertex {i}: {:?}",
                &k[3 * i..3 * i + 3]
            );
        }
    }
    // A flat grid has no mean curvature at its interior vertex.
    let (g, gt) = grid(3, 3);
    let kg = loss::mean_curvature_normal(tensor(&g, &device), &LossTopology::new(&gt, &device))
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    assert!(kg[12..15].iter().all(|c| c.abs() < 1e-3), "{kg:?}");
    // Radius 5 cm against 10 cm: |40 - 20|^2 = 400 / m^2 at every vertex.
    assert!(value(loss::mean_curvature_loss(x.clone(), x.clone(), &lt)).abs() < 1e-9);
    let (v2, _) = octahedron(0.1);
    let got = value(loss::mean_curvature_loss(x, tensor(&v2, &device), &lt));
    assert!((got - 400.0).abs() < 0.05, "{got}");
}

#[test]
fn penetration_loss_counts_depth_inside_the_tolerance_only() {
    let device = Device::default();
    // Two vertices; the body point at the origin with normal +y.
    let target = tensor(&[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], &device);
    let pred = tensor(&[[0.0, -0.01, 0.0], [0.0, -0.2, 0.0]], &device);
    let body = tensor(&[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], &device);
    let normal = tensor(&[[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]], &device);
    // Vertex 0 is 1 cm inside and within d_tol = 5 cm of its target; vertex 1 is 20 cm
    // away from its target and so ignored: (0.01 + 0) / 2.
    let got = value(loss::penetration_loss(pred, target, body, normal, 0.05));
    assert!((got - 0.005).abs() < 1e-7, "{got}");
}

#[test]
fn gradients_of_every_loss_are_finite_on_degenerate_triangles() {
    let device = Device::default().autodiff();
    let (v, topo) = grid(3, 3);
    let lt = LossTopology::new(&topo, &device);
    // Collapse a triangle to a point and make another a sliver.
    let mut bad = v.clone();
    bad[4] = bad[0];
    bad[5] = [bad[2][0], bad[2][1] + 1e-7, 0.0];
    let pred = tensor(&bad, &device).require_grad();
    let target = tensor(&v, &device);
    let body = tensor(&v, &device);
    let normal = tensor(&vec![[0.0, 0.0, 1.0]; v.len()], &device);
    let flat: Vec<glam::Vec3> = v.iter().map(|p| glam::Vec3::from_array(*p)).collect();
    let rq_rows = loss::rq_neighbourhoods(&[&flat], 8, &device);
    let terms: Vec<(&str, Tensor<1>)> = vec![
        ("vert", loss::vertex_loss(pred.clone(), target.clone())),
        ("norm", loss::normal_loss(pred.clone(), target.clone(), &lt)),
        (
            "bend",
            loss::bending_loss(pred.clone(), target.clone(), &lt),
        ),
        (
            "umc",
            loss::uniform_curvature_loss(pred.clone(), target.clone(), &lt),
        ),
        (
            "pen",
            loss::penetration_loss(pred.clone(), target.clone(), body, normal, 0.05),
        ),
        (
            "mc",
            loss::mean_curvature_loss(pred.clone(), target.clone(), &lt),
        ),
        // The target grid is flat: every neighbourhood's covariance is singular.
        (
            "rq",
            loss::rayleigh_loss(pred.clone(), target.clone(), rq_rows.clone(), 8),
        ),
    ];
    for (name, l) in terms {
        let grads = l.backward();
        let g = pred.grad(&grads).expect("a gradient");
        let data = g.into_data().try_to_vec::<f32>().unwrap();
        assert!(data.iter().all(|x| x.is_finite()), "{name}: {data:?}");
    }
}

#[test]
fn a_saved_and_loaded_checkpoint_predicts_the_same() {
    let device = Device::default();
    let (_, topo) = grid(5, 4);
    let g = Graph::new(&topo, &device);
    for layer_norm in [false, true] {
        let c = ModelConfig {
            layer_norm,
            ..small_config(Variant::Local)
        };
        device.seed(3);
        let net = GarNet::new(&c, 13, &device);
        // Give the zero-initialised output layer weights so that predictions are not all 0.
        let net = net.map(&mut Jitter);
        let input = random_input(&c, 2, topo.vertices, 13, &device);
        let before = net
            .forward(&input, &g)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert!(before.iter().any(|&x| x != 0.0));
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.bpk");
        learn::train::save_model(&net, &path).unwrap();
        device.seed(99);
        let fresh = GarNet::new(&c, 13, &device);
        let loaded = learn::train::load_model(fresh, &path).unwrap();
        let after = loaded
            .forward(&input, &g)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert_eq!(before, after, "layer_norm {layer_norm}");
    }
}

#[test]
fn swapped_body_features_equal_draping_with_the_other_body() {
    use learn::model::Swap;
    let device = Device::default();
    let (_, topo) = grid(5, 4);
    let g = Graph::new(&topo, &device);
    let n = topo.vertices;
    let flat = |t: Tensor<3>| t.into_data().try_to_vec::<f32>().unwrap();
    for (variant, swap) in [
        (
            Variant::Global,
            Swap {
                global: true,
                ..Swap::NONE
            },
        ),
        (
            Variant::Local,
            Swap {
                global: true,
                local: true,
                offsets: true,
            },
        ),
        (
            Variant::GlobalParams,
            Swap {
                global: true,
                ..Swap::NONE
            },
        ),
    ] {
        let c = ModelConfig {
            layer_norm: true,
            body_offsets: swap.offsets,
            ..small_config(variant)
        };
        device.seed(5);
        let net = GarNet::new(&c, 13, &device).map(&mut Jitter);
        // Two drapes whose neighbour lists have the same pattern relative to their own
        // body, so that exchanging the bodies exchanges every body feature.
        let (p, pd) = (c.body_points, c.local_points());
        let pattern = |len: usize, rows: usize, b: usize| -> Vec<i64> {
            (0..len)
                .map(|i| (b * rows + (i * 7919) % rows) as i64)
                .collect()
        };
        let index = |per: usize, rows: usize| -> Tensor<1, Int> {
            let v: Vec<i64> = (0..2).flat_map(|b| pattern(per, rows, b)).collect();
            Tensor::from_data(TensorData::new(v, [2 * per]), &device)
        };
        let mut input = random_input(&c, 2, n, 13, &device);
        input.pool_index = index(pd * c.local_pool_k, p);
        input.local_index = index(n * c.local_k, pd);
        let first_last =
            |t: Tensor<3>| Tensor::cat(vec![t.clone().narrow(0, 1, 1), t.narrow(0, 0, 1)], 0);
        let exchanged = Input {
            offsets: input.offsets.clone().map(first_last),
            body: Tensor::cat(
                vec![
                    input.body.clone().narrow(0, 1, 1),
                    input.body.clone().narrow(0, 0, 1),
                ],
                0,
            ),
            params: Tensor::cat(
                vec![
                    input.params.clone().narrow(0, 1, 1),
                    input.params.clone().narrow(0, 0, 1),
                ],
                0,
            ),
            ..input.clone()
        };
        let own = flat(net.forward(&input, &g));
        assert_eq!(own, flat(net.forward_swapped(&input, &g, Swap::NONE)));
        let swapped = flat(net.forward_swapped(&input, &g, swap));
        let other = flat(net.forward(&exchanged, &g));
        let worst = max_abs_diff(&swapped, &other);
        // Rounding only: the jittered weights give outputs up to about 1e4, and another
        // order of the same sums (other tests share the device's generator and threads, so
        // the draws and the work's split vary) moves them by a few 1e-8 of that.
        let scale = other.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(
            worst < 1e-5 + 1e-7 * scale,
            "{variant:?}: {worst} of {scale}"
        );
        // And the swap does change the prediction (the bodies differ).
        let moved = max_abs_diff(&swapped, &own);
        assert!(moved > 1e-3, "{variant:?}: {moved}");
        // A batch of one drape has no other drape: nothing is swapped.
        let single = random_input(&c, 1, n, 13, &device);
        assert_eq!(
            flat(net.forward(&single, &g)),
            flat(net.forward_swapped(&single, &g, swap))
        );
    }
}

/// The largest absolute difference between two equally long lists.
fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max)
}

/// Adds 0.1 to every parameter.
struct Jitter;
impl burn::module::ModuleMapper for Jitter {
    fn map_float<const D: usize>(
        &mut self,
        p: burn::module::Param<Tensor<D>>,
    ) -> burn::module::Param<Tensor<D>> {
        p.map(|t| t + 0.1)
    }
}

#[test]
fn forward_flops_match_hand_counts() {
    use learn::model::{LOCAL_WIDTH, forward_flops};
    // Global-Params without convolutions' cost beyond the dense layers: garment MLP 3->4
    // on 10 vertices, conv_in 4->2 (+ 5 parameters -> 2 once), no blocks, fusion_in
    // (4 + 2 + 2) -> 3 (+ 5 -> 3 once), out 3 -> 3.
    let c = ModelConfig {
        variant: Variant::GlobalParams,
        garment_mlp: vec![4],
        conv_width: 2,
        conv_blocks: 0,
        fusion: vec![3],
        ..ModelConfig::default()
    };
    let expect = 2.0
        * (10.0 * 3.0 * 4.0
            + 10.0 * 4.0 * 2.0
            + 5.0 * 2.0
            + 10.0 * 8.0 * 3.0
            + 5.0 * 3.0
            + 10.0 * 3.0 * 3.0);
    assert_eq!(forward_flops(&c, 5, 10, 7), expect);
    // One FeaStNet block adds u (C+3 -> M), the [M, K] x [K, C+3] aggregation and the
    // (M (C+3)) -> C map on every vertex.
    let one = ModelConfig {
        conv_blocks: 1,
        ..c.clone()
    };
    let (ci, m, k, n) = (5.0, 4.0, 7.0, 10.0);
    let block = 2.0 * n * (ci * m + m * k * ci + m * ci * 2.0);
    assert_eq!(forward_flops(&one, 5, 10, 7) - expect, block);
    // Local over Global: the local reduction on the body points and its fusion input.
    let g = ModelConfig {
        variant: Variant::Global,
        ..small_config(Variant::Global)
    };
    let l = ModelConfig {
        variant: Variant::Local,
        ..g.clone()
    };
    let extra = 2.0 * (60.0 * 16.0 * LOCAL_WIDTH as f64 + 10.0 * LOCAL_WIDTH as f64 * 16.0);
    assert_eq!(
        forward_flops(&l, 5, 10, 7) - forward_flops(&g, 5, 10, 7),
        extra
    );
}

#[test]
fn the_positional_encoding_holds_the_coordinates_and_their_sines_and_cosines() {
    let device = Device::default();
    let x = Tensor::<3>::from_data(TensorData::new(vec![0.5f32, -1.0, 2.0], [1, 1, 3]), &device);
    let e = learn::model::positional_encoding(x, 2);
    assert_eq!(e.dims(), [1, 1, 15]);
    let v: Vec<f32> = e.into_data().try_to_vec::<f32>().unwrap();
    let want = [
        0.5f32,
        -1.0,
        2.0, // xyz
        0.5f32.sin(),
        (-1.0f32).sin(),
        2.0f32.sin(),
        0.5f32.cos(),
        (-1.0f32).cos(),
        2.0f32.cos(),
        1.0f32.sin(),
        (-2.0f32).sin(),
        4.0f32.sin(),
        1.0f32.cos(),
        (-2.0f32).cos(),
        4.0f32.cos(),
    ];
    for (a, b) in v.iter().zip(want) {
        assert!((a - b).abs() < 1e-6, "{v:?}");
    }
    // The encoding widens the garment MLP's input and counts in the FLOPs; 17 bands are refused.
    let c = ModelConfig {
        fourier_bands: 4,
        ..ModelConfig::default()
    };
    c.validate().unwrap();
    assert!(
        learn::model::forward_flops(&c, 0, 1000, 8)
            > learn::model::forward_flops(&ModelConfig::default(), 0, 1000, 8)
    );
    let bad = ModelConfig {
        fourier_bands: 17,
        ..ModelConfig::default()
    };
    assert!(
        bad.validate()
            .unwrap_err()
            .to_string()
            .contains("fourier_bands")
    );
}

#[test]
fn a_block_that_starts_at_zero_adds_nothing_until_it_learns() {
    let device = Device::default();
    let (_, topo) = grid(4, 3);
    let g = Graph::new(&topo, &device);
    let x = Tensor::<3>::random([2, topo.vertices, 5], Distribution::Default, &device);
    let how = g.aggregation(2, &device);
    let zero = FeaStConv::new(5, 4, 3, true, &device)
        .forward(x.clone(), &g, &how)
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    assert!(zero.iter().all(|&v| v == 0.0), "{zero:?}");
    // He-initialised, the same block's output is not zero.
    let he = FeaStConv::new(5, 4, 3, false, &device)
        .forward(x, &g, &how)
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    assert!(he.iter().any(|&v| v.abs() > 1e-3));
}

/// Per-sample inputs of the Local variant in which sample `s`'s indices point at its own
/// rows, so a batch can be compared with its samples one at a time.
fn consistent_input(c: &ModelConfig, n: usize, samples: &[usize], device: &Device) -> Input {
    let (p, pd) = (c.body_points, c.local_points());
    let b = samples.len();
    // Sample s's random rows, the same whatever else is in the batch.
    let rows = |base: u64, count: usize, width: usize| -> Tensor<3> {
        let parts = samples
            .iter()
            .map(|&s| {
                device.seed(base + s as u64);
                Tensor::random([1, count, width], Distribution::Default, device)
            })
            .collect();
        Tensor::cat(parts, 0)
    };
    let mut pool = Vec::new();
    let mut local = Vec::new();
    for (k, &s) in samples.iter().enumerate() {
        let (ko, s) = (k as i64, s);
        pool.extend(
            (0..pd * c.local_pool_k).map(|i| ko * p as i64 + ((i * 31 + s * 7) % p) as i64),
        );
        local.extend((0..n * c.local_k).map(|i| ko * pd as i64 + ((i * 13 + s * 5) % pd) as i64));
    }
    let (pl, ll) = (pool.len(), local.len());
    Input {
        body: rows(100, p, 6),
        params: Tensor::zeros([b, 13], device),
        warped: rows(200, n, 3),
        pool_index: Tensor::from_data(TensorData::new(pool, [pl]), device),
        local_index: Tensor::from_data(TensorData::new(local, [ll]), device),
        offsets: None,
    }
}

#[test]
fn layer_norm_adds_a_scale_and_shift_per_hidden_feature_and_a_drape_predicts_the_same_alone_or_in_a_batch()
 {
    let device = Device::default();
    let (_, topo) = grid(6, 5);
    let g = Graph::new(&topo, &device);
    let plain = small_config(Variant::Local);
    let c = ModelConfig {
        layer_norm: true,
        ..plain.clone()
    };
    c.validate().unwrap();
    // Every normalised layer's width: the spatial transformer's MLP and head, both body
    // blocks, the garment MLP, the layer into the convolutions, each FeaStNet block, the
    // first fusion layer and the other fusion layers.
    let widths: usize = [
        c.stn_mlp.iter().sum::<usize>(),
        c.stn_head.iter().sum(),
        c.body_mlp1.iter().sum(),
        c.body_mlp2.iter().sum(),
        c.garment_mlp.iter().sum(),
        c.conv_width,
        c.conv_blocks * c.conv_width,
        c.fusion.iter().sum(),
    ]
    .iter()
    .sum();
    assert_eq!(widths, 162);
    let with = GarNet::new(&c, 13, &device).num_params();
    let without = GarNet::new(&plain, 13, &device).num_params();
    assert_eq!(with - without, 2 * widths);

    // Unlike a batch normalisation, the prediction of a drape does not depend on what
    // else is in its batch.
    device.seed(5);
    let net = GarNet::new(&c, 13, &device).map(&mut Jitter);
    let n = topo.vertices;
    let batch = net
        .forward(&consistent_input(&c, n, &[0, 1], &device), &g)
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    let mut alone = Vec::new();
    for s in [0, 1] {
        alone.extend(
            net.forward(&consistent_input(&c, n, &[s], &device), &g)
                .into_data()
                .try_to_vec::<f32>()
                .unwrap(),
        );
    }
    assert_eq!(batch.len(), 2 * n * 3);
    assert!(batch.iter().any(|v| v.abs() > 1e-3));
    let worst = max_abs_diff(&batch, &alone);
    assert!(worst < 1e-4, "batch and one at a time differ by {worst}");
    // The normalisation is there: the same linear weights without it (the norms draw no
    // random numbers, so the same seed gives the same weights) predict something else.
    device.seed(5);
    let other = GarNet::new(&plain, 13, &device).map(&mut Jitter);
    let o = other
        .forward(&consistent_input(&c, n, &[0, 1], &device), &g)
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    assert!(o.iter().zip(&batch).any(|(a, b)| (a - b).abs() > 1e-3));
}

/// Adds normal noise (standard deviation 0.05) to every parameter: weights of a trained
/// network's scale, the zero-initialised ones included.
struct Noise;
impl burn::module::ModuleMapper for Noise {
    fn map_float<const D: usize>(
        &mut self,
        p: burn::module::Param<Tensor<D>>,
    ) -> burn::module::Param<Tensor<D>> {
        p.map(|t| {
            let noise = Tensor::random(t.shape(), Distribution::Normal(0.0, 0.05), &t.device());
            t + noise
        })
    }
}

/// At inference (off the autodiff device) the forward pass runs its host kernels (the
/// body stream's MLPs, the garment MLP with `conv_in`, the residual blocks and the fusion
/// head fused, the maxima and the local max in SIMD registers); on the autodiff device
/// the training operations (burn's and the crate's own with their backward: the linear
/// layers, the max pools, the leaky ReLU, FeaStNet's aggregation). Both give the same
/// translations for every variant, with and without layer normalisation, for one drape and a batch of three (143 vertices: tiles that end
/// part-way through a block of rows).
#[test]
fn the_inference_kernels_give_burns_forward_pass() {
    let ad = Device::default().autodiff();
    ad.seed(21);
    let plain = ad.clone().inner();
    let (_, topo) = grid(13, 11);
    let n = topo.vertices;
    for variant in Variant::ALL {
        for layer_norm in [false, true] {
            for b in [1, 3] {
                let c = ModelConfig {
                    layer_norm,
                    ..small_config(variant)
                };
                let net = GarNet::new(&c, 13, &ad).map(&mut Noise);
                let input = random_input(&c, b, n, 13, &ad);
                let want = net.forward(&input, &Graph::new(&topo, &ad));
                let indices = random_input(&c, b, n, 13, &plain);
                let input = Input {
                    body: input.body.inner(),
                    params: input.params.inner(),
                    warped: input.warped.inner(),
                    pool_index: indices.pool_index,
                    local_index: indices.local_index,
                    offsets: input.offsets.map(|o| o.inner()),
                };
                let got = net.valid().forward(&input, &Graph::new(&topo, &plain));
                let flat = |t: Tensor<3>| t.into_data().try_to_vec::<f32>().unwrap();
                let (got, want) = (flat(got), flat(want.inner()));
                let scale = want.iter().fold(1e-12f32, |s, v| s.max(v.abs()));
                assert!(
                    scale > 1e-3,
                    "{variant:?}: the jittered network moves the garment"
                );
                let err = max_abs_diff(&got, &want);
                assert!(
                    err / scale < 2e-5,
                    "{variant:?}, layer norm {layer_norm}, batch {b}: {err} of {scale}"
                );
            }
        }
    }
}
