//! Seeded sampling of body shapes and poses.
//!
//! Random numbers come from ChaCha8 seeded with a `u64`, so the same seed gives the same
//! sample on every machine and in every release of drape that keeps this algorithm.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use sim::body::pose::{BlendMode, euler_xyz, to_euler_xyz};
use sim::body::{Family, Pose, PoseLibrary, ShapeParams};

/// The generator every sampler uses.
pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// Seed of the shape stream that goes with pose seed `seed`: a fixed odd-constant mix, so
/// shapes and poses drawn for one sample are independent but both follow from one seed.
pub fn shape_seed(seed: u64) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x5348_4150_4553_4545
}

/// Ranges `[low, high]` of uniformly sampled shape parameters.
///
/// The defaults sample adults (25 to 64 years) of moderate height. MakeHuman's height axis
/// is steep and lopsided (0.73 m per unit below 0.5, 1.44 m above; height=1 is a 2.45 m
/// giant whose body also loses relative heaviness), so the default [0.35, 0.62] gives women
/// of 1.48 to 1.76 m and men of 1.62 to 1.90 m (measured on the shipped asset).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ShapeRanges {
    /// Gender range (default [0, 1]: female to male).
    pub gender: [f32; 2],
    /// Age range (default [0.5, 0.8]: 25 to 64 years).
    pub age: [f32; 2],
    /// Muscle range (default [0.25, 0.75]).
    pub muscle: [f32; 2],
    /// Weight range (default [0.25, 0.75]).
    pub weight: [f32; 2],
    /// Height range (default [0.35, 0.62]).
    pub height: [f32; 2],
    /// Proportions range (default [0.3, 0.7]).
    pub proportions: [f32; 2],
}

impl Default for ShapeRanges {
    fn default() -> Self {
        Self {
            gender: [0.0, 1.0],
            age: [0.5, 0.8],
            muscle: [0.25, 0.75],
            weight: [0.25, 0.75],
            height: [0.35, 0.62],
            proportions: [0.3, 0.7],
        }
    }
}

impl ShapeRanges {
    /// One shape drawn uniformly from the ranges (race shares at 1/3 each).
    pub fn sample(&self, rng: &mut impl Rng) -> ShapeParams {
        let mut u = |r: [f32; 2]| r[0] + (r[1] - r[0]) * rng.random::<f32>();
        ShapeParams {
            gender: u(self.gender),
            age: u(self.age),
            muscle: u(self.muscle),
            weight: u(self.weight),
            height: u(self.height),
            proportions: u(self.proportions),
            ..ShapeParams::default()
        }
    }

    /// The 2^6 = 64 corner bodies of the ranges.
    pub fn corners(&self) -> Vec<ShapeParams> {
        (0..64u32)
            .map(|m| {
                let pick = |r: [f32; 2], bit: u32| r[((m >> bit) & 1) as usize];
                ShapeParams {
                    gender: pick(self.gender, 0),
                    age: pick(self.age, 1),
                    muscle: pick(self.muscle, 2),
                    weight: pick(self.weight, 3),
                    height: pick(self.height, 4),
                    proportions: pick(self.proportions, 5),
                    ..ShapeParams::default()
                }
            })
            .collect()
    }
}

/// A pose drawn from the prior, with how it was made.
#[derive(Debug, Clone)]
pub struct SampledPose {
    /// The pose.
    pub pose: Pose,
    /// Its motion family.
    pub family: Family,
    /// The two key poses blended.
    pub keyposes: (String, String),
    /// Blend weight of the second key pose.
    pub blend: f32,
}

impl SampledPose {
    /// One line: family, key poses and blend.
    pub fn describe(&self) -> String {
        format!(
            "{}: {} -> {} at {:.2}, perturbed",
            self.family.name(),
            self.keyposes.0,
            self.keyposes.1,
            self.blend
        )
    }
}

/// The pose prior: pick a family by weight, two of its key poses (neighbours in a cycle for
/// walking), blend them per bone with a uniform weight, perturb every limited bone's Euler
/// angles with Gaussian noise of the bone's `jitter`, and clamp to the joint limits.
#[derive(Debug, Clone)]
pub struct PosePrior {
    /// The library the prior draws from.
    pub library: PoseLibrary,
}

/// A standard normal number (Box-Muller).
fn normal(rng: &mut impl Rng) -> f32 {
    let u1: f32 = rng.random::<f32>().max(1e-12);
    let u2: f32 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}

impl PosePrior {
    /// A prior over a pose library.
    pub fn new(library: PoseLibrary) -> Self {
        Self { library }
    }

    /// One pose from a seed.
    pub fn sample_seeded(&self, seed: u64) -> SampledPose {
        self.sample(&mut rng(seed))
    }

    /// One pose.
    pub fn sample(&self, rng: &mut impl Rng) -> SampledPose {
        let families: Vec<(&Family, &sim::body::pose::FamilySpec)> =
            self.library.families.iter().collect();
        let total: f32 = families.iter().map(|(_, s)| s.weight).sum();
        let mut pick = rng.random::<f32>() * total;
        let mut chosen = families.len() - 1;
        for (i, (_, s)) in families.iter().enumerate() {
            if pick < s.weight {
                chosen = i;
                break;
            }
            pick -= s.weight;
        }
        let (&family, spec) = families[chosen];
        let n = spec.keyposes.len();
        let i = rng.random_range(0..n);
        let j = match spec.blend {
            BlendMode::Cycle => (i + 1) % n,
            BlendMode::Any => (i + 1 + rng.random_range(0..n - 1)) % n,
        };
        let blend: f32 = rng.random();
        let a = &self.library.keyposes[&spec.keyposes[i]];
        let b = &self.library.keyposes[&spec.keyposes[j]];
        let mut pose = a.slerp(b, blend);
        // Perturb the limited bones; clamping puts the others back at rest.
        for (q, lim) in pose.rotations.iter_mut().zip(&self.library.limits) {
            if let Some(l) = lim {
                let [x, y, z] = to_euler_xyz(*q);
                let s = l.jitter.to_radians();
                *q = euler_xyz(
                    x + s * normal(rng),
                    y + s * normal(rng),
                    z + s * normal(rng),
                );
            }
        }
        let pose = self.library.clamp(&pose);
        SampledPose {
            pose,
            family,
            keyposes: (spec.keyposes[i].clone(), spec.keyposes[j].clone()),
            blend,
        }
    }
}
