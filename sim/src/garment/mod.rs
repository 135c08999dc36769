//! Garment templates: built-in garments cut from MakeHuman's CC0 helper meshes, user
//! templates imported from OBJ, skinning weights transferred from the body, and the DQS warp
//! `M = dqs(M0, body)`.
//!
//! - `def.rs`: the definitions in `configs/garments/*.toml`;
//! - `cut.rs`: plane cuts and the stitching of two openings;
//! - `build.rs`: definition to relaxed mesh;
//! - `skin.rs`: bindings to the body and weight transfer;
//! - `template.rs`: the stored template and the warp.
//!
//! Built templates are cached in `<assets>/garments/built/` (not committed; rebuilt when the
//! definition, the helper meshes or the build code change), imported ones are kept in
//! `<assets>/garments/user/`.

pub mod build;
pub mod cut;
pub mod def;
pub mod skin;
pub mod template;

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use crate::body::{BodyError, BodyModel, ShapeParams, ShapedBody};
use crate::cloth::collision::BodyCollider;
use crate::cloth::{SimConfig, SimError};
use crate::mesh::{MeshError, TriMesh, remesh};
pub use def::GarmentDef;
pub use template::Template;

/// The garments' source meshes, relative to the assets folder (written by `drape body import`).
pub const HELPERS_FILE: &str = "garments/source/makehuman-helpers.obj";

/// Bumped whenever the build steps change, so cached templates are rebuilt. 5: the
/// solver's sweeps in two halves (the relaxation's result moves by float noise).
pub const BUILD_VERSION: u32 = 5;

/// Bumped whenever grading changes, so cached sizes are graded again (the base templates
/// stay). 2: no push-out to the clearance and no gravity in the grading relaxation.
pub const GRADE_VERSION: u32 = 2;

/// The vertex count of the CPU-training variant of the built-in garments.
pub const LOW_RESOLUTION: usize = 3_000;

/// Why a garment could not be built, imported or loaded.
#[derive(Debug, thiserror::Error)]
pub enum GarmentError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
    /// The helper meshes file is malformed.
    #[error("garment source {path}: {reason}")]
    Source {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A stored template is malformed.
    #[error("garment template {path} is corrupt: {reason}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A definition is wrong or cannot be built.
    #[error("garment definition: {0}")]
    Definition(String),
    /// No garment of that name.
    #[error("no garment named {name:?}; built-in: tshirt, sweater, dress, jeans{user}")]
    Unknown {
        /// The name asked for.
        name: String,
        /// Imported garments, listed for the message.
        user: String,
    },
    /// An imported mesh is not a usable garment.
    #[error("cannot import {path} as a garment: {reason}")]
    Rejected {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A mesh problem.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// A body problem.
    #[error(transparent)]
    Body(#[from] BodyError),
    /// A simulator problem.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// Writing a template failed (nothing was written).
    #[error(transparent)]
    Write(#[from] crate::io::WriteError),
}

/// The definition of a built-in garment.
pub fn built_in(name: &str) -> Option<GarmentDef> {
    def::BUILT_IN
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(n, text)| {
            GarmentDef::from_toml(text, &format!("configs/garments/{n}.toml"))
                .expect("built-in definitions parse (tested)")
        })
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Skins a mesh on the canonical body: bindings and weights (parts restricted to bones), the
/// `split` bones' division averaged over its reach (m; [`skin::smoothing_rounds`]).
fn skin_mesh(
    mesh: TriMesh,
    canonical: &ShapedBody<'_>,
    only: &[Vec<u16>],
    split: Option<([u16; 2], f32)>,
) -> (
    TriMesh,
    crate::body::skinning::SkinWeights,
    Vec<skin::Binding>,
) {
    let model = canonical.model;
    let collider = BodyCollider::new(&canonical.vertices, &model.triangles, 0.01);
    let bindings = skin::bind(&mesh.vertices, &collider);
    let weights = skin::transfer_weights(
        &mesh,
        &bindings,
        &model.triangles,
        &model.skin,
        model.skeleton.len(),
        only,
        split.map(|(bones, reach)| (bones, skin::smoothing_rounds(&mesh, reach))),
    );
    (mesh, weights, bindings)
}

/// Builds a built-in (or any) definition into a template at about `vertices` vertices.
pub fn build_template(
    def: &GarmentDef,
    helpers_path: &Path,
    canonical: &ShapedBody<'_>,
    vertices: usize,
    key: String,
) -> Result<Template, GarmentError> {
    let helpers = build::read_helpers(helpers_path)?;
    // The template comes to rest with its own fabric's friction.
    let default = SimConfig::default();
    let config = SimConfig {
        friction: def.friction().unwrap_or(default.friction),
        ..default
    };
    // The split's bones first: a misspelt name fails before the build's relaxation.
    let split = match def.split() {
        None => None,
        Some(sp) => {
            let mut bones = [0u16; 2];
            for (b, n) in bones.iter_mut().zip(&sp.bones) {
                *b = canonical
                    .model
                    .skeleton
                    .index(n)
                    .map(|i| i as u16)
                    .ok_or_else(|| {
                        GarmentError::Definition(format!(
                            "{}: skinning split: no bone named {n}",
                            def.name
                        ))
                    })?;
            }
            Some((bones, sp.reach))
        }
    };
    let built = build::build(def, &helpers, canonical, &config, vertices, true)?;
    let parts = build::part_of(def, canonical, &built.mesh.vertices)?;
    let skeleton = &canonical.model.skeleton;
    let mut restricted: Vec<Vec<u16>> = Vec::new();
    for p in &def.parts {
        let list = match &p.bones {
            None => Vec::new(),
            Some(names) => names
                .iter()
                .map(|n| {
                    skeleton.index(n).map(|i| i as u16).ok_or_else(|| {
                        GarmentError::Definition(format!("{}: no bone named {n}", def.name))
                    })
                })
                .collect::<Result<_, _>>()?,
        };
        restricted.push(list);
    }
    let only: Vec<Vec<u16>> = parts
        .iter()
        .map(|&p| restricted[p as usize].clone())
        .collect();
    let (mesh, skin, bindings) = skin_mesh(built.mesh, canonical, &only, split);
    let a = built.angles;
    Ok(Template {
        meta: template::TemplateMeta {
            format: template::FORMAT.to_string(),
            name: def.name.clone(),
            origin: "built-in".into(),
            resolution: vertices,
            key,
            size: None,
            friction: def.friction(),
            below_band: def.below_band(),
            substeps: def.substeps(),
            crease_contacts: def.crease_contacts(),
            build: serde_json::json!({
                "vertices": mesh.vertices.len(),
                "triangles": mesh.triangles.len(),
                "target_edge_m": built.edge,
                "min_angle_deg": a.min_deg,
                "min_angle_p1_deg": a.p1_deg,
                "share_below_20_deg": a.share_below_20,
                "degenerate": a.degenerate,
                "relax_frames": built.relax_frames,
                "relaxed": built.relaxed,
                "relax_strain_p95": built.relax_strain_p95,
                "seconds": built.seconds,
            }),
        },
        mesh,
        skin,
        bindings,
        shape_moves: Default::default(),
    })
}

/// Where templates live and how they are found.
#[derive(Debug, Clone)]
pub struct Library {
    /// The assets folder.
    pub assets: PathBuf,
}

impl Library {
    /// The library of an assets folder.
    pub fn new(assets: &Path) -> Self {
        Self {
            assets: assets.to_path_buf(),
        }
    }

    fn helpers(&self) -> PathBuf {
        self.assets.join(HELPERS_FILE)
    }

    /// Cache file of a built-in garment at a resolution.
    pub fn built_path(&self, name: &str, vertices: usize) -> PathBuf {
        self.assets
            .join("garments/built")
            .join(format!("{name}-{vertices}.safetensors"))
    }

    /// Cache file of one of a graded built-in garment's other sizes.
    pub fn size_path(&self, name: &str, vertices: usize, size: &str) -> PathBuf {
        self.assets
            .join("garments/built")
            .join(format!("{name}-{vertices}-{size}.safetensors"))
    }

    /// File of an imported garment.
    pub fn user_path(&self, name: &str) -> PathBuf {
        self.assets
            .join("garments/user")
            .join(format!("{name}.safetensors"))
    }

    /// Names of the imported garments.
    pub fn user_names(&self) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(self.assets.join("garments/user"))
            .into_iter()
            .flatten()
            .flatten()
            .filter_map(|e| {
                e.file_name()
                    .to_str()?
                    .strip_suffix(".safetensors")
                    .map(str::to_string)
            })
            .collect();
        names.sort();
        names
    }

    /// The cache key of a built-in definition: its text, the helper meshes, the build code.
    pub fn key(&self, text: &str) -> Result<String, GarmentError> {
        let path = self.helpers();
        let helpers = std::fs::read(&path).map_err(|source| GarmentError::Io { path, source })?;
        let mut h = Sha256::new();
        h.update(text.as_bytes());
        h.update(&helpers);
        h.update(BUILD_VERSION.to_le_bytes());
        Ok(hex(&h.finalize()))
    }

    /// Builds a built-in garment (no cache).
    pub fn build(
        &self,
        name: &str,
        vertices: usize,
        canonical: &ShapedBody<'_>,
    ) -> Result<Template, GarmentError> {
        let (_, text) = def::BUILT_IN
            .iter()
            .find(|(n, _)| *n == name)
            .ok_or_else(|| self.unknown(name))?;
        let def = GarmentDef::from_toml(text, &format!("configs/garments/{name}.toml"))
            .map_err(GarmentError::Definition)?;
        build_template(&def, &self.helpers(), canonical, vertices, self.key(text)?)
    }

    fn unknown(&self, name: &str) -> GarmentError {
        let user = self.user_names();
        GarmentError::Unknown {
            name: name.to_string(),
            user: if user.is_empty() {
                String::new()
            } else {
                format!("; imported: {}", user.join(", "))
            },
        }
    }

    /// Whether built-in garment `name`'s cached template at `vertices` is current: it
    /// loads and was built from today's definition and build code (else [`Self::get`]
    /// builds it again).
    pub fn is_current(&self, name: &str, vertices: usize, model: &BodyModel) -> bool {
        def::BUILT_IN
            .iter()
            .find(|(n, _)| *n == name)
            .is_some_and(|(_, text)| {
                matches!(self.cached(name, text, vertices, model), Ok(Some(_)))
            })
    }

    /// Built-in garment `name`'s (definition `text`) cached template at `vertices`, if it
    /// loads and its key is today's.
    fn cached(
        &self,
        name: &str,
        text: &str,
        vertices: usize,
        model: &BodyModel,
    ) -> Result<Option<Template>, GarmentError> {
        let key = self.key(text)?;
        Ok(Template::load(
            &self.built_path(name, vertices),
            model.triangles.len(),
            model.skeleton.len(),
        )
        .ok()
        .filter(|t| t.meta.key == key))
    }

    /// A garment by name: a built-in one at `vertices` (from the cache, built and cached on
    /// first use) or an imported one. `built` is told when a build happens (it takes seconds).
    pub fn get(
        &self,
        name: &str,
        vertices: usize,
        model: &BodyModel,
        built: &mut dyn FnMut(&str),
    ) -> Result<Template, GarmentError> {
        let bones = model.skeleton.len();
        let tris = model.triangles.len();
        if let Some((_, text)) = def::BUILT_IN.iter().find(|(n, _)| *n == name) {
            if let Some(t) = self.cached(name, text, vertices, model)? {
                return Ok(t);
            }
            let path = self.built_path(name, vertices);
            built(&format!(
                "building {name} at {vertices} vertices (cached in {})",
                path.display()
            ));
            let canonical = model.shape(&Default::default())?;
            let t = self.build(name, vertices, &canonical)?;
            store(&t, &path)?;
            return Ok(t);
        }
        let path = self.user_path(name);
        if path.exists() {
            return Template::load(&path, tris, bones);
        }
        Err(self.unknown(name))
    }

    /// A garment in a size: the base size is [`Self::get`]'s template; another size of a
    /// graded built-in garment is that template graded to the size's reference body (cached
    /// like the base, built on first use).
    pub fn get_size(
        &self,
        name: &str,
        vertices: usize,
        size: &str,
        model: &BodyModel,
        built: &mut dyn FnMut(&str),
    ) -> Result<Template, GarmentError> {
        let def = built_in(name);
        let grading = def.as_ref().and_then(|d| d.grading.as_ref());
        let base = def
            .as_ref()
            .map_or(def::DEFAULT_BASE_SIZE, |d| d.base_size());
        if size == base {
            return self.get(name, vertices, model, built);
        }
        let known = def.as_ref().map_or_else(
            || vec![def::DEFAULT_BASE_SIZE.to_string()],
            |d| d.size_names(),
        );
        let (Some(def), Some(sdef)) = (
            def.as_ref(),
            grading.and_then(|g| g.sizes.iter().find(|s| s.name == size)),
        ) else {
            return Err(GarmentError::Definition(format!(
                "{name} has no size {size:?}; its sizes: {}",
                known.join(", ")
            )));
        };
        let text = def::BUILT_IN
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, t)| *t)
            .expect("a built-in definition");
        let key = format!("{}-grade{GRADE_VERSION}", self.key(text)?);
        let path = self.size_path(name, vertices, size);
        if path.exists()
            && let Ok(t) = Template::load(&path, model.triangles.len(), model.skeleton.len())
            && t.meta.key == key
        {
            return Ok(t);
        }
        let base = self.get(name, vertices, model, built)?;
        built(&format!(
            "grading {name} at {vertices} vertices to size {size} (cached in {})",
            path.display()
        ));
        let mut t = grade(&base, def, sdef, model)?;
        t.meta.key = key;
        store(&t, &path)?;
        Ok(t)
    }

    /// The size chart of a garment: each size's reference measurements (`None` for a garment
    /// that is not graded: it has one size).
    pub fn size_chart(
        &self,
        name: &str,
        model: &BodyModel,
    ) -> Result<Option<SizeChart>, GarmentError> {
        let Some(g) = built_in(name).and_then(|d| d.grading) else {
            return Ok(None);
        };
        let mut sizes = vec![(g.base.clone(), ShapeParams::default())];
        sizes.extend(g.sizes.iter().map(|s| (s.name.clone(), s.shape)));
        let sizes = sizes
            .into_iter()
            .map(|(n, shape)| {
                let body = model.shape(&shape)?;
                Ok((n, measure(&body, &g.by)?))
            })
            .collect::<Result<Vec<_>, GarmentError>>()?;
        Ok(Some(SizeChart {
            by: g.by,
            sizes,
            rule: PickRule::V2,
        }))
    }

    /// Imports a user's OBJ as garment `name` (see [`import_mesh`]) and stores it.
    /// `friction` is the garment's own friction against the body (`None`: the simulator
    /// config's), as a built-in definition's `[material]` gives it. An imported garment of
    /// the same name is replaced only with `replace`: runs and datasets name their garment,
    /// and would warp the new mesh.
    pub fn import(
        &self,
        obj: &Path,
        name: &str,
        friction: Option<f32>,
        model: &BodyModel,
        replace: bool,
    ) -> Result<(Template, PathBuf), GarmentError> {
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            return Err(GarmentError::Rejected {
                path: obj.to_path_buf(),
                reason: format!("name {name:?}: use letters, digits, - and _"),
            });
        }
        if built_in(name).is_some() || name == "tube" {
            return Err(GarmentError::Rejected {
                path: obj.to_path_buf(),
                reason: format!("{name} is a built-in garment; choose another name"),
            });
        }
        if !replace && self.user_path(name).exists() {
            return Err(GarmentError::Rejected {
                path: obj.to_path_buf(),
                reason: format!(
                    "a garment named {name} is imported already ({}); choose another name, or pass --force to replace it (runs and datasets of the old one would then warp the new mesh)",
                    self.user_path(name).display()
                ),
            });
        }
        if let Some(mu) = friction {
            def::check_friction(mu).map_err(|reason| GarmentError::Rejected {
                path: obj.to_path_buf(),
                reason,
            })?;
        }
        let mesh = TriMesh::read_obj(obj)?.in_first_use_order();
        let canonical = model.shape(&Default::default())?;
        let mut t = import_mesh(mesh, name, obj, &canonical)?;
        t.meta.friction = friction;
        let path = self.user_path(name);
        store(&t, &path)?;
        Ok((t, path))
    }
}

/// How a size is picked from a body's measurements ([`SizeChart::pick`]): the sum over the
/// measurements of the squared `body / reference - 1`, a measurement where the size is too
/// small counting more than one where it is too large (a tight garment strains, a loose
/// one only hangs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PickRule {
    /// Before session 26: a size too small counts 4 times, height included. The datasets
    /// made before then keep it (the reproduction's `cpu-repro-*` did until session 53).
    V1,
    /// Since session 26: a girth too small counts 10 times, a height too small 4 times as
    /// before. Under V1 a heavy woman (hips 1.005 m) wore the dress size whose hips
    /// measure 0.980 m, picked for its height over the next size (hips 1.017 m), and her
    /// drape was stretched round the hips (p95 3.20%; 2.24% in the larger size). Counting
    /// height 10 times too put a 1.63 m woman in a size made for 1.71 m, whose 3k
    /// sweater's collar folded and caught; counting it once put a 1.78 m man in M, made
    /// for 1.66 m, whose 3k sweater did not come to rest (docs/garments.md, "Sizes").
    V2,
}

impl PickRule {
    /// The rule's number in dataset configs (`size_pick`).
    pub fn number(self) -> u32 {
        match self {
            Self::V1 => 1,
            Self::V2 => 2,
        }
    }

    /// The rule of a number (`None` if there is none).
    pub fn from_number(n: u32) -> Option<Self> {
        match n {
            1 => Some(Self::V1),
            2 => Some(Self::V2),
            _ => None,
        }
    }

    /// How much a relative difference `d = body / reference - 1` of measurement `name`
    /// counts.
    fn misfit(self, name: &str, d: f32) -> f32 {
        let tight = match self {
            Self::V1 => 4.0,
            Self::V2 if name == "height" => 4.0,
            Self::V2 => 10.0,
        };
        d * d * if d > 0.0 { tight } else { 1.0 }
    }
}

/// A graded garment's size chart: the measurements that choose a size and each size's
/// reference values.
#[derive(Debug, Clone, PartialEq)]
pub struct SizeChart {
    /// Measurement names (`chest`, `waist`, `hips`, `height`).
    pub by: Vec<String>,
    /// Size name and its reference body's measurements (m), in the order of `by`.
    pub sizes: Vec<(String, Vec<f32>)>,
    /// How the size is picked ([`PickRule::V2`] unless set).
    pub rule: PickRule,
}

impl SizeChart {
    /// The chart picking by another rule (a dataset's `size_pick`).
    pub fn with_rule(mut self, rule: PickRule) -> Self {
        self.rule = rule;
        self
    }

    /// The size a body wears: the one whose reference measurements are closest in relative
    /// terms by the chart's [`PickRule`] (the first size on ties), with the body's
    /// measurements.
    pub fn pick(&self, body: &ShapedBody<'_>) -> Result<(String, Vec<f32>), GarmentError> {
        let m = measure(body, &self.by)?;
        let misfit = |r: &[f32]| -> f32 {
            m.iter()
                .zip(r)
                .zip(&self.by)
                .map(|((b, r), name)| self.rule.misfit(name, b / r - 1.0))
                .sum::<f32>()
        };
        let best = self
            .sizes
            .iter()
            .min_by(|a, b| misfit(&a.1).total_cmp(&misfit(&b.1)))
            .expect("a chart has sizes");
        Ok((best.0.clone(), m))
    }
}

/// A body's measurements by name (tape girths and height, m).
pub fn measure(body: &ShapedBody<'_>, by: &[String]) -> Result<Vec<f32>, GarmentError> {
    let girths = body.girths()?;
    by.iter()
        .map(|m| match m.as_str() {
            "height" => Ok(body.height()),
            girth => girths.get(girth).ok_or_else(|| {
                GarmentError::Definition(format!(
                    "unknown measurement {girth:?}; measurements are {}",
                    def::SIZE_MEASUREMENTS.join(", ")
                ))
            }),
        })
        .collect()
}

/// One size of a graded garment: the base template carried to the size's reference body
/// (the warp's shape transfer, so the ease follows the body), any vertex inside that body
/// moved onto its surface, and relaxed there without gravity (the base already hangs).
/// Topology, skinning and bindings are the base's, so every size has the same vertices and
/// faces.
pub fn grade(
    base: &Template,
    def: &GarmentDef,
    size: &def::SizeDef,
    model: &BodyModel,
) -> Result<Template, GarmentError> {
    let t0 = std::time::Instant::now();
    let canonical = model.shape(&ShapeParams::default())?;
    let reference = model.shape(&size.shape)?;
    let mut mesh = base.mesh.clone();
    // Bit for bit the reshape every size was graded with before session 48.
    mesh.vertices = base.reshape_by_smoothing(&canonical, &reference);
    // Only vertices inside the body are moved out (onto its surface), and the relaxation
    // runs without gravity: the base template already hangs as it does under gravity and
    // sits where the body holds it. Pushing it out to the build's clearance and letting it
    // sag again would loosen it with every grading: the jeans graded to the canonical body
    // itself had a 4.4% longer waistband (0.849 m against 0.813 m) and slid 45 cm down the
    // body where the base size holds (docs/garments.md, "Sizes").
    let relaxed = build::settle(
        &mut mesh,
        &reference,
        0.0,
        &SimConfig {
            gravity: [0.0; 3],
            friction: base.friction(&SimConfig::default()),
            ..SimConfig::default()
        },
        true,
        true,
        &def.name,
    )?;
    let mut meta = base.meta.clone();
    meta.size = Some(template::SizeMeta {
        name: size.name.clone(),
        reference: size.shape,
    });
    meta.build = serde_json::json!({
        "graded_from": def.grading.as_ref().map(|g| g.base.clone()),
        "vertices": mesh.vertices.len(),
        "triangles": mesh.triangles.len(),
        "relax_frames": relaxed.frames,
        "relaxed": relaxed.converged,
        "relax_strain_p95": relaxed.strain_p95,
        "seconds": t0.elapsed().as_secs_f64(),
    });
    Ok(Template {
        meta,
        mesh,
        skin: base.skin.clone(),
        bindings: base.bindings.clone(),
        shape_moves: Default::default(),
    })
}

/// Writes a template file, creating its folder.
fn store(t: &Template, path: &Path) -> Result<(), GarmentError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| GarmentError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    crate::io::write_all_or_nothing(&[(path, &t.encode())])?;
    Ok(())
}

/// Checks a user's garment mesh on the canonical body and skins it: manifold edges, no
/// degenerate faces, a plausible size (0.1 to 2.5 m across), placed around the body, no
/// vertex inside the body at any depth and no edge through it. `path` names it in errors.
pub fn import_mesh(
    mesh: TriMesh,
    name: &str,
    path: &Path,
    canonical: &ShapedBody<'_>,
) -> Result<Template, GarmentError> {
    let reject = |reason: String| GarmentError::Rejected {
        path: path.to_path_buf(),
        reason,
    };
    crate::cloth::model::validate_mesh(&mesh).map_err(reject)?;
    let stats = remesh::angle_stats(&mesh);
    if stats.degenerate > 0 {
        return Err(reject(format!("{} degenerate triangles", stats.degenerate)));
    }
    let (lo, hi) = crate::mesh::bounds(&mesh.vertices).expect("validated: not empty");
    let size = (hi - lo).max_element();
    if !(0.1..=2.5).contains(&size) {
        return Err(reject(format!(
            "it is {size:.3} units across; garments are 0.1 to 2.5 m (is the OBJ in metres?)"
        )));
    }
    let collider = BodyCollider::new(&canonical.vertices, &canonical.model.triangles, 0.01);
    crate::cloth::drape::check_placement(&collider, &mesh.vertices)
        .map_err(|e| reject(e.to_string()))?;
    // Inside at any depth, as the simulator's verification counts it.
    let inside = crate::cloth::drape::penetration(&collider, &mesh.vertices).count;
    if inside > 0 {
        return Err(reject(format!(
            "{inside} vertices lie inside the canonical body in its rest pose; the template must be outside it"
        )));
    }
    // Cloth across a limb or the torso: both ends of an edge outside, its point at a
    // quarter, half or three quarters inside deeper than the simulator lets a drape's
    // edge go (`max_edge_penetration`, 5 mm). A shallower chord is what a coarse mesh
    // lying on the body's curves makes (1.7 mm on the 800-vertex dress), not a crossing.
    let limit = SimConfig::default().max_edge_penetration;
    let through = crate::cloth::drape::edges_through_body(
        &collider,
        &mesh.edges(),
        &mesh.vertices,
        limit,
        true,
    );
    if let Some(deepest) = through.iter().map(|e| e.depth).reduce(f32::max) {
        return Err(reject(format!(
            "{} edges pass through the canonical body in its rest pose (the deepest {:.1} mm inside); the template must be outside it",
            through.len(),
            deepest * 1e3
        )));
    }
    let (mesh, skin, bindings) = skin_mesh(mesh, canonical, &[], None);
    Ok(Template {
        meta: template::TemplateMeta {
            format: template::FORMAT.to_string(),
            name: name.to_string(),
            origin: "imported".into(),
            resolution: 0,
            key: String::new(),
            size: None,
            friction: None,
            below_band: None,
            substeps: None,
            crease_contacts: false,
            build: serde_json::json!({
                "source": path.display().to_string(),
                "vertices": mesh.vertices.len(),
                "triangles": mesh.triangles.len(),
                "min_angle_deg": stats.min_deg,
                "share_below_20_deg": stats.share_below_20,
            }),
        },
        mesh,
        skin,
        bindings,
        shape_moves: Default::default(),
    })
}
