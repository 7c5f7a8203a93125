//! MJCF models built into the binary, named in a scenario as `vehicle.model = "mjsafe:<name>"`
//! (a CommonRoad world's default vehicle: docs/commonroad.md), so that a scenario file anywhere
//! runs without a copy of `models/`.

use std::path::Path;

/// The prefix of a built-in model's name.
pub const PREFIX: &str = "mjsafe:";

/// The built-in models: name and MJCF text (the files of `models/`).
const BUILTIN: [(&str, &str); 1] = [("commonroad_car.xml", include_str!("../models/commonroad_car.xml"))];

/// Whether `path` names a built-in model (`mjsafe:<name>`).
pub fn is_builtin(path: &Path) -> bool {
    path.to_str().is_some_and(|p| p.starts_with(PREFIX))
}

/// The text of the built-in model `path` names, or the names there are.
pub fn builtin(path: &Path) -> Result<&'static str, String> {
    let name = path.to_str().and_then(|p| p.strip_prefix(PREFIX)).unwrap_or_default();
    BUILTIN
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, text)| *text)
        .ok_or_else(|| {
            let names: Vec<String> = BUILTIN.iter().map(|(n, _)| format!("{PREFIX}{n}")).collect();
            format!(
                "expected a built-in model ({}), found {}",
                names.join(", "),
                path.display()
            )
        })
}
