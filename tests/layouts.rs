//! The same log in other valid MCAP layouts (issue 21), written by Python's `mcap` Writer:
//! LZ4, uncompressed and zstd chunks of other sizes, and the run metadata after the messages,
//! read the same as the original.

mod common;
use common::*;

use std::path::Path;

fn rewrite(src: &Path, dst: &Path, compression: &str, chunk_size: &str, metadata: &str) {
    let o = std::process::Command::new(python())
        .arg(root().join("tests/rewrite_log.py"))
        .args([src, dst])
        .args([compression, chunk_size, metadata])
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "rewrite failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// `analyze --json` of a log without the field naming the file.
fn metrics(file: &Path) -> serde_json::Value {
    let mut m = analyze_json(file);
    m.as_object_mut().unwrap().remove("file");
    m
}

#[test]
fn lz4_uncompressed_and_rechunked_logs_analyse_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let original = dir.path().join("original.mcap");
    run_ok(&scenario("bicycle_obstacle_gamma_m.toml"), &original, &[]);
    let expected = metrics(&original);
    for metadata in ["first", "last"] {
        for (compression, chunk_size) in [
            ("lz4", "1048576"),
            ("none", "65536"),
            ("zstd", "4096"),
            ("lz4", "300000"),
        ] {
            let copy = dir.path().join(format!("{compression}-{chunk_size}-{metadata}.mcap"));
            rewrite(&original, &copy, compression, chunk_size, metadata);
            assert_eq!(
                metrics(&copy),
                expected,
                "{compression} chunks of {chunk_size} bytes, metadata {metadata}"
            );
            let o = mjsafe(&["info", copy.to_str().unwrap()]);
            assert!(o.status.success(), "info {compression}: {}", stderr(&o));
            println!("{compression} chunks of {chunk_size} B, metadata {metadata}: same metrics");
        }
    }
    // A stream is read once: late metadata is an error there, never defaults.
    let late = dir.path().join("lz4-1048576-last.mcap");
    let o = std::process::Command::new("sh")
        .arg("-c")
        .arg(format!(
            "cat '{}' | '{}' analyze /dev/stdin",
            late.display(),
            env!("CARGO_BIN_EXE_mjsafe")
        ))
        .output()
        .unwrap();
    assert!(!o.status.success(), "{}", stdout(&o));
    assert!(stderr(&o).contains("comes after the messages"), "{}", stderr(&o));
}
