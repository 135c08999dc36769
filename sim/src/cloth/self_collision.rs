//! Optional self-collision, NvCloth style: particles closer than a minimum distance are
//! pushed apart, except pairs that are that close in the rest shape (neighbours).
//! A hash grid with cells of the minimum distance finds the pairs; particles are visited
//! in index order, so the result is deterministic.

use std::collections::HashMap;

use glam::{IVec3, Vec3};

use super::model::ClothModel;

/// Self-collision state: the minimum distance and the rest shape for culling.
#[derive(Debug, Clone)]
pub struct SelfCollision {
    distance: f32,
    rest: Vec<Vec3>,
    grid: HashMap<IVec3, Vec<u32>>,
}

impl SelfCollision {
    /// Self-collision of a cloth with minimum distance `distance` (m).
    pub fn new(model: &ClothModel, distance: f32) -> Self {
        Self {
            distance,
            rest: model.rest.clone(),
            grid: HashMap::new(),
        }
    }

    /// One pass over all close pairs.
    pub fn solve(&mut self, x: &mut [Vec3], inv_mass: &[f32]) {
        let d = self.distance;
        let cell = |p: Vec3| (p / d).floor().as_ivec3();
        for list in self.grid.values_mut() {
            list.clear();
        }
        for (i, p) in x.iter().enumerate() {
            self.grid.entry(cell(*p)).or_default().push(i as u32);
        }
        let cull = (1.5 * d) * (1.5 * d);
        for i in 0..x.len() {
            let ci = cell(x[i]);
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let Some(list) = self.grid.get(&(ci + IVec3::new(dx, dy, dz))) else {
                            continue;
                        };
                        for &j in list {
                            let j = j as usize;
                            if j <= i || self.rest[i].distance_squared(self.rest[j]) < cull {
                                continue;
                            }
                            let delta = x[i] - x[j];
                            let len = delta.length();
                            let w = inv_mass[i] + inv_mass[j];
                            if len >= d || len < 1e-9 || w == 0.0 {
                                continue;
                            }
                            let corr = delta / len * ((d - len) / w);
                            x[i] += corr * inv_mass[i];
                            x[j] -= corr * inv_mass[j];
                        }
                    }
                }
            }
        }
    }
}
