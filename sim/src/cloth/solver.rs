//! The time step. One frame, as a list of stages:
//!
//! 1. **detect**: find each particle's nearest body triangle among those whose swept boxes
//!    (inflated by the margin) it can reach this frame (thickness + its own travel), once
//!    per frame, through the BVH; a particle's last search is reused while the body stands
//!    still and the particle stays inside that search's slack;
//! 2. for each substep (`h = frame / substeps`):
//!    1. **predict**: `v += g h`, clamp the speed, `x += v h`;
//!    2. **solve**: one Gauss-Seidel sweep over the constraint colours (XPBD), inside each
//!       half of the particles (the halves at once on two threads), then across them; with
//!       `shear_bend_substeps` set, shear and bending only every few substeps and the
//!       stretch constraints every substep; `stretch_iterations` - 1 more stretch sweeps;
//!    3. **collide**: push particles out of the body interpolated to the substep's time,
//!       along the contact's pseudo-normal (inelastically), then apply Coulomb friction;
//!    4. **velocities**: `v = (x - x_before) / h`, damped by `exp(-damping h)`;
//! 3. **measure**: largest displacement over the frame and kinetic energy (the rest test
//!    of the drape protocol uses them).
//!
//! With the body's thin parts given ([`Solver::frame_with`], `thin.rs`), detection also
//! finds, for each mesh edge whose midpoint is near a thin part, the nearest body triangle
//! to that midpoint, kept if it is thin (its search reused like a particle's while the
//! body stands still); and each substep, after the particles' collisions, a midpoint closer
//! than `thickness` to it is pushed out along its normal, each end by its share of the
//! inverse masses (both by the push when they weigh the same), without friction. On the
//! frame's thread, in edge order.
//!
//! Determinism: the particles are split in two halves (`Halves`); each sweep solves the
//! constraints inside each half in colour order, the two halves at once when a second
//! thread is free (`Team`), then the constraints joining them. The halves share no
//! particle, so one thread or two give the same bits. Detection and collision treat each
//! particle on its own; no floating-point sum is split across threads.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::time::Instant;

use glam::{Vec3, Vec3A};
use rayon::prelude::*;
use serde::Serialize;

use super::SimConfig;
use super::collision::{BodyCollider, Contact};
use super::constraints::dihedral;
use super::constraints::distance::{Halves, Kind, Prepared, SplitSweep};
use super::model::ClothModel;
use super::thin::ThinParts;

/// A contact's point and pseudo-normal at the start and end of a frame (the point moves
/// linearly in between: its barycentrics are fixed for the frame).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Plane {
    q0: Vec3A,
    q1: Vec3A,
    n0: Vec3A,
    n1: Vec3A,
}

/// A particle's contact state.
#[derive(Debug, Clone, Copy)]
struct ContactState {
    /// Its contact this frame, if any.
    plane: Option<Plane>,
    /// The other side of a crease it sits in, if any ([`BodyCollider::crease`]; particles
    /// only, not edges' midpoints).
    crease: Option<Plane>,
    /// Where and with which radius it last searched (NaN before the first search, so the
    /// first frame always searches).
    searched: (Vec3, f32),
}

impl Default for ContactState {
    fn default() -> Self {
        Self {
            plane: None,
            crease: None,
            searched: (Vec3::ZERO, f32::NAN),
        }
    }
}

/// Wall time spent in each stage (s).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StageTimes {
    /// Moving the body model to the next frame (drape protocol).
    pub body: f64,
    /// Refitting the BVH and contact detection.
    pub detect: f64,
    /// Prediction.
    pub predict: f64,
    /// Constraint sweeps.
    pub solve: f64,
    /// Contact enforcement and friction.
    pub collide: f64,
    /// Velocity update and damping.
    pub velocities: f64,
    /// Self-collision.
    pub self_collision: f64,
}

impl StageTimes {
    /// Sum of all stages.
    pub fn total(&self) -> f64 {
        self.body
            + self.detect
            + self.predict
            + self.solve
            + self.collide
            + self.velocities
            + self.self_collision
    }
}

/// What one frame did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameStats {
    /// Largest particle displacement over the frame (m).
    pub max_displacement: f32,
    /// Kinetic energy at the end of the frame (J).
    pub kinetic_energy: f32,
    /// False if any position became non-finite.
    pub finite: bool,
}

/// Solver state of one cloth.
#[derive(Debug, Clone)]
pub struct Solver<'m> {
    /// The cloth.
    pub model: &'m ClothModel,
    /// Parameters (the constraints are prepared for their substep length; `set_substeps`
    /// changes it and prepares them again).
    config: SimConfig,
    /// Positions (m), 16-byte aligned for SIMD; [`Solver::positions`] gives them as `Vec3`.
    x: Vec<Vec3A>,
    /// Velocities (m/s).
    v: Vec<Vec3A>,
    /// Use rayon inside a frame (results are identical either way).
    pub parallel: bool,
    /// Time per stage so far.
    pub times: StageTimes,
    /// Substeps run so far.
    pub substeps_run: u64,
    /// Half-sweeps solved by the helper thread so far (0 on one thread).
    pub helper_half_sweeps: u64,
    x_before: Vec<Vec3A>,
    x_frame: Vec<Vec3A>,
    /// Per particle: its contact this frame and its last search.
    contacts: Vec<ContactState>,
    /// The movable particles with a contact this frame, in index order, and their
    /// contacts: what the collision stage visits every substep.
    active: Vec<(u32, Plane)>,
    /// Per mesh edge: its midpoint's contact on the body's thin parts this frame and its
    /// last search (empty until a frame has thin parts).
    edge_contacts: Vec<ContactState>,
    /// The edges with such a contact this frame and a movable end, in index order.
    edge_active: Vec<(u32, Plane)>,
    /// The edges near a thin part this frame and the last (buffers, in index order).
    edge_candidates: Vec<u32>,
    edge_previous: Vec<u32>,
    /// Edge midpoints pushed out of a thin part so far (one per edge and substep).
    pub edge_pushes: u64,
    /// Distance constraints solved every substep, prepared for its length, in colour
    /// order: all of them if shear and bending run at the full rate, else the stretch ones.
    sweep: SplitSweep,
    /// Shear and bending constraints solved every `shear_bend_interval`-th substep,
    /// prepared for that longer step (empty if they are in `sweep`).
    slow: SplitSweep,
    /// The stretch constraints alone, for the sweeps after the first of a substep when
    /// `stretch_iterations` > 1 and `sweep` holds every constraint (else empty).
    stretch_only: SplitSweep,
    /// The particles in two halves, for the sweeps.
    halves: Halves,
    /// The positions in the halves' order while the sweeps run.
    buf: Vec<Vec3A>,
    self_grid: super::self_collision::SelfCollision,
}

impl<'m> Solver<'m> {
    /// The parameters.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// Particle positions (m).
    pub fn positions(&self) -> Vec<Vec3> {
        self.x.iter().map(|p| Vec3::from(*p)).collect()
    }

    /// Sets the stretch sweeps per substep from the next substep on (the rest of the config
    /// as it was): how a stalled drape settles on (`SimConfig::stall_frames`).
    pub fn set_stretch_iterations(&mut self, sweeps: u32) {
        self.config.stretch_iterations = sweeps.max(1);
    }

    /// Runs the next frames with `substeps` substeps (the drape protocol's
    /// `settle_substeps` once the body holds still): the constraints are prepared again for
    /// the new substep length; positions, velocities and contacts carry over.
    pub fn set_substeps(&mut self, substeps: u32) {
        if substeps == self.config.substeps {
            return;
        }
        let mut c = self.config.clone();
        c.substeps = substeps;
        let (sweep, slow, stretch_only) = sweeps(self.model, &c, &self.halves);
        self.sweep = sweep;
        self.slow = slow;
        self.stretch_only = stretch_only;
        self.config = c;
    }

    /// A solver with the cloth at `x` and at rest.
    pub fn new(model: &'m ClothModel, config: &SimConfig, x: Vec<Vec3>) -> Self {
        assert_eq!(x.len(), model.len());
        let x: Vec<Vec3A> = x.into_iter().map(Vec3A::from).collect();
        let n = x.len();
        let halves = Halves::new(&model.rest);
        let (sweep, slow, stretch_only) = sweeps(model, config, &halves);
        Self {
            sweep,
            slow,
            stretch_only,
            buf: Vec::with_capacity(halves.len()),
            halves,
            model,
            config: config.clone(),
            v: vec![Vec3A::ZERO; n],
            x_before: x.clone(),
            x_frame: x.clone(),
            x,
            parallel: true,
            times: StageTimes::default(),
            substeps_run: 0,
            helper_half_sweeps: 0,
            contacts: vec![ContactState::default(); n],
            active: Vec::new(),
            edge_contacts: Vec::new(),
            edge_active: Vec::new(),
            edge_candidates: Vec::new(),
            edge_previous: Vec::new(),
            edge_pushes: 0,
            self_grid: super::self_collision::SelfCollision::new(model, config.self_distance),
        }
    }

    /// Advances one frame against `body`, whose positions move from its frame start to its
    /// frame end (see [`BodyCollider::advance`] and [`BodyCollider::hold`]).
    pub fn frame(&mut self, body: &BodyCollider) -> FrameStats {
        self.frame_with(body, None)
    }

    /// [`Solver::frame`] with edge contacts against the body's thin parts, if given
    /// ([`ThinParts`], moved with `body`): each mesh edge's midpoint is kept `thickness`
    /// away from them as each particle is from the whole body.
    pub fn frame_with(&mut self, body: &BodyCollider, thin: Option<&ThinParts>) -> FrameStats {
        let c = self.config.clone();
        let frame_dt = c.frame_dt();
        self.x_frame.copy_from_slice(&self.x);

        // 1. detect
        let t0 = Instant::now();
        // While the body stands still, a particle's last search can be reused: a search
        // that found nothing while the particle stays within that search's slack (all that
        // is within its reach now was within the radius searched then), a contact while the
        // particle has moved less than half the margin.
        let still = body.travel() == 0.0;
        let (x, v, thickness) = (&self.x, &self.v, c.thickness);
        let creases = c.crease_contacts == Some(true);
        let detect = |(i, state): (usize, &mut ContactState)| {
            let travel = v[i].length() * frame_dt;
            detect_one(
                body,
                Target::Particle { creases, thin },
                state,
                Vec3::from(x[i]),
                travel,
                thickness,
                still,
            );
        };
        if self.parallel {
            self.contacts.par_iter_mut().enumerate().for_each(detect);
        } else {
            self.contacts.iter_mut().enumerate().for_each(detect);
        }
        self.active.clear();
        let w = &self.model.inv_mass;
        // A particle in a crease: its contact, then the crease's other side.
        self.active.extend(
            self.contacts
                .iter()
                .enumerate()
                .filter(|(i, _)| w[*i] != 0.0)
                .flat_map(|(i, st)| {
                    st.plane
                        .into_iter()
                        .chain(st.crease)
                        .map(move |p| (i as u32, p))
                }),
        );
        // The edges' midpoints against the thin parts.
        self.edge_active.clear();
        if let Some(thin) = thin {
            let edges = &self.model.edges;
            self.edge_contacts
                .resize(edges.len(), ContactState::default());
            // The candidates: edges whose midpoint lies near a group of thin parts, with
            // the fastest particle's travel as everyone's (one pass over the edges that
            // touches no contact state; most edges are far from the hands and feet).
            let travel = v
                .iter()
                .map(|p| p.length_squared())
                .fold(0.0, f32::max)
                .sqrt()
                * frame_dt;
            let reach = thickness + travel + body.margin();
            let mut candidates = std::mem::take(&mut self.edge_candidates);
            let previous = std::mem::take(&mut self.edge_previous);
            candidates.clear();
            candidates.extend((0..edges.len() as u32).filter(|&e| {
                let [a, b] = edges[e as usize].map(|i| i as usize);
                thin.near(Vec3::from(0.5 * (x[a] + x[b])), reach)
            }));
            // The last frame's candidates that are not candidates now forget their search.
            for &e in &previous {
                if candidates.binary_search(&e).is_err() {
                    self.edge_contacts[e as usize] = ContactState::default();
                }
            }
            for &e in &candidates {
                let [a, b] = edges[e as usize].map(|i| i as usize);
                let travel = v[a].length().max(v[b].length()) * frame_dt;
                let here = Vec3::from(0.5 * (x[a] + x[b]));
                let state = &mut self.edge_contacts[e as usize];
                detect_one(
                    body,
                    Target::Edge(thin),
                    state,
                    here,
                    travel,
                    thickness,
                    still,
                );
            }
            self.edge_active.extend(candidates.iter().filter_map(|&e| {
                let [a, b] = edges[e as usize];
                self.edge_contacts[e as usize]
                    .plane
                    .filter(|_| w[a as usize] + w[b as usize] != 0.0)
                    .map(|p| (e, p))
            }));
            self.edge_previous = candidates;
            self.edge_candidates = previous;
        }
        self.times.detect += t0.elapsed().as_secs_f64();

        let interval = c.shear_bend_interval();
        // The sweeps' buffer and the sweeps, lent to the team of this frame's substeps.
        let mut buf = std::mem::take(&mut self.buf);
        buf.resize(self.halves.len(), Vec3A::ZERO);
        let (a, b) = buf.split_at_mut(self.halves.split());
        let slow = std::mem::take(&mut self.slow);
        let sweep = std::mem::take(&mut self.sweep);
        let stretch_only = std::mem::take(&mut self.stretch_only);
        let stretch = if interval == 1 { &stretch_only } else { &sweep };
        let team = Team::new([&slow, &sweep, stretch], b);
        let substeps = |this: &mut Self, a: &mut [Vec3A]| {
            for s in 0..c.substeps {
                this.substep(s, &team, a);
            }
        };
        if self.parallel && rayon::current_num_threads() > 1 {
            rayon::join(
                || {
                    let _done = team.done_on_drop();
                    substeps(self, a)
                },
                || team.help(),
            );
        } else {
            substeps(self, a);
        }
        self.helper_half_sweeps += u64::from(team.helped.load(Ordering::Acquire));
        // The team, which borrows the sweeps, is done with them: they go back.
        self.slow = slow;
        self.sweep = sweep;
        self.stretch_only = stretch_only;
        self.buf = buf;

        // 3. measure
        let mut max_d2 = 0.0f32;
        let mut ke = 0.0f32;
        let mut finite = true;
        for i in 0..self.x.len() {
            finite &= self.x[i].is_finite();
            max_d2 = max_d2.max(self.x[i].distance_squared(self.x_frame[i]));
            ke += 0.5 * self.model.mass[i] * self.v[i].length_squared();
        }
        FrameStats {
            max_displacement: max_d2.sqrt(),
            kinetic_energy: ke,
            finite,
        }
    }

    /// Substep `s` of a frame (stages 2.1 to 2.4), the sweeps run by `team` on the buffer
    /// whose first half is `a`.
    fn substep(&mut self, s: u32, team: &Team<'_>, a: &mut [Vec3A]) {
        let c = &self.config;
        let (h, vmax, interval) = (c.substep_dt(), c.max_velocity, c.shear_bend_interval());
        let (substeps, stretch_iterations) = (c.substeps, c.stretch_iterations);
        let g = Vec3A::from(c.gravity());
        let damp = (-c.damping * h).exp();
        let h_slow = h * interval as f32;
        let inv_h2_slow = 1.0 / (h_slow * h_slow);
        // 2.1 predict
        let t = Instant::now();
        self.x_before.copy_from_slice(&self.x);
        for ((x, v), w) in self
            .x
            .iter_mut()
            .zip(self.v.iter_mut())
            .zip(&self.model.inv_mass)
        {
            if *w == 0.0 {
                *v = Vec3A::ZERO;
                continue;
            }
            *v += g * h;
            let speed = v.length();
            if speed > vmax {
                *v *= vmax / speed;
            }
            *x += *v * h;
        }
        self.times.predict += t.elapsed().as_secs_f64();

        // 2.2 solve
        let t = Instant::now();
        {
            let mut b = team.b.lock().expect("the helper does not panic");
            self.halves.gather(&self.x, a, &mut b);
        }
        if s.is_multiple_of(interval) {
            // Shear and bending first, so the stretch sweep has the last word before
            // the contacts.
            team.sweep(SLOW, a);
            if !self.model.dihedral.is_empty() {
                let mut b = team.b.lock().expect("the helper does not panic");
                self.halves.scatter(a, &b, &mut self.x);
                self.solve_dihedral(inv_h2_slow);
                self.halves.gather(&self.x, a, &mut b);
            }
        }
        team.sweep(EVERY, a);
        for _ in 1..stretch_iterations {
            team.sweep(STRETCH, a);
        }
        {
            let b = team.b.lock().expect("the helper does not panic");
            self.halves.scatter(a, &b, &mut self.x);
        }
        self.times.solve += t.elapsed().as_secs_f64();

        // 2.3 collide
        let t = Instant::now();
        let (tb, te) = (s as f32 / substeps as f32, (s + 1) as f32 / substeps as f32);
        self.collide(tb, te);
        self.times.collide += t.elapsed().as_secs_f64();

        if self.config.self_collision {
            let t = Instant::now();
            let mut x3: Vec<Vec3> = self.x.iter().map(|p| Vec3::from(*p)).collect();
            self.self_grid.solve(&mut x3, &self.model.inv_mass);
            for (p, q) in self.x.iter_mut().zip(&x3) {
                *p = Vec3A::from(*q);
            }
            self.times.self_collision += t.elapsed().as_secs_f64();
        }

        // 2.4 velocities
        let t = Instant::now();
        for ((v, x), xb) in self.v.iter_mut().zip(&self.x).zip(&self.x_before) {
            *v = (*x - *xb) / h * damp;
        }
        self.times.velocities += t.elapsed().as_secs_f64();
        self.substeps_run += 1;
    }

    /// One sweep over the distance constraints (stage 2.2 without the optional dihedral
    /// constraints), on this thread: the same bits as in a frame on one thread or two.
    pub fn solve_distance(&mut self) {
        self.buf.resize(self.halves.len(), Vec3A::ZERO);
        let split = self.halves.split();
        let (a, b) = self.buf.split_at_mut(split);
        self.halves.gather(&self.x, a, b);
        self.sweep.run(&mut self.buf);
        let (a, b) = self.buf.split_at(split);
        self.halves.scatter(a, b, &mut self.x);
    }

    fn solve_dihedral(&mut self, inv_h2: f32) {
        let m = self.model;
        for range in &m.dihedral_colours {
            for c in &m.dihedral[range.clone()] {
                let p = c.p.map(|i| i as usize);
                let dx = dihedral::solve(
                    c,
                    p.map(|i| Vec3::from(self.x[i])),
                    p.map(|i| m.inv_mass[i]),
                    inv_h2,
                );
                for k in 0..4 {
                    self.x[p[k]] += Vec3A::from(dx[k]);
                }
            }
        }
    }

    /// Pushes this frame's contact particles out to `thickness` along the contact normal at
    /// time `te` of the frame, then removes tangential motion relative to the body up to
    /// `friction` times the push (static) or by that much (kinetic). The push is inelastic
    /// unless `elastic_pushout` is set:
    /// a particle that started the substep inside the thickness leaves it with the body's
    /// normal speed, not with the push over `h` on top. Without that, a few particles
    /// pressed into a crease or between a hand and a thigh bounced in a limit cycle (0.4 to
    /// 4.8 mm a frame for 600 frames, with the contacts unchanged) and their drapes never
    /// came to rest at 20 substeps (session 16: the tube on `random:11`, the jeans on
    /// sample 42).
    ///
    /// A particle in a crease of the body has two planes in the list, its contact's and
    /// the crease's other side's (`SimConfig::crease_contacts`), pushed out of one then
    /// the other in every substep.
    ///
    /// On one thread: splitting the contact list in two halves for the two cores made this
    /// stage 1.8 times slower and the sweep after it slower too (10k T-shirt; a worker woken
    /// every substep, positions' cache lines moving between cores).
    fn collide(&mut self, tb: f32, te: f32) {
        let thickness = self.config.thickness;
        let elastic = self.config.elastic_pushout;
        for (i, p) in &self.active {
            let i = *i as usize;
            let x = &mut self.x[i];
            let q = p.q0.lerp(p.q1, te);
            let n = p.n0.lerp(p.n1, te).normalize_or_zero();
            let d = (*x - q).dot(n);
            if d >= thickness {
                continue;
            }
            let push = thickness - d;
            *x += n * push;
            // The contact point at the substep's start.
            let qb = p.q0.lerp(p.q1, tb);
            let xb = &mut self.x_before[i];
            if !elastic {
                // Inelastic: a particle that began the substep closer than `thickness` is
                // moved out without gaining the outward speed `push / h` that the velocity
                // update would give it, as if it had begun the substep on the surface.
                let db = (*xb - qb).dot(n);
                if db < thickness {
                    *xb += n * (thickness - db);
                }
            }
            // Friction against the body's motion over this substep.
            let rel = (*x - *xb) - (q - qb);
            let tangential = rel - n * rel.dot(n);
            let tl = tangential.length();
            if tl > 0.0 {
                let limit = self.model.friction_of(i) * push;
                *x -= if tl <= limit {
                    tangential
                } else {
                    tangential * (limit / tl)
                };
            }
        }
        // Edge midpoints out of the thin parts: the midpoint moves by the push, each end in
        // proportion to its inverse mass (both by the push when they weigh the same), with
        // the particles' inelastic rule and no friction.
        let w = &self.model.inv_mass;
        for (e, p) in &self.edge_active {
            let [a, b] = self.model.edges[*e as usize].map(|i| i as usize);
            let q = p.q0.lerp(p.q1, te);
            let n = p.n0.lerp(p.n1, te).normalize_or_zero();
            let d = (0.5 * (self.x[a] + self.x[b]) - q).dot(n);
            if d >= thickness {
                continue;
            }
            let share = 2.0 / (w[a] + w[b]);
            let (sa, sb) = (w[a] * share, w[b] * share);
            let push = n * (thickness - d);
            self.x[a] += push * sa;
            self.x[b] += push * sb;
            self.edge_pushes += 1;
            if !elastic {
                let qb = p.q0.lerp(p.q1, tb);
                let db = (0.5 * (self.x_before[a] + self.x_before[b]) - qb).dot(n);
                if db < thickness {
                    let back = n * (thickness - db);
                    self.x_before[a] += back * sa;
                    self.x_before[b] += back * sb;
                }
            }
        }
    }
}

/// What [`detect_one`] searches for.
#[derive(Clone, Copy)]
enum Target<'t> {
    /// A particle: its nearest triangle and, with `creases`, the other side of a crease
    /// it sits in ([`BodyCollider::crease`]), unless either side is one of the `thin`
    /// parts: the small, sharply curved features of hands and feet are no fold a cuff or
    /// a hem rests in (docs/sim.md, "Creases").
    Particle {
        creases: bool,
        thin: Option<&'t ThinParts>,
    },
    /// An edge's midpoint near a group of the thin parts: only a nearest triangle that is
    /// thin counts.
    Edge(&'t ThinParts),
}

/// Contact detection for one point (a particle or an edge's midpoint, `target`) that moves
/// by up to `travel` this frame: the nearest triangle of `body` within `thickness + travel`
/// of it, or the state's last search kept while the body stands still (`still`) and the
/// point stays inside that search's slack (all that is within its reach now was within the
/// radius searched then) or, for a contact, has moved less than half the margin.
fn detect_one(
    body: &BodyCollider,
    target: Target<'_>,
    state: &mut ContactState,
    here: Vec3,
    travel: f32,
    thickness: f32,
    still: bool,
) {
    let margin = body.margin();
    let moved = here.distance(state.searched.0) + travel;
    let keep = match state.plane {
        None => moved + thickness <= state.searched.1 + margin,
        Some(_) => moved <= 0.5 * margin,
    };
    if still && keep {
        // A kept contact may come from a frame in which the body moved; its plane must
        // not replay that motion in every frame of a still body (it kicked resting
        // particles off the body at each frame's start, and they bounced at half the
        // frame rate: the drapes that never came to rest).
        for p in state.plane.iter_mut().chain(&mut state.crease) {
            p.q0 = p.q1;
            p.n0 = p.n1;
        }
        return;
    }
    let radius = thickness + travel;
    // `found`: the nearest triangle; `contact`: the one kept (an edge keeps only a thin
    // one); `crease`: a particle's fold's other side, unless either side is thin.
    let (found, contact, crease) = match target {
        Target::Edge(thin) => {
            let found = body.contact(here, radius);
            (found, found.filter(|c| thin.is_thin(c.tri)), None)
        }
        Target::Particle { creases: false, .. } => {
            let found = body.contact(here, radius);
            (found, found, None)
        }
        Target::Particle {
            creases: true,
            thin,
        } => {
            let (found, crease) = body.contact_and_crease(here, radius);
            let thin_side = |c: &Contact| thin.is_some_and(|t| t.is_thin(c.tri));
            let crease = crease.filter(|c| !thin_side(c) && !found.as_ref().is_some_and(thin_side));
            (found, found, crease)
        }
    };
    let plane = |c: Contact| Plane {
        q0: body.point_at(&c, 0.0).into(),
        q1: body.point_at(&c, 1.0).into(),
        n0: body.normal_at(&c, 0.0).into(),
        n1: body.normal_at(&c, 1.0).into(),
    };
    state.plane = contact.map(plane);
    state.crease = crease.map(plane);
    // A contact turned down because its triangle is not thin says nothing about the thin
    // triangles a little farther away: that search is not reused.
    let reusable = found.is_none() || contact.is_some();
    state.searched = (here, if reusable { radius } else { f32::NAN });
}

/// Which of a frame's sweeps a job is: shear and bending (when they run apart), the sweep of
/// every substep, the extra stretch sweeps.
const SLOW: u32 = 0;
const EVERY: u32 = 1;
const STRETCH: u32 = 2;

/// The sweeps of one frame's substeps, shared by the thread that runs the frame and a
/// helper. For each sweep the frame's thread posts a job, solves half 0, then solves half 1
/// too unless the helper has claimed it first (if so it waits for it), then the joins. So
/// the halves of a sweep run at once when a second thread is free, and one after the other
/// otherwise, with the same bits. The helper spins between jobs: a rayon join per sweep
/// cost more than the half it would save (a parked worker takes tens of microseconds to
/// wake; a half-sweep of the 10k tube's stretch constraints takes about 35).
struct Team<'s> {
    /// The sweeps, by job kind.
    sweeps: [&'s SplitSweep; 3],
    /// Half 1 of the buffer.
    b: Mutex<&'s mut [Vec3A]>,
    /// The last job posted: its number (from 1) times 4 plus its kind.
    posted: AtomicU32,
    /// Number of the last job whose half 1 a thread has claimed.
    claimed: AtomicU32,
    /// Number of the last job whose half 1 is solved.
    solved: AtomicU32,
    /// Set when the frame's substeps are over: the helper returns.
    over: AtomicBool,
    /// Set if the helper panicked: the frame's thread stops waiting for it and panics too.
    failed: AtomicBool,
    /// Half-sweeps the helper solved.
    helped: AtomicU32,
    /// Number of the frame thread's last job (only that thread writes it).
    jobs: AtomicU32,
}

/// Spins, and after [`SPINS_BEFORE_YIELD`] calls also yields the thread's time slice (the
/// other thread may have been descheduled).
fn backoff(count: &mut u32) {
    *count = count.saturating_add(1);
    if *count > SPINS_BEFORE_YIELD {
        std::thread::yield_now();
    } else {
        std::hint::spin_loop();
    }
}

/// Spins of a waiting team thread before it starts yielding (a few tens of microseconds:
/// longer than a half-sweep of the 10k tube's stretch constraints).
const SPINS_BEFORE_YIELD: u32 = 1 << 14;

/// Sets its flag if dropped while its thread panics.
struct Failed<'a>(&'a AtomicBool);

impl Drop for Failed<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.store(true, Ordering::Release);
        }
    }
}

/// Ends a team's help when dropped (also if the substeps panic).
struct Over<'t, 's>(&'t Team<'s>);

impl Drop for Over<'_, '_> {
    fn drop(&mut self) {
        self.0.over.store(true, Ordering::Release);
    }
}

impl<'s> Team<'s> {
    fn new(sweeps: [&'s SplitSweep; 3], b: &'s mut [Vec3A]) -> Self {
        Self {
            sweeps,
            b: Mutex::new(b),
            posted: AtomicU32::new(0),
            claimed: AtomicU32::new(0),
            solved: AtomicU32::new(0),
            over: AtomicBool::new(false),
            failed: AtomicBool::new(false),
            helped: AtomicU32::new(0),
            jobs: AtomicU32::new(0),
        }
    }

    /// A guard that ends the help when dropped.
    fn done_on_drop(&self) -> Over<'_, 's> {
        Over(self)
    }

    /// Solves half 1 of job `posted`.
    fn solve_half_1(&self, posted: u32) {
        let mut b = self
            .b
            .lock()
            .expect("the frame's thread does not panic holding it");
        self.sweeps[(posted & 3) as usize].run_half(1, &mut b);
        drop(b);
        self.solved.store(posted >> 2, Ordering::Release);
    }

    /// The helper: claims and solves half 1 of each job posted until the substeps are over.
    /// It spins between jobs, and yields its time slice after a while without one (the
    /// collision stage of a substep).
    fn help(&self) {
        let _flag = Failed(&self.failed);
        let mut idle = 0u32;
        while !self.over.load(Ordering::Acquire) {
            let posted = self.posted.load(Ordering::Acquire);
            let job = posted >> 2;
            if job > 0
                && self
                    .claimed
                    .compare_exchange(job - 1, job, Ordering::AcqRel, Ordering::Acquire)
                    .is_ok()
            {
                self.solve_half_1(posted);
                self.helped.fetch_add(1, Ordering::Relaxed);
                idle = 0;
            } else {
                backoff(&mut idle);
            }
        }
    }

    /// One sweep of kind `kind` (the frame's thread), half 0 of the buffer being `a`.
    fn sweep(&self, kind: u32, a: &mut [Vec3A]) {
        let sweep = self.sweeps[kind as usize];
        if sweep.is_empty() {
            return;
        }
        let job = self.jobs.fetch_add(1, Ordering::Relaxed) + 1;
        let posted = (job << 2) | kind;
        self.posted.store(posted, Ordering::Release);
        sweep.run_half(0, a);
        if self
            .claimed
            .compare_exchange(job - 1, job, Ordering::AcqRel, Ordering::Acquire)
            .is_ok()
        {
            self.solve_half_1(posted);
        } else {
            let mut waited = 0u32;
            while self.solved.load(Ordering::Acquire) < job {
                assert!(
                    !self.failed.load(Ordering::Acquire),
                    "the sweeps' helper thread panicked"
                );
                backoff(&mut waited);
            }
        }
        let mut b = self.b.lock().expect("the helper does not panic");
        sweep.run_joins(a, &mut b);
    }
}

/// The distance constraints of `model` whose kind passes `keep`, prepared for substeps of
/// length `h` and grouped for the sweep (a colour's subset is still independent).
fn prepare(model: &ClothModel, h: f32, halves: &Halves, keep: impl Fn(Kind) -> bool) -> SplitSweep {
    let (w, inv_h2) = (&model.inv_mass, 1.0 / (h * h));
    let mut prepared = Vec::with_capacity(model.distance.len());
    let mut colours = Vec::with_capacity(model.distance_colours.len());
    for range in &model.distance_colours {
        let start = prepared.len();
        for k in range.clone() {
            if keep(model.distance_kind[k]) {
                let c = &model.distance[k];
                prepared.push(Prepared::new(c, w[c.i as usize], w[c.j as usize], inv_h2));
            }
        }
        colours.push(start..prepared.len());
    }
    SplitSweep::new(&prepared, &colours, halves)
}

/// The sweeps of a solver for `config`'s substep: (every substep, slow, stretch only).
fn sweeps(
    model: &ClothModel,
    config: &SimConfig,
    halves: &Halves,
) -> (SplitSweep, SplitSweep, SplitSweep) {
    let h = config.substep_dt();
    let interval = config.shear_bend_interval();
    let (sweep, slow) = if interval == 1 {
        (prepare(model, h, halves, |_| true), SplitSweep::default())
    } else {
        (
            prepare(model, h, halves, |k| k == Kind::Stretch),
            prepare(model, h * interval as f32, halves, |k| k != Kind::Stretch),
        )
    };
    let stretch_only = if config.stretch_iterations > 1 && interval == 1 {
        prepare(model, h, halves, |k| k == Kind::Stretch)
    } else {
        SplitSweep::default()
    };
    (sweep, slow, stretch_only)
}
