//! Shape parameters and MakeHuman's macro-target weighting.
//!
//! A macro target file is named by the values it stands for on each axis, e.g.
//! `universal-female-young-maxmuscle-averageweight` or
//! `height/male-old-minmuscle-maxweight-maxheight`. Its weight is the product of the
//! weights of those values (MakeHuman's scheme, formulas in `../shared/notes/body-model.md`):
//!
//! - gender g: male = g, female = 1 - g
//! - age a < 0.5: baby = max(0, 1 - 5.333 a), young = max(0, 3.2 (a - 0.1875)),
//!   child = max(0, min(1, 5.333 a) - young); a >= 0.5: old = 2a - 1, young = 1 - old
//! - muscle, weight, height, proportions x: min = max(0, 1 - 2x), max = max(0, 2x - 1),
//!   average = 1 - min - max (height and proportions have no "average" file)
//! - race: the three values normalised to sum to 1.

use serde::{Deserialize, Serialize};

use super::BodyError;

/// The macro parameters of a body. Every value lies in [0, 1]; 0.5 is the average person.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ShapeParams {
    /// 0 = female, 1 = male (default 0.5).
    pub gender: f32,
    /// 0 = 1 year, 0.1875 = 11 years, 0.5 = 25 years, 1 = 90 years (default 0.5).
    pub age: f32,
    /// Muscle tone (default 0.5).
    pub muscle: f32,
    /// Body mass (default 0.5).
    pub weight: f32,
    /// Height (default 0.5; 1 is a 2.45 m giant, sample moderately).
    pub height: f32,
    /// Body proportions, 0 = uncommon, 1 = ideal (default 0.5).
    pub proportions: f32,
    /// Share of the African race target (default 1/3; the three shares are normalised).
    pub african: f32,
    /// Share of the Asian race target (default 1/3).
    pub asian: f32,
    /// Share of the Caucasian race target (default 1/3).
    pub caucasian: f32,
}

impl Default for ShapeParams {
    fn default() -> Self {
        Self {
            gender: 0.5,
            age: 0.5,
            muscle: 0.5,
            weight: 0.5,
            height: 0.5,
            proportions: 0.5,
            african: 1.0 / 3.0,
            asian: 1.0 / 3.0,
            caucasian: 1.0 / 3.0,
        }
    }
}

impl ShapeParams {
    /// The parameters by name, in a fixed order (for validation and reports).
    pub fn named(&self) -> [(&'static str, f32); 9] {
        [
            ("gender", self.gender),
            ("age", self.age),
            ("muscle", self.muscle),
            ("weight", self.weight),
            ("height", self.height),
            ("proportions", self.proportions),
            ("african", self.african),
            ("asian", self.asian),
            ("caucasian", self.caucasian),
        ]
    }

    /// The values of [`ShapeParams::named`], in its order.
    pub fn values(&self) -> [f32; 9] {
        self.named().map(|(_, v)| v)
    }

    /// The inverse of [`ShapeParams::values`]: parameters from their values in that order.
    pub fn from_named(v: [f32; 9]) -> Self {
        Self {
            gender: v[0],
            age: v[1],
            muscle: v[2],
            weight: v[3],
            height: v[4],
            proportions: v[5],
            african: v[6],
            asian: v[7],
            caucasian: v[8],
        }
    }

    /// Checks that every parameter is finite and in [0, 1] and that the race shares do not
    /// all vanish.
    pub fn validate(&self) -> Result<(), BodyError> {
        for (name, value) in self.named() {
            if !(0.0..=1.0).contains(&value) {
                return Err(BodyError::BadParameter {
                    name: name.to_string(),
                    value,
                    reason: "must lie in [0, 1]".into(),
                });
            }
        }
        if self.african + self.asian + self.caucasian <= 0.0 {
            return Err(BodyError::BadParameter {
                name: "african+asian+caucasian".into(),
                value: 0.0,
                reason: "the race shares must not all be zero".into(),
            });
        }
        Ok(())
    }

    /// Weight of one axis value under these parameters.
    pub fn factor_weight(&self, f: Factor) -> f32 {
        let min_avg_max = |x: f32| {
            let min = (1.0 - 2.0 * x).max(0.0);
            let max = (2.0 * x - 1.0).max(0.0);
            [min, 1.0 - min - max, max]
        };
        match f {
            Factor::Gender(Gender::Female) => 1.0 - self.gender,
            Factor::Gender(Gender::Male) => self.gender,
            Factor::Age(age) => {
                let a = self.age;
                let (baby, child, young, old) = if a < 0.5 {
                    let young = (3.2 * (a - 0.1875)).max(0.0);
                    let baby = (1.0 - 5.333 * a).max(0.0);
                    let child = ((5.333 * a).min(1.0) - young).max(0.0);
                    (baby, child, young, 0.0)
                } else {
                    let old = 2.0 * a - 1.0;
                    (0.0, 0.0, 1.0 - old, old)
                };
                match age {
                    Age::Baby => baby,
                    Age::Child => child,
                    Age::Young => young,
                    Age::Old => old,
                }
            }
            Factor::Muscle(l) => min_avg_max(self.muscle)[l as usize],
            Factor::Weight(l) => min_avg_max(self.weight)[l as usize],
            Factor::Height(l) => min_avg_max(self.height)[l as usize],
            Factor::Proportions(l) => min_avg_max(self.proportions)[l as usize],
            Factor::Race(r) => {
                let sum = self.african + self.asian + self.caucasian;
                let share = match r {
                    Race::African => self.african,
                    Race::Asian => self.asian,
                    Race::Caucasian => self.caucasian,
                };
                share / sum
            }
        }
    }

    /// Weight of a target file whose name parsed to `factors`.
    pub fn target_weight(&self, factors: &[Factor]) -> f32 {
        factors.iter().map(|&f| self.factor_weight(f)).product()
    }
}

/// Gender axis values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Gender {
    /// female = 1 - g
    Female,
    /// male = g
    Male,
}

/// Age axis values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Age {
    /// 1 year
    Baby,
    /// 11 years
    Child,
    /// 25 years
    Young,
    /// 90 years
    Old,
}

/// Race axis values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Race {
    /// african
    African,
    /// asian
    Asian,
    /// caucasian
    Caucasian,
}

/// A min / average / max axis value (index into the min-average-max weights).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// min (also "uncommon" proportions)
    Min = 0,
    /// average
    Average = 1,
    /// max (also "ideal" proportions)
    Max = 2,
}

/// One axis value a target file stands for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Factor {
    /// gender
    Gender(Gender),
    /// age
    Age(Age),
    /// race
    Race(Race),
    /// muscle
    Muscle(Level),
    /// weight
    Weight(Level),
    /// height
    Height(Level),
    /// proportions
    Proportions(Level),
}

/// Parses a macro target's name (its path below `targets/macrodetails/` without
/// `.target.gz`, e.g. `height/female-young-averagemuscle-minweight-maxheight`) into the
/// axis values it stands for.
pub fn parse_target_name(name: &str) -> Option<Vec<Factor>> {
    let base = name.rsplit('/').next()?;
    let mut out = Vec::new();
    for token in base.split('-') {
        let f = match token {
            "universal" => continue,
            "female" => Factor::Gender(Gender::Female),
            "male" => Factor::Gender(Gender::Male),
            "baby" => Factor::Age(Age::Baby),
            "child" => Factor::Age(Age::Child),
            "young" => Factor::Age(Age::Young),
            "old" => Factor::Age(Age::Old),
            "african" => Factor::Race(Race::African),
            "asian" => Factor::Race(Race::Asian),
            "caucasian" => Factor::Race(Race::Caucasian),
            "minmuscle" => Factor::Muscle(Level::Min),
            "averagemuscle" => Factor::Muscle(Level::Average),
            "maxmuscle" => Factor::Muscle(Level::Max),
            "minweight" => Factor::Weight(Level::Min),
            "averageweight" => Factor::Weight(Level::Average),
            "maxweight" => Factor::Weight(Level::Max),
            "minheight" => Factor::Height(Level::Min),
            "maxheight" => Factor::Height(Level::Max),
            "uncommonproportions" => Factor::Proportions(Level::Min),
            "idealproportions" => Factor::Proportions(Level::Max),
            _ => return None,
        };
        out.push(f);
    }
    (!out.is_empty()).then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_weights_sum_to_one() {
        for i in 0..=20 {
            let x = i as f32 / 20.0;
            let p = ShapeParams {
                age: x,
                muscle: x,
                gender: x,
                ..Default::default()
            };
            let ages: f32 = [Age::Baby, Age::Child, Age::Young, Age::Old]
                .map(|a| p.factor_weight(Factor::Age(a)))
                .iter()
                .sum();
            assert!((ages - 1.0).abs() < 2e-3, "age {x}: {ages}");
            let m: f32 = [Level::Min, Level::Average, Level::Max]
                .map(|l| p.factor_weight(Factor::Muscle(l)))
                .iter()
                .sum();
            assert!((m - 1.0).abs() < 1e-6);
            let g = p.factor_weight(Factor::Gender(Gender::Male))
                + p.factor_weight(Factor::Gender(Gender::Female));
            assert!((g - 1.0).abs() < 1e-6);
        }
    }

    #[test]
    fn axis_weights_take_makehuman_values() {
        let w = |p: ShapeParams, f: Factor| p.factor_weight(f);
        let at = |age: f32| ShapeParams {
            age,
            ..Default::default()
        };
        // 11 years is all child; 25 all young; 57.5 half young half old; 90 all old.
        assert!((w(at(0.1875), Factor::Age(Age::Child)) - 1.0).abs() < 1e-3);
        assert!((w(at(0.5), Factor::Age(Age::Young)) - 1.0).abs() < 1e-6);
        assert!((w(at(0.75), Factor::Age(Age::Old)) - 0.5).abs() < 1e-6);
        assert!((w(at(1.0), Factor::Age(Age::Old)) - 1.0).abs() < 1e-6);
        // Age 0.25: young = 3.2 (0.25 - 0.1875) = 0.2, child = 1 - 0.2 = 0.8, no baby.
        assert!((w(at(0.25), Factor::Age(Age::Young)) - 0.2).abs() < 1e-5);
        assert!((w(at(0.25), Factor::Age(Age::Child)) - 0.8).abs() < 1e-5);
        assert_eq!(w(at(0.25), Factor::Age(Age::Baby)), 0.0);
        // Age 0.1: baby = 1 - 0.5333 = 0.4667, child = 0.5333.
        assert!((w(at(0.1), Factor::Age(Age::Baby)) - 0.4667).abs() < 1e-3);
        // Muscle 0.2: min 0.6, average 0.4, max 0; weight 0.9: max 0.8, average 0.2.
        let p = ShapeParams {
            muscle: 0.2,
            weight: 0.9,
            gender: 0.3,
            ..Default::default()
        };
        assert!((w(p, Factor::Muscle(Level::Min)) - 0.6).abs() < 1e-6);
        assert!((w(p, Factor::Muscle(Level::Average)) - 0.4).abs() < 1e-6);
        assert_eq!(w(p, Factor::Muscle(Level::Max)), 0.0);
        assert!((w(p, Factor::Weight(Level::Max)) - 0.8).abs() < 1e-6);
        assert!((w(p, Factor::Gender(Gender::Male)) - 0.3).abs() < 1e-6);
        assert!((w(p, Factor::Gender(Gender::Female)) - 0.7).abs() < 1e-6);
        // Race shares are normalised.
        let r = ShapeParams {
            african: 2.0 / 3.0,
            asian: 0.0,
            caucasian: 2.0 / 3.0,
            ..Default::default()
        };
        assert!((w(r, Factor::Race(Race::African)) - 0.5).abs() < 1e-6);
    }

    #[test]
    fn target_names_parse() {
        let f = parse_target_name("height/male-old-minmuscle-maxweight-maxheight").unwrap();
        assert_eq!(
            f,
            vec![
                Factor::Gender(Gender::Male),
                Factor::Age(Age::Old),
                Factor::Muscle(Level::Min),
                Factor::Weight(Level::Max),
                Factor::Height(Level::Max)
            ]
        );
        assert!(parse_target_name("universal-female-young-whatever").is_none());
        let p = ShapeParams {
            gender: 1.0,
            age: 1.0,
            muscle: 0.0,
            weight: 1.0,
            height: 1.0,
            ..Default::default()
        };
        assert!((p.target_weight(&f) - 1.0).abs() < 1e-6);
    }

    #[test]
    fn validation_names_the_parameter() {
        let p = ShapeParams {
            weight: 1.5,
            ..Default::default()
        };
        let e = p.validate().unwrap_err().to_string();
        assert!(e.contains("weight") && e.contains("1.5"), "{e}");
        let p = ShapeParams {
            age: f32::NAN,
            ..Default::default()
        };
        assert!(p.validate().is_err());
    }
}
