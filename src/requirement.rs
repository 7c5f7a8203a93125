//! The `[[requirements]]` section: STL formulas over a run's signals, each reported as the
//! metric `req.<name>` (docs/requirements.md). The section's spec, its names (also those of
//! `--require NAME=FORMULA`) and its checks at load; the monitors are
//! `metrics::requirements`'.

use serde::{Deserialize, Serialize};

use crate::params::ParamError;
use crate::section::{Section, SectionContext};

/// One `[[requirements]]` entry: a name (the `req.<name>` metric) and an STL formula over the
/// run's signals (docs/requirements.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RequirementSpec {
    pub name: String,
    pub formula: String,
}

/// The longest requirement name (a metric column `req.<name>`).
pub const MAX_REQUIREMENT_NAME: usize = 64;

/// A requirement's name: letters, digits, `_` and `-`, at most [`MAX_REQUIREMENT_NAME`]
/// characters.
pub fn check_requirement_name(name: &str) -> Result<(), String> {
    let ok = !name.is_empty()
        && name.len() <= MAX_REQUIREMENT_NAME
        && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
    if ok {
        Ok(())
    } else {
        Err(format!(
            "expected a name of 1 to {MAX_REQUIREMENT_NAME} letters, digits, `_` or `-` (the metric `req.<name>`), found {name:?}"
        ))
    }
}

/// `NAME=FORMULA` of `--require`: the name and the formula's text, both checked.
pub fn parse_require_flag(text: &str) -> Result<(String, String), String> {
    let Some((name, formula)) = text.split_once('=') else {
        return Err(format!("expected NAME=FORMULA, found {text:?}"));
    };
    let name = name.trim();
    check_requirement_name(name)?;
    crate::stl::parse(formula).map_err(|e| e.to_string())?;
    Ok((name.to_string(), formula.trim().to_string()))
}

/// At most this many requirements per run (each is a metric column and a monitor).
pub const MAX_REQUIREMENTS: usize = 64;

/// The checks of the section when the scenario loads: at most [`MAX_REQUIREMENTS`], distinct
/// names a metric column can carry, formulas that parse (their bounds are checked against the
/// plant step with the model: `stl::Formula::check_step`). Keys are the scenario's
/// (`requirements[2].formula`).
pub fn validate(list: &[RequirementSpec]) -> Result<(), ParamError> {
    if list.len() > MAX_REQUIREMENTS {
        return Err(ParamError::new(
            "requirements",
            format!("expected at most {MAX_REQUIREMENTS} requirements, found {}", list.len()),
        ));
    }
    for (i, r) in list.iter().enumerate() {
        check_requirement_name(&r.name).map_err(|e| ParamError::new(format!("requirements[{i}].name"), e))?;
        if list[..i].iter().any(|other| other.name == r.name) {
            return Err(ParamError::new(
                format!("requirements[{i}].name"),
                format!("`{}` is already the name of an earlier requirement", r.name),
            ));
        }
        crate::stl::parse(&r.formula)
            .map_err(|e| ParamError::new(format!("requirements[{i}].formula"), e.to_string()))?;
    }
    Ok(())
}

/// `[[requirements]]`: checked here; the run's description carries them to the monitors.
impl Section for Vec<RequirementSpec> {
    fn validate(&self, _key: &str, _cx: &SectionContext<'_>) -> Result<(), ParamError> {
        validate(self)
    }
}
