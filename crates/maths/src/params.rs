//! What a registered kind (filter, nominal) is built from: its typed parameters ([`Params`])
//! and the error of a parameter it cannot accept ([`ParamError`]). A leaf module: the scenario
//! schema, the registry, the filters and the nominals all use it, and it uses none of them.

use serde::de::DeserializeOwned;
use serde::Serialize;

/// A kind's parameters: deserialized from the scenario's table (unknown keys should be refused
/// with `#[serde(deny_unknown_fields)]`), checked, and serialized back into the log's resolved
/// scenario (defaults filled in).
pub trait Params: Serialize + DeserializeOwned {
    /// Checks what serde cannot (signs, ranges, consistency); keys are scenario keys
    /// (`filter.m`). Checks that need the model belong in the constructor.
    fn validate(&self) -> Result<(), ParamError> {
        Ok(())
    }

    /// The run's label, given the kind's registered label (e.g. `γm filter (4.67)` →
    /// `γm filter (4.67), m = 50`): what plots, legends and `analyze --brief` name the run by.
    fn label(&self, kind_label: &str) -> String {
        kind_label.to_string()
    }
}

/// A parameter or scenario field a filter or nominal cannot accept: the scenario key (e.g.
/// `filter.m`, `delays.steering`) and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("key `{key}`: {message}")]
pub struct ParamError {
    /// The scenario key, e.g. `filter.m`.
    pub key: String,
    /// What was expected (and found).
    pub message: String,
}

impl ParamError {
    /// The error for `key`.
    pub fn new(key: impl Into<String>, message: impl Into<String>) -> ParamError {
        ParamError {
            key: key.into(),
            message: message.into(),
        }
    }
}
/// A kind table as a scenario writes it (`filter`, `nominal`, an obstacle's `motion`): `kind`
/// first, then the kind's parameters in their order.
pub fn serialize_kind_table<S: serde::Serializer>(
    kind: &str,
    params: &toml::Table,
    serializer: S,
) -> Result<S::Ok, S::Error> {
    use serde::ser::SerializeMap;
    let mut map = serializer.serialize_map(Some(1 + params.len()))?;
    map.serialize_entry("kind", kind)?;
    for (key, value) in params {
        map.serialize_entry(key, value)?;
    }
    map.end()
}
