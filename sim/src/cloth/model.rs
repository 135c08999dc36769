//! The cloth as the solver sees it: particles with masses, and coloured constraints,
//! cooked from a triangle mesh whose positions are the rest shape.

use std::collections::{BTreeMap, HashMap};
use std::ops::Range;

use glam::Vec3;

use super::constraints::dihedral::{self, Dihedral};
use super::constraints::distance::{self, Distance, Kind};
use super::{SimConfig, SimError, coloring};
use crate::mesh::TriMesh;

/// Particles and constraints of one cloth.
#[derive(Debug, Clone)]
pub struct ClothModel {
    /// Rest positions (m).
    pub rest: Vec<Vec3>,
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
    /// Particle masses (kg).
    pub mass: Vec<f32>,
    /// Inverse masses (1/kg); 0 pins a particle.
    pub inv_mass: Vec<f32>,
    /// Mesh edges (for strain reports), each once, `i < j`.
    pub edges: Vec<[u32; 2]>,
    /// Distance constraints, sorted by colour.
    pub distance: Vec<Distance>,
    /// Ranges of `distance` with one colour each.
    pub distance_colours: Vec<Range<usize>>,
    /// What each of `distance` models.
    pub distance_kind: Vec<Kind>,
    /// Dihedral bending constraints, sorted by colour (empty unless enabled).
    pub dihedral: Vec<Dihedral>,
    /// Ranges of `dihedral` with one colour each.
    pub dihedral_colours: Vec<Range<usize>>,
    /// Coulomb friction coefficient between this cloth and the body: the config's, or a
    /// garment's own (`Template::cloth`).
    pub friction: f32,
    /// Per-particle friction coefficients in place of `friction` (empty: `friction` for
    /// every particle).
    pub friction_map: Vec<f32>,
    /// Substeps a frame this cloth needs, at least, while the body moves and while it
    /// settles: a garment's own (`Template::cloth`; `None`: the config's). See
    /// [`ClothModel::drape_config`].
    pub substeps: Option<u32>,
    /// Whether this cloth takes crease contacts when the config leaves them unset: a
    /// garment's own (`Template::cloth`; false: not). See [`ClothModel::drape_config`].
    pub crease_contacts: bool,
}

/// Checks that a mesh can be simulated: finite positions, valid indices, no degenerate or
/// duplicate faces, every edge shared by at most two faces.
pub fn validate_mesh(mesh: &TriMesh) -> Result<(), String> {
    let n = mesh.vertices.len();
    if mesh.triangles.is_empty() {
        return Err("the mesh has no faces".into());
    }
    if let Some(i) = mesh.vertices.iter().position(|v| !v.is_finite()) {
        return Err(format!("vertex {i} has a non-finite coordinate"));
    }
    let mut used = vec![false; n];
    for t in &mesh.triangles {
        for &i in t {
            if let Some(u) = used.get_mut(i as usize) {
                *u = true;
            }
        }
    }
    if let Some(i) = used.iter().position(|u| !u) {
        return Err(format!("vertex {i} belongs to no face"));
    }
    let mut edge_faces: HashMap<(u32, u32), u32> = HashMap::new();
    let mut seen = std::collections::HashSet::new();
    for (f, t) in mesh.triangles.iter().enumerate() {
        if t.iter().any(|&i| i as usize >= n) {
            return Err(format!("face {f} refers to a vertex that does not exist"));
        }
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            return Err(format!("face {f} repeats a vertex"));
        }
        let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
        let area = 0.5 * (b - a).cross(c - a).length();
        let scale = (b - a)
            .length_squared()
            .max((c - a).length_squared())
            .max(1e-30);
        if area < 1e-6 * scale {
            return Err(format!("face {f} has (almost) zero area"));
        }
        let mut key = *t;
        key.sort_unstable();
        if !seen.insert(key) {
            return Err(format!("face {f} is a duplicate"));
        }
        for k in 0..3 {
            let (u, v) = (t[k], t[(k + 1) % 3]);
            let e = edge_faces.entry((u.min(v), u.max(v))).or_insert(0);
            *e += 1;
            if *e > 2 {
                return Err(format!(
                    "edge {u}-{v} is shared by more than two faces (non-manifold)"
                ));
            }
        }
    }
    Ok(())
}

impl ClothModel {
    /// The config a drape of this cloth runs with: `config` with `substeps` and
    /// `settle_substeps` raised to the cloth's own [`ClothModel::substeps`] where that is
    /// more, and `crease_contacts` set to the cloth's own [`ClothModel::crease_contacts`]
    /// where `config` leaves it unset. An error if the result is not a valid config (a
    /// `shear_bend_substeps` that does not divide the garment's substeps).
    pub fn drape_config(&self, config: &SimConfig) -> Result<SimConfig, String> {
        let mut c = SimConfig {
            crease_contacts: Some(config.crease_contacts.unwrap_or(self.crease_contacts)),
            ..config.clone()
        };
        let Some(n) = self.substeps else {
            return Ok(c);
        };
        c.substeps = c.substeps.max(n);
        c.settle_substeps = c.settle_substeps.max(n);
        c.validate()
            .map_err(|e| format!("with the garment's own {n} substeps: {e}"))?;
        Ok(c)
    }

    /// Number of distance constraints of each kind: stretch, shear, bend.
    pub fn kind_counts(&self) -> [usize; 3] {
        let mut n = [0usize; 3];
        for k in &self.distance_kind {
            n[*k as usize] += 1;
        }
        n
    }

    /// Cooks a cloth from its rest mesh. `pinned` particles get infinite mass.
    pub fn new(mesh: &TriMesh, config: &SimConfig, pinned: &[u32]) -> Result<Self, SimError> {
        config.validate().map_err(|reason| SimError::Config {
            path: "(in memory)".into(),
            reason,
        })?;
        validate_mesh(mesh).map_err(SimError::BadMesh)?;
        if let Some(&p) = pinned.iter().find(|&&p| p as usize >= mesh.vertices.len()) {
            return Err(SimError::BadMesh(format!(
                "pinned particle {p} does not exist"
            )));
        }
        let x = &mesh.vertices;
        let n = x.len();
        // Masses from areas; vertex areas for compliance scaling.
        let mut vertex_area = vec![0.0f32; n];
        let mut edge_area: BTreeMap<(u32, u32), f32> = BTreeMap::new();
        let mut edge_opposite: BTreeMap<(u32, u32), Vec<u32>> = BTreeMap::new();
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|i| x[i as usize]);
            let area = 0.5 * (b - a).cross(c - a).length();
            for k in 0..3 {
                vertex_area[t[k] as usize] += area / 3.0;
                let (u, v) = (t[k], t[(k + 1) % 3]);
                let key = (u.min(v), u.max(v));
                *edge_area.entry(key).or_insert(0.0) += area;
                edge_opposite.entry(key).or_default().push(t[(k + 2) % 3]);
            }
        }
        let mass: Vec<f32> = vertex_area.iter().map(|a| a * config.density).collect();
        let mut inv_mass: Vec<f32> = mass
            .iter()
            .map(|m| if *m > 0.0 { 1.0 / m } else { 0.0 })
            .collect();
        for &p in pinned {
            if let Some(w) = inv_mass.get_mut(p as usize) {
                *w = 0.0;
            }
        }

        // Stretch on edges; neighbours for the two-ring.
        let edges: Vec<[u32; 2]> = edge_area.keys().map(|&(a, b)| [a, b]).collect();
        let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); n];
        for &[a, b] in &edges {
            neighbours[a as usize].push(b);
            neighbours[b as usize].push(a);
        }
        let mut constraints: Vec<(Distance, Kind)> = Vec::new();
        let limits = |rest: f32| {
            (
                rest * (1.0 - config.compression_limit),
                rest * (1.0 + config.stretch_limit),
            )
        };
        for (&(a, b), &area) in &edge_area {
            let rest = x[a as usize].distance(x[b as usize]);
            let (min, max) = limits(rest);
            let compliance = config.stretch_compliance * rest * rest / area;
            constraints.push((
                Distance {
                    i: a,
                    j: b,
                    rest,
                    compliance,
                    min,
                    max,
                },
                Kind::Stretch,
            ));
        }
        // Shear and bend between particles two edges apart, as NvCloth's cooker classifies
        // them; a pair reached through several middle particles keeps its first class.
        let mut pairs: BTreeMap<(u32, u32), (Kind, u32)> = BTreeMap::new();
        for (b, nb) in neighbours.iter().enumerate() {
            for (k, &a) in nb.iter().enumerate() {
                for &c in &nb[k + 1..] {
                    let key = (a.min(c), a.max(c));
                    if edge_area.contains_key(&key) || pairs.contains_key(&key) {
                        continue;
                    }
                    if let Some(kind) = distance::classify(x[a as usize], x[b], x[c as usize]) {
                        pairs.insert(key, (kind, b as u32));
                    }
                }
            }
        }
        for (&(a, c), &(kind, b)) in &pairs {
            let rest = x[a as usize].distance(x[c as usize]);
            let base = if kind == Kind::Shear {
                config.shear_compliance
            } else {
                config.bend_compliance
            };
            let area = 2.0 * vertex_area[b as usize].max(1e-12);
            let compliance = base * rest * rest / area;
            constraints.push((
                Distance {
                    i: a,
                    j: c,
                    rest,
                    compliance,
                    min: 0.0,
                    max: f32::MAX,
                },
                kind,
            ));
        }
        // Colour, then sort by colour and, inside a colour, by first particle.
        let refs: Vec<[u32; 2]> = constraints.iter().map(|(c, _)| [c.i, c.j]).collect();
        let slices: Vec<&[u32]> = refs.iter().map(|r| &r[..]).collect();
        let (colours, count) = coloring::greedy(&slices, n);
        let mut order: Vec<usize> = (0..constraints.len()).collect();
        order.sort_by_key(|&k| (colours[k], constraints[k].0.i.min(constraints[k].0.j)));
        let distance: Vec<Distance> = order.iter().map(|&k| constraints[k].0).collect();
        let distance_kind: Vec<Kind> = order.iter().map(|&k| constraints[k].1).collect();
        let distance_colours = colour_ranges(
            &order.iter().map(|&k| colours[k]).collect::<Vec<_>>(),
            count,
        );

        // Optional dihedral bending on interior edges.
        let (mut dihedral, mut dihedral_colours) = (Vec::new(), Vec::new());
        if config.dihedral_bending {
            let mut all = Vec::new();
            for (&(a, b), opp) in &edge_opposite {
                if let [c, d] = opp[..] {
                    let p = [a, b, c, d];
                    if let Some(rest) = dihedral::rest_angle(p.map(|i| x[i as usize])) {
                        let len2 = x[a as usize].distance_squared(x[b as usize]);
                        let area = edge_area[&(a, b)];
                        let compliance = config.dihedral_compliance * area / len2.max(1e-12);
                        all.push(Dihedral {
                            p,
                            rest,
                            compliance,
                        });
                    }
                }
            }
            let slices: Vec<&[u32]> = all.iter().map(|d| &d.p[..]).collect();
            let (colours, count) = coloring::greedy(&slices, n);
            let mut order: Vec<usize> = (0..all.len()).collect();
            order.sort_by_key(|&k| (colours[k], all[k].p[0]));
            dihedral = order.iter().map(|&k| all[k]).collect();
            dihedral_colours = colour_ranges(
                &order.iter().map(|&k| colours[k]).collect::<Vec<_>>(),
                count,
            );
        }

        Ok(Self {
            rest: x.clone(),
            triangles: mesh.triangles.clone(),
            mass,
            inv_mass,
            edges,
            distance,
            distance_colours,
            distance_kind,
            dihedral,
            dihedral_colours,
            friction: config.friction,
            friction_map: Vec::new(),
            substeps: None,
            crease_contacts: false,
        })
    }

    /// Coulomb friction coefficient of particle `i` against the body.
    #[inline]
    pub fn friction_of(&self, i: usize) -> f32 {
        self.friction_map.get(i).copied().unwrap_or(self.friction)
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.rest.len()
    }

    /// True for a cloth without particles (never, for a cooked one).
    pub fn is_empty(&self) -> bool {
        self.rest.is_empty()
    }
}

fn colour_ranges(sorted_colours: &[u32], count: u32) -> Vec<Range<usize>> {
    let mut ranges = Vec::with_capacity(count as usize);
    let mut start = 0;
    for c in 0..count {
        let end = start
            + sorted_colours[start..]
                .iter()
                .take_while(|&&k| k == c)
                .count();
        ranges.push(start..end);
        start = end;
    }
    ranges
}
