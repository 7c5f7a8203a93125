//! The dependency rules of docs/ARCHITECTURE.md, checked on the sources: no import cycle
//! between top-level modules, pure maths never reaches the MuJoCo bindings or the log, the
//! scenario schema and the analysis need no MuJoCo type, sinks never read through the analysis;
//! no function over 150 lines; episodes assembled only on the run path; the control loop holds
//! stages; the maths crate depends on no simulation, log or I/O crate. Each guard is also run
//! on a planted violation, which it must report.
//! A file's test module (`#[cfg(test)] mod tests`, inline or a `tests.rs`) is left out: it may
//! use the counting allocator of `mujoco`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// The source roots of the layers: the simulation library's `src/` and the pure maths crate's
/// (`crates/maths/src/`, re-exported by the library under the same module names).
const SOURCE_ROOTS: [&str; 2] = ["src", "crates/maths/src"];

/// Every `.rs` file under the [`SOURCE_ROOTS`]: its path relative to the repository and its
/// code without the file's test module (its last item; other items stay). Files of a module's
/// tests (`#[cfg(test)] mod tests;` in `tests.rs`) are left out.
fn rust_sources() -> Vec<(std::path::PathBuf, String)> {
    let repository = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut sources = Vec::new();
    let mut stack: Vec<_> = SOURCE_ROOTS.iter().map(|root| repository.join(root)).collect();
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            if path.extension().is_none_or(|e| e != "rs") || path.file_name().is_some_and(|n| n == "tests.rs") {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let code = text.split("#[cfg(test)]\nmod tests {").next().unwrap().to_string();
            sources.push((path.strip_prefix(repository).unwrap().to_path_buf(), code));
        }
    }
    sources
}

/// The path of a source file relative to its crate's source root (`barrier.rs` of
/// `crates/maths/src/barrier.rs`).
fn within_root(path: &Path) -> &Path {
    (SOURCE_ROOTS.iter())
        .find_map(|root| path.strip_prefix(root).ok())
        .unwrap_or(path)
}

fn dependencies() -> BTreeMap<String, BTreeSet<String>> {
    dependencies_of(rust_sources())
}

/// [`dependencies`] of the given sources (path relative to the repository, code). A module of
/// the maths crate and the library's re-export of it are one node (`crate::barrier` names it in
/// both).
fn dependencies_of(sources: Vec<(std::path::PathBuf, String)>) -> BTreeMap<String, BTreeSet<String>> {
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (path, code) in sources {
        let first = within_root(&path)
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let module = first.trim_end_matches(".rs").to_string();
        if module == "lib" || module == "main" {
            continue;
        }
        let deps = graph.entry(module.clone()).or_default();
        for (at, _) in code.match_indices("crate::") {
            let name: String = code[at + 7..]
                .chars()
                .take_while(|c| c.is_ascii_lowercase() || *c == '_')
                .collect();
            if !name.is_empty() && name != module {
                deps.insert(name);
            }
        }
    }
    graph
}

fn reaches(graph: &BTreeMap<String, BTreeSet<String>>, from: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut todo = vec![from.to_string()];
    while let Some(m) = todo.pop() {
        for d in graph.get(&m).into_iter().flatten() {
            if seen.insert(d.clone()) {
                todo.push(d.clone());
            }
        }
    }
    seen
}

#[test]
fn no_import_cycle_between_top_level_modules() {
    let graph = dependencies();
    assert!(graph.len() > 20, "{graph:?}");
    for module in graph.keys() {
        let through: Vec<&String> = graph[module]
            .iter()
            .filter(|d| reaches(&graph, d).contains(module))
            .collect();
        assert!(through.is_empty(), "{module} depends on itself through {through:?}");
    }
}

/// The layer rules `graph` breaks, one line each.
fn layer_violations(graph: &BTreeMap<String, BTreeSet<String>>) -> Vec<String> {
    let mut broken = Vec::new();
    for maths in [
        "dynamics",
        "barrier",
        "road",
        "actor",
        "footprint",
        "predictor",
        "prescribed_time",
        "params",
        "delay",
        "nominal",
        "filter",
        "stl",
    ] {
        let reached = reaches(graph, maths);
        for forbidden in [
            "mujoco", "log", "episode", "plant", "vehicle", "analyze", "metrics", "run",
        ] {
            if reached.contains(forbidden) {
                broken.push(format!("{maths} reaches {forbidden}"));
            }
        }
    }
    for schema_or_analysis in ["scenario", "analyze", "metrics", "table", "params", "message"] {
        if reaches(graph, schema_or_analysis).contains("mujoco") {
            broken.push(format!("{schema_or_analysis} reaches mujoco"));
        }
    }
    // Sinks only observe: the log never reads through the analysis or the metrics.
    let log = reaches(graph, "log");
    for forbidden in ["analyze", "metrics", "run"] {
        if log.contains(forbidden) {
            broken.push(format!("log reaches {forbidden}"));
        }
    }
    broken
}

#[test]
fn pure_maths_schema_and_analysis_keep_their_distance() {
    let broken = layer_violations(&dependencies());
    assert!(broken.is_empty(), "layer rules broken: {broken:?}");
    // The guard sees planted violations: a barrier reaching MuJoCo through the plant, a sink
    // reading the metrics.
    let planted = dependencies_of(vec![
        ("crates/maths/src/barrier.rs".into(), "use crate::plant::Plant;".into()),
        ("src/plant.rs".into(), "use crate::mujoco::Model;".into()),
        ("src/log/mod.rs".into(), "use crate::metrics::RunFacts;".into()),
    ]);
    assert_eq!(
        layer_violations(&planted),
        ["barrier reaches mujoco", "barrier reaches plant", "log reaches metrics"]
    );
}

/// The functions of the [`SOURCE_ROOTS`] (test modules left out) and their lengths in lines, by brace
/// matching from each `fn` line (as ../shared/tools/long_functions.py counts them).
fn function_lengths() -> Vec<(String, usize)> {
    function_lengths_of(&rust_sources())
}

/// [`function_lengths`] of the given sources (path relative to the repository, code).
fn function_lengths_of(sources: &[(std::path::PathBuf, String)]) -> Vec<(String, usize)> {
    let mut found = Vec::new();
    for (relative, code) in sources.iter().filter(|(p, _)| !p.ends_with("ffi.rs")) {
        let lines: Vec<&str> = code.lines().collect();
        for (k, line) in lines.iter().enumerate() {
            let trimmed = line.trim_start();
            let after = [
                "pub(crate) ",
                "pub(super) ",
                "pub ",
                "const ",
                "unsafe ",
                "extern \"C\" ",
            ]
            .iter()
            .fold(trimmed, |t, p| t.strip_prefix(p).unwrap_or(t));
            let Some(name) = after.strip_prefix("fn ") else {
                continue;
            };
            if line.trim_end().ends_with(';') {
                continue;
            }
            let name: String = name.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
            let (mut depth, mut started) = (0i64, false);
            for (e, body) in lines.iter().enumerate().skip(k) {
                depth += body.matches('{').count() as i64 - body.matches('}').count() as i64;
                started |= body.contains('{');
                if started && depth <= 0 {
                    found.push((format!("{}::{name}", relative.display()), e - k + 1));
                    break;
                }
            }
        }
    }
    found
}

/// No function of the library or the maths crate grows past 150 lines (the last two that did, `control_tick` and
/// `run_guided`, were split into stages and helpers).
#[test]
fn no_function_grows_past_150_lines() {
    let too_long = |lengths: &[(String, usize)]| -> Vec<String> {
        (lengths.iter())
            .filter(|(_, lines)| *lines > 150)
            .map(|(name, lines)| format!("{name} ({lines} lines)"))
            .collect()
    };
    let lengths = function_lengths();
    assert!(lengths.len() > 500, "the scan found the functions: {}", lengths.len());
    let long = too_long(&lengths);
    assert!(long.is_empty(), "functions over 150 lines (split them): {long:?}");
    // The guard sees a planted violation: a function of 151 lines (and not one of 150).
    let body = |name: &str, lines: usize| format!("pub fn {name}() {{\n{}}}\n", "    x();\n".repeat(lines - 2));
    let planted = vec![
        ("src/planted.rs".into(), body("grown_long", 151)),
        ("crates/maths/src/planted.rs".into(), body("just_fits", 150)),
    ];
    assert_eq!(
        too_long(&function_lengths_of(&planted)),
        ["src/planted.rs::grown_long (151 lines)"]
    );
}

/// The files of `sources` (relative to the repository) that assemble an episode (`Episode::new`)
/// outside the run path: everything runs through `run::Prepared` (src/run.rs), which the
/// episode module itself serves.
fn episodes_outside_the_run_path(sources: &[(std::path::PathBuf, String)]) -> Vec<String> {
    (sources.iter())
        .filter(|(path, code)| {
            code.contains("Episode::new(") && !(path.starts_with("src/run.rs") || path.starts_with("src/episode"))
        })
        .map(|(path, _)| path.display().to_string())
        .collect()
}

/// One run path: bench's probe and falsify's pre-flight assemble through `run::Prepared`, and
/// so does every other command; the Python package too.
#[test]
fn episodes_are_assembled_only_on_the_run_path() {
    let mut sources = rust_sources();
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/src");
    for entry in std::fs::read_dir(&python).unwrap() {
        let path = entry.unwrap().path();
        let code = std::fs::read_to_string(&path).unwrap();
        sources.push((Path::new("python/src").join(path.file_name().unwrap()), code));
    }
    let outside = episodes_outside_the_run_path(&sources);
    assert!(
        outside.is_empty(),
        "Episode::new outside the run path (use run::Prepared): {outside:?}"
    );
    // The guard sees a planted violation.
    let planted = vec![
        (
            "src/bench.rs".into(),
            "let mut probe = Episode::new(&loaded)?;".to_string(),
        ),
        (
            "src/run.rs".into(),
            "let mut episode = Episode::new(loaded)?;".to_string(),
        ),
    ];
    assert_eq!(episodes_outside_the_run_path(&planted), ["src/bench.rs"]);
}

/// The dependencies of the maths crate's manifest (`crates/maths/Cargo.toml` text) that break
/// its boundary: anything beyond linear algebra, a QP solver, the parsed CommonRoad data, serde,
/// error types and TOML parameters — the library (`mjsafe`), MuJoCo, the log or any I/O.
fn maths_crate_breaches(manifest: &str) -> Vec<String> {
    const ALLOWED: [&str; 6] = [
        "clarabel",
        "mjsafe-commonroad",
        "nalgebra",
        "serde",
        "thiserror",
        "toml",
    ];
    let manifest: toml::Table = manifest.parse().unwrap();
    let dependencies = manifest.get("dependencies").and_then(|d| d.as_table());
    (dependencies.into_iter().flat_map(|d| d.keys()))
        .filter(|name| !ALLOWED.contains(&name.as_str()))
        .map(|name| format!("the maths crate depends on {name}"))
        .collect()
}

/// The pure maths is a crate of its own: its manifest names no MuJoCo, log or library crate, so
/// no import of the maths can reach them (the compiler refuses it).
#[test]
fn the_maths_crate_depends_on_no_simulation_log_or_io_crate() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/maths/Cargo.toml");
    let breaches = maths_crate_breaches(&std::fs::read_to_string(path).unwrap());
    assert!(breaches.is_empty(), "{breaches:?}");
    // The guard sees a planted violation: the maths depending on the library, or on the log.
    let planted = "[dependencies]\nnalgebra = \"0.35\"\nmjsafe = { path = \"../..\" }\nmcap = \"0.26\"\n";
    assert_eq!(
        maths_crate_breaches(planted),
        ["the maths crate depends on mjsafe", "the maths crate depends on mcap"]
    );
}

/// The fields of `struct ControlLoop` in `code` (the field names before `:`, comments left out;
/// the last declaration, the one inside `control_loop!`, not the macro's pattern).
fn control_loop_fields(code: &str) -> Vec<String> {
    let Some(start) = code.rfind("pub struct ControlLoop {") else {
        return Vec::new();
    };
    let body = &code[start..];
    let body = &body[..body.find("\n}").unwrap_or(body.len())];
    (body.lines().skip(1))
        .map(str::trim)
        .filter(|line| !line.starts_with("//") && !line.starts_with('#'))
        .filter_map(|line| line.split_once(':').map(|(name, _)| name.trim().to_string()))
        .collect()
}

/// What is wrong with a `ControlLoop` of these fields: more than ten (the six stages, the timing
/// and the tick's bookkeeping) means loose fields crept back.
fn loose_control_loop(fields: &[String]) -> Option<String> {
    (fields.len() > 10 || fields.len() < 6).then(|| {
        format!(
            "ControlLoop has {} fields (group them into stages): {fields:?}",
            fields.len()
        )
    })
}

/// The control loop holds the tick's stages (each a struct owning its state), not loose fields.
#[test]
fn the_control_loop_holds_stages_not_loose_fields() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/episode/control.rs");
    let fields = control_loop_fields(&std::fs::read_to_string(path).unwrap());
    assert_eq!(loose_control_loop(&fields), None);
    // The guard sees a planted violation: the loop before issue 52, 24 loose fields.
    let loose: String = (0..24)
        .map(|k| format!("    /// Field {k}.\n    field_{k}: f64,\n"))
        .collect();
    let planted = control_loop_fields(&format!("pub struct ControlLoop {{\n{loose}}}\n"));
    assert_eq!(planted.len(), 24);
    assert!(loose_control_loop(&planted).is_some());
}

/// The keys of the tables declared `section` in `scenario_tables!` (scenario.rs).
fn section_keys(scenario_code: &str) -> Vec<String> {
    (scenario_code.lines().map(str::trim))
        .filter_map(|line| line.strip_prefix("section "))
        .filter_map(|rest| rest.split_once(':').map(|(key, _)| key.trim().to_string()))
        .collect()
}

/// The body of `fn name(` in `code` (to the first line that is a lone `}`).
fn function_body<'a>(code: &'a str, name: &str) -> &'a str {
    let Some(start) = code.find(&format!("fn {name}(")) else {
        return "";
    };
    let body = &code[start..];
    &body[..body.find("\n}\n").unwrap_or(body.len())]
}

/// Where the scenario's checks or the loop's configuration name a section's table directly
/// instead of going through `Section` (a table's checks and its part of the loop are its own).
fn sections_bypassed(scenario_code: &str, build_code: &str) -> Vec<String> {
    let mut found = Vec::new();
    for key in section_keys(scenario_code) {
        let access = format!("sc.{key}");
        let direct = |body: &str| {
            body.match_indices(&access)
                .any(|(i, _)| !body[i + access.len()..].starts_with(|c: char| c == '_' || c.is_alphanumeric()))
        };
        if direct(function_body(scenario_code, "validate")) {
            found.push(format!("scenario::validate reads `{access}`"));
        }
        if direct(function_body(build_code, "configure_control")) {
            found.push(format!("episode::build::configure_control reads `{access}`"));
        }
    }
    found
}

/// A scenario table is registered by one declaration: `scenario::validate` and the control
/// loop's configuration reach every section through `Section`, never by name.
#[test]
fn scenario_tables_are_reached_through_section() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let scenario = std::fs::read_to_string(root.join("src/scenario.rs")).unwrap();
    let build = std::fs::read_to_string(root.join("src/episode/build.rs")).unwrap();
    assert!(section_keys(&scenario).len() >= 12, "{:?}", section_keys(&scenario));
    assert_eq!(sections_bypassed(&scenario, &build), Vec::<String>::new());
    // The guard sees a planted violation: the sensor set by name, as before issue 52.
    let planted = build.replace(
        "fn configure_control(\n",
        "fn configure_control(\n    if let Some(sensing) = &sc.sensing {}\n",
    );
    assert_eq!(
        sections_bypassed(&scenario, &planted),
        ["episode::build::configure_control reads `sc.sensing`"]
    );
}
