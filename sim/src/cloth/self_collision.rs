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
        self.grid.clear();
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloth::SimConfig;
    use crate::mesh::primitives;

    #[test]
    fn close_particles_are_pushed_apart_and_rest_neighbours_are_not() {
        let config = SimConfig::default();
        // 1 cm spacing: particles far apart on the cloth, folded onto each other.
        let grid = primitives::grid(Vec3::ZERO, Vec3::X * 0.1, Vec3::Z * 0.1, 10, 10);
        let model = ClothModel::new(&grid, &config, &[]).unwrap();
        let mut sc = SelfCollision::new(&model, 0.004);
        let mut x = grid.vertices.clone();
        let (a, b) = (0usize, 120usize);
        x[b] = x[a] + Vec3::new(0.0, 0.001, 0.0);
        sc.solve(&mut x, &model.inv_mass);
        assert!(
            x[a].distance(x[b]) >= 0.004 - 1e-6,
            "{}",
            x[a].distance(x[b])
        );
        // Momentum: equal masses moved equally and oppositely.
        assert!(
            ((x[a] - grid.vertices[a]) + (x[b] - (grid.vertices[a] + Vec3::Y * 0.001))).length()
                < 1e-6
        );
        // 3 mm spacing: neighbours are closer than 4 mm at rest and must stay as they are.
        let fine = primitives::grid(Vec3::ZERO, Vec3::X * 0.03, Vec3::Z * 0.03, 10, 10);
        let model = ClothModel::new(&fine, &config, &[]).unwrap();
        let mut sc = SelfCollision::new(&model, 0.004);
        let mut x = fine.vertices.clone();
        sc.solve(&mut x, &model.inv_mass);
        assert_eq!(x, fine.vertices);
    }
}
