//! Bounds on what an MJCF model makes MuJoCo allocate, checked on the text before
//! `mj_loadXML` sees it: the compiler allocates from attributes such as `<size nkey>` or a
//! builtin texture's width × height before any check of its own (10⁸ keyframes reached 5 GB
//! in 5 s, and under a memory limit MuJoCo's C++ `bad_alloc` crossed into Rust).
//!
//! A small tag scanner (comments, processing instructions and CDATA skipped), not an XML
//! parser: MuJoCo reports the model's syntax errors itself. `<include file>`s are scanned too,
//! from the including file's folder, as MuJoCo resolves them.

use std::path::{Path, PathBuf};

/// Most doubles of MuJoCo's stack (`<size nstack>`) a model may ask for (400 MB).
pub const MAX_NSTACK: f64 = 50_000_000.0;

/// (element, attribute, most): single attributes that size an allocation.
const SINGLE: [(&str, &str, f64); 14] = [
    ("size", "nkey", 10_000.0),
    ("size", "nuserdata", 10_000_000.0),
    ("size", "nstack", MAX_NSTACK),
    ("size", "njmax", 1_000_000.0),
    ("size", "nconmax", 100_000.0),
    ("size", "nuser_body", 1_000.0),
    ("size", "nuser_jnt", 1_000.0),
    ("size", "nuser_geom", 1_000.0),
    ("size", "nuser_site", 1_000.0),
    ("size", "nuser_cam", 1_000.0),
    ("size", "nuser_tendon", 1_000.0),
    ("size", "nuser_actuator", 1_000.0),
    ("size", "nuser_sensor", 1_000.0),
    ("numeric", "size", 10_000_000.0),
];

/// (element, attributes whose product is bounded, most, what it counts).
const PRODUCTS: [(&str, &[&str], f64, &str); 2] = [
    ("hfield", &["nrow", "ncol"], 16_777_216.0, "height samples"),
    ("composite", &["count"], 100_000.0, "generated elements"),
];

/// Most texels a builtin texture may make MuJoCo allocate (3 bytes each). MuJoCo 2.2.2 makes
/// a cube or skybox texture (the default type) of six faces of the larger side squared, and
/// does not check the allocation: `width="65536" height="3"` crashed it.
const MAX_BUILTIN_TEXELS: f64 = 1e8;

/// Most nested `<include>` levels followed.
const MAX_INCLUDE_DEPTH: usize = 16;

/// One element's start tag: its name and attributes (values as written).
struct Tag<'a> {
    name: &'a str,
    attributes: Vec<(&'a str, &'a str)>,
}

/// The start tags of `xml` in order (end tags, comments, `<?…?>`, `<!…>` and CDATA skipped).
fn tags(xml: &str) -> Vec<Tag<'_>> {
    let mut out = Vec::new();
    let mut rest = xml;
    while let Some(at) = rest.find('<') {
        rest = &rest[at + 1..];
        fn skip_to<'a>(rest: &'a str, end: &str) -> &'a str {
            rest.find(end).map_or("", |i| &rest[i + end.len()..])
        }
        if rest.starts_with("!--") {
            rest = skip_to(rest, "-->");
            continue;
        }
        if rest.starts_with("![CDATA[") {
            rest = skip_to(rest, "]]>");
            continue;
        }
        if rest.starts_with('?') || rest.starts_with('!') || rest.starts_with('/') {
            rest = skip_to(rest, ">");
            continue;
        }
        let name_end = rest
            .find(|c: char| c.is_whitespace() || c == '>' || c == '/')
            .unwrap_or(rest.len());
        let name = &rest[..name_end];
        rest = &rest[name_end..];
        let mut attributes = Vec::new();
        loop {
            rest = rest.trim_start();
            if rest.is_empty() || rest.starts_with('>') || rest.starts_with("/>") {
                break;
            }
            let Some(eq) = rest.find('=') else { break };
            let key = rest[..eq].trim();
            let after = rest[eq + 1..].trim_start();
            let Some(quote) = after.chars().next().filter(|&c| c == '"' || c == '\'') else {
                break;
            };
            let Some(close) = after[1..].find(quote) else { break };
            attributes.push((key, &after[1..1 + close]));
            rest = &after[close + 2..];
        }
        out.push(Tag { name, attributes });
    }
    out
}

/// The product of the numbers in an attribute value ("10 10 10" → 1000); `None` when a word
/// is not a number (MuJoCo reports that itself).
fn product(value: &str) -> Option<f64> {
    value
        .split_whitespace()
        .map(|w| w.parse::<f64>().ok())
        .try_fold(1.0, |acc, v| Some(acc * v?.abs()))
}

/// The value of the last `<element attribute="…">` in `xml` (the one MuJoCo keeps when an
/// element such as `<size>` is repeated), and how many `<count>` elements it has; `<include>`d
/// files are not read.
pub fn last_attribute_and_count(xml: &str, (element, attribute): (&str, &str), count: &str) -> (Option<String>, usize) {
    let mut last = None;
    let mut counted = 0;
    for tag in tags(xml) {
        counted += usize::from(tag.name == count);
        if tag.name == element {
            if let Some((_, value)) = tag.attributes.iter().rev().find(|(k, _)| *k == attribute) {
                last = Some(value.to_string());
            }
        }
    }
    (last, counted)
}

/// Checks `xml` (from the file `origin`) and the files it includes: `Err` names the element,
/// the attribute, its value and the bound.
pub fn check_model_sizes(xml: &str, origin: &str) -> Result<(), String> {
    check_text(xml, Path::new(origin), 0)
}

fn check_text(xml: &str, origin: &Path, depth: usize) -> Result<(), String> {
    // The including file names itself in the error line; an included one is named here.
    let place = if depth == 0 {
        String::new()
    } else {
        format!("{} (included): ", origin.display())
    };
    for tag in tags(xml) {
        let attribute = |name: &str| tag.attributes.iter().find(|(k, _)| *k == name).map(|(_, v)| *v);
        for (element, key, most) in SINGLE {
            if tag.name != element {
                continue;
            }
            if let Some(value) = attribute(key) {
                if product(value).is_some_and(|v| v.is_nan() || v > most) {
                    return Err(format!(
                        "{place}<{element} {key}=\"{value}\">: expected at most {most} (mjsafe bounds what the model makes MuJoCo allocate)"
                    ));
                }
            }
        }
        for (element, keys, most, what) in PRODUCTS {
            if tag.name != element {
                continue;
            }
            let values: Vec<(&str, &str)> = keys.iter().filter_map(|k| attribute(k).map(|v| (*k, v))).collect();
            let total = values
                .iter()
                .map(|(_, v)| product(v))
                .try_fold(1.0, |acc, v| Some(acc * v?));
            if values.len() == keys.len() && total.is_some_and(|t| t.is_nan() || t > most) {
                let written: Vec<String> = values.iter().map(|(k, v)| format!("{k}=\"{v}\"")).collect();
                return Err(format!(
                    "{place}<{element} {}>: {} {what}, expected at most {most} (mjsafe bounds what the model makes MuJoCo allocate)",
                    written.join(" "),
                    total.unwrap_or(f64::INFINITY)
                ));
            }
        }
        if tag.name == "texture" && attribute("builtin").is_some_and(|b| b.trim() != "none") {
            // Each side as MuJoCo reads an integer (at least 1 of a non-integer like 1e-9).
            let side = |key: &str| {
                attribute(key)
                    .and_then(|v| v.trim().parse::<f64>().ok())
                    .map_or(0.0, |v| v.abs().max(1.0))
            };
            let larger = side("width").max(side("height"));
            let texels = 6.0 * larger * larger;
            if texels.is_nan() || texels > MAX_BUILTIN_TEXELS {
                return Err(format!(
                    "{place}<texture builtin width=\"{}\" height=\"{}\">: {texels:e} texels (six faces of the larger side squared), expected at most {MAX_BUILTIN_TEXELS:e} (mjsafe bounds what the model makes MuJoCo allocate)",
                    attribute("width").unwrap_or(""),
                    attribute("height").unwrap_or("")
                ));
            }
        }
        if tag.name == "include" {
            if let Some(file) = attribute("file") {
                check_include(origin, file, depth)?;
            }
        }
    }
    Ok(())
}

/// Scans an included file as MuJoCo finds it (relative to the including file's folder).
fn check_include(origin: &Path, file: &str, depth: usize) -> Result<(), String> {
    if depth >= MAX_INCLUDE_DEPTH {
        return Err(format!(
            "{}: <include file=\"{file}\">: more than {MAX_INCLUDE_DEPTH} nested includes",
            origin.display()
        ));
    }
    let path: PathBuf = match origin.parent() {
        Some(dir) if Path::new(file).is_relative() => dir.join(file),
        _ => PathBuf::from(file),
    };
    // A file that cannot be read is MuJoCo's to report (with its own message).
    let Ok(text) = crate::files::read_text_limited(&path, "MJCF include", crate::files::MODEL_LIMIT) else {
        return Ok(());
    };
    check_text(&text, &path, depth + 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn large_sizes_are_refused_with_element_attribute_and_bound() {
        let e = check_model_sizes(r#"<mujoco><size nkey="100000000"/></mujoco>"#, "m.xml").unwrap_err();
        assert!(
            e.contains("<size nkey=\"100000000\">") && e.contains("at most 10000"),
            "{e}"
        );
        let e = check_model_sizes(
            r#"<mujoco><asset><texture builtin="checker" width="100000" height='100000'/></asset></mujoco>"#,
            "m.xml",
        )
        .unwrap_err();
        assert!(e.contains("texels"), "{e}");
        // MuJoCo's cube texture squares the larger side: 65536 × 3 is 2.6e10 texels.
        let e = check_model_sizes(r#"<texture builtin="checker" width="65536" height="3"/>"#, "m.xml").unwrap_err();
        assert!(e.contains("texels"), "{e}");
        let e = check_model_sizes(r#"<composite type="grid" count="1000 1000 1"/>"#, "m.xml").unwrap_err();
        assert!(e.contains("generated elements"), "{e}");
        assert!(check_model_sizes(r#"<size nkey="inf"/>"#, "m.xml").is_err());
    }

    #[test]
    fn ordinary_models_comments_and_unparsed_values_pass() {
        let xml = r#"<?xml version="1.0"?>
            <!-- <size nkey="100000000"/> -->
            <mujoco><size nkey="10" njmax="500"/><asset><texture builtin="checker" width="512" height="512"/><texture file="a.png"/>
            <hfield name="h" nrow="100" ncol="100" size="1 1 1 1"/></asset>
            <size nkey="many"/></mujoco>"#;
        check_model_sizes(xml, "m.xml").unwrap();
        check_model_sizes(
            &std::fs::read_to_string("models/bicycle.xml").unwrap(),
            "models/bicycle.xml",
        )
        .unwrap();
    }
}
