//! The garment a dataset drapes. Its base template is the network's `M0` (stored in
//! `static.safetensors`; every sample's warp `M` is the base template's). A config with
//! `sizes = true` drapes each body in the size its measurements pick from a graded
//! garment's chart: the drape starts from that size's template on its reference body, and
//! the size's name goes into the sample's record. The sizes share the base template's
//! topology, so the shards and the network are the same either way; the size is a function
//! of the body's shape, which the network sees.

use sim::body::{BodyModel, ShapeParams, ShapedBody};
use sim::cloth::ClothModel;
use sim::garment::template::Template;
use sim::garment::{Library, SizeChart};

use std::collections::BTreeMap;

use crate::DatasetError;
use crate::config::DatasetConfig;

/// One size: its template, cooked for the dataset's simulator config.
#[derive(Debug)]
pub struct Size {
    /// Size name (`M`, `men-L`, ...).
    pub name: String,
    /// The base template graded to the size's reference body.
    pub template: Template,
    /// The template cooked for the simulator.
    pub cloth: ClothModel,
}

/// Where a drape starts: the size's template on its reference body.
#[derive(Debug)]
pub struct Start<'a> {
    /// Size name (`None`: the dataset does not use sizes).
    pub size: Option<&'a str>,
    /// The template the drape starts from.
    pub template: &'a Template,
    /// It, cooked.
    pub cloth: &'a ClothModel,
    /// The body shape the template is made for: the drape's body morph starts there.
    pub reference: ShapeParams,
}

/// The base template and, with sizes, every size and the chart.
#[derive(Debug)]
pub struct Wardrobe {
    /// The base template (the network's `M0`).
    pub base: Template,
    base_cloth: ClothModel,
    /// The base template's top opening (`Template::top_opening`; every size shares it).
    top: Vec<u32>,
    sizes: Option<(SizeChart, Vec<Size>)>,
}

impl Wardrobe {
    /// The wardrobe of dataset `config` whose base template is `base`: with `sizes`, also
    /// every size of the graded garment at the config's resolution (graded and cached in
    /// `assets` on first use; `built` hears of each build). Every template is cooked for the
    /// config's simulator.
    pub fn new(
        base: Template,
        config: &DatasetConfig,
        model: &BodyModel,
        assets: &std::path::Path,
        built: &mut dyn FnMut(&str),
    ) -> Result<Self, DatasetError> {
        let (garment, sim) = (&config.garment, &config.sim);
        let base_cloth = base.cloth(sim)?;
        let sizes = if config.sizes {
            let lib = Library::new(assets);
            let Some(chart) = lib.size_chart(garment, model)? else {
                return Err(DatasetError::Invalid(format!(
                    "sizes = true, but garment {garment} is not graded (configs/garments/{garment}.toml has no [grading]); remove sizes or pick a graded garment"
                )));
            };
            let mut v = Vec::new();
            for (name, _) in &chart.sizes {
                let template = lib.get_size(garment, config.resolution, name, model, built)?;
                if template.mesh.triangles != base.mesh.triangles {
                    return Err(DatasetError::Invalid(format!(
                        "size {name} of {garment} does not share the base template's triangles"
                    )));
                }
                let cloth = template.cloth(sim)?;
                v.push(Size {
                    name: name.clone(),
                    template,
                    cloth,
                });
            }
            let rule = sim::garment::PickRule::from_number(config.size_pick).ok_or_else(|| {
                DatasetError::Invalid(format!("size_pick = {} is no rule", config.size_pick))
            })?;
            Some((chart.with_rule(rule), v))
        } else {
            None
        };
        Ok(Self {
            top: base.top_opening(),
            base,
            base_cloth,
            sizes,
        })
    }

    /// The garment's top opening, to judge whether a drape slid down the body
    /// (`DrapeResult::judge_slide`).
    pub fn top_opening(&self) -> &[u32] {
        &self.top
    }

    /// Friction between the garment and the body its drapes run with (every size shares
    /// the base template's material).
    pub fn friction(&self) -> f32 {
        self.base_cloth.friction
    }

    /// The garment's friction below a band along its top opening (its definition's
    /// `[material] below_band`), shared by every size.
    pub fn below_band(&self) -> Option<sim::garment::def::BelowBand> {
        self.base.meta.below_band
    }

    /// The garment's own substeps a frame (its definition's `[simulation]`; `None`: the
    /// simulator config's), shared by every size.
    pub fn substeps(&self) -> Option<u32> {
        self.base_cloth.substeps
    }

    /// Whether the garment takes crease contacts when the simulator config leaves them
    /// unset (its definition's `[simulation]`), shared by every size.
    pub fn crease_contacts(&self) -> bool {
        self.base_cloth.crease_contacts
    }

    /// Each size's sha256 of its template's vertex positions (f32 little-endian; empty
    /// without sizes): what the manifest records and a redrape checks.
    pub fn size_fingerprints(&self) -> BTreeMap<String, String> {
        self.sizes.as_ref().map_or_else(BTreeMap::new, |(_, v)| {
            v.iter()
                .map(|s| (s.name.clone(), fingerprint(&s.template)))
                .collect()
        })
    }

    /// Where the drape of a body of rest shape `shaped` starts: the size the chart picks
    /// for it (the base without sizes).
    pub fn start(&self, shaped: &ShapedBody<'_>) -> Result<Start<'_>, DatasetError> {
        match &self.sizes {
            None => self.start_of(None),
            Some((chart, _)) => self.start_of(Some(&chart.pick(shaped)?.0)),
        }
    }

    /// The start of a recorded sample: the size named in its record (the base without
    /// sizes). Fails if the record names a size this wardrobe does not have.
    pub fn start_of(&self, size: Option<&str>) -> Result<Start<'_>, DatasetError> {
        match (&self.sizes, size) {
            (None, None) => Ok(Start {
                size: None,
                template: &self.base,
                cloth: &self.base_cloth,
                reference: self.base.reference(),
            }),
            (Some((_, sizes)), Some(name)) => {
                let s = sizes.iter().find(|s| s.name == name).ok_or_else(|| {
                    let names: Vec<&str> = sizes.iter().map(|s| s.name.as_str()).collect();
                    DatasetError::Invalid(format!(
                        "the sample's size {name:?} is not one of the garment's sizes ({})",
                        names.join(", ")
                    ))
                })?;
                Ok(Start {
                    size: Some(&s.name),
                    template: &s.template,
                    cloth: &s.cloth,
                    reference: s.template.reference(),
                })
            }
            (None, Some(name)) => Err(DatasetError::Invalid(format!(
                "the sample was draped in size {name:?}, but this dataset's config has no sizes"
            ))),
            (Some(_), None) => Err(DatasetError::Invalid(
                "the dataset uses sizes, but the sample's record names none".into(),
            )),
        }
    }
}

/// sha256 of a template's vertex positions (f32 little-endian).
fn fingerprint(t: &Template) -> String {
    let bytes: Vec<u8> = t
        .mesh
        .vertices
        .iter()
        .flat_map(|v| v.to_array())
        .flat_map(f32::to_le_bytes)
        .collect();
    crate::generate::sha256(&bytes)
}
