//! `source = …` of a CAN output as written ([`SourceSettings`]): one axis, or a weighted mix of
//! axes; its parsing, display and validation.

use crate::scale::Source;
use rove_core::error::ConfigErrors;
use rove_core::mapping::Axis;
use serde::de::{self, MapAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize};
use std::fmt;

/// `source = …` as written: an axis name, or `{ mix = [["throttle", 1.0], ["roll", -1.0]] }`.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum SourceSettings {
    /// One axis.
    Axis(Axis),
    /// A weighted sum.
    Mix {
        /// `(axis, weight)` pairs.
        mix: Vec<(Axis, f64)>,
    },
}

impl<'de> Deserialize<'de> for SourceSettings {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct SourceVisitor;
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Mix {
            mix: Vec<(Axis, f64)>,
        }
        impl<'de> Visitor<'de> for SourceVisitor {
            type Value = SourceSettings;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("an axis or { mix = [[\"throttle\", 1.0], [\"roll\", 1.0]] }")
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<SourceSettings, E> {
                Axis::deserialize(de::value::StrDeserializer::new(v)).map(SourceSettings::Axis)
            }
            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<SourceSettings, A::Error> {
                let Mix { mix } = Mix::deserialize(de::value::MapAccessDeserializer::new(map))?;
                Ok(SourceSettings::Mix { mix })
            }
        }
        deserializer.deserialize_any(SourceVisitor)
    }
}

impl fmt::Display for SourceSettings {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SourceSettings::Axis(a) => f.write_str(a.name()),
            SourceSettings::Mix { mix } => {
                let terms: Vec<String> = (mix.iter())
                    .map(|(a, w)| format!("[\"{}\", {w}]", a.name()))
                    .collect();
                write!(f, "{{ mix = [{}] }}", terms.join(", "))
            }
        }
    }
}

/// Most terms in a mix: one per axis.
pub const MIX_TERMS_MAX: usize = 4;

/// Largest weight magnitude in a mix. Weights are gains on ±32767 axes; 4 already saturates a
/// quarter stick, anything larger is almost surely a typo (a device unit where a gain belongs).
pub const MIX_WEIGHT_MAX: f64 = 4.0;

impl SourceSettings {
    /// The required `source` key, validated.
    pub(super) fn validate(source: &Option<Self>, errors: &mut ConfigErrors) -> Option<Source> {
        let this = errors.required("source", source)?;
        let mix = match &this {
            SourceSettings::Axis(a) => return Some(Source::Axis(*a)),
            SourceSettings::Mix { mix } => mix,
        };
        if mix.is_empty() || mix.len() > MIX_TERMS_MAX {
            let rule = format!("a mix needs 1..={MIX_TERMS_MAX} terms");
            errors.add("source", &this, rule);
        }
        for (i, (axis, weight)) in mix.iter().enumerate() {
            let name = axis.name();
            if !weight.is_finite() || weight.abs() > MIX_WEIGHT_MAX || *weight == 0.0 {
                let rule =
                    format!("weight of {name} must be non-zero and within ±{MIX_WEIGHT_MAX}");
                errors.add("source", &this, rule);
            }
            if mix[..i].iter().any(|(other, _)| other == axis) {
                errors.add("source", &this, format!("{name} appears twice in the mix"));
            }
        }
        Some(Source::Mix(mix.clone()))
    }
}
