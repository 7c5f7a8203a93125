//! Files a model names (`<include>`, meshes) are found from the model file's folder, whatever
//! the working directory.

mod common;
use common::*;

use std::path::Path;

/// A binary STL tetrahedron.
fn stl() -> Vec<u8> {
    let tris: [[[f32; 3]; 3]; 4] = [
        [[0., 0., 0.], [1., 0., 0.], [0., 1., 0.]],
        [[0., 0., 0.], [0., 1., 0.], [0., 0., 1.]],
        [[0., 0., 0.], [0., 0., 1.], [1., 0., 0.]],
        [[1., 0., 0.], [0., 0., 1.], [0., 1., 0.]],
    ];
    let mut b = vec![0u8; 80];
    b.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    for t in tris {
        b.extend_from_slice(&[0u8; 12]);
        for v in t {
            for c in v {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        b.extend_from_slice(&[0, 0]);
    }
    b
}

/// `dir/case/m.xml` (the bicycle with `extra` after its `<compiler>`) and `dir/case/s.toml`.
fn case(dir: &Path, extra: &str) -> std::path::PathBuf {
    let case = dir.join("case");
    std::fs::create_dir_all(case.join("sub")).unwrap();
    let model = std::fs::read_to_string(root().join("models/bicycle.xml")).unwrap();
    let compiler = r#"<compiler angle="radian"/>"#;
    assert!(model.contains(compiler));
    write(
        &case,
        "m.xml",
        &model.replace(compiler, &format!("{compiler}\n{extra}")),
    );
    let scenario = std::fs::read_to_string(scenario("bicycle_obstacle.toml")).unwrap();
    write(&case, "s.toml", &scenario.replace("../models/bicycle.xml", "m.xml"))
}

/// Runs the scenario by a path relative to the repository root (the working directory).
fn run(dir: &Path, scenario: &Path) -> std::process::Output {
    let relative = pathdiff(scenario);
    let out = dir.join("out.mcap");
    mjsafe(&[
        "run",
        &relative,
        "--set",
        "duration=0.5",
        "--out",
        out.to_str().unwrap(),
    ])
}

/// `path` relative to the repository root, through `..` (so the working directory differs).
fn pathdiff(path: &Path) -> String {
    let ups = root().components().count() - 1;
    let rel = path.strip_prefix("/").unwrap();
    format!("{}{}", "../".repeat(ups), rel.display())
}

#[test]
fn includes_and_meshes_are_found_from_the_model_folder() {
    let dir = tempfile::tempdir().unwrap();
    let s = case(
        dir.path(),
        r#"<include file="inc.xml"/><asset><mesh name="m" file="sub/part.stl"/></asset>"#,
    );
    write(&dir.path().join("case"), "inc.xml", "<mujoco><default/></mujoco>");
    std::fs::write(dir.path().join("case/sub/part.stl"), stl()).unwrap();
    let o = run(dir.path(), &s);
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    assert!(dir.path().join("out.mcap").is_file());
}

#[test]
fn a_missing_include_is_one_line_naming_the_model_and_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let s = case(dir.path(), r#"<include file="missing.xml"/>"#);
    let o = run(dir.path(), &s);
    let err = stderr(&o);
    assert!(!o.status.success());
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("m.xml") && err.contains("case/missing.xml"), "{err}");
    assert!(!dir.path().join("out.mcap").exists() && !dir.path().join("out.mcap.partial").exists());
}
