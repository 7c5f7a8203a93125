//! Links Debian's MuJoCo 2.2.2 and compiles the log schema (proto/mjsafe.proto) with prost.
use std::path::Path;

fn main() {
    println!("cargo:rerun-if-changed=proto/mjsafe.proto");
    println!("cargo:rerun-if-changed=build.rs");

    let lib_dirs = [
        "/usr/lib/x86_64-linux-gnu",
        "/usr/lib/aarch64-linux-gnu",
        "/usr/lib",
        "/usr/local/lib",
    ];
    let found = lib_dirs.iter().find(|dir| Path::new(dir).join("libmujoco.so").exists());
    match found {
        Some(dir) => println!("cargo:rustc-link-search=native={dir}"),
        None => panic!(
            "libmujoco.so (MuJoCo 2.2.2) not found in {lib_dirs:?}.\n\
             Install Debian's package: apt-get install libmujoco-dev   (or run scripts/setup.sh)"
        ),
    }
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
