//! This crate's own tests and benches find MuJoCo's library where they were linked against it (an rpath
//! to `MUJOCO_DYNAMIC_LINK_DIR`), as the binary does (the root's build.rs).

fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    if std::env::var_os("CARGO_FEATURE_PHYSICS").is_none() {
        return;
    }
    if let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
        println!("cargo::rustc-link-arg-tests=-Wl,-rpath,{dir}");
        println!("cargo::rustc-link-arg-benches=-Wl,-rpath,{dir}");
    }
}
