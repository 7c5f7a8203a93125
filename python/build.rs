//! The module finds a MuJoCo installed outside the system's library directories (the root
//! crate's `MUJOCO_DIR` / `MUJOCO_LIB_DIR`) at run time: its directory becomes the module's run
//! path, as it is the `mjsafe` binary's (link arguments of a dependency's build script do not
//! reach a dependent's link).
fn main() {
    println!("cargo:rerun-if-env-changed=DEP_MUJOCO_LIB_DIR");
    if let Some(dir) = std::env::var_os("DEP_MUJOCO_LIB_DIR").filter(|d| !d.is_empty()) {
        println!(
            "cargo:rustc-link-arg=-Wl,-rpath,{}",
            std::path::Path::new(&dir).display()
        );
    }
}
