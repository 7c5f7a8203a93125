//! Links MuJoCo 2.2.2 (Debian's package, or the one `MUJOCO_DIR` / `MUJOCO_LIB_DIR` names) and
//! compiles the log schema (proto/mjsafe.proto) with prost.
use std::path::{Path, PathBuf};

/// The library directories searched when no override is given (Debian's multiarch paths first).
const SYSTEM_LIB_DIRS: [&str; 4] = [
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib",
    "/usr/local/lib",
];

fn env_path(name: &str) -> Option<PathBuf> {
    println!("cargo:rerun-if-env-changed={name}");
    std::env::var_os(name).filter(|v| !v.is_empty()).map(PathBuf::from)
}

/// `mujoco.h` of `include_dir` must be 2.2.2's: src/mujoco/ffi.rs is generated from it.
fn check_header(include_dir: &Path, from: &str) {
    let header = include_dir.join("mujoco/mujoco.h");
    match std::fs::read_to_string(&header) {
        Ok(text) if text.contains("#define mjVERSION_HEADER 222") => {}
        Ok(_) => panic!(
            "{} ({from}) is not MuJoCo 2.2.2's (no `#define mjVERSION_HEADER 222`); \
             mjsafe's bindings (src/mujoco/ffi.rs) are generated from 2.2.2",
            header.display()
        ),
        Err(e) => panic!("{} ({from}): {e}", header.display()),
    }
}

fn main() {
    println!("cargo:rerun-if-changed=proto/mjsafe.proto");
    println!("cargo:rerun-if-changed=build.rs");

    // Overrides: MUJOCO_LIB_DIR / MUJOCO_INCLUDE_DIR name the directories, MUJOCO_DIR a prefix
    // holding lib/ and include/ (MuJoCo's release archive, a /opt install).
    let prefix = env_path("MUJOCO_DIR");
    let lib_override = env_path("MUJOCO_LIB_DIR")
        .map(|d| (d, "MUJOCO_LIB_DIR"))
        .or_else(|| prefix.as_ref().map(|p| (p.join("lib"), "MUJOCO_DIR")));
    let include_override = env_path("MUJOCO_INCLUDE_DIR")
        .map(|d| (d, "MUJOCO_INCLUDE_DIR"))
        .or_else(|| prefix.as_ref().map(|p| (p.join("include"), "MUJOCO_DIR")));

    let mut include_dir: Option<PathBuf> = None;
    match lib_override {
        Some((dir, from)) => {
            if !dir.join("libmujoco.so").exists() {
                panic!(
                    "{from}: {} holds no libmujoco.so (MuJoCo 2.2.2). Set MUJOCO_DIR to the prefix \
                     with lib/libmujoco.so and include/mujoco/mujoco.h, or MUJOCO_LIB_DIR to the \
                     library's directory",
                    dir.display()
                );
            }
            let include = include_override.unwrap_or_else(|| (dir.join("../include"), from));
            check_header(&include.0, include.1);
            include_dir = Some(include.0);
            println!("cargo:rustc-link-search=native={}", dir.display());
            // Found at run time without LD_LIBRARY_PATH.
            println!("cargo:rustc-link-arg=-Wl,-rpath,{}", dir.display());
            // For the crates that link this one (`links = "mujoco"`: DEP_MUJOCO_LIB_DIR), e.g.
            // the Python package's module, whose run path needs it too.
            println!("cargo:lib_dir={}", dir.display());
        }
        None => {
            if let Some((dir, from)) = include_override {
                check_header(&dir, from);
                include_dir = Some(dir);
            }
            let found = SYSTEM_LIB_DIRS
                .iter()
                .find(|dir| Path::new(dir).join("libmujoco.so").exists());
            match found {
                Some(dir) => println!("cargo:rustc-link-search=native={dir}"),
                None => panic!(
                    "libmujoco.so (MuJoCo 2.2.2) not found in {SYSTEM_LIB_DIRS:?}.\n\
                     Install Debian's package: apt-get install libmujoco-dev   (or run scripts/setup.sh),\n\
                     or point MUJOCO_DIR at a MuJoCo 2.2.2 prefix (lib/libmujoco.so, include/mujoco/mujoco.h)"
                ),
            }
        }
    }
    // mj_loadXML behind a C++ try/catch (src/mujoco/load_xml.cpp): no exception reaches Rust.
    println!("cargo:rerun-if-changed=src/mujoco/load_xml.cpp");
    let mut shim = cc::Build::new();
    shim.cpp(true).file("src/mujoco/load_xml.cpp").warnings(true);
    if let Some(dir) = &include_dir {
        shim.include(dir);
    }
    shim.compile("mjsafe_load_xml");
    // mj_step / mj_forward behind setjmp, and the mju_error handler that jumps back
    // (src/mujoco/guard.c): a MuJoCo error ends the run, not the process.
    println!("cargo:rerun-if-changed=src/mujoco/guard.c");
    let mut guard = cc::Build::new();
    guard.file("src/mujoco/guard.c").std("c11").warnings(true);
    if let Some(dir) = &include_dir {
        guard.include(dir);
    }
    guard.compile("mjsafe_guard");
    println!("cargo:rustc-link-lib=dylib=mujoco");

    let out_dir = std::env::var("OUT_DIR").expect("cargo sets OUT_DIR");
    let descriptor_path = Path::new(&out_dir).join("mjsafe_descriptor.bin");
    if let Err(e) = prost_build::Config::new()
        .file_descriptor_set_path(&descriptor_path)
        .compile_protos(&["proto/mjsafe.proto"], &["proto"])
    {
        panic!("compiling proto/mjsafe.proto failed: {e}\nprotoc comes from Debian's package protobuf-compiler (scripts/setup.sh installs it)");
    }
}
